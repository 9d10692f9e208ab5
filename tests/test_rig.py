"""The sensor rig file: camera calibration + extrinsics, named by the mission; the simulator's
defaults come from the shipped rig; bad files are refused naming the field."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.rig_files import T_B_C, T_B_L, write_opencv_calibration

import insulator_rs as ir
from insulator_rs.exceptions import ConfigError
from insulator_rs.mission.config import load_mission
from insulator_rs.rig import RIGS_DIR, load_rig, resolve_rig, scaled_camera, simulator_rig

MISSIONS = Path(ir.__file__).resolve().parent / "missions"


def write_rig(folder: Path, *, calibration: str = "cam.yaml", T_b_c=T_B_C, T_b_l=T_B_L) -> Path:
    rig = folder / "rig.toml"
    rig.write_text(f'[camera]\ncalibration = "{calibration}"\nT_b_c = {T_b_c}\n\n[lidar]\nT_b_l = {T_b_l}\n')
    return rig


def test_a_mission_names_its_rig_and_the_calibration_is_read_with_load_camera_model(tmp_path):
    write_opencv_calibration(tmp_path / "cam.yaml")
    write_rig(tmp_path)
    text = (MISSIONS / "tower_a.toml").read_text().replace('rig = "simulator"', 'rig = "rig.toml"')
    (tmp_path / "mission.toml").write_text(text)
    rig = load_mission(tmp_path / "mission.toml").rig
    assert rig is not None and rig.source.endswith("rig.toml")
    reference = ir.load_camera_model(tmp_path / "cam.yaml")
    np.testing.assert_array_equal(rig.camera.camera_matrix(), reference.camera_matrix())
    assert (rig.camera.cx, rig.camera.cy) == (731.2, 528.9)
    np.testing.assert_array_equal(rig.T_b_c, T_B_C)
    np.testing.assert_array_equal(rig.T_b_l, T_B_L)


def test_the_simulators_defaults_are_the_shipped_rig():
    from insulator_rs.sim.camera_render import default_camera_model, default_T_b_c
    from insulator_rs.sim.lidar import default_T_b_l

    rig = load_rig(RIGS_DIR / "simulator.toml")
    assert resolve_rig("simulator") == RIGS_DIR / "simulator.toml"
    np.testing.assert_array_equal(default_camera_model().camera_matrix(), rig.camera.camera_matrix())
    assert default_camera_model().dist == rig.camera.dist
    np.testing.assert_array_equal(default_T_b_c(), rig.T_b_c)
    np.testing.assert_array_equal(default_T_b_l(), rig.T_b_l)
    for name in ("tower_a", "tower_b"):
        assert load_mission(MISSIONS / f"{name}.toml").rig.source == simulator_rig().source


def test_scaling_keeps_a_real_principal_point():
    """Reference: cv2.resize's pixel mapping, x_dst = (x_src + 0.5) * s - 0.5 (pixel centres at
    integers): a point's projection in the scaled model equals the full model's, mapped."""
    cam = ir.CameraModel(1100.0, 1098.5, 731.2, 528.9, 1440, 1080, dist=(-0.21, 0.09, 0.0004, -0.0002, -0.01))
    small = scaled_camera(cam, 0.25)
    assert (small.width, small.height) == (360, 270)
    assert small.cx == pytest.approx((731.2 + 0.5) * 0.25 - 0.5)
    assert small.cy == pytest.approx((528.9 + 0.5) * 0.25 - 0.5)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-2, 2, 50), rng.uniform(-1.5, 1.5, 50), rng.uniform(4, 10, 50)])
    uv, _ = ir.project_points(pts, np.eye(4), cam)
    uv_small, _ = ir.project_points(pts, np.eye(4), small)
    np.testing.assert_allclose(uv_small, (uv + 0.5) * 0.25 - 0.5, atol=1e-9)
    centred = ir.CameraModel(700.0, 700.0, 639.5, 479.5, 1280, 960)
    assert (scaled_camera(centred, 0.25).cx, scaled_camera(centred, 0.25).cy) == (159.5, 119.5)


@pytest.mark.parametrize("mutate, field", [
    (lambda f: write_rig(f, calibration="missing.yaml"), "camera.calibration"),
    (lambda f: write_rig(f, T_b_c=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), "camera.T_b_c"),
    (lambda f: write_rig(f, T_b_l=[[2.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]), "lidar.T_b_l"),
    (lambda f: (f / "rig.toml").write_text(f'[camera]\ncalibration = "cam.yaml"\n[lidar]\nT_b_l = {T_B_L}\n'),
     "camera.T_b_c"),
    (lambda f: (f / "rig.toml").write_text(f'[camera]\ncalibration = "cam.yaml"\nT_b_c = {T_B_C}\n'), "lidar"),
    (lambda f: (f / "rig.toml").write_text(f'[camera]\ncalibration = 3\n[lidar]\nT_b_l = {T_B_L}\n'),
     "camera.calibration"),
    (lambda f: (f / "rig.toml").write_text(
        f'[camera]\ncalibration = "cam.yaml"\nT_b_c = {T_B_C}\nfocal = 3\n[lidar]\nT_b_l = {T_B_L}\n'),
     "camera.focal"),
    (lambda f: (f / "rig.toml").write_text(
        f'[camera]\ncalibration = "cam.yaml"\nT_b_c = {T_B_C}\n[lidar]\nT_b_l = {T_B_L}\nfov_deg = [52, -7]\n'),
     "lidar.fov_deg"),
    (lambda f: (f / "rig.toml").write_text(
        f'[camera]\ncalibration = "cam.yaml"\nT_b_c = {T_B_C}\n[lidar]\nT_b_l = {T_B_L}\nfov_deg = "wide"\n'),
     "lidar.fov_deg"),
])
def test_bad_rig_files_are_refused_naming_the_field(tmp_path, mutate, field):
    write_opencv_calibration(tmp_path / "cam.yaml")
    mutate(tmp_path)
    with pytest.raises(ConfigError, match=f"rig.toml: {field}"):
        load_rig(tmp_path / "rig.toml")
    text = (MISSIONS / "tower_a.toml").read_text().replace('rig = "simulator"', 'rig = "rig.toml"')
    (tmp_path / "mission.toml").write_text(text)
    with pytest.raises(ConfigError, match=f"mission.toml: vehicle.rig: .*rig.toml: {field}"):
        load_mission(tmp_path / "mission.toml")


# (table, attribute, values and what they read as (None: refused), the refusal's stated range)
LATENCIES = [
    # a measured figure, either sign: it is measured against the LiDAR's clock
    ("camera", "camera_latency_s", (("0.045", 0.045), ("0", 0.0), ("-0.01", -0.01), ("0.6", None), ("-0.6", None),
                                    ("true", None), ('"45 ms"', None)), r"\[-0.5, 0.5\]"),
    # a delay: 0 for a Mid-360 on Ethernet
    ("lidar", "lidar_latency_s", (("0.06", 0.06), ("0", 0.0), ("-0.01", None), ("0.6", None), ("true", None),
                                  ('"60 ms"', None)), r"\[0, 0.5\]"),
]


@pytest.mark.parametrize("table,attribute,values,bounds", LATENCIES)
def test_the_latencies_are_read_and_bounded(tmp_path, table, attribute, values, bounds):
    """``[camera] latency_s`` and ``[lidar] latency_s``: 0 when left out, a figure within the
    table's bounds, else refused by name."""
    write_opencv_calibration(tmp_path / "cam.yaml")
    assert getattr(load_rig(write_rig(tmp_path)), attribute) == 0.0
    assert getattr(simulator_rig(), attribute) == 0.0
    text = (tmp_path / "rig.toml").read_text()
    for value, ok in values:
        (tmp_path / "rig.toml").write_text(text.replace(f"[{table}]\n", f"[{table}]\nlatency_s = {value}\n"))
        if ok is not None:
            assert getattr(load_rig(tmp_path / "rig.toml"), attribute) == ok
        else:
            with pytest.raises(ConfigError, match=rf"rig.toml: {table}.latency_s: expected a number in {bounds} s"):
                load_rig(tmp_path / "rig.toml")


