"""Load a :class:`insulator_rs.CameraModel` from camera-calibration files.

Two formats are read:

* OpenCV ``cv::FileStorage`` YAML (``%YAML:1.0``, as written by OpenCV's
  calibration sample): ``camera_matrix`` and ``distortion_coefficients`` as
  ``!!opencv-matrix`` nodes, ``image_width`` / ``image_height`` integers.
  Parsed with ``cv2.FileStorage`` itself, so whatever OpenCV writes, we read.
* livox_camera_calib's / Autoware's camera-LiDAR OpenCV YAML: ``CameraMat``, ``DistCoeffs``
  (or ``DistCoeff``), ``Camera.width`` / ``Camera.height`` (or ``ImageSize``), and the
  LiDAR-to-camera extrinsic ``ExtrinsicMat`` (``p_c = T_c_l p_l``; Autoware's
  ``CameraExtrinsicMat`` is the camera's pose in the LiDAR frame, inverted here).
* Kalibr's ``camchain.yaml``: ``cam0`` with ``camera_model: pinhole``, ``intrinsics``
  (fu, fv, pu, pv), ``distortion_model: radtan``, ``distortion_coeffs`` (k1, k2, r1, r2),
  ``resolution`` and ``T_cam_imu``.
* ROS ``sensor_msgs/CameraInfo`` YAML, either the message form (``width``,
  ``height``, ``distortion_model``, ``D``, ``K``; ROS 2's lowercase ``d``/``k``
  too) or the ``camera_calibration_parsers`` form (``image_width``,
  ``image_height``, ``distortion_model``, ``camera_matrix: {data: [...]}``,
  ``distortion_coefficients: {data: [...]}``).

The camera model is OpenCV's pinhole with radial-tangential distortion
(k1, k2, p1, p2, k3). A file whose lens model needs more than that (non-zero
k4..k6 of the rational model, a thin-prism or tilt term, a skew of 1e-3 fx or more, a
fisheye model) is refused rather than silently approximated; a smaller skew (real
calibrations carry ~0.1 px) is folded in with a warning. Every error is a
:class:`insulator_rs.exceptions.ConfigError` whose message names the file and
the field.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from insulator_rs._core import CameraModel
from insulator_rs.exceptions import ConfigError
from insulator_rs.poses import check_pose
from insulator_rs.textfile import read_config_text

__all__ = ["Calibration", "load_calibration", "load_camera_model", "load_kalibr_camchain", "load_opencv_yaml",
           "load_ros_camera_info"]

# A skew below this fraction of fx is a calibration's numerical residue (~0.1 px), folded in
# with a warning: the model has none (it moves a point by under 1 px across 1000 px of height).
SKEW_FOLD_FRACTION = 1e-3

# Distortion models of ROS camera_info whose first five coefficients are OpenCV's
# (k1, k2, p1, p2, k3); "rational_polynomial" appends k4, k5, k6 (denominator terms).
_ROS_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial")
_N_DIST = 5
_Dist = tuple[float, float, float, float, float]  # (k1, k2, p1, p2, k3)
# Most elements of an !!opencv-matrix we read: a 3x3 camera matrix, at most 14 distortion
# coefficients. Checked before OpenCV allocates the matrix (a file claiming 100000 x 100000
# would make it try 80 GB).
_MAX_MATRIX_SIDE = 14


@dataclass(frozen=True)
class Calibration:
    """What a calibration file holds: the ``camera`` and, where the file has one, the
    LiDAR-to-camera extrinsic ``T_c_l`` (4x4, ``p_c = T_c_l @ p_l``) or Kalibr's ``T_cam_imu``."""

    camera: CameraModel
    T_c_l: np.ndarray | None = None
    T_cam_imu: np.ndarray | None = None


def load_camera_model(path: str | Path) -> CameraModel:
    """Load a camera model from any calibration file :func:`load_calibration` reads."""
    return load_calibration(path).camera


