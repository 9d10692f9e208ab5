"""The safe exit (flight/safe_exit.py), without a mission: what the plan still held at the abort,
the hand-over to the pilot (and a hold command that fails too), and nothing flown while a failsafe
has the vehicle, before it took off, or once it is on the ground. The routes flown out are
tests/test_safe_abort.py's.

Reference: the plan's items counted and the exploration left measured here with numpy.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from insulator_rs.exceptions import VehicleError, VehicleFailsafe
from insulator_rs.flight.safe_exit import SafeExit
from insulator_rs.mission.state_machine import PlanItem
from insulator_rs.planning.exploration import PlanKind
from insulator_rs.planning.waypoints import InspectionWaypoint


class Pilot:
    def __init__(self, *, landed=False, airborne=True, failsafe=None, hold_fails=False):
        self.failsafe, self.airborne = failsafe, airborne
        self.held, self.hold_fails = 0, hold_fails
        self.vehicle = SimpleNamespace(state=lambda: SimpleNamespace(landed=landed), hold=self._hold)
        self.sm = SimpleNamespace(plan=[], deferred={})
        self.said: list[str] = []
        self.summaries = 0

    def _hold(self):
        self.held += 1
        if self.hold_fails:
            raise VehicleError("no COMMAND_ACK for DO_SET_MODE")

    def say(self, text):
        self.said.append(text)

    def now(self):
        return 12.0

    def write_summary(self):
        self.summaries += 1


class Observer:
    def __init__(self):
        self.handed: list[tuple[float, str]] = []

    def handed_over(self, time_s, reason):
        self.handed.append((time_s, reason))


def _exit(pilot, insulators=()):
    registry = SimpleNamespace(insulators=list(insulators))
    return SafeExit(pilot, geom=None, registry=registry, v_max=np.ones(3), a_max=np.ones(3), crossing_clearance=3.0,
                    observer=Observer(), seen=lambda: None)


def _wp(side):
    return InspectionWaypoint(np.zeros(3), 0.0, 0.0, np.zeros(3), 1, side)


def test_what_the_plan_still_held_is_noted():
    pilot = Pilot()
    scan = [np.array([0.0, 0.0, 6.0]), np.array([3.0, 4.0, 6.0]), np.array([3.0, 4.0, 18.0])]
    pilot.sm.plan = [PlanItem(PlanKind.INSPECT, np.zeros(3), 0.0, 1, _wp(1)),
                     PlanItem(PlanKind.SCAN, scan[0], 0.0, 1), PlanItem(PlanKind.SCAN, scan[1], 0.0, 1),
                     PlanItem(PlanKind.CROSS, scan[2], 0.0, 0), PlanItem(PlanKind.LAND, np.zeros(3), 0.0, -1)]
    pilot.sm.deferred = {-1: [_wp(-1), _wp(-1)]}
    found = [SimpleNamespace(id=1, inspected=True), SimpleNamespace(id=2, inspected=False)]
    exit_ = _exit(pilot, found)
    exit_.note_what_is_left()
    length = float(np.linalg.norm(scan[1] - scan[0]) + np.linalg.norm(scan[2] - scan[1]))
    assert exit_.left == {"insulators_uninspected": [2], "inspection_waypoints": 3, "exploration_waypoints": 3,
                          "exploration_left_m": length}


def test_the_hand_over_holds_and_tells_the_pilot():
    pilot = Pilot()
    exit_ = _exit(pilot)
    exit_.hand_over("no safe route to land: boxed in")
    assert pilot.held == 1 and exit_.handed_over == "no safe route to land: boxed in"
    assert exit_.observer.handed == [(12.0, "no safe route to land: boxed in")]
    assert pilot.summaries == 1 and any("holding for the pilot" in s for s in pilot.said)


def test_a_hold_command_that_fails_is_said_in_the_hand_over():
    pilot = Pilot(hold_fails=True)
    exit_ = _exit(pilot)
    exit_.hand_over("no safe route to land")
    assert exit_.handed_over == ("no safe route to land; the hold command failed too: "
                                 "no COMMAND_ACK for DO_SET_MODE")


def test_nothing_is_flown_under_a_failsafe_before_take_off_or_on_the_ground():
    for pilot in (Pilot(failsafe=VehicleFailsafe("link lost", "RTL")), Pilot(airborne=False), Pilot(landed=True)):
        exit_ = _exit(pilot)
        exit_.leave()  # geom is None: any planning would fail loudly
        assert exit_.route is None and exit_.handed_over is None and pilot.held == 0
