"""The autopilot session (flight/autopilot_session.py), without a mission: the tower's PX4
parameters set on a vehicle that has a parameter store (and nothing on one without), restored
once the vehicle is on the ground and kept while it still flies; the take-off and the landing of
the in-process vehicle.

Reference: the store's own values before and after (a dict standing for PX4's parameters), the
settings :func:`~insulator_rs.planning.px4_failsafes.tower_failsafe_parameters` gives for the small
scene, the in-process vehicle's reported state.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from helpers.flights import small_scene

from insulator_rs.exceptions import VehicleFailsafe
from insulator_rs.flight.autopilot_session import AutopilotSession
from insulator_rs.flight.pilot import CONTROL_PERIOD
from insulator_rs.mission.config import load_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import State
from insulator_rs.planning.exploration import MIN_PASS_HEIGHT
from insulator_rs.planning.px4_failsafes import tower_failsafe_parameters
from insulator_rs.ports.vehicle import FlightMode, VehicleState
from insulator_rs.report import FlightClock
from insulator_rs.sim.kinematics import KinematicVehicle


class DictStore:
    """PX4's parameters as a dict: every read and set answered and verified."""

    def __init__(self, values, *, gcs=True):
        self.values, self.gcs, self.sets = dict(values), gcs, []

    def read(self, name):
        return self.values[name]

    def set(self, name, value):
        self.sets.append(name)
        self.values[name] = value
        return value

    def ground_station(self, wait):
        return self.gcs


class Pilot:
    """The loop's view reduced to the vehicle and the bookkeeping the session writes."""

    def __init__(self, vehicle):
        self.vehicle = vehicle
        self.sm = SimpleNamespace(state=State.IDLE)
        self.t_start, self.clock, self.airborne = 0.0, FlightClock(0.0), False
        self.failsafe, self.abort_reason = None, None
        self.said: list[str] = []
        self.summaries = 0

    def tick(self, position, velocity, yaw):
        self.vehicle.send_setpoint(position, velocity, yaw)
        return self.vehicle.advance(CONTROL_PERIOD)

    def say(self, text):
        self.said.append(text)

    def now(self):
        return self.vehicle.state().time - self.t_start

    def write_summary(self):
        self.summaries += 1

    def on_failsafe(self, exc):
        self.failsafe = exc


@pytest.fixture
def geom(tmp_path):
    return MissionGeometry.from_mission(load_mission(small_scene(tmp_path)[1]))


def _session(pilot, geom, poses=None, observed=None):
    energy = SimpleNamespace(observe=lambda st: observed.append(st) if observed is not None else None)
    return AutopilotSession(pilot, geom, sensors=None, detector=None, crossing_clearance=3.0, battery_reserve=0.25,
                            observer=None, energy=energy,
                            log_pose=lambda st: poses.append(st) if poses is not None else None)


def _px4_defaults(settings):
    return {**{s.name: -1 for s in settings}, "RTL_RETURN_ALT": 60.0}


def _settings(geom, vehicle, *, gcs=True):
    return tower_failsafe_parameters(geom.volumes, vehicle.state().position, geom.path_points(),
                                     crossing_clearance=3.0, ground_station=gcs, vehicle_return_alt=60.0)


def test_a_vehicle_without_parameters_gets_none_set(geom):
    session = _session(Pilot(KinematicVehicle(start_position=geom.takeoff)), geom)
    session.configure()
    assert session.setup is None
    session.restore()  # nothing to put back


class ParamVehicle(SimpleNamespace):
    """A vehicle with a parameter store, on the ground or in the air as scripted."""

    def state(self):
        return self.states[min(self.k, len(self.states) - 1)]

    def advance(self, dt):
        self.k += 1
        return self.state()


def _at(t, *, landed, mode):
    return VehicleState(time=t, position=np.zeros(3), velocity=np.zeros(3), yaw=0.0, armed=not landed, mode=mode,
                        landed=landed)


