"""SE(3) everywhere: the simulated airframe tilts and leans into the wind, the vehicle port and
the MAVLink boundary carry the full attitude, and the localization needs it.

References: numpy for the tilt (atan(a/g)) and the lean in a steady wind (atan(k w / g) of the
drag model); scipy.spatial.transform.Rotation for every frame conversion; the scene's ground
truth for the localization error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from insulator_rs.mavlink.frames import (
    ENU_TO_NED,
    FLU_TO_FRD,
    attitude_enu_flu_to_ned_frd,
    attitude_ned_frd_to_enu_flu,
    attitude_quaternion_ned_frd_to_enu_flu,
    quaternion_ned_frd_from_enu_flu,
)
from insulator_rs.poses import (level_pose, pose_from_quaternion, quaternion_from_rotation,
                                rotation_from_quaternion, tilt_of, yaw_of)
from insulator_rs.ports.vehicle import VehicleState
from insulator_rs.sim.kinematics import GRAVITY, LINEAR_DRAG_PER_S, KinematicVehicle, MotionLimits, Setpoint
from insulator_rs.sim.wind import WindSpec, dryden_low_altitude

quaternions = st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1)


def _scipy_wxyz(R: np.ndarray) -> np.ndarray:
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


def _same_rotation(a: np.ndarray, b: np.ndarray, atol: float = 1e-9) -> None:
    """q and -q are one rotation (w = 0 leaves the sign to rounding)."""
    assert min(np.abs(a - b).max(), np.abs(a + b).max()) < atol, (a, b)


# -- conversions against scipy ---------------------------------------------------------------

@given(quaternions)
def test_quaternion_matrix_round_trip_matches_scipy(q) -> None:
    """Tolerance 1e-9: both are closed forms in float64."""
    q = np.asarray(q) / np.linalg.norm(q)
    R = rotation_from_quaternion(q)
    np.testing.assert_allclose(R, Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix(), atol=1e-9)
    back = quaternion_from_rotation(R)
    assert back[0] >= 0.0
    _same_rotation(back, q)
    _same_rotation(back, _scipy_wxyz(R))


@given(quaternions)
def test_px4_quaternion_to_enu_flu_matches_scipy(q) -> None:
    """PX4's q (w, x, y, z of R_ned_frd) -> R_enu_flu = R_enu_ned R_ned_frd R_frd_flu, the reference
    built by scipy from the two axis maps; and back."""
    q = np.asarray(q) / np.linalg.norm(q)
    R_ned_frd = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    ref = ENU_TO_NED.T @ R_ned_frd @ FLU_TO_FRD
    R = attitude_quaternion_ned_frd_to_enu_flu(q)
    np.testing.assert_allclose(R, ref, atol=1e-9)
    _same_rotation(quaternion_ned_frd_from_enu_flu(R), _scipy_wxyz(R_ned_frd))


@given(st.floats(-3.0, 3.0), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))
def test_px4_euler_matches_scipy_and_inverts(roll, pitch, yaw) -> None:
    """ATTITUDE's roll/pitch/yaw (intrinsic Z-Y-X in NED/FRD) against scipy's 'ZYX'."""
    R_ned_frd = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    R = attitude_ned_frd_to_enu_flu(roll, pitch, yaw)
    np.testing.assert_allclose(R, ENU_TO_NED.T @ R_ned_frd @ FLU_TO_FRD, atol=1e-9)
    back = attitude_enu_flu_to_ned_frd(R)
    np.testing.assert_allclose(attitude_ned_frd_to_enu_flu(*back), R, atol=1e-9)


def test_vehicle_state_pose_is_the_full_attitude_and_yaw_its_heading() -> None:
    R = Rotation.from_euler("ZYX", [0.7, 0.2, -0.1]).as_matrix()
    q = quaternion_from_rotation(R)
    st_ = VehicleState(1.0, np.array([1.0, 2.0, 3.0]), np.zeros(3), yaw_of(R), True, "OFFBOARD", False, attitude=q)
    np.testing.assert_allclose(st_.T_w_b[:3, :3], R, atol=1e-12)
    assert st_.yaw == pytest.approx(0.7)
    assert tilt_of(level_pose(st_.T_w_b)) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(pose_from_quaternion(st_.position, q), st_.T_w_b)


# -- the airframe ------------------------------------------------------------------------------

def _hovering(wind: WindSpec | None = None, limits: MotionLimits | None = None) -> KinematicVehicle:
    v = KinematicVehicle(start_position=(0.0, 0.0, 20.0), ground_z=0.0, wind=wind, limits=limits)
    v.command_setpoint(Setpoint(position=np.array([0.0, 0.0, 20.0]), yaw=0.0))
    v.arm()
    v.set_mode("OFFBOARD")
    return v


def test_braking_tilts_the_body_by_atan_a_over_g() -> None:
    """Still air, no drag: a steady 3 m/s^2 deceleration tilts the body atan(3 / g) = 17.0 degrees
    backward (nose up, thrust pointing against the motion). Reference: numpy, 0.1 degree."""
    v = _hovering(limits=MotionLimits(drag=0.0))
    v.model.velocity = np.array([6.0, 0.0, 0.0])
    a = 3.0
    t0 = v.clock.now
    for _ in range(150):  # 1.5 s of braking (the lag settles in ~0.6 s), a setpoint per step
        speed = max(0.0, 6.0 - a * (v.clock.now + 0.01 - t0))
        v.command_setpoint(Setpoint(position=np.array([math.nan, math.nan, 20.0]),
                                    velocity=np.array([speed, 0.0, 0.0]), yaw=0.0))
        st_ = v.advance(0.01)
    R = st_.T_w_b[:3, :3]
    expected = math.degrees(math.atan2(a, GRAVITY))
    assert math.degrees(tilt_of(R)) == pytest.approx(expected, abs=0.1)
    assert R[0, 2] < 0  # the thrust (body z) leans backward: the vehicle pitches nose up
    _, pitch_ned, _ = attitude_enu_flu_to_ned_frd(R)
    assert math.degrees(pitch_ned) == pytest.approx(expected, abs=0.1)  # PX4: pitch up is positive


def test_a_steady_wind_is_leaned_into_as_the_drag_model_says() -> None:
    """8 m/s from the west (blowing east), no turbulence: the vehicle holds its position leaning
    atan(k w / g) = 11.5 degrees into the wind (its thrust points west). Reference: numpy."""
    wind = WindSpec(speed=8.0, from_deg=270.0, turbulence=0.0)
    np.testing.assert_allclose(wind.mean, [8.0, 0.0, 0.0], atol=1e-12)
    v = _hovering(wind)
    for _ in range(100):
        v.command_setpoint(Setpoint(position=np.array([0.0, 0.0, 20.0]), yaw=0.0))
        st_ = v.advance(0.05)
    R = st_.T_w_b[:3, :3]
    expected = math.degrees(math.atan2(LINEAR_DRAG_PER_S * 8.0, GRAVITY))
    assert math.degrees(tilt_of(R)) == pytest.approx(expected, abs=0.1)
    assert R[0, 2] < 0  # body z toward the west: into the wind
    assert np.linalg.norm(st_.position - [0.0, 0.0, 20.0]) < 0.05  # the controller fights the push
    assert 5.0 < math.degrees(math.atan2(LINEAR_DRAG_PER_S * 5.0, GRAVITY)) < 15.0
    assert 5.0 < math.degrees(math.atan2(LINEAR_DRAG_PER_S * 10.0, GRAVITY)) < 15.0


def test_the_tilt_never_passes_px4s_limit() -> None:
    v = _hovering(limits=MotionLimits(max_horizontal_acceleration=30.0, max_tilt=math.radians(45.0)))
    tilts = []
    for _ in range(40):
        v.command_setpoint(Setpoint(position=np.array([40.0, 0.0, 20.0]), yaw=0.0))
        tilts.append(tilt_of(v.advance(0.05).T_w_b))
    assert max(tilts) <= math.radians(45.0) + 1e-9
    assert max(tilts) > math.radians(40.0)


@pytest.mark.slow
def test_turbulence_is_seeded_and_has_drydens_intensity() -> None:
    """Same seed, same wind history; the gusts' standard deviation within 25 % of MIL-F-8785C's
    sigma_u at 20 m over a long run (a 116 m correlation length at 8 m/s: 14 s)."""
    def history(seed: int) -> np.ndarray:
        v = _hovering(WindSpec(speed=8.0, from_deg=0.0, seed=seed))
        out = []
        for _ in range(4000):
            v.command_setpoint(Setpoint(position=np.array([0.0, 0.0, 20.0]), yaw=0.0))
            v.advance(0.1)
            out.append(v.model.wind_velocity.copy())
        return np.array(out)

    a, b = history(3), history(3)
    np.testing.assert_array_equal(a, b)
    sigma, _ = dryden_low_altitude(20.0, 8.0)
    assert np.std(a[:, 1]) == pytest.approx(sigma[0], rel=0.25)  # u: along the mean (north-south here)
    assert np.mean(a[:, 1]) == pytest.approx(-8.0, abs=1.0)  # from the north: blowing south


# -- the done-when: localizations in wind and braking ------------------------------------------

@pytest.mark.slow
def test_localizations_in_8_mps_wind_and_3_mps2_braking_need_the_full_attitude(capsys) -> None:
    """The airframe study's cell (evaluation/airframe_study.py): tower A, w = 8 m, 8 m/s wind,
    braking at 3 m/s^2, the bounded method (the product's). The same frames and scans through
    two pipelines: with the attitude the vehicle reports, the mean centre error against the
    scene's truth is <= 0.10 m; with the same poses made level (yaw only) it is worse."""
    from insulator_rs.evaluation.airframe_study import format_airframe_table, run_airframe_cell, summarize_airframe
    from insulator_rs.evaluation.localization_study import TOWERS, StudyConfig
    from insulator_rs.evaluation.study_scenes import StudyRig

    cfg = StudyConfig(towers=("A",), events=8, methods=("bounded",))
    rig = StudyRig(TOWERS["A"], cfg, seed=0)
    cells = summarize_airframe(run_airframe_cell(rig, "A", 8.0, cfg, wind=8.0, braking=3.0))
    with capsys.disabled():
        print("\n" + format_airframe_table(cells))
    full = next(c for c in cells if c.attitude == "full")
    level = next(c for c in cells if c.attitude == "level")
    assert full.n >= 4, full
    assert full.mean <= 0.10, full
    assert full.tilt_mean_deg > 5.0  # the airframe really was tilted
    assert not level.n or level.mean > 2 * full.mean, (full, level)


def test_wind_option_is_checked_against_its_bounds() -> None:
    import argparse

    from insulator_rs.bounds import wind_option

    assert wind_option("8") == (8.0, 0.0)
    assert wind_option("8,270") == (8.0, 270.0)
    for bad in ("25", "-1", "8,400", "8,90,1", "fast"):
        with pytest.raises(argparse.ArgumentTypeError):
            wind_option(bad)
