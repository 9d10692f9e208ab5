"""The abort policy (flight/abort_policy.py), without a mission: the operator's request, the
flight-time limit, the camera silent for SENSOR_LOST_TIMEOUT s (counted from the mission's start,
not while flying home), and the HOLD that resumes when the vehicle is back in offboard or aborts
after HOLD_TIMEOUT s. The checks are made in that order: the first reason given is the first rule.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from insulator_rs.flight.abort_policy import HOLD_TIMEOUT, SENSOR_LOST_TIMEOUT, AbortPolicy
from insulator_rs.flight.pilot import CONTROL_PERIOD
from insulator_rs.mission.state_machine import State
from insulator_rs.ports.vehicle import VehicleState


def _state(t, *, mode="OFFBOARD", healthy=True):
    return VehicleState(time=t, position=np.zeros(3), velocity=np.zeros(3), yaw=0.0, armed=True, mode=mode,
                        landed=False, healthy=healthy)


class Runner:
    def __init__(self):
        self.counts = SimpleNamespace(frames=0)

    def lost(self, now, timeout):
        return None


def _policy(state=State.EXPLORE, max_flight_time=600.0):
    sm = SimpleNamespace(state=state, plan=[], deferred={})
    pilot = SimpleNamespace(sm=sm)
    energy = SimpleNamespace(check=lambda st, t, plan, deferred: None)
    runner = Runner()
    return AbortPolicy(pilot, runner, energy, max_flight_time=max_flight_time), runner, sm


def test_the_operator_and_the_flight_time_limit():
    policy, _, _ = _policy(max_flight_time=100.0)
    policy.started(0.0)
    assert policy.due(_state(1.0), 100.0) is None
    assert policy.due(_state(1.0), 100.1) == "flight time limit of 100 s"
    policy.request("operator abort")
    assert policy.due(_state(1.0), 100.1) == "operator abort"  # the operator's first


def test_a_silent_camera_aborts_after_the_timeout_from_the_start_and_not_on_the_way_home():
    policy, runner, sm = _policy()
    policy.started(50.0)
    assert policy.due(_state(50.0 + SENSOR_LOST_TIMEOUT), 1.0) is None
    runner.counts.frames = 1  # a frame: the silence starts again
    assert policy.due(_state(55.0), 1.0) is None
    assert policy.due(_state(55.0 + SENSOR_LOST_TIMEOUT), 1.0) is None
    reason = policy.due(_state(55.0 + SENSOR_LOST_TIMEOUT + 0.1), 1.0)
    assert reason == f"sensor lost: no camera frame for {SENSOR_LOST_TIMEOUT:.0f} s"
    sm.state = State.FINISH  # on the way home perception is over
    assert policy.due(_state(200.0), 1.0) is None


class HoldPilot:
    """A vehicle out of offboard that comes back (``back_at`` s) or not; the abort is noted."""

    def __init__(self, back_at=None):
        self.time, self.back_at = 0.0, back_at
        self.sm = SimpleNamespace(state=State.HOLD, resume=self._resume)
        self.offboard_asked = 0
        self.aborted: list[tuple[str, float]] = []
        self.vehicle = SimpleNamespace(state=self._now, start_offboard=self._ask)

    def _now(self):
        back = self.back_at is not None and self.time >= self.back_at
        return _state(self.time, mode="OFFBOARD" if back and self.offboard_asked else "POSCTL")

    def _ask(self):
        self.offboard_asked += 1

    def _resume(self, time):
        self.sm.state = State.EXPLORE

    def tick(self, position, velocity, yaw):
        self.time += CONTROL_PERIOD
        return self._now()

    def abort(self, reason, time=None):
        self.aborted.append((reason, time))
        self.sm.state = State.ABORT

    def say(self, text):
        pass

    def now(self):
        return self.time


def _hold(pilot):
    AbortPolicy(pilot, Runner(), SimpleNamespace(), max_flight_time=600.0).hold()


def test_a_hold_resumes_once_the_vehicle_is_back_in_offboard():
    pilot = HoldPilot(back_at=2.0)
    _hold(pilot)
    assert pilot.sm.state == State.EXPLORE and not pilot.aborted
    assert 2.0 <= pilot.time < 2.0 + 2 * CONTROL_PERIOD


def test_a_fault_that_does_not_clear_aborts_after_the_hold_timeout():
    pilot = HoldPilot(back_at=None)
    _hold(pilot)
    assert pilot.sm.state == State.ABORT and pilot.offboard_asked > 0
    (reason, time), = pilot.aborted
    assert reason == f"fault did not clear within {HOLD_TIMEOUT:.0f} s"
    assert HOLD_TIMEOUT < time <= HOLD_TIMEOUT + CONTROL_PERIOD + 1e-9
