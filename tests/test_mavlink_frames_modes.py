"""Frame conversions, PX4 custom_mode encoding, signing keys and the sim's type_mask reading."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from insulator_rs.exceptions import ConfigError
from insulator_rs.mavlink import frames, px4_modes
from insulator_rs.sim.px4 import setpoint_from_target_local_ned
from insulator_rs.mavlink.signing import KEY_LENGTH, key_from_passphrase, load_signing_key
from insulator_rs.mavlink.wire import mavlink2 as M
from insulator_rs.ports.vehicle import FlightMode

finite = st.floats(-1e4, 1e4, allow_nan=False)
angles = st.floats(-math.pi, math.pi, allow_nan=False)
ORIGIN = (47.397742, 8.545594, 488.0)


@settings(max_examples=50, deadline=None)
@given(east=finite, north=finite, up=st.floats(-500, 500))
def test_enu_to_ned_matches_pymap3d(east: float, north: float, up: float) -> None:
    """Reference: pymap3d's geodetic2ned of the point pymap3d.enu2geodetic places at
    (east, north, up); tolerance 1e-6 m (round trip through geodetic coordinates)."""
    lat, lon, alt = pymap3d.enu2geodetic(east, north, up, *ORIGIN)
    ned = np.array(pymap3d.geodetic2ned(lat, lon, alt, *ORIGIN))
    np.testing.assert_allclose(frames.enu_to_ned([east, north, up]), ned, atol=1e-6)
    np.testing.assert_allclose(frames.ned_to_enu(ned), [east, north, up], atol=1e-6)


@settings(max_examples=50, deadline=None)
@given(vectors=st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=8))
def test_conversions_are_involutions_on_batches(vectors) -> None:
    array = np.array(vectors)
    np.testing.assert_array_equal(frames.ned_to_enu(frames.enu_to_ned(array)), array)
    np.testing.assert_array_equal(frames.frd_to_flu(frames.flu_to_frd(array)), array)
    np.testing.assert_array_equal(frames.enu_to_ned(array), array @ frames.ENU_TO_NED.T)
    np.testing.assert_array_equal(frames.flu_to_frd(array), array @ frames.FLU_TO_FRD.T)


def test_nan_components_stay_in_their_axis() -> None:
    converted = frames.ned_to_enu([1.0, 2.0, math.nan])
    np.testing.assert_array_equal(converted[:2], [2.0, 1.0])
    assert math.isnan(converted[2])


@given(yaw=angles)
def test_yaw_conversion_matches_the_heading_vector(yaw: float) -> None:
    """ENU yaw points the body x axis at (cos, sin) in (east, north); the NED yaw of
    the same heading points at (cos, sin) in (north, east)."""
    yaw_ned = frames.yaw_enu_to_ned(yaw)
    heading_enu = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    np.testing.assert_allclose(frames.enu_to_ned(heading_enu),
                               [math.cos(yaw_ned), math.sin(yaw_ned), 0.0], atol=1e-12)
    assert abs(math.remainder(frames.yaw_ned_to_enu(yaw_ned) - yaw, 2 * math.pi)) < 1e-12


@settings(max_examples=50, deadline=None)
@given(roll=st.floats(-1.5, 1.5), pitch=st.floats(-1.5, 1.5), yaw=angles)
def test_attitude_conversion_round_trips_and_is_a_rotation(roll: float, pitch: float, yaw: float) -> None:
    r_enu_flu = frames.attitude_ned_frd_to_enu_flu(roll, pitch, yaw)
    np.testing.assert_allclose(r_enu_flu @ r_enu_flu.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r_enu_flu) == pytest.approx(1.0)
    back = frames.attitude_enu_flu_to_ned_frd(r_enu_flu)
    np.testing.assert_allclose(back, (roll, pitch, yaw), atol=1e-9)


def test_level_attitude_maps_body_forward_to_the_enu_heading() -> None:
    """Reference by hand: yaw 0 in NED (north) means FLU forward = ENU (0, 1, 0), and
    FLU left = west (-1, 0, 0), FLU up = up."""
    r = frames.attitude_ned_frd_to_enu_flu(0.0, 0.0, 0.0)
    np.testing.assert_allclose(r, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)


def test_bad_vector_shape_names_the_argument() -> None:
    with pytest.raises(ValueError, match=r"vector must have shape \(\.\.\., 3\)"):
        frames.enu_to_ned([1.0, 2.0])


@pytest.mark.parametrize(
    ("mode", "custom_mode"),
    # Values as PX4 reports them in HEARTBEAT.custom_mode (main << 16 | sub << 24).
    [("OFFBOARD", 393216), ("POSCTL", 196608), ("MANUAL", 65536), ("HOLD", 50593792),
     ("TAKEOFF", 33816576), ("LAND", 100925440), ("RTL", 84148224), ("MISSION", 67371008)],
)
def test_custom_mode_encoding_matches_px4(mode: str, custom_mode: int) -> None:
    assert px4_modes.encode_custom_mode(mode) == custom_mode
    assert px4_modes.decode_custom_mode(custom_mode) == mode


def test_offboard_is_main_mode_6_and_unknown_modes_decode_to_numbers() -> None:
    assert px4_modes.main_sub_modes(FlightMode.OFFBOARD) == (6, 0)
    assert px4_modes.decode_custom_mode(2 << 16) == "PX4_2_0"  # ALTCTL, not modelled
    assert px4_modes.decode_custom_mode((3 << 16) | (1 << 24)) == "POSCTL"  # POSCTL slow sub mode
    assert px4_modes.mode_from_set_mode(7, 0) is None
    with pytest.raises(ValueError, match="custom_mode must be a uint32"):
        px4_modes.decode_custom_mode(-1)
    with pytest.raises(ValueError, match="no PX4 encoding"):
        px4_modes.encode_custom_mode("ACRO")


def test_signing_key_files(tmp_path) -> None:
    key = key_from_passphrase("tower")
    assert len(key) == KEY_LENGTH
    hex_file = tmp_path / "key.hex"
    hex_file.write_text(key.hex() + "\n")
    raw_file = tmp_path / "key.bin"
    raw_file.write_bytes(key)
    assert load_signing_key(hex_file) == key
    assert load_signing_key(raw_file) == key
    short = tmp_path / "short"
    short.write_text("abcd")
    with pytest.raises(ConfigError, match="expected 64 hex characters or 32 raw bytes, got 4 bytes"):
        load_signing_key(short)
    with pytest.raises(ConfigError, match="cannot read"):
        load_signing_key(tmp_path / "missing")


def _target(mask: int, *, pos=(1.0, 2.0, -3.0), vel=(0.5, 0.0, 0.0), yaw=0.0, yaw_rate=0.0):
    return M.MAVLink_set_position_target_local_ned_message(0, 1, 1, M.MAV_FRAME_LOCAL_NED, mask,
                                                            *pos, *vel, 0, 0, 0, yaw, yaw_rate)


def test_type_mask_position_velocity_yaw() -> None:
    """The client's mask (accel and yaw rate ignored) gives position, velocity, yaw in ENU."""
    from insulator_rs.mavlink.client import TYPE_MASK_POS_VEL_YAW

    assert TYPE_MASK_POS_VEL_YAW == 2496  # 64|128|256 (accel) + 2048 (yaw rate)
    sp = setpoint_from_target_local_ned(_target(TYPE_MASK_POS_VEL_YAW))
    np.testing.assert_allclose(sp.position, [2.0, 1.0, 3.0])
    np.testing.assert_allclose(sp.velocity, [0.0, 0.5, 0.0])
    assert sp.yaw == pytest.approx(math.pi / 2) and sp.yaw_rate is None


