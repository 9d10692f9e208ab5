"""The second look as a behaviour (flight/second_look.py ``SecondLookFlight``), without a mission:
where the search ends the vehicle hovers until perception has handed on the frames taken up to
its arrival (at most the pairing window + PAIRING_WAIT), once per item; a refused track is looked
at through one record for all calls, not when anchored on a known string; a look with no clear
viewpoint is recorded as not flown. The choice of candidate and the viewpoints are
tests/test_second_look.py's; the looks flown, its missions'.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from helpers.flights import small_scene

from insulator_rs.exceptions import PlanningError
from insulator_rs.flight import second_look
from insulator_rs.flight.pilot import CONTROL_PERIOD
from insulator_rs.flight.second_look import REFUSED_TRACK_MIN_CONFIDENT, SecondLookFlight
from insulator_rs.mission.config import load_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import PlanItem, State
from insulator_rs.perception.pairing import PAIRING_WAIT
from insulator_rs.planning.exploration import PlanKind
from insulator_rs.tracking.registry import Insulator

PAIRING_WINDOW = 0.3


class Pilot:
    """Hovers in vehicle time; the state machine says where the head stands."""

    def __init__(self, *, ends_search=False, ends_side=False):
        self.time = 10.0
        self.ticks: list[np.ndarray] = []
        self.sm = SimpleNamespace(state=State.EXPLORE, plan_version=0, head_ends_search=lambda: ends_search,
                                  head_ends_side=lambda: ends_side)
        self.vehicle = SimpleNamespace(state=lambda: SimpleNamespace(time=self.time, position=np.zeros(3)))
        self.said: list[str] = []

    def tick(self, position, velocity, yaw):
        self.ticks.append(np.array(position))
        self.time += CONTROL_PERIOD
        return self.vehicle.state()

    def say(self, text):
        self.said.append(text)

    def now(self):
        return self.time

    def healthy(self):
        return True


class Runner:
    """Perception that catches up with ``arrival`` after ``lag`` s (None: never)."""

    def __init__(self, pilot, *, lag=None, tracks=()):
        self.pilot, self.lag, self.tracks = pilot, lag, list(tracks)
        self.pipeline = SimpleNamespace(pairing_window=PAIRING_WINDOW, refused_tracks=self._refused)
        self.asked: list[int] = []
        self.start = pilot.time

    def caught_up(self, time):
        return self.lag is not None and self.pilot.time >= self.start + self.lag

    def _refused(self, min_confident):
        self.asked.append(min_confident)
        return list(self.tracks)


@pytest.fixture
def parts(tmp_path):
    mission = load_mission(small_scene(tmp_path)[1])
    return mission, MissionGeometry.from_mission(mission)


def _looks(pilot, runner, parts, registry=None):
    mission, geom = parts
    registry = registry or SimpleNamespace(candidates=[], insulators=[], gate=1.0)
    return SecondLookFlight(pilot, legs=None, registry=registry, runner=runner, geom=geom, mission=mission,
                            detect_period=0.5)


ITEM = PlanItem(PlanKind.CROSS, np.array([0.0, 0.0, 20.0]), 0.0, 0)


def test_nothing_is_held_where_neither_the_search_nor_a_side_ends(parts):
    pilot = Pilot()
    runner = Runner(pilot)
    assert _looks(pilot, runner, parts).may_end(ITEM)
    assert pilot.ticks == [] and runner.asked == []


def test_the_vehicle_hovers_where_the_search_ends_until_perception_caught_up_once_per_item(parts):
    pilot = Pilot(ends_search=True)
    runner = Runner(pilot, lag=0.2)
    looks = _looks(pilot, runner, parts)
    assert not looks.may_end(ITEM)  # re-plan from there: a find of those frames comes first
    assert len(pilot.ticks) == 4 and all(np.array_equal(p, ITEM.position) for p in pilot.ticks)
    assert looks.may_end(ITEM)  # caught up, nothing to look at: on
    assert len(pilot.ticks) == 4
    assert runner.asked == [REFUSED_TRACK_MIN_CONFIDENT]


def test_the_hover_ends_at_the_pairing_window_and_wait_when_perception_never_catches_up(parts):
    pilot = Pilot(ends_search=True)
    looks = _looks(pilot, Runner(pilot, lag=None), parts)
    start = pilot.time
    assert not looks.may_end(ITEM)
    waited = pilot.time - start
    limit = PAIRING_WINDOW + PAIRING_WAIT + CONTROL_PERIOD
    assert limit <= waited + 1e-9 < limit + CONTROL_PERIOD


def _track(anchor, confident):
    return SimpleNamespace(anchor=np.array(anchor, float), evidence=SimpleNamespace(confident_boxes=confident))


def test_a_refused_track_has_one_record_for_all_calls_and_none_on_a_known_string(parts):
    mission, geom = parts
    known = Insulator(id=1, center=np.array([0.0, 3.0, 10.0]), axis=np.array([0.0, 0.0, 1.0]), observations=5,
                      side=1)
    on_known = _track([0.0, 3.2, 10.8], 9)  # on the known string's segment: its steel seen
    weak, strong = _track([1.0, -3.0, 9.0], 3), _track([-1.0, -3.0, 11.0], 5)
    pilot = Pilot()
    registry = SimpleNamespace(candidates=[], insulators=[known], gate=1.0)
    looks = _looks(pilot, Runner(pilot, tracks=[weak, on_known, strong]), parts, registry)
    first = looks.refused_candidates()
    assert [c.center.tolist() for c in first] == [strong.anchor.tolist(), weak.anchor.tolist()]
    assert all(c.id == 0 and c.observations == 0 and c.side == geom.line.side(c.center) for c in first)
    again = looks.refused_candidates()
    assert all(a is b for a, b in zip(first, again))  # what has been looked at stays known


def test_a_look_with_no_clear_viewpoint_is_recorded_as_not_flown(parts, monkeypatch):
    def boxed_in(center, line, volumes, *, min_height):
        raise PlanningError("no viewpoint clear of the safety volumes")

    monkeypatch.setattr(second_look, "look_viewpoints", boxed_in)
    pilot = Pilot()
    looks = _looks(pilot, Runner(pilot), parts)
    candidate = Insulator(id=0, center=np.array([0.0, 3.0, 10.0]), axis=np.zeros(3), observations=2, side=1)
    looks.look(candidate)
    assert pilot.ticks == []
    record = looks.looks[-1].as_record()
    assert record["note"] == "not flown: no viewpoint clear of the safety volumes"
    assert record["observations_before"] == record["observations_after"] == 2 and not record["confirmed"]
    assert record["views"] == 0 and record["source"] == "candidate"
