"""The in-process kinematic multirotor and its PX4-like autopilot rules."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from insulator_rs.exceptions import CommandRejected, VehicleError, VehicleFailsafe
from insulator_rs.sim.kinematics import (
    AutopilotParameters,
    KinematicVehicle,
    MotionLimits,
    MultirotorModel,
    OdometryNoise,
    Setpoint,
    SimClock,
)
from insulator_rs.ports.vehicle import FlightMode, Vehicle

DT = 0.05  # control tick, s (20 Hz, as the mission streams setpoints)


def minimum_time_trapezoid(distance: float, v_max: float, a_max: float) -> float:
    """Shortest time to move ``distance`` from rest to rest with |v| <= v_max, |a| <= a_max
    (bang-coast-bang): the physical lower bound no controller can beat."""
    if distance <= v_max**2 / a_max:
        return 2.0 * math.sqrt(distance / a_max)
    return distance / v_max + v_max / a_max


def fly_model(model: MultirotorModel, setpoint: Setpoint, seconds: float, dt: float = 0.01):
    """Step the model and record (t, position, velocity, yaw) every dt."""
    log = []
    for i in range(int(round(seconds / dt))):
        model.step(dt, setpoint)
        log.append(((i + 1) * dt, model.position.copy(), model.velocity.copy(), model.yaw))
    return log


def airborne_model(**limits: float) -> MultirotorModel:
    return MultirotorModel(limits=MotionLimits(**limits), position=np.array([0.0, 0.0, 10.0]))


def test_kinematic_vehicle_implements_the_vehicle_protocol() -> None:
    assert isinstance(KinematicVehicle(), Vehicle)


def test_point_to_point_respects_the_minimum_time_bound_and_does_not_overshoot() -> None:
    """Reference: the analytic bang-coast-bang minimum time (a lower bound, exact physics);
    the vehicle must not arrive earlier, must arrive within 1.5x of it plus 2 s of
    settling, and may overshoot by at most 5 cm."""
    limits = dict(max_horizontal_speed=3.0, max_horizontal_acceleration=4.0)
    model = airborne_model(**limits)
    target = np.array([20.0, 0.0, 10.0])
    log = fly_model(model, Setpoint(position=target), 20.0)
    bound = minimum_time_trapezoid(20.0, 3.0, 4.0)
    arrival = next(t for t, p, _v, _y in log if np.linalg.norm(p - target) < 0.1)
    assert bound <= arrival <= 1.5 * bound + 2.0
    assert max(p[0] for _t, p, _v, _y in log) <= target[0] + 0.05
    assert np.linalg.norm(log[-1][1] - target) < 0.01


@settings(max_examples=25, deadline=None)
@given(
    target=st.tuples(*[st.floats(-30.0, 30.0)] * 3),
    velocity=st.tuples(*[st.floats(-8.0, 8.0)] * 3),
)
def test_velocity_and_acceleration_limits_are_never_exceeded(target, velocity) -> None:
    """Property: for any position + velocity feed-forward setpoint, horizontal and vertical
    speed and acceleration (finite differences of the logged state) stay within limits."""
    lim = MotionLimits(max_horizontal_speed=3.0, max_vertical_speed=1.5,
                       max_horizontal_acceleration=5.0, max_vertical_acceleration=2.0)
    model = MultirotorModel(limits=lim, position=np.array([0.0, 0.0, 100.0]))
    sp = Setpoint(position=np.array(target) + [0, 0, 100.0], velocity=np.array(velocity))
    log = fly_model(model, sp, 4.0)
    vel = np.array([v for _t, _p, v, _y in log])
    acc = np.diff(np.vstack([np.zeros(3), vel]), axis=0) / 0.01
    assert np.all(np.linalg.norm(vel[:, :2], axis=1) <= lim.max_horizontal_speed + 1e-9)
    assert np.all(np.abs(vel[:, 2]) <= lim.max_vertical_speed + 1e-9)
    assert np.all(np.linalg.norm(acc[:, :2], axis=1) <= lim.max_horizontal_acceleration + 1e-6)
    assert np.all(np.abs(acc[:, 2]) <= lim.max_vertical_acceleration + 1e-6)


def test_moving_setpoint_with_feed_forward_is_tracked_closely() -> None:
    """A setpoint moving at 2 m/s east with its velocity as feed-forward: after the
    start-up transient the tracking error is below 2 cm."""
    model = airborne_model()
    errors = []
    for i in range(400):
        t = i * 0.01
        sp = Setpoint(position=np.array([2.0 * t, 0.0, 10.0]), velocity=np.array([2.0, 0.0, 0.0]))
        model.step(0.01, sp)
        if t > 2.0:
            errors.append(np.linalg.norm(model.position - [2.0 * (t + 0.01), 0.0, 10.0]))
    assert max(errors) < 0.02


def test_yaw_turns_the_short_way_at_the_rate_limit() -> None:
    """From 170 deg to -170 deg is a 20 deg turn through 180, at 90 deg/s about 0.22 s."""
    model = airborne_model(max_yaw_rate=math.radians(90))
    model.yaw = math.radians(170)
    log = fly_model(model, Setpoint(position=model.position.copy(), yaw=math.radians(-170)), 0.5)
    yaws = np.unwrap([y for *_rest, y in log])
    assert np.all(np.abs(np.diff(yaws)) <= math.radians(90) * 0.01 + 1e-9)
    assert yaws.max() <= math.radians(190) + 1e-6
    assert math.isclose(log[-1][3], math.radians(-170), abs_tol=1e-6)
    reached = next(t for t, *_r, y in log if abs(math.remainder(y - math.radians(-170), 2 * math.pi)) < 1e-6)
    assert reached == pytest.approx(20 / 90, abs=0.02)


def start_flying(vehicle: KinematicVehicle, altitude: float = 5.0) -> None:
    """Arm, take off and switch to offboard holding the reached position."""
    vehicle.arm()
    vehicle.takeoff(altitude)
    for _ in range(200):
        state = vehicle.advance(DT)
        if state.mode == "HOLD":
            break
    assert vehicle.state().mode == "HOLD"
    vehicle.send_setpoint(vehicle.state().position)
    vehicle.start_offboard()


def test_takeoff_offboard_trajectory_land_and_auto_disarm() -> None:
    vehicle = KinematicVehicle(start_position=(1.0, 2.0, 0.0))
    state = vehicle.state()
    assert state.landed and not state.armed
    start_flying(vehicle, 5.0)
    assert vehicle.state().position[2] == pytest.approx(5.0, abs=0.3)
    target = np.array([6.0, 2.0, 8.0])
    for _ in range(300):
        vehicle.send_setpoint(target, yaw=1.0)
        state = vehicle.advance(DT)
    assert state.mode == "OFFBOARD"
    np.testing.assert_allclose(state.position, target, atol=0.02)
    assert state.yaw == pytest.approx(1.0, abs=1e-3)
    vehicle.land()
    touchdown = None
    for _ in range(400):
        state = vehicle.advance(DT)
        if state.landed and touchdown is None:
            touchdown = state.time
        if not state.armed:
            break
    assert touchdown is not None and not state.armed
    assert state.position[2] == pytest.approx(0.0, abs=1e-9)
    # COM_DISARM_LAND = 2 s after touchdown (within one tick)
    assert state.time - touchdown == pytest.approx(2.0, abs=DT + 1e-9)


def test_offboard_is_refused_without_a_setpoint_stream() -> None:
    vehicle = KinematicVehicle()
    vehicle.arm()
    with pytest.raises(CommandRejected, match="OFFBOARD refused by the vehicle: no offboard setpoint stream"):
        vehicle.start_offboard()
    vehicle.send_setpoint((0.0, 0.0, 0.0))
    vehicle.advance(1.5)  # stream went stale: older than COM_OF_LOSS_T
    with pytest.raises(CommandRejected):
        vehicle.start_offboard()
    vehicle.send_setpoint((0.0, 0.0, 0.0))
    vehicle.start_offboard()
    assert vehicle.state().mode == "OFFBOARD"


def test_arming_twice_is_accepted_as_px4_does_and_takeoff_while_disarmed_is_refused() -> None:
    vehicle = KinematicVehicle()
    with pytest.raises(CommandRejected, match="takeoff refused by the vehicle: vehicle is disarmed"):
        vehicle.takeoff(5.0)
    vehicle.arm()
    vehicle.arm()  # PX4 Commander::arm returns TRANSITION_NOT_CHANGED -> ACCEPTED
    assert vehicle.state().armed


def test_arming_is_refused_without_position_and_with_a_critical_battery() -> None:
    vehicle = KinematicVehicle()
    vehicle.inject_position_loss(True)
    with pytest.raises(CommandRejected, match="no valid position estimate"):
        vehicle.arm()
    vehicle.inject_position_loss(False)
    vehicle.battery_fraction = 0.05
    with pytest.raises(CommandRejected, match="battery critical"):
        vehicle.arm()


def test_offboard_loss_falls_back_to_position_mode_after_com_of_loss_t() -> None:
    """Reference: PX4 v1.16.0 SITL, stream stopped in OFFBOARD: "Failsafe activated" and the
    HEARTBEAT shows POSCTL (COM_OBL_RC_ACT = 0) about 1.5 s later; the vehicle holds."""
    vehicle = KinematicVehicle()
    start_flying(vehicle)
    last_setpoint_time = vehicle.state().time
    where = vehicle.state().position
    state = vehicle.advance(0.95)
    assert state.mode == "OFFBOARD"
    with pytest.raises(VehicleFailsafe) as failsafe:
        vehicle.advance(0.1)
    assert failsafe.value.reason == "offboard setpoints lost for more than 1 s"
    assert failsafe.value.action == "posctl"
    state = vehicle.state()
    assert state.mode == "POSCTL"
    assert state.fault == "offboard setpoints lost for more than 1 s"
    assert not state.healthy
    assert state.time - last_setpoint_time == pytest.approx(1.05, abs=1e-6)
    np.testing.assert_allclose(vehicle.advance(2.0).position, where, atol=0.05)


def test_offboard_loss_clears_when_setpoints_come_again_as_px4_v116_does() -> None:
    """Reference: PX4 v1.16.0 SITL, session 17's tower B flight (its ULog, read with pyulog): a
    1.19 s stall of the companion's setpoints put PX4 in RTL (COM_OBL_RC_ACT 3) at 32.000 s and
    back in OFFBOARD, failsafe flag cleared, at 32.060 s, with no command from the companion."""
    vehicle = KinematicVehicle(params=AutopilotParameters(offboard_loss_mode="RTL"))
    start_flying(vehicle)
    with pytest.raises(VehicleFailsafe):
        vehicle.advance(1.1)
    assert vehicle.state().mode == "RTL" and not vehicle.state().healthy
    vehicle.advance(0.2)  # still no setpoint: the fallback holds
    assert vehicle.state().mode == "RTL"
    vehicle.send_setpoint(vehicle.state().position)
    state = vehicle.advance(DT)
    assert state.mode == "OFFBOARD" and state.fault is None and state.healthy


def test_a_mode_chosen_during_the_offboard_fallback_ends_it() -> None:
    vehicle = KinematicVehicle(params=AutopilotParameters(offboard_loss_mode="RTL"))
    start_flying(vehicle)
    with pytest.raises(VehicleFailsafe):
        vehicle.advance(1.1)
    vehicle.hold()  # the pilot (or the companion) chose a mode: OFFBOARD is no longer intended
    vehicle.send_setpoint(vehicle.state().position)
    assert vehicle.advance(0.5).mode == "HOLD"


def test_disarm_in_the_air_is_refused_and_preflight_auto_disarm() -> None:
    vehicle = KinematicVehicle()
    start_flying(vehicle)
    with pytest.raises(CommandRejected, match="disarm refused by the vehicle: not landed"):
        vehicle.disarm()
    ground = KinematicVehicle(params=AutopilotParameters(preflight_disarm_delay=3.0))
    ground.arm()
    assert ground.advance(2.9).armed
    assert not ground.advance(0.2).armed


def test_battery_critical_triggers_return_to_launch_and_landing_at_home() -> None:
    params = AutopilotParameters(battery_drain_per_s=0.05, battery_floor=0.0, return_altitude=8.0)
    vehicle = KinematicVehicle(params=params, start_position=(0.0, 0.0, 0.0))
    start_flying(vehicle, 5.0)
    target = np.array([10.0, -5.0, 5.0])
    with pytest.raises(VehicleFailsafe, match=r"battery critical \(7%\); action: rtl"):
        for _ in range(600):
            vehicle.send_setpoint(target)
            vehicle.advance(DT)
    state = vehicle.state()
    assert state.mode == "RTL" and state.fault == "battery critical (7%)"
    peak = 0.0
    for _ in range(2000):
        state = vehicle.advance(DT)
        peak = max(peak, state.position[2])
        if not state.armed:
            break
    assert not state.armed and state.landed
    assert peak == pytest.approx(8.0, abs=0.35)
    np.testing.assert_allclose(state.position, [0.0, 0.0, 0.0], atol=0.35)


def test_battery_drains_to_the_sitl_floor_only() -> None:
    """SIM_BAT_MIN_PCT as PX4 SIH has it (50 %): the charge stops there (our airframe's default
    floor is 0, the whole pack)."""
    vehicle = KinematicVehicle(params=AutopilotParameters(battery_drain_per_s=0.1, battery_floor=0.5))
    start_flying(vehicle)
    for _ in range(200):
        vehicle.send_setpoint(vehicle.state().position)
        state = vehicle.advance(DT)
    assert state.battery_fraction == pytest.approx(0.5) and state.mode == "OFFBOARD"


def test_odometry_noise_has_the_configured_spread_and_is_seeded() -> None:
    """Reference: numpy sample standard deviation of 4000 draws, within 5 %."""
    noisy = KinematicVehicle(noise=OdometryNoise(position=0.2, velocity=0.1, yaw=0.05), seed=7)
    samples = [noisy.state() for _ in range(4000)]
    pos = np.array([s.position for s in samples])
    vel = np.array([s.velocity for s in samples])
    yaw = np.array([s.yaw for s in samples])
    np.testing.assert_allclose(pos.std(axis=0), 0.2, rtol=0.05)
    np.testing.assert_allclose(vel.std(axis=0), 0.1, rtol=0.05)
    assert yaw.std() == pytest.approx(0.05, rel=0.05)
    again = KinematicVehicle(noise=OdometryNoise(position=0.2, velocity=0.1, yaw=0.05), seed=7)
    np.testing.assert_array_equal(again.state().position, samples[0].position)


def test_gps_glitch_offsets_published_position_only() -> None:
    vehicle = KinematicVehicle()
    vehicle.inject_gps_glitch((3.0, 0.0, 0.0))
    np.testing.assert_allclose(vehicle.state().position, [3.0, 0.0, 0.0])
    np.testing.assert_allclose(vehicle.model.position, [0.0, 0.0, 0.0])


def test_position_loss_in_flight_lands_with_a_reason() -> None:
    vehicle = KinematicVehicle()
    start_flying(vehicle)
    vehicle.inject_position_loss(True)
    state = vehicle.state()
    assert state.mode == "LAND" and state.fault == "position estimate lost" and not state.healthy
    with pytest.raises(VehicleFailsafe, match="position estimate lost; action: land"):
        vehicle.advance(DT)
    vehicle.advance(DT)  # raised once only


def test_shared_clock_and_closed_vehicle() -> None:
    clock = SimClock(10.0)
    vehicle = KinematicVehicle(clock=clock)
    vehicle.advance(0.25)
    assert clock.now == pytest.approx(10.25)
    vehicle.close()
    with pytest.raises(VehicleError, match="closed"):
        vehicle.state()


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda v: v.send_setpoint((0.0, 0.0)), ValueError, "position must have shape"),
        (lambda v: v.send_setpoint((0.0, math.nan, 0.0)), ValueError, "position must be finite"),
        (lambda v: v.send_setpoint((0, 0, 0), velocity="abc"), TypeError, "velocity"),
        (lambda v: v.send_setpoint((0, 0, 0), yaw=math.inf), ValueError, "yaw must be finite"),
        (lambda v: v.advance(0.0), ValueError, "dt must be > 0"),
        (lambda v: v.advance(None), TypeError, "dt must be a number"),
        (lambda v: v.takeoff(-1.0), ValueError, "altitude must be > 0"),
        (lambda v: v.set_mode("ACRO"), ValueError, "mode must be one of"),
    ],
)
def test_bad_arguments_name_the_argument(call, error, match) -> None:
    with pytest.raises(error, match=match):
        call(KinematicVehicle())


def test_bad_limits_are_rejected() -> None:
    with pytest.raises(ValueError, match="max_horizontal_speed"):
        MotionLimits(max_horizontal_speed=0.0)
    with pytest.raises(ValueError, match="noise position"):
        OdometryNoise(position=-1.0)
    with pytest.raises(ValueError, match="offboard_loss_timeout"):
        AutopilotParameters(offboard_loss_timeout=math.nan)


def test_modes_are_plain_strings_in_state() -> None:
    vehicle = KinematicVehicle()
    assert vehicle.state().mode == FlightMode.HOLD.value
    assert type(vehicle.state().mode) is str


def test_the_reported_pose_follows_the_attitude_through_a_braking_frame() -> None:
    """``sim.sensors.reported_pose`` (what simulated sensors render at when only the autopilot's
    report is there: ``--sim-sensors``, the wire LiDAR) at times up to one LiDAR frame (0.1 s)
    before the newest state, while the airframe brakes hard. Reference: the airframe's own true
    pose history. Carried back along the velocity only (the newest attitude for every time), a
    braking frame's attitude was off by several degrees (its ground 12-25 m away rendered 0.5-3.5 m
    high); interpolated between the reported states, within a degree."""
    from scipy.spatial.transform import Rotation

    from insulator_rs.sim.sensors import reported_pose

    vehicle = KinematicVehicle(start_position=(0.0, 0.0, 0.0))
    start_flying(vehicle, 10.0)
    pose = reported_pose(vehicle)
    worst_old = worst_new = 0.0
    for i in range(120):  # fly out at full speed, then ask for a stop: the body pitches back hard
        target = np.array([40.0, 0.0, 10.0]) if i < 60 else vehicle.state().position
        vehicle.send_setpoint(target if i < 60 else np.array([12.0, 0.0, 10.0]), yaw=0.0)
        st = vehicle.advance(DT)
        pose(st.time)  # a sensor asks every tick: the reported states are kept
        if i < 3:  # before two ticks are kept, the past is carried back along the rates only
            continue
        for back in (0.05, 0.0749, 0.0999):
            truth = vehicle.true_pose_at(st.time - back)[:3, :3]
            new = pose(st.time - back)[:3, :3]
            worst_new = max(worst_new, Rotation.from_matrix(new.T @ truth).magnitude())
            worst_old = max(worst_old, Rotation.from_matrix(st.T_w_b[:3, :3].T @ truth).magnitude())
    assert math.degrees(worst_old) > 3.0  # the braking really pitches the body within a frame
    # between reported states 50 ms apart the slerp misses the angular acceleration: measured 0.63
    # degrees at the worst midpoint, against 24 with the newest attitude for every time
    assert math.degrees(worst_new) < 1.0 and worst_new < 0.1 * worst_old
