"""The payload's attitude conversions at the MAVLink boundary (mavlink/frames.py, mavlink/payload.py)
against scipy's ``Rotation`` (reference: its intrinsic 'ZYX' Euler angles, MAVLink's order; 1e-9),
and the per-zoom intrinsics and zoom percentages the adapter asks for."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import insulator_rs as ir
from insulator_rs.exceptions import PayloadError, SensorError
from insulator_rs.flight.gimbal import stabilised_T_b_c
from insulator_rs.inspection_camera import InspectionCamera
from insulator_rs.mavlink.frames import (
    ENU_TO_NED,
    camera_quaternion_ned,
    camera_rotation_w,
    quaternion_yaw_pitch,
    yaw_pitch_of_quaternion,
)
from insulator_rs.mavlink.payload import gimbal_aim_of_quaternion, gimbal_device_quaternion, zoom_percent
from insulator_rs.poses import pose_from_yaw
from insulator_rs.ports.payload import PayloadFault

ANGLES = [(0.3, -0.4), (-2.0, 0.1), (1.2, -1.5), (0.0, 0.0), (-0.7, 0.45)]


def scipy_wxyz(yaw: float, pitch: float) -> np.ndarray:
    x, y, z, w = Rotation.from_euler("ZYX", [yaw, pitch, 0.0]).as_quat()
    return np.array([w, x, y, z])


@pytest.mark.parametrize(("yaw", "pitch"), ANGLES)
def test_yaw_pitch_quaternion_is_scipys_zyx(yaw: float, pitch: float) -> None:
    q = np.array(quaternion_yaw_pitch(yaw, pitch))
    ref = scipy_wxyz(yaw, pitch)
    assert np.allclose(q, ref, atol=1e-9) or np.allclose(q, -ref, atol=1e-9)
    assert yaw_pitch_of_quaternion(q) == pytest.approx((yaw, pitch), abs=1e-9)


@pytest.mark.parametrize(("yaw", "pitch"), ANGLES)
def test_gimbal_quaternion_uses_mavlinks_clockwise_yaw(yaw: float, pitch: float) -> None:
    """Our yaw is counter-clockwise from the heading; MAVLink's is clockwise (FRD): negated."""
    q = np.array(gimbal_device_quaternion(pitch, yaw))
    ref = scipy_wxyz(-yaw, pitch)
    assert np.allclose(q, ref, atol=1e-9) or np.allclose(q, -ref, atol=1e-9)
    assert gimbal_aim_of_quaternion(q) == pytest.approx((pitch, yaw), abs=1e-9)


@pytest.mark.parametrize(("yaw_body", "pitch", "yaw"), [(0.4, -0.3, 0.2), (-2.5, -1.2, -0.6), (1.0, 0.2, 0.0)])
def test_camera_attitude_quaternion_round_trips_to_the_optical_frame(yaw_body: float, pitch: float,
                                                                    yaw: float) -> None:
    """CAMERA_IMAGE_CAPTURED.q (NED, x along the optical axis) <-> R_w_c (ENU, OpenCV's optical
    frame): the optical axis points where scipy's ZYX rotation of NED's x points."""
    T_w_b = pose_from_yaw(np.zeros(3), yaw_body)
    T_b_c = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1.0]])
    R_w_c = (T_w_b @ stabilised_T_b_c(T_w_b, T_b_c, pitch, yaw))[:3, :3]
    q = camera_quaternion_ned(R_w_c)
    assert np.allclose(camera_rotation_w(q), R_w_c, atol=1e-9)
    yaw_ned = math.pi / 2 - (yaw_body + yaw)  # heading from north, clockwise
    axis_ned = Rotation.from_euler("ZYX", [yaw_ned, pitch, 0.0]).apply([1.0, 0.0, 0.0])
    assert np.allclose(ENU_TO_NED @ R_w_c[:, 2], axis_ned, atol=1e-9)


def test_zoom_percent_is_linear_in_focal_length() -> None:
    cam = InspectionCamera(ir.CameraModel(100.0, 100.0, 50.0, 40.0, 100, 80), np.eye(4), (100.0, 900.0))
    assert [zoom_percent(cam, f) for f in (100.0, 500.0, 900.0, 1000.0)] == pytest.approx([0, 50, 100, 100])
    fixed = InspectionCamera(ir.CameraModel(100.0, 100.0, 50.0, 40.0, 100, 80), np.eye(4), (100.0, 100.0))
    assert zoom_percent(fixed, 100.0) == 0.0


def test_payload_error_names_its_fault() -> None:
    err = PayloadError(PayloadFault.ZOOM_REFUSED, "MAV_CMD_SET_CAMERA_ZOOM: DENIED")
    assert isinstance(err, SensorError) and err.fault is PayloadFault.ZOOM_REFUSED
    assert str(err) == "payload zoom_refused: MAV_CMD_SET_CAMERA_ZOOM: DENIED"
