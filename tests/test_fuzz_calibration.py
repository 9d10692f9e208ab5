"""Fuzzing the camera-calibration loaders (hypothesis; insulator_rs/calibration.py).

Contract: any existing file gives a ``CameraModel`` or a ``ConfigError`` whose message starts
with the file's path, never another exception (OpenCV's ``cv2.error`` included) and never an
80 GB allocation (a matrix claiming 100000 x 100000). And valid calibrations are accepted:
cameras generated here, written by OpenCV's own ``cv2.FileStorage`` (YAML and XML) and as ROS
camera_info (both layouts), load back with the same parameters (reference: the generated
values, exact up to the writer's float formatting, rtol 1e-12).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from insulator_rs.calibration import load_camera_model
from insulator_rs.exceptions import ConfigError

FUZZ = settings(max_examples=60, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def _clean(path: Path):
    try:
        return load_camera_model(path)
    except ConfigError as exc:
        assert str(exc).startswith(str(path)), str(exc)
        return None


PREFIXES = st.sampled_from([b"", b"%YAML:1.0\n", b"%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n",
                            b"<?xml version=\"1.0\"?>\n<opencv_storage>\n", b"K: "])


@FUZZ
@given(prefix=PREFIXES, data=st.binary(max_size=800))
def test_random_bytes_are_refused_cleanly(tmp_path_factory, prefix, data):
    path = tmp_path_factory.mktemp("c") / "calib.yaml"
    path.write_bytes(prefix + data)
    _clean(path)


numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(10**6), 10**6),
                    st.integers(10**300, 10**400), st.text(max_size=4), st.none(), st.booleans())
values = st.recursive(numbers, lambda inner: st.one_of(st.lists(inner, max_size=16),
                                                       st.dictionaries(st.sampled_from(["data", "rows", "cols"]),
                                                                       inner, max_size=3)), max_leaves=30)
ROS_KEYS = ["K", "k", "D", "d", "width", "height", "distortion_model", "camera_matrix",
            "distortion_coefficients", "image_width", "image_height"]


@FUZZ
@given(doc=st.dictionaries(st.sampled_from(ROS_KEYS), values, max_size=8))
def test_random_ros_documents_are_refused_cleanly(tmp_path_factory, doc):
    path = tmp_path_factory.mktemp("c") / "info.yaml"
    path.write_text(yaml.safe_dump(doc))
    _clean(path)


@FUZZ
@given(rows=st.integers(-5, 200_000), cols=st.integers(-5, 200_000),
       data=st.lists(st.floats(-1e3, 1e3), max_size=20), dt=st.sampled_from(["d", "f", "i", "u", "x"]),
       which=st.sampled_from(["camera_matrix", "distortion_coefficients"]))
def test_opencv_matrix_headers_are_checked(tmp_path_factory, rows, cols, data, dt, which):
    """rows/cols that disagree with the data, absurd sizes, unknown element types."""
    good = {"camera_matrix": (3, 3, [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0]),
            "distortion_coefficients": (1, 5, [0.0] * 5)}
    good[which] = (rows, cols, data)
    text = "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n"
    for name, (r, c, d) in good.items():
        text += (f"{name}: !!opencv-matrix\n   rows: {r}\n   cols: {c}\n   dt: {dt if name == which else 'd'}\n"
                 f"   data: [ {', '.join(repr(float(v)) for v in d)} ]\n")
    path = tmp_path_factory.mktemp("c") / "cv.yaml"
    path.write_text(text)
    model = _clean(path)
    if which == "camera_matrix" and (rows, cols) != (3, 3):
        assert model is None


def test_huge_and_mismatched_matrices_name_the_field(tmp_path):
    base = ("%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n"
            "camera_matrix: !!opencv-matrix\n   rows: {r}\n   cols: {c}\n   dt: d\n"
            "   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\n"
            "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
            "   data: [ 0., 0., 0., 0., 0. ]\n")
    path = tmp_path / "big.yaml"
    path.write_text(base.format(r=100000, c=100000))
    with pytest.raises(ConfigError, match=r"big.yaml: field 'camera_matrix' is 100000 x 100000"):
        load_camera_model(path)
    path.write_text(base.format(r=3, c=4))
    with pytest.raises(ConfigError, match=r"field 'camera_matrix' declares 3 x 4 = 12 elements but its "
                                          r"'data' holds 9"):
        load_camera_model(path)
    folder = tmp_path / "folder.yaml"
    folder.mkdir()
    with pytest.raises(ConfigError, match=r"folder.yaml: is a directory"):
        load_camera_model(folder)
    latin = tmp_path / "latin.yaml"
    latin.write_bytes("# Kamera München\nK: [1]\n".encode("latin-1"))
    with pytest.raises(ConfigError, match=r"latin.yaml: not UTF-8 text"):
        load_camera_model(latin)


# ---- valid calibrations are accepted -------------------------------------------------------

@st.composite
def cameras(draw):
    width, height = draw(st.integers(16, 8000)), draw(st.integers(12, 6000))
    fx, fy = draw(st.floats(50.0, 20000.0)), draw(st.floats(50.0, 20000.0))
    cx, cy = draw(st.floats(0.0, width - 1.0)), draw(st.floats(0.0, height - 1.0))
    dist = [draw(st.floats(-0.5, 0.5)) for _ in range(2)] + [draw(st.floats(-0.01, 0.01)) for _ in range(2)] \
        + [draw(st.floats(-0.2, 0.2))]
    return fx, fy, cx, cy, width, height, dist


def _check(model, cam) -> None:
    fx, fy, cx, cy, width, height, dist = cam
    np.testing.assert_allclose([model.fx, model.fy, model.cx, model.cy], [fx, fy, cx, cy], rtol=1e-12)
    assert (model.width, model.height) == (width, height)
    np.testing.assert_allclose(model.dist, dist, rtol=1e-12, atol=0)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cam=cameras(), ext=st.sampled_from(["yaml", "xml"]))
def test_opencv_written_calibrations_load(tmp_path_factory, cam, ext):
    fx, fy, cx, cy, width, height, dist = cam
    path = tmp_path_factory.mktemp("cv") / f"calib.{ext}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", width)
    fs.write("image_height", height)
    fs.write("camera_matrix", np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]))
    fs.write("distortion_coefficients", np.array([dist]))
    fs.release()
    _check(load_camera_model(path), cam)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cam=cameras(), layout=st.sampled_from(["ros1", "ros2", "parsers"]))
def test_ros_camera_info_loads_and_round_trips(tmp_path_factory, cam, layout):
    fx, fy, cx, cy, width, height, dist = cam
    k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
    if layout == "parsers":
        doc = {"image_width": width, "image_height": height, "distortion_model": "plumb_bob",
               "camera_matrix": {"rows": 3, "cols": 3, "data": k},
               "distortion_coefficients": {"rows": 1, "cols": 5, "data": dist}}
    else:
        kk, dd = ("K", "D") if layout == "ros1" else ("k", "d")
        doc = {"width": width, "height": height, "distortion_model": "plumb_bob", kk: k, dd: dist}
    path = tmp_path_factory.mktemp("ros") / "info.yaml"
    path.write_text(yaml.safe_dump(doc))
    model = load_camera_model(path)
    _check(model, cam)
    # round trip: the loaded model written back as camera_info loads to the same model
    back = {"width": model.width, "height": model.height, "distortion_model": "plumb_bob",
            "K": [model.fx, 0.0, model.cx, 0.0, model.fy, model.cy, 0.0, 0.0, 1.0],
            "D": [float(v) for v in model.dist]}
    path.write_text(yaml.safe_dump(back))
    _check(load_camera_model(path), cam)