def test_a_missing_rig_file_and_a_bad_value_are_named(tmp_path):
    text = (MISSIONS / "tower_a.toml").read_text()
    (tmp_path / "m1.toml").write_text(text.replace('rig = "simulator"', 'rig = "nowhere.toml"'))
    with pytest.raises(ConfigError, match="m1.toml: vehicle.rig: .*nowhere.toml: <file>: no such file"):
        load_mission(tmp_path / "m1.toml")
    (tmp_path / "m2.toml").write_text(text.replace('rig = "simulator"', "rig = 4"))
    with pytest.raises(ConfigError, match="m2.toml: vehicle.rig: expected a rig file's path"):
        load_mission(tmp_path / "m2.toml")
    (tmp_path / "m3.toml").write_text("\n".join(line for line in text.splitlines() if not line.startswith("rig =")))
    assert load_mission(tmp_path / "m3.toml").rig is None


def _rotation_y(pitch_down_deg: float) -> np.ndarray:
    """A body rotation pitching x down by the angle (FLU: a positive rotation about y)."""
    a = np.radians(pitch_down_deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    return T


def test_the_shared_view_is_inside_the_image_by_cv2_project_points_and_the_mid360_fov():
    """Reference: cv2.projectPoints with the calibration's distortion. A point straight ahead of a
    level body at each edge elevation of the shared view lands in the image (on the pinhole edge
    row or inside it: the barrel lens sees more), and one 2 deg beyond the camera's edge does not
    reach past it by more than the lens does; the lower edge is the Mid-360's -7 deg."""
    rig = simulator_rig()
    down, up = rig.vertical_view()
    assert np.degrees(down) == pytest.approx(-7.0)  # the LiDAR bounds it below
    cam = rig.camera
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
    T_c_b = np.linalg.inv(rig.T_b_c)
    for el in (down, up):
        p_b = 10.0 * np.array([np.cos(el), 0.0, np.sin(el)])
        p_c = T_c_b[:3, :3] @ p_b + T_c_b[:3, 3]
        px, _ = cv2.projectPoints(p_c[None], np.zeros(3), np.zeros(3), K, np.array(cam.dist))
        assert -0.5 - 1e-6 <= px[0, 0, 1] <= cam.height - 0.5 + 1e-6, (np.degrees(el), px)
    # the upper edge is the camera's: its top row, pinhole (cv2 without distortion)
    p_b = 10.0 * np.array([np.cos(up), 0.0, np.sin(up)])
    p_c = T_c_b[:3, :3] @ p_b + T_c_b[:3, 3]
    px, _ = cv2.projectPoints(p_c[None], np.zeros(3), np.zeros(3), K, np.zeros(5))
    assert px[0, 0, 1] == pytest.approx(-0.5, abs=1e-6)


def test_a_pitched_camera_and_a_narrower_lidar_move_the_shared_view(tmp_path):
    write_opencv_calibration(tmp_path / "cam.yaml")
    level = load_rig(write_rig(tmp_path))
    T_b_c_pitched = (_rotation_y(10.0) @ np.array(T_B_C)).tolist()
    pitched = load_rig(write_rig(tmp_path, T_b_c=T_b_c_pitched))
    (down0, up0), (down1, up1) = level.vertical_view(), pitched.vertical_view()
    assert np.degrees(up0 - up1) == pytest.approx(10.0, abs=1e-6)  # the camera's top edge came down 10 deg
    assert down0 == down1  # still the LiDAR's -7 deg
    rig = write_rig(tmp_path)  # level again
    rig.write_text(rig.read_text() + "fov_deg = [-30.0, 20.0]\n")
    narrow = load_rig(rig)
    assert narrow.lidar_fov_deg == (-30.0, 20.0)
    assert np.degrees(narrow.vertical_view()[1]) == pytest.approx(20.0)
    rig.write_text(rig.read_text().replace("fov_deg = [-30.0, 20.0]", "fov_deg = [60.0, 80.0]"))
    with pytest.raises(ConfigError, match="rig.toml: camera.T_b_c, lidar.T_b_l: .*share no elevation"):
        load_rig(rig).vertical_view()
