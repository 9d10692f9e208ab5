"""Calibration loaders on real files written to tmp_path (OpenCV FileStorage, ROS YAML)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml  # type: ignore[import-untyped]

import insulator_rs as ir
from insulator_rs.calibration import load_camera_model, load_opencv_yaml, load_ros_camera_info
from insulator_rs.exceptions import ConfigError

K = np.array([[1210.5, 0.0, 800.25], [0.0, 1205.0, 600.5], [0.0, 0.0, 1.0]])
DIST5 = np.array([-0.21, 0.08, 0.0012, -0.0007, -0.015])


def write_opencv(path: Path, *, k: np.ndarray | None = K, dist: np.ndarray | None = DIST5,
                 width: int | None = 1600, height: int | None = 1200) -> Path:
    """Writes a calibration file with cv2.FileStorage itself (as OpenCV's sample does)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if width is not None:
        fs.write("image_width", width)
    if height is not None:
        fs.write("image_height", height)
    if k is not None:
        fs.write("camera_matrix", k)
    if dist is not None:
        fs.write("distortion_coefficients", dist.reshape(1, -1))
    fs.release()
    return path


def ros_message(**overrides: Any) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "height": 1200,
        "width": 1600,
        "distortion_model": "plumb_bob",
        "D": DIST5.tolist(),
        "K": K.ravel().tolist(),
        "R": np.eye(3).ravel().tolist(),
        "P": np.column_stack([K, np.zeros(3)]).ravel().tolist(),
    }
    doc.update(overrides)
    return {k: v for k, v in doc.items() if v is not None}


def write_yaml(path: Path, doc: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump(doc))
    return path


def assert_is_reference_camera(cam: ir.CameraModel, dist: np.ndarray = DIST5) -> None:
    np.testing.assert_array_equal(cam.camera_matrix(), K)
    np.testing.assert_array_equal(cam.dist, dist)
    assert (cam.width, cam.height) == (1600, 1200)


def test_opencv_file_round_trip_projects_like_cv2(tmp_path: Path) -> None:
    """Reference: cv2.projectPoints with the K and dist stored in the file; 1e-6 rel / 1e-3 px."""
    path = write_opencv(tmp_path / "cam.yaml")
    assert "!!opencv-matrix" in path.read_text()
    cam = load_opencv_yaml(path)
    assert_is_reference_camera(cam)
    assert load_camera_model(path) == cam
    pts = np.random.default_rng(0).uniform([-3, -2, 4], [3, 2, 20], size=(200, 3))
    uv, _ = ir.project_points(pts, np.eye(4), cam)
    expected, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, DIST5)
    np.testing.assert_allclose(uv, expected.reshape(-1, 2), rtol=1e-6, atol=1e-3)


def test_classic_yaml_1_0_file(tmp_path: Path) -> None:
    """The ``%YAML:1.0`` layout of OpenCV's calibration sample, written by hand."""
    path = tmp_path / "classic.yml"
    path.write_text(
        "%YAML:1.0\n---\nimage_width: 1600\nimage_height: 1200\n"
        "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        f"   data: [ {', '.join(map(repr, K.ravel().tolist()))} ]\n"
        "distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n"
        f"   data: [ {', '.join(map(repr, DIST5.tolist()))} ]\n"
    )
    assert_is_reference_camera(load_camera_model(path))


def test_opencv_xml_file(tmp_path: Path) -> None:
    assert_is_reference_camera(load_camera_model(write_opencv(tmp_path / "cam.xml")))


def test_opencv_short_and_long_distortion_vectors(tmp_path: Path) -> None:
    cam = load_opencv_yaml(write_opencv(tmp_path / "four.yaml", dist=DIST5[:4]))
    np.testing.assert_array_equal(cam.dist, [*DIST5[:4], 0.0])
    eight = np.concatenate([DIST5, np.zeros(3)])
    assert_is_reference_camera(load_opencv_yaml(write_opencv(tmp_path / "eight.yaml", dist=eight)))
    rational = np.concatenate([DIST5, [0.01, 0.0, 0.0]])
    with pytest.raises(ConfigError, match=r"rational\.yaml: field 'distortion_coefficients' has non-zero terms"):
        load_opencv_yaml(write_opencv(tmp_path / "rational.yaml", dist=rational))


