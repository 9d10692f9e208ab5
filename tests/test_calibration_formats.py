"""The calibration files users have: livox_camera_calib's / Autoware's camera-LiDAR OpenCV YAML
(written here by cv2.FileStorage itself), Kalibr's camchain.yaml, and a small skew folded in.

Reference: cv2.projectPoints with the file's own K and distortion, and the extrinsic as
written; tolerance 1e-6 px (the same numbers, carried through our loader)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import yaml

from insulator_rs.calibration import load_calibration
from insulator_rs.exceptions import ConfigError
from insulator_rs.rig import load_rig

K = np.array([[1450.2, 0.0, 962.4], [0.0, 1449.7, 541.9], [0.0, 0.0, 1.0]])
D = np.array([[-0.091, 0.084, 0.0007, -0.0004, 0.0]])
# the LiDAR 8 cm below and 5 cm behind the camera, axes L (x fwd, z up) -> C (z fwd, y down)
T_C_L = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.05], [0.0, 0.0, 0.0, 1.0]])


def _matrix_node(name, m):
    m = np.atleast_2d(np.asarray(m, dtype=np.float64))
    data = ", ".join(repr(float(v)) for v in m.ravel())
    return f"{name}: !!opencv-matrix\n   rows: {m.shape[0]}\n   cols: {m.shape[1]}\n   dt: d\n   data: [ {data} ]\n"


def _livox_file(path, *, skew=0.0, extrinsic="ExtrinsicMat", T=T_C_L):
    """A camera-LiDAR calibration as livox_camera_calib users keep it (OpenCV YAML with
    ORB-SLAM-style dotted keys, which cv2.FileStorage reads but no longer writes)."""
    k = K.copy()
    k[0, 1] = skew
    text = "%YAML:1.0\n---\n" + _matrix_node("CameraMat", k) + _matrix_node("DistCoeffs", D)
    text += "Camera.width: 1920\nCamera.height: 1080\n"
    if extrinsic:
        text += _matrix_node(extrinsic, T)
    path.write_text(text)
    return path


def _project(camera, pts_c):
    uv, valid = __import__("insulator_rs").project_points(pts_c, np.eye(4), camera)
    return uv


def test_livox_camera_calib_layout_reads_intrinsics_and_extrinsic(tmp_path):
    cal = load_calibration(_livox_file(tmp_path / "calib.yaml"))
    cam = cal.camera
    assert (cam.width, cam.height) == (1920, 1080)
    pts = np.array([[0.3, -0.2, 8.0], [-1.0, 0.5, 12.0], [0.0, 0.0, 5.0]])
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, D)
    assert np.allclose(_project(cam, pts), ref.reshape(-1, 2), atol=1e-6)
    assert np.allclose(cal.T_c_l, T_C_L)


def test_autoware_extrinsic_is_the_camera_pose_in_the_lidar_frame(tmp_path):
    cal = load_calibration(_livox_file(tmp_path / "aw.yaml", extrinsic="CameraExtrinsicMat",
                                       T=np.linalg.inv(T_C_L)))
    assert np.allclose(cal.T_c_l, T_C_L, atol=1e-12)


def test_a_rig_takes_the_camera_extrinsic_from_the_calibration(tmp_path):
    _livox_file(tmp_path / "calib.yaml")
    T_b_l = np.array([[1.0, 0, 0, 0.1], [0, 1.0, 0, 0], [0, 0, 1.0, -0.1], [0, 0, 0, 1.0]])
    (tmp_path / "rig.toml").write_text('[camera]\ncalibration = "calib.yaml"\n\n[lidar]\nT_b_l = '
                                       + str(T_b_l.tolist()) + "\n")
    rig = load_rig(tmp_path / "rig.toml")
    assert np.allclose(rig.T_b_c, T_b_l @ np.linalg.inv(T_C_L))
    # a point seen by the LiDAR lands where the camera sees it: T_c_l == inv(T_b_c) @ T_b_l
    assert np.allclose(np.linalg.inv(rig.T_b_c) @ rig.T_b_l, T_C_L, atol=1e-12)


def test_a_small_skew_is_folded_in_with_a_warning_a_large_one_refused(tmp_path):
    with pytest.warns(UserWarning, match="skew 0.1 px .* folded in"):
        cam = load_calibration(_livox_file(tmp_path / "s.yaml", skew=0.1)).camera
    assert math.isclose(cam.fx, K[0, 0])
    with pytest.raises(ConfigError, match="CameraMat.* skew of 5 px"):
        load_calibration(_livox_file(tmp_path / "b.yaml", skew=5.0))


def test_kalibr_camchain(tmp_path):
    T_cam_imu = np.array([[0.0, -1.0, 0.0, 0.02], [0.0, 0.0, -1.0, 0.01], [1.0, 0.0, 0.0, -0.03], [0, 0, 0, 1.0]])
    doc = {"cam0": {"camera_model": "pinhole", "intrinsics": [float(v) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2])],
                    "distortion_model": "radtan", "distortion_coeffs": D[0, :4].tolist(),
                    "resolution": [1920, 1080], "T_cam_imu": T_cam_imu.tolist(), "rostopic": "/cam0/image_raw"}}
    path = tmp_path / "camchain.yaml"
    path.write_text(yaml.safe_dump(doc, default_flow_style=None))
    cal = load_calibration(path)
    pts = np.array([[0.3, -0.2, 8.0], [-1.0, 0.5, 12.0]])
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, D)
    assert np.allclose(_project(cal.camera, pts), ref.reshape(-1, 2), atol=1e-6)
    assert np.allclose(cal.T_cam_imu, T_cam_imu)


@pytest.mark.parametrize("edit, field", [
    (lambda c: c.update(camera_model="omni"), "cam0.camera_model"),
    (lambda c: c.update(distortion_model="equidistant"), "cam0.distortion_model"),
    (lambda c: c.update(intrinsics=[1.0, 2.0]), "cam0.intrinsics"),
    (lambda c: c.update(resolution=[1920]), "cam0.resolution"),
    (lambda c: c.update(T_cam_imu=[[1, 0, 0, 0]] * 4), "cam0.T_cam_imu"),
])
def test_bad_kalibr_files_are_refused_naming_the_field(tmp_path, edit, field):
    cam = {"camera_model": "pinhole", "intrinsics": [900.0, 900.0, 640.0, 360.0], "distortion_model": "radtan",
           "distortion_coeffs": [0.0, 0.0, 0.0, 0.0], "resolution": [1280, 720]}
    edit(cam)
    path = tmp_path / "camchain.yaml"
    path.write_text(yaml.safe_dump({"cam0": cam}))
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_calibration(path)


def test_a_bad_extrinsic_is_refused_naming_the_field(tmp_path):
    bad = T_C_L.copy()
    bad[0, 0] = 2.0
    with pytest.raises(ConfigError, match="ExtrinsicMat"):
        load_calibration(_livox_file(tmp_path / "e.yaml", T=bad))
