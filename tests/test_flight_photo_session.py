"""The photo session (flight/photo_session.py), without a mission: the settle rule (heading within
PHOTO_YAW_TOLERANCE, speed under PHOTO_SPEED_TOLERANCE, held ``hold`` s, or PHOTO_SETTLE_TIMEOUT),
the retake rule (1 + ``photo_retakes`` shots while unfit, with an inspection camera only) and a
photo the camera does not deliver (said, counted as a sensor error where the sensors raised, no
record). The vehicle is a scripted pilot: each tick hands out the next state.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from insulator_rs.exceptions import SensorError
from insulator_rs.flight.photo_session import (PHOTO_SETTLE_TIMEOUT, PHOTO_SPEED_TOLERANCE, PHOTO_YAW_TOLERANCE,
                                               PhotoSession, settle)
from insulator_rs.flight.pilot import CONTROL_PERIOD
from insulator_rs.mission.state_machine import State
from insulator_rs.perception.photo_check import PhotoCheck
from insulator_rs.perception.photo_verdict import PhotoVerdict, Reason
from insulator_rs.planning.waypoints import InspectionWaypoint
from insulator_rs.ports.vehicle import VehicleState

WP = InspectionWaypoint(np.array([1.0, 2.0, 8.0]), 0.5, -0.2, np.array([1.0, 8.0, 9.0]), 3, 1)


class ScriptedPilot:
    """Tick k hands out ``script(k)``; ``abort_at``: the tick the state machine aborts at."""

    def __init__(self, script, abort_at=None):
        self.script, self.abort_at, self.ticks = script, abort_at, 0
        self.sm = SimpleNamespace(state=State.INSPECT)
        self.vehicle = SimpleNamespace(state=lambda: self.script(self.ticks))
        self.said: list[str] = []
        self.summaries = 0

    def tick(self, position, velocity, yaw):
        self.ticks += 1
        if self.abort_at is not None and self.ticks >= self.abort_at:
            self.sm.state = State.ABORT
        return self.script(self.ticks)

    def say(self, text):
        self.said.append(text)

    def now(self):
        return self.ticks * CONTROL_PERIOD

    def write_summary(self):
        self.summaries += 1


def _state(k, *, yaw=WP.yaw, speed=0.0):
    return VehicleState(time=k * CONTROL_PERIOD, position=WP.position.copy(), velocity=np.array([speed, 0.0, 0.0]),
                        yaw=yaw, armed=True, mode="OFFBOARD", landed=False)


def test_settled_once_heading_and_speed_are_within_tolerance_and_held():
    # braking and turning for 20 ticks, then still and on heading
    def script(k):
        return _state(k, yaw=WP.yaw + 2 * PHOTO_YAW_TOLERANCE, speed=0.5) if k < 20 else _state(k)

    st = settle(ScriptedPilot(script), WP, 0.0)
    assert st is not None and st.time == pytest.approx(20 * CONTROL_PERIOD)
    st = settle(ScriptedPilot(script), WP, 2.0)  # held 2 s from the start: settled long before
    assert st is not None and st.time == pytest.approx(2.0)


def test_the_tolerances_are_strict_bounds():
    at_bounds = ScriptedPilot(lambda k: _state(k, yaw=WP.yaw + PHOTO_YAW_TOLERANCE, speed=PHOTO_SPEED_TOLERANCE))
    st = settle(at_bounds, WP, 0.0)
    assert st is not None and st.time > PHOTO_SETTLE_TIMEOUT  # never settled: the timeout let it go


def test_a_vehicle_that_never_settles_is_let_go_at_the_timeout():
    st = settle(ScriptedPilot(lambda k: _state(k, speed=1.0)), WP, 0.0)
    assert st is not None
    assert PHOTO_SETTLE_TIMEOUT < st.time <= PHOTO_SETTLE_TIMEOUT + CONTROL_PERIOD + 1e-9


def test_an_abort_while_settling_gives_no_state():
    assert settle(ScriptedPilot(lambda k: _state(k, speed=1.0), abort_at=5), WP, 0.0) is None


class _Photos:
    """The photos' record as the session writes it: no photo is saved in these tests, only why
    a photo asked for gave none (per insulator)."""

    def __init__(self):
        self.records = []
        self.failures = {}

    def missing(self, insulator_id, why):
        self.failures.setdefault(insulator_id, []).append(why)


def _session(pilot, *, inspection, sensors=None, retakes=2, cls=PhotoSession):
    rig = SimpleNamespace(inspection=inspection, camera=SimpleNamespace(height=480, fy=400.0), T_b_c=np.eye(4))
    errors: list[SensorError] = []
    session = cls(pilot, SimpleNamespace(), sensors=sensors, rig=rig, detector=None,
                           registry=SimpleNamespace(insulators=[]), photos=_Photos(),
                           params=SimpleNamespace(photo_retakes=retakes, insulator_length=2.0),
                           observer=None, on_sensor_error=errors.append)
    return session, errors


class Scripted(PhotoSession):
    """Every shot's check from ``checks`` in turn (the shot itself is the real session's job)."""

    def shoot(self, wp, attempt):
        self.attempts.append(attempt)
        return self.checks.pop(0)


def _scripted(pilot, checks, *, inspection, retakes=2):
    session, _ = _session(pilot, inspection=inspection, retakes=retakes, cls=Scripted)
    session.attempts, session.checks = [], list(checks)
    return session


def _check(fit):
    return PhotoCheck(PhotoVerdict.passed() if fit else PhotoVerdict.unfit([Reason.CUT], "cut at the top"))


def test_an_unfit_photo_is_retaken_up_to_the_limit_with_an_inspection_camera():
    pilot = ScriptedPilot(_state)
    session = _scripted(pilot, [_check(False)] * 3, inspection=object())
    session.take_photo(WP)
    assert session.attempts == [1, 2, 3]
    assert sum("retake" in s for s in pilot.said) == 2
    session = _scripted(pilot, [_check(False), _check(True), _check(False)], inspection=object())
    session.take_photo(WP)
    assert session.attempts == [1, 2]  # fit at the second: no more


def test_without_an_inspection_camera_an_unfit_photo_is_kept_not_retaken():
    session = _scripted(ScriptedPilot(_state), [_check(False)] * 3, inspection=None)
    session.take_photo(WP)
    assert session.attempts == [1]


def test_no_image_from_the_camera_is_said_and_nothing_is_recorded():
    class NoPhoto:
        def photo(self, now, T_b_c, camera=None):
            return None

    class Failing:
        def photo(self, now, T_b_c, camera=None):
            raise SensorError("camera unplugged")

    for sensors, errors_expected in ((NoPhoto(), 0), (Failing(), 1)):
        pilot = ScriptedPilot(_state)
        session, errors = _session(pilot, inspection=None, sensors=sensors)
        assert session.shoot(WP, 1) is None
        assert len(errors) == errors_expected
        assert session.photos.records == [] and pilot.summaries == 0
        assert any("photo of insulator 3: no image from the camera" in s for s in pilot.said)
        assert session.photos.failures == {3: ["no image from the camera"]}  # the summary says why


def test_the_sensors_reason_for_a_missing_photo_is_said_and_kept_for_the_insulator():
    class PayloadFailing:
        def photo(self, now, T_b_c, camera=None):
            return None

        def photo_failure(self):
            return "payload: zoom_refused (attempt 1)"

    pilot = ScriptedPilot(_state)
    session, _ = _session(pilot, inspection=None, sensors=PayloadFailing())
    assert session.shoot(WP, 1) is None
    assert session.photos.failures == {3: ["payload: zoom_refused (attempt 1)"]}
    assert any("photo of insulator 3: payload: zoom_refused (attempt 1)" in s for s in pilot.said)


def test_the_photos_field_of_view_frames_the_waypoints():
    session, _ = _session(ScriptedPilot(_state), inspection=None)
    assert session.fov == pytest.approx(2 * math.atan(240 / 400.0))