def test_type_mask_ignored_axes_become_uncontrolled() -> None:
    mask = (M.POSITION_TARGET_TYPEMASK_Z_IGNORE | M.POSITION_TARGET_TYPEMASK_VX_IGNORE
            | M.POSITION_TARGET_TYPEMASK_VY_IGNORE | M.POSITION_TARGET_TYPEMASK_VZ_IGNORE
            | M.POSITION_TARGET_TYPEMASK_YAW_IGNORE | M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE)
    sp = setpoint_from_target_local_ned(_target(mask))
    assert sp.velocity is None and sp.yaw is None and sp.yaw_rate is None
    assert sp.position is not None
    np.testing.assert_allclose(sp.position[:2], [2.0, 1.0])
    assert math.isnan(sp.position[2])


@given(custom_mode=st.integers(0, 2**32 - 1))
def test_any_custom_mode_decodes_to_a_name(custom_mode: int) -> None:
    name = px4_modes.decode_custom_mode(custom_mode)
    assert isinstance(name, str) and name
    if not name.startswith("PX4_"):
        main, sub = px4_modes.main_sub_modes(name)
        assert main == (custom_mode >> 16) & 0xFF


@settings(max_examples=100, deadline=None)
@given(mask=st.integers(0, 0xFFFF), values=st.lists(
    st.floats(allow_nan=True, allow_infinity=False, width=32), min_size=11, max_size=11))
def test_any_type_mask_reads_without_error_and_nan_marks_ignored_axes(mask: int, values) -> None:
    sp = setpoint_from_target_local_ned(_target(mask, pos=values[0:3], vel=values[3:6], yaw=values[9],
                                                yaw_rate=values[10]))
    # An axis is uncontrolled when its bit is set or its value is NaN (PX4 reads NaN
    # in a trajectory setpoint as "not controlled").
    ned_uncontrolled = [bool(mask & bit) or math.isnan(v) for bit, v in zip((1, 2, 4), values[0:3])]
    if all(ned_uncontrolled):
        assert sp.position is None
    else:
        assert sp.position is not None
        enu_uncontrolled = [ned_uncontrolled[1], ned_uncontrolled[0], ned_uncontrolled[2]]
        for axis, uncontrolled in enumerate(enu_uncontrolled):
            assert math.isnan(sp.position[axis]) == uncontrolled
    assert not (sp.yaw is not None and sp.yaw_rate is not None)
    if sp.yaw is not None:
        assert -math.pi <= sp.yaw < math.pi


def test_simulated_px4_survives_garbage_datagrams() -> None:
    """Property: random datagrams (some with a MAVLink 2 start byte) never break the
    simulated PX4; afterwards a valid command is still answered."""
    import socket
    import time

    from insulator_rs.sim.px4 import SimulatedPx4
    from insulator_rs.mavlink.wire import mavutil

    with SimulatedPx4() as sim, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:

        @settings(max_examples=60, deadline=None)
        @given(payload=st.binary(min_size=0, max_size=300), mavlink_start=st.booleans())
        def send_garbage(payload: bytes, mavlink_start: bool) -> None:
            sender.sendto((b"\xfd" if mavlink_start else b"") + payload, sim.address)

        send_garbage()
        time.sleep(0.2)
        peer = mavutil.mavlink_connection(f"udpout:{sim.address[0]}:{sim.address[1]}", source_system=255)
        try:
            peer.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            ack = peer.recv_match(type="COMMAND_ACK", blocking=True, timeout=2.0)
        finally:
            peer.close()
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        assert sim.with_vehicle(lambda v: v.armed)