def load_calibration(path: str | Path) -> Calibration:
    """Load a calibration file: OpenCV FileStorage (plain, or livox_camera_calib's / Autoware's
    camera-LiDAR layout), Kalibr camchain or ROS camera_info (see the module docstring).

    OpenCV files are told by their ``%YAML:1.0`` header (older OpenCV), an
    ``!!opencv-matrix`` node (OpenCV 4/5 write ``%YAML 1.2``) or an ``<opencv_storage>``
    XML root; Kalibr's by a ``cam0`` with ``intrinsics``; anything else is ROS camera_info.
    """
    path = Path(path)
    text = _read_text(path)
    if text.lstrip().startswith("%YAML:") or "!!opencv-matrix" in text or "<opencv_storage>" in text:
        return _load_opencv_calibration(path)
    if "cam0:" in text and "intrinsics" in text:
        return load_kalibr_camchain(path)
    return Calibration(load_ros_camera_info(path))


def load_opencv_yaml(
    path: str | Path, *, width: int | None = None, height: int | None = None
) -> CameraModel:
    """Read an OpenCV ``FileStorage`` calibration file (YAML or XML).

    ``width``/``height`` (pixels) override or stand in for ``image_width`` /
    ``image_height`` when the file lacks them.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: calibration file not found")
    storage = _open_storage(path)
    try:
        k = _opencv_matrix(storage, path, "camera_matrix")
        dist = _opencv_matrix(storage, path, "distortion_coefficients")
        size = {
            "image_width": width if width is not None else _opencv_int(storage, path, "image_width"),
            "image_height": height
            if height is not None
            else _opencv_int(storage, path, "image_height"),
        }
    finally:
        storage.release()
    return _camera_from_arrays(
        path,
        k,
        "camera_matrix",
        _opencv_distortion(path, dist),
        size["image_width"],
        size["image_height"],
    )


def _load_opencv_calibration(path: Path) -> Calibration:
    """An OpenCV FileStorage file: the plain calibration layout, or the camera-LiDAR one."""
    import cv2

    storage = _open_storage(path)
    try:
        if storage.getNode("CameraMat").empty():
            return Calibration(load_opencv_yaml(path))
        k = _opencv_matrix(storage, path, "CameraMat")
        d_field = "DistCoeffs" if not storage.getNode("DistCoeffs").empty() else "DistCoeff"
        dist = _opencv_matrix(storage, path, d_field)
        if not storage.getNode("Camera.width").empty():
            width, height = _opencv_int(storage, path, "Camera.width"), _opencv_int(storage, path, "Camera.height")
        else:
            size = storage.getNode("ImageSize")
            if size.empty() or size.size() != 2:
                raise ConfigError(f"{path}: missing field 'Camera.width'/'Camera.height' (or 'ImageSize')")
            width, height = int(size.at(0).real()), int(size.at(1).real())
        e_field = next((f for f in ("ExtrinsicMat", "CameraExtrinsicMat") if not storage.getNode(f).empty()), None)
        T_c_l = None
        if e_field is not None:
            T = _opencv_matrix(storage, path, e_field)
            if T.shape != (4, 4):
                raise ConfigError(f"{path}: field '{e_field}' must be 4x4, got shape {T.shape}")
            T_c_l = _rigid(path, e_field, T)
            if e_field == "CameraExtrinsicMat":  # Autoware writes the camera's pose in the LiDAR frame
                T_c_l = np.linalg.inv(T_c_l)
    except cv2.error as exc:
        raise ConfigError(f"{path}: not a readable OpenCV FileStorage file ({exc})") from exc
    finally:
        storage.release()
    camera = _camera_from_arrays(path, k, "CameraMat", _opencv_distortion(path, dist), width, height)
    return Calibration(camera, T_c_l=T_c_l)


def load_kalibr_camchain(path: str | Path, camera: str = "cam0") -> Calibration:
    """Read ``camera`` (default ``cam0``) of a Kalibr ``camchain.yaml`` (pinhole, radtan)."""
    path = Path(path)
    doc = _yaml_mapping(path)
    cam = doc.get(camera)
    if not isinstance(cam, Mapping):
        raise ConfigError(f"{path}: missing field '{camera}' (a Kalibr camera chain's camera)")
    model = cam.get("camera_model", "pinhole")
    if model != "pinhole":
        raise ConfigError(f"{path}: field '{camera}.camera_model' is {model!r}; supported: 'pinhole'")
    dmodel = cam.get("distortion_model", "radtan")
    if dmodel not in ("radtan", "none"):
        raise ConfigError(f"{path}: field '{camera}.distortion_model' is {dmodel!r}; supported: 'radtan' "
                          f"(OpenCV's radial-tangential)")
    intr = _float_array(path, f"{camera}.intrinsics", cam.get("intrinsics")).ravel()
    if intr.size != 4:
        raise ConfigError(f"{path}: field '{camera}.intrinsics' must hold fu, fv, pu, pv, got {intr.size} numbers")
    coeffs = _float_array(path, f"{camera}.distortion_coeffs", cam.get("distortion_coeffs", [])).ravel()
    if dmodel == "radtan" and coeffs.size != 4:
        raise ConfigError(f"{path}: field '{camera}.distortion_coeffs' must hold k1, k2, r1, r2, got {coeffs.size}")
    res = _float_array(path, f"{camera}.resolution", cam.get("resolution")).ravel()
    if res.size != 2 or not np.all(res == np.round(res)) or np.any(res <= 0):
        raise ConfigError(f"{path}: field '{camera}.resolution' must be [width, height] in pixels")
    k = np.array([[intr[0], 0.0, intr[2]], [0.0, intr[1], intr[3]], [0.0, 0.0, 1.0]])
    dist = _five_coefficients(path, f"{camera}.distortion_coeffs", coeffs)
    cam_model = _camera_from_arrays(path, k, f"{camera}.intrinsics", dist, int(res[0]), int(res[1]))
    T_cam_imu = None
    if "T_cam_imu" in cam:
        rows = cam["T_cam_imu"]
        if not isinstance(rows, Sequence) or isinstance(rows, (str, bytes)) or len(rows) != 4:
            raise ConfigError(f"{path}: field '{camera}.T_cam_imu' must be 4 rows of 4 numbers")
        T = np.stack([_float_array(path, f"{camera}.T_cam_imu[{i}]", r) for i, r in enumerate(rows)]) \
            if all(isinstance(r, Sequence) and len(r) == 4 for r in rows) else np.zeros((0,))
        if T.shape != (4, 4):
            raise ConfigError(f"{path}: field '{camera}.T_cam_imu' must be 4x4, got shape {T.shape}")
        T_cam_imu = _rigid(path, f"{camera}.T_cam_imu", T)
    return Calibration(cam_model, T_cam_imu=T_cam_imu)


def load_ros_camera_info(path: str | Path) -> CameraModel:
    """Read a ROS camera_info YAML file (message or camera_calibration_parsers form)."""
    path = Path(path)
    doc = _yaml_mapping(path)

    if "camera_matrix" in doc:  # camera_calibration_parsers layout
        k_field, d_field, w_field, h_field = (
            "camera_matrix",
            "distortion_coefficients",
            "image_width",
            "image_height",
        )
        k_raw = _ros_data(path, doc, k_field)
        d_raw = _ros_data(path, doc, d_field)
    else:  # message layout (ROS 1 upper-case, ROS 2 lower-case)
        k_field = _first_present(doc, ("K", "k"), path)
        d_field = _first_present(doc, ("D", "d"), path)
        w_field, h_field = "width", "height"
        k_raw, d_raw = doc[k_field], doc[d_field]

    model = doc.get("distortion_model", "plumb_bob")
    if model not in _ROS_DISTORTION_MODELS:
        raise ConfigError(
            f"{path}: field 'distortion_model' is {model!r}; supported: "
            + ", ".join(_ROS_DISTORTION_MODELS)
        )
    k = _float_array(path, k_field, k_raw)
    d = _float_array(path, d_field, d_raw).ravel()
    if k.size != 9:
        raise ConfigError(f"{path}: field '{k_field}' must hold 9 numbers, got {k.size}")
    expected = {"plumb_bob": 5, "rational_polynomial": 8}[model]
    if d.size not in (0, expected):  # an uncalibrated camera publishes an empty D
        raise ConfigError(
            f"{path}: field '{d_field}' must hold {expected} numbers for "
            f"distortion_model {model!r}, got {d.size}"
        )
    dist = _five_coefficients(path, d_field, d)
    return _camera_from_arrays(
        path,
        k.reshape(3, 3),
        k_field,
        dist,
        _int_field(path, doc, w_field),
        _int_field(path, doc, h_field),
    )


# --- helpers ------------------------------------------------------------------------


def _yaml_mapping(path: Path) -> Mapping[str, Any]:
    """The YAML document at ``path``, a mapping; every failure a ConfigError naming the file."""
    try:
        doc = yaml.safe_load(_read_text(path))
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc})") from exc
    except (ValueError, OverflowError, RecursionError) as exc:
        if isinstance(exc, ConfigError):
            raise
        # PyYAML's constructors: a date such as 2001-02-30, a too deeply nested document.
        raise ConfigError(f"{path}: not valid YAML ({type(exc).__name__}: {exc})") from exc
    if not isinstance(doc, Mapping):
        raise ConfigError(f"{path}: expected a YAML mapping at the top level")
    return doc


def _read_text(path: Path) -> str:
    if not path.exists() and not path.is_symlink():
        raise FileNotFoundError(f"{path}: calibration file not found")
    return read_config_text(path, str(path))


def _opencv_matrix(storage: Any, path: Path, field: str) -> np.ndarray:
    node = storage.getNode(field)
    if node.isNone():
        raise ConfigError(f"{path}: missing field '{field}'")
    if not node.isMap():
        raise ConfigError(f"{path}: field '{field}' is not an !!opencv-matrix node")
    rows, cols, data = node.getNode("rows"), node.getNode("cols"), node.getNode("data")
    if not (rows.isInt() and cols.isInt()):
        raise ConfigError(f"{path}: field '{field}' needs integer 'rows' and 'cols'")
    n_rows, n_cols = int(rows.real()), int(cols.real())
    if not (1 <= n_rows <= _MAX_MATRIX_SIDE and 1 <= n_cols <= _MAX_MATRIX_SIDE):
        raise ConfigError(f"{path}: field '{field}' is {n_rows} x {n_cols}; a camera matrix is 3 x 3 "
                          f"and distortion has at most 14 coefficients")
    if not data.isSeq() or data.size() != n_rows * n_cols:
        got = data.size() if data.isSeq() else "no list"
        raise ConfigError(f"{path}: field '{field}' declares {n_rows} x {n_cols} = {n_rows * n_cols} "
                          f"elements but its 'data' holds {got}")
    import cv2

    try:
        mat = node.mat()
    except cv2.error as exc:  # e.g. a 'dt' OpenCV does not know
        raise ConfigError(f"{path}: field '{field}' is not a readable !!opencv-matrix ({exc})") from exc
    if mat is None:
        raise ConfigError(f"{path}: field '{field}' is not an !!opencv-matrix node")
    return np.asarray(mat, dtype=np.float64)


def _opencv_int(storage: Any, path: Path, field: str) -> int:
    node = storage.getNode(field)
    if node.isNone():
        raise ConfigError(f"{path}: missing field '{field}' (pass width=/height= to supply it)")
    if not node.isInt():
        raise ConfigError(f"{path}: field '{field}' must be an integer")
    return int(node.real())


def _opencv_distortion(path: Path, dist: np.ndarray) -> _Dist:
    flat = dist.ravel()
    # OpenCV writes 4, 5, 8, 12 or 14 coefficients; (k1,k2,p1,p2[,k3[,k4,k5,k6[,s1..s4[,tx,ty]]]]).
    if flat.size not in (4, 5, 8, 12, 14):
        raise ConfigError(
            f"{path}: field 'distortion_coefficients' must hold 4, 5, 8, 12 or 14 numbers, "
            f"got {flat.size}"
        )
    return _five_coefficients(path, "distortion_coefficients", flat)


def _five_coefficients(path: Path, field: str, coeffs: np.ndarray) -> _Dist:
    """(k1, k2, p1, p2, k3) from a longer or shorter OpenCV coefficient vector.

    Missing trailing terms are zero (4 coefficients: no k3; none: no distortion).
    Extra terms must be zero: projecting without a non-zero k4..k6 or prism term
    would be silently wrong.
    """
    if not np.all(np.isfinite(coeffs)):
        raise ConfigError(f"{path}: field '{field}' holds a non-finite number")
    extra = coeffs[_N_DIST:]
    if np.any(extra != 0.0):
        raise ConfigError(
            f"{path}: field '{field}' has non-zero terms beyond (k1, k2, p1, p2, k3) "
            f"({extra.tolist()}); this lens model is not supported"
        )
    padded = np.zeros(_N_DIST)
    padded[: min(coeffs.size, _N_DIST)] = coeffs[:_N_DIST]
    k1, k2, p1, p2, k3 = (float(c) for c in padded)
    return (k1, k2, p1, p2, k3)


def _camera_from_arrays(
    path: Path, k: np.ndarray, k_field: str, dist: _Dist, width: int, height: int
) -> CameraModel:
    if k.shape != (3, 3):
        raise ConfigError(f"{path}: field '{k_field}' must be 3x3, got shape {k.shape}")
    if not np.all(np.isfinite(k)):
        raise ConfigError(f"{path}: field '{k_field}' holds a non-finite number")
    if k[0, 1] != 0.0:
        if not abs(k[0, 1]) < SKEW_FOLD_FRACTION * abs(k[0, 0]):
            raise ConfigError(f"{path}: field '{k_field}' has a non-zero skew of {k[0, 1]:g} px (>= {SKEW_FOLD_FRACTION:g} fx); "
                              f"the camera model has none")
        warnings.warn(f"{path}: field '{k_field}': skew {k[0, 1]:g} px (< {SKEW_FOLD_FRACTION:g} fx) folded in "
                      f"(the camera model has none)", stacklevel=3)
        k = k.copy()
        k[0, 1] = 0.0
    if k[1, 0] != 0.0 or not np.array_equal(k[2], [0.0, 0.0, 1.0]):
        raise ConfigError(
            f"{path}: field '{k_field}' is not a camera matrix [[fx,0,cx],[0,fy,cy],[0,0,1]]"
        )
    try:
        return CameraModel(
            float(k[0, 0]),
            float(k[1, 1]),
            float(k[0, 2]),
            float(k[1, 2]),
            width,
            height,
            dist=dist,
        )
    except (ValueError, TypeError, OverflowError) as exc:
        raise ConfigError(f"{path}: invalid camera parameters ({exc})") from exc


def _ros_data(path: Path, doc: Mapping[str, Any], field: str) -> Any:
    node = doc.get(field)
    if node is None:
        raise ConfigError(f"{path}: missing field '{field}'")
    if not isinstance(node, Mapping) or "data" not in node:
        raise ConfigError(f"{path}: missing field '{field}.data'")
    return node["data"]


def _first_present(doc: Mapping[str, Any], names: Sequence[str], path: Path) -> str:
    for name in names:
        if name in doc:
            return name
    raise ConfigError(f"{path}: missing field '{names[0]}'")


def _float_array(path: Path, field: str, raw: Any) -> np.ndarray:
    if isinstance(raw, (str, bytes)) or not isinstance(raw, Sequence):
        raise ConfigError(f"{path}: field '{field}' must be a list of numbers")
    try:
        values = [float(x) for x in raw if not isinstance(x, (bool, str, bytes))]
    except (TypeError, ValueError, OverflowError) as exc:
        raise ConfigError(f"{path}: field '{field}' must be a list of numbers ({exc})") from exc
    if len(values) != len(raw):
        raise ConfigError(f"{path}: field '{field}' must be a list of numbers")
    return np.asarray(values, dtype=np.float64)


def _int_field(path: Path, doc: Mapping[str, Any], field: str) -> int:
    if field not in doc:
        raise ConfigError(f"{path}: missing field '{field}'")
    value = doc[field]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{path}: field '{field}' must be an integer, got {value!r}")
    if isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        raise ConfigError(f"{path}: field '{field}' must be an integer, got {value!r}")
    return int(value)


def _rigid(path: Path, field: str, T: np.ndarray) -> np.ndarray:
    """``T`` checked as a rigid transform (rotation and translation), named on error."""
    try:
        return check_pose(f"{path}: field '{field}'", T)
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc


def _open_storage(path: Path) -> Any:
    import cv2  # local: cv2 is heavy and only the OpenCV loaders need it

    if path.is_dir():
        raise ConfigError(f"{path}: is a directory, not a file")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV raises SystemError on parse failures
        raise ConfigError(f"{path}: not a readable OpenCV FileStorage file ({exc})") from exc
    if not storage.isOpened():
        raise ConfigError(f"{path}: not a readable OpenCV FileStorage file")
    return storage