def test_the_towers_values_are_set_then_put_back_on_the_ground(geom):
    vehicle = ParamVehicle(states=[_at(0.0, landed=True, mode="HOLD")], k=0)
    settings = _settings(geom, vehicle)
    old = _px4_defaults(settings)
    vehicle.parameters = DictStore(old)
    pilot = Pilot(vehicle)
    session = _session(pilot, geom)
    session.configure()
    assert session.setup is not None and session.setup.pending
    for s in settings:
        assert vehicle.parameters.values[s.name] == s.value
    assert any(text.startswith("autopilot parameters set and verified: ") for text in pilot.said)
    session.restore()
    assert vehicle.parameters.values == old
    assert session.setup.restore_status == "restored" and not session.setup.pending


def test_the_restore_waits_for_px4s_own_landing_and_logs_it(geom):
    states = [_at(t, landed=False, mode="RTL") for t in (0.0, 1.0, 2.0)] + [_at(3.0, landed=True, mode="LAND")]
    vehicle = ParamVehicle(states=states, k=0)
    vehicle.parameters = DictStore(_px4_defaults(_settings(geom, vehicle)))
    poses: list[VehicleState] = []
    session = _session(Pilot(vehicle), geom, poses)
    session.configure()
    session.restore()
    assert session.setup.restore_status == "restored"
    assert [st.time for st in poses] == [1.0, 2.0, 3.0]


def test_a_vehicle_still_holding_in_the_air_keeps_the_towers_values(geom):
    vehicle = ParamVehicle(states=[_at(0.0, landed=False, mode="HOLD")], k=0)
    settings = _settings(geom, vehicle)
    vehicle.parameters = DictStore(_px4_defaults(settings))
    session = _session(Pilot(vehicle), geom)
    session.configure()
    session.restore()
    assert session.setup.restore_status == "not restored: the vehicle is still in the air (mode HOLD): " \
                                           "the tower's values stay set"
    assert vehicle.k == 0  # a hover is someone's to end: not waited for
    for s in settings:
        assert vehicle.parameters.values[s.name] == s.value


def test_take_off_climbs_to_the_first_pass_height_in_offboard_and_anchors_the_clock(geom):
    vehicle = KinematicVehicle(start_position=geom.takeoff)
    pilot = Pilot(vehicle)
    pilot.sm.state = State.EXPLORE
    t0 = vehicle.state().time
    assert _session(pilot, geom).take_off()
    st = vehicle.state()
    assert pilot.airborne and pilot.t_start == t0 and pilot.clock.vehicle_time == t0
    assert st.armed and st.mode == FlightMode.OFFBOARD.value
    assert st.position[2] - geom.takeoff[2] == pytest.approx(MIN_PASS_HEIGHT, abs=0.4)


def test_landing_descends_to_the_ground_and_feeds_the_pose_log_and_the_battery(geom):
    vehicle = KinematicVehicle(start_position=geom.takeoff)
    pilot = Pilot(vehicle)
    poses: list[VehicleState] = []
    observed: list[VehicleState] = []
    session = _session(pilot, geom, poses, observed)
    session.land()  # never took off: nothing
    assert not poses and vehicle.state().landed
    pilot.sm.state = State.EXPLORE
    assert session.take_off()
    session.land()
    st = vehicle.state()
    assert st.landed and poses and observed and poses[-1].landed


def test_a_failsafe_has_the_vehicle_so_no_landing_is_commanded(geom):
    vehicle = KinematicVehicle(start_position=geom.takeoff)
    pilot = Pilot(vehicle)
    pilot.sm.state = State.EXPLORE
    session = _session(pilot, geom)
    assert session.take_off()
    pilot.failsafe = VehicleFailsafe("link lost", "RTL")
    session.land()
    assert vehicle.state().mode == FlightMode.OFFBOARD.value and not vehicle.state().landed
