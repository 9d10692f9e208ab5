"""The vehicle's sensor rig: camera calibration and the extrinsics ``T_b_c``, ``T_b_l``.

A rig file (TOML) describes one airframe, so many missions can share it; a mission names
it with ``[vehicle] rig = "<file>"`` (a path relative to the mission file, or the name of a
shipped rig such as ``"simulator"``). The form (see ``rigs/simulator.toml``)::

    [camera]
    calibration = "camera.yaml"   # OpenCV FileStorage, livox_camera_calib / Autoware camera-LiDAR,
                                  # Kalibr camchain or ROS camera_info YAML, relative to this file
    T_b_c = [[...], [...], [...], [0, 0, 0, 1]]   # 4x4 rows: p_b = T_b_c @ p_c; may be left out when
                                                  # the calibration holds the LiDAR-camera extrinsic

    [lidar]
    T_b_l = [[...], [...], [...], [0, 0, 0, 1]]   # 4x4 rows: p_b = T_b_l @ p_l

The simulator's own defaults (its camera lens, where its camera and Mid-360 sit) come
from the shipped ``simulator`` rig, so the simulated sensors and the perception that reads
them cannot drift apart. Every error is a :class:`~insulator_rs.exceptions.ConfigError`
naming the file and the field.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs._toml import tomllib
from insulator_rs.calibration import load_calibration
from insulator_rs.exceptions import ConfigError
from insulator_rs.poses import check_pose
from insulator_rs.textfile import read_config_text

RIGS_DIR = Path(__file__).resolve().parent / "rigs"
SIMULATOR_RIG = "simulator"


@dataclass(frozen=True)
class CameraLens:
    """What the photos' EXIF and the GCS's CAMERA_INFORMATION say of the camera: ``make``,
    ``model`` (rig file ``[camera] make``/``model``, at most 32 characters) and
    ``pixel_pitch_um`` (``[camera] pixel_pitch_um``: the sensor's pixel size, which turns the
    calibration's focal length in px into mm); None where the rig does not say."""

    make: str | None = None
    model: str | None = None
    pixel_pitch_um: float | None = None

    def focal_length_mm(self, camera: CameraModel) -> float | None:
        if self.pixel_pitch_um is None:
            return None
        return 0.5 * (camera.fx + camera.fy) * self.pixel_pitch_um * 1e-3


@dataclass(frozen=True)
class SensorRig:
    """A validated rig: ``camera`` (full-resolution intrinsics), ``T_b_c`` and ``T_b_l`` (4x4
    float64 rigid transforms), ``source`` (the file it came from), ``lens`` (make, model, pixel
    pitch of the camera, where the rig gives them)."""

    source: str
    camera: CameraModel
    T_b_c: np.ndarray
    T_b_l: np.ndarray
    lens: CameraLens = CameraLens()

    def exif_camera(self) -> dict[str, Any]:
        """The photos' EXIF camera fields: make, model and the focal length in mm (from the
        full-resolution calibration and the pixel pitch; None where the rig does not say)."""
        return {"make": self.lens.make, "model": self.lens.model,
                "focal_length_mm": self.lens.focal_length_mm(self.camera)}


def resolve_rig(name: str, relative_to: Path | None = None) -> Path:
    """The rig file ``name`` stands for: a shipped rig's name, or a path (relative to
    ``relative_to``, the mission file's folder, when not absolute)."""
    shipped = RIGS_DIR / f"{name}.toml"
    if "/" not in name and "\\" not in name and not name.endswith(".toml") and shipped.is_file():
        return shipped
    path = Path(name).expanduser()
    if not path.is_absolute() and relative_to is not None:
        path = relative_to / path
    return path


def _matrix(source: str, table: dict[str, Any], prefix: str, key: str) -> np.ndarray:
    field = f"{prefix}.{key}"
    if key not in table:
        raise ConfigError(f"{source}: {field}: missing (a 4x4 matrix, rows)")
    try:
        value = np.array(table[key], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: {field}: expected 4 rows of 4 numbers ({exc})") from exc
    try:
        return check_pose(field, value)
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from exc


def _table(source: str, data: dict[str, Any], key: str, allowed: set[str]) -> dict[str, Any]:
    table = data.get(key)
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: {key}: missing table" if table is None
                          else f"{source}: {key}: expected a table, got {type(table).__name__}")
    extra = sorted(set(table) - allowed)
    if extra:
        raise ConfigError(f"{source}: {key}.{extra[0]}: unknown field (allowed: {', '.join(sorted(allowed))})")
    return table


def load_rig(path: str | Path) -> SensorRig:
    """Read and validate a rig file (see the module docstring)."""
    p = Path(path)
    source = str(p)
    text = read_config_text(p, f"{source}: <file>")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: <file>: cannot parse: {exc}") from exc
    extra = sorted(set(data) - {"camera", "lidar"})
    if extra:
        raise ConfigError(f"{source}: {extra[0]}: unknown field (allowed: camera, lidar)")
    cam_t = _table(source, data, "camera", {"calibration", "T_b_c", "make", "model", "pixel_pitch_um"})
    lidar_t = _table(source, data, "lidar", {"T_b_l"})
    calibration = cam_t.get("calibration")
    if not isinstance(calibration, str) or not calibration:
        raise ConfigError(f"{source}: camera.calibration: expected the calibration file's path, "
                          f"got {calibration!r}")
    cal_path = Path(calibration).expanduser()
    if not cal_path.is_absolute():
        cal_path = p.resolve().parent / cal_path
    try:
        cal = load_calibration(cal_path)
    except (ConfigError, OSError) as exc:  # a bad calibration, or none at that path
        raise ConfigError(f"{source}: camera.calibration: {exc}") from exc
    T_b_l = _matrix(source, lidar_t, "lidar", "T_b_l")
    if "T_b_c" in cam_t or cal.T_c_l is None:
        T_b_c = _matrix(source, cam_t, "camera", "T_b_c")
    else:  # the camera-LiDAR calibration's extrinsic places the camera on the body through the LiDAR
        T_b_c = T_b_l @ np.linalg.inv(cal.T_c_l)
    return SensorRig(source, cal.camera, T_b_c, T_b_l, _lens(source, cam_t))


def _lens(source: str, cam_t: dict[str, Any]) -> CameraLens:
    """``[camera] make``, ``model`` (printable ASCII, 1-32 characters: EXIF and MAVLink's
    CAMERA_INFORMATION hold 32 bytes) and ``pixel_pitch_um`` (0.5-50 um: phone to machine-vision
    sensors)."""
    names: dict[str, str | None] = {}
    for key in ("make", "model"):
        v = cam_t.get(key)
        if v is not None and not (isinstance(v, str) and 1 <= len(v) <= 32 and all(32 <= ord(c) < 127 for c in v)):
            raise ConfigError(f"{source}: camera.{key}: expected 1-32 printable ASCII characters, got {v!r}")
        names[key] = v
    pitch = cam_t.get("pixel_pitch_um")
    if pitch is not None:
        if isinstance(pitch, bool) or not isinstance(pitch, (int, float)) or not (0.5 <= float(pitch) <= 50.0):
            raise ConfigError(f"{source}: camera.pixel_pitch_um: expected a number in [0.5, 50] um, got {pitch!r}")
        pitch = float(pitch)
    return CameraLens(names["make"], names["model"], pitch)


@functools.lru_cache(maxsize=1)
def _simulator_rig() -> SensorRig:
    return load_rig(RIGS_DIR / f"{SIMULATOR_RIG}.toml")


def simulator_rig() -> SensorRig:
    """The shipped rig of the simulated airframe (arrays copied: callers may modify them)."""
    rig = _simulator_rig()
    return SensorRig(rig.source, rig.camera, rig.T_b_c.copy(), rig.T_b_l.copy(), rig.lens)


def scaled_camera(model: CameraModel, scale: float) -> CameraModel:
    """``model`` for the same lens at ``scale`` times the resolution (a binned or resized image).

    Pixel centres sit at integer coordinates (OpenCV), so a pixel edge at -0.5 stays at -0.5:
    ``u' = (u + 0.5) * s - 0.5`` for the principal point, ``f' = f * s``; distortion acts on
    normalized coordinates and is unchanged. The per-axis factor is the rounded size's
    (``w' / w``), so the image still spans the same field of view."""
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale: must be a finite number > 0, got {scale!r}")
    w, h = max(16, int(round(model.width * scale))), max(12, int(round(model.height * scale)))
    sx, sy = w / model.width, h / model.height
    return CameraModel(model.fx * sx, model.fy * sy, (model.cx + 0.5) * sx - 0.5, (model.cy + 0.5) * sy - 0.5,
                       w, h, dist=[float(k) for k in model.dist])
