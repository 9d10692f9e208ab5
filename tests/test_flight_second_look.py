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
from insulator_rs.flight.energy_budget import EnergyBudget
from insulator_rs.flight.reserve import ESTIMATE_MARGIN, ReserveEstimate
from insulator_rs.flight import second_look
from insulator_rs.flight.pilot import CONTROL_PERIOD
from insulator_rs.flight.second_look import REFUSED_TRACK_MIN_CONFIDENT, SecondLookFlight
from insulator_rs.mission.config import load_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import PlanItem, State
from insulator_rs.perception.pairing import PAIRING_WAIT
from insulator_rs.planning.energy import ConsumptionFit, RouteDemand, route_demand
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


def _energy(geom, *, available=None, needed_finish=0.0):
    """The mission's energy budget; with ``available``, as weighed once: a pack that uses 0.1 %
    a second hovering and 0.01 % a metre (a 1000 s hover), ``available`` above the reserve and
    ``needed_finish`` for the rest of the plan."""
    energy = EnergyBudget(geom, v_max=np.array([3.0, 3.0, 1.5]), a_max=np.array([2.0, 2.0, 1.0]), reserve=0.25,
                          crossing_clearance=3.0, way_out=lambda here: None)
    if available is not None:
        fit = ConsumptionFit(per_s=0.001, per_m=0.0001, start=1.0, samples=100, span_s=100.0, rms=0.0)
        energy.battery.estimate = ReserveEstimate(
            time_s=100.0, fraction=0.25 + available, available=available, needed_finish=needed_finish,
            needed_return=0.01, rest_of_plan=RouteDemand(0.0, 0.0), way_out=RouteDemand(0.0, 0.0), fit=fit)
    return energy


def _looks(pilot, runner, parts, registry=None, energy=None):
    mission, geom = parts
    registry = registry or SimpleNamespace(candidates=[], insulators=[], gate=1.0)
    return SecondLookFlight(pilot, legs=None, registry=registry, runner=runner, geom=geom, mission=mission,
                            detect_period=0.5, energy=energy or _energy(geom))


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


def _views(center, line, volumes, *, min_height):
    return [(np.array([7.0, 3.0, 8.0]), 0.0), (np.array([7.0, 6.5, 8.0]), 0.0)]


@pytest.mark.parametrize("spare_s", [-5.0, 5.0])
def test_a_look_the_battery_cannot_spare_is_recorded_as_not_flown(parts, monkeypatch, spare_s):
    """The look's cost (there through its views and back, each view's settle and watch at their
    limits, with the reserve's ESTIMATE_MARGIN) against what the latest weighing leaves after the
    rest of the plan: short by 5 s of hover, not flown and said why; 5 s to spare, flown."""
    monkeypatch.setattr(second_look, "look_viewpoints", _views)
    monkeypatch.setattr(SecondLookFlight, "watch_from", lambda self, view, candidate, version: None)
    mission, geom = parts
    pilot = Pilot()
    candidate = Insulator(id=0, center=np.array([0.0, 3.0, 10.0]), axis=np.zeros(3), observations=2, side=1)
    probe = _looks(pilot, Runner(pilot, lag=0.0), parts)
    views = [p for p, _ in _views(None, None, None, min_height=0.0)]
    demand = route_demand(np.vstack([np.zeros(3), *views, np.zeros(3)]), probe.energy.limits[0],
                          probe.energy.limits[1], stops=2, stop_time=probe.view_time(candidate))
    fit = ConsumptionFit(per_s=0.001, per_m=0.0001, start=1.0, samples=100, span_s=100.0, rms=0.0)
    cost = ESTIMATE_MARGIN * fit.consumed(demand.time_s, demand.distance_m)
    energy = _energy(geom, available=0.30, needed_finish=0.30 - cost - ESTIMATE_MARGIN * fit.per_s * spare_s)
    looks = _looks(pilot, Runner(pilot, lag=0.0), parts, energy=energy)
    looks.look(candidate)
    record = looks.looks[-1].as_record()
    if spare_s < 0:
        assert record["note"].startswith("not flown: the battery keeps it for the plan (short by 0.6%)"), record
        assert record["views"] == 0 and "the battery keeps 0.6% too little" in pilot.said[-1]
    else:
        assert record["note"] is None and record["views"] == 2, record


def test_a_look_before_the_first_weighing_is_flown(parts, monkeypatch):
    """No consumption fit yet (the first minutes, or a vehicle reporting no charge): the look
    is flown, as the reserve's own check waits for a fit too."""
    monkeypatch.setattr(second_look, "look_viewpoints", _views)
    monkeypatch.setattr(SecondLookFlight, "watch_from", lambda self, view, candidate, version: None)
    pilot = Pilot()
    looks = _looks(pilot, Runner(pilot, lag=0.0), parts)
    assert looks.energy.battery.estimate is None
    looks.look(Insulator(id=0, center=np.array([0.0, 3.0, 10.0]), axis=np.zeros(3), observations=2, side=1))
    assert looks.looks[-1].as_record()["views"] == 2