def test_opencv_size_override(tmp_path: Path) -> None:
    path = write_opencv(tmp_path / "nosize.yaml", width=None, height=None)
    with pytest.raises(ConfigError, match=r"nosize\.yaml: missing field 'image_width'"):
        load_opencv_yaml(path)
    cam = load_opencv_yaml(path, width=1600, height=1200)
    assert_is_reference_camera(cam)


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"k": None}, "missing field 'camera_matrix'"),
        ({"dist": None}, "missing field 'distortion_coefficients'"),
        ({"height": None}, "missing field 'image_height'"),
        ({"k": np.eye(2)}, "field 'camera_matrix' must be 3x3"),
        ({"k": np.array([[100.0, 1.0, 50], [0, 100, 50], [0, 0, 1]])}, "non-zero skew"),
        ({"k": np.array([[0.0, 0, 50], [0, 100, 50], [0, 0, 1]])}, "invalid camera parameters.*fx"),
        ({"dist": np.zeros(3)}, "must hold 4, 5, 8, 12 or 14 numbers, got 3"),
        ({"dist": np.array([np.nan, 0, 0, 0, 0])}, "non-finite"),
        ({"width": 0}, "invalid camera parameters.*width"),
    ],
)
def test_opencv_errors_name_file_and_field(tmp_path: Path, kwargs: dict[str, Any], pattern: str) -> None:
    path = write_opencv(tmp_path / "bad.yaml", **kwargs)
    with pytest.raises(ConfigError, match=rf"bad\.yaml: .*{pattern}"):
        load_opencv_yaml(path)


def test_opencv_unreadable_and_missing_files(tmp_path: Path) -> None:
    garbage = tmp_path / "garbage.yaml"
    garbage.write_text("%YAML:1.0\n---\n: : [\n")
    with pytest.raises(ConfigError, match="garbage.yaml"):
        load_opencv_yaml(garbage)
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        load_opencv_yaml(tmp_path / "nope.yaml")
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        load_camera_model(tmp_path / "nope.yaml")


def test_ros_message_forms(tmp_path: Path) -> None:
    ros1 = write_yaml(tmp_path / "ros1.yaml", ros_message())
    assert_is_reference_camera(load_ros_camera_info(ros1))
    assert_is_reference_camera(load_camera_model(ros1))
    lower = ros_message(D=None, K=None, d=DIST5.tolist(), k=K.ravel().tolist())
    assert_is_reference_camera(load_ros_camera_info(write_yaml(tmp_path / "ros2.yaml", lower)))
    rational = ros_message(distortion_model="rational_polynomial", D=[*DIST5.tolist(), 0.0, 0.0, 0.0])
    assert_is_reference_camera(load_ros_camera_info(write_yaml(tmp_path / "rat.yaml", rational)))
    uncalibrated = ros_message(D=[])
    np.testing.assert_array_equal(load_ros_camera_info(write_yaml(tmp_path / "u.yaml", uncalibrated)).dist, np.zeros(5))


def test_ros_calibration_parser_form(tmp_path: Path) -> None:
    doc = {
        "image_width": 1600,
        "image_height": 1200,
        "camera_name": "basler",
        "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": DIST5.tolist()},
    }
    assert_is_reference_camera(load_camera_model(write_yaml(tmp_path / "parser.yaml", doc)))
    del doc["distortion_coefficients"]
    with pytest.raises(ConfigError, match=r"parser2\.yaml: missing field 'distortion_coefficients'"):
        load_ros_camera_info(write_yaml(tmp_path / "parser2.yaml", doc))


@pytest.mark.parametrize(
    ("overrides", "pattern"),
    [
        ({"K": None}, "missing field 'K'"),
        ({"D": None}, "missing field 'D'"),
        ({"width": None}, "missing field 'width'"),
        ({"height": "tall"}, "field 'height' must be an integer"),
        ({"K": [1.0, 2.0]}, "field 'K' must hold 9 numbers, got 2"),
        ({"K": ["a"] * 9}, "field 'K' must be a list of numbers"),
        ({"D": [0.1, 0.2]}, "field 'D' must hold 5 numbers for distortion_model 'plumb_bob', got 2"),
        ({"distortion_model": "equidistant"}, "field 'distortion_model' is 'equidistant'"),
        (
            {"distortion_model": "rational_polynomial", "D": [*DIST5.tolist(), 0.5, 0.0, 0.0]},
            "field 'D' has non-zero terms",
        ),
    ],
)
def test_ros_errors_name_file_and_field(tmp_path: Path, overrides: dict[str, Any], pattern: str) -> None:
    path = write_yaml(tmp_path / "info.yaml", ros_message(**overrides))
    with pytest.raises(ConfigError, match=rf"info\.yaml: {pattern}"):
        load_ros_camera_info(path)


def test_ros_not_a_mapping_or_not_yaml(tmp_path: Path) -> None:
    listy = tmp_path / "list.yaml"
    listy.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="list.yaml: expected a YAML mapping"):
        load_ros_camera_info(listy)
    broken = tmp_path / "broken.yaml"
    broken.write_text("K: [1, 2\n")
    with pytest.raises(ConfigError, match="broken.yaml: not valid YAML"):
        load_ros_camera_info(broken)
