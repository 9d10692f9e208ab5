"""The sensor rig file: camera calibration + extrinsics, named by the mission; the simulator's
defaults come from the shipped rig; bad files are refused naming the field."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

import insulator_rs as ir
from insulator_rs.exceptions import ConfigError
from insulator_rs.mission.config import load_mission
from insulator_rs.rig import RIGS_DIR, load_rig, resolve_rig, scaled_camera, simulator_rig

MISSIONS = Path(ir.__file__).resolve().parent / "missions"
T_B_C = [[0.0, 0.0, 1.0, 0.05], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, -0.1], [0.0, 0.0, 0.0, 1.0]]
T_B_L = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.12], [0.0, 0.0, 0.0, 1.0]]


def write_opencv_calibration(path: Path) -> None:
    """A real calibration's form: OpenCV FileStorage, principal point off the centre."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1440)
    fs.write("image_height", 1080)
    fs.write("camera_matrix", np.array([[1100.0, 0, 731.2], [0, 1098.5, 528.9], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[-0.21, 0.09, 0.0004, -0.0002, -0.01]]))
    fs.release()


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
