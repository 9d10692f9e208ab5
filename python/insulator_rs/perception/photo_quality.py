"""An inspection photo's planned figures, from the camera and the geometry (not its verdict).

For a photo taken by a camera (intrinsics ``camera``, pose ``T_c_w``) of an insulator (centre,
unit axis, length and shed diameter in W), moving at ``speed`` m/s with exposure ``exposure`` s:

* **GSD** (ground sample distance on the insulator, mm/px): the metres one pixel spans at the
  insulator, depth / focal length, at its farther end (the worst part of the string);
* **frame share**: the share of the image the string's box fills (area), and the share of the
  image's width or height its longer side spans;
* **whole**: both ends and the sheds' rims project inside the image (a margin of
  :data:`EDGE_MARGIN_PX`);
* **motion blur** (px): speed x exposure / GSD (the smear of one exposure on the sensor);
  ``blur_within_limit`` when it is at most :data:`MAX_BLUR_PX`. (Named apart from the photo's
  own sharpness, the Laplacian variance :mod:`~insulator_rs.perception.photo_check` measures.)

Defect inspection (cracked sheds, flashover marks) wants :data:`MAX_GSD_MM` = 2 mm/px or finer.
Whether a photo is fit is not decided here: that is its
:class:`~insulator_rs.perception.photo_verdict.PhotoVerdict`, from the photo itself.
Pinhole figures: lens distortion moves the ends a few pixels and is ignored for the GSD.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

import insulator_rs as ir

# mm/px: the finest detail a defect inspection needs resolved (a crack, a burn mark).
MAX_GSD_MM = 2.0
# px: at most this much smear in one exposure is within the limit (less than a pixel: no detail lost).
MAX_BLUR_PX = 1.0
# px: an end this close to the image border does not count as inside.
EDGE_MARGIN_PX = 2.0
# s: exposure of an inspection photo in daylight (1/500 s, a typical shutter for a UAV gimbal camera).
DEFAULT_EXPOSURE = 1.0 / 500.0
# m: the shed diameter of common composite/glass strings (0.2-0.3 m); the scenes' are 0.22-0.24.
STRING_DIAMETER = 0.25


#: Points on each end shed's rim: the string's outline in an image (its box) to a few pixels.
RIM_POINTS = 16


def end_rims(center: np.ndarray, unit_axis: np.ndarray, length: float, radius: float) -> np.ndarray:
    """(2 * RIM_POINTS, 3) points on the rims (``radius`` m) of a string's two end sheds (W), the
    string ``length`` m along ``unit_axis`` about ``center``: the first end's ring, then the other's."""
    u = np.asarray(unit_axis, dtype=np.float64)
    c = np.asarray(center, dtype=np.float64)
    e1 = np.cross(u, [0.0, 0.0, 1.0] if abs(u[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    a = np.linspace(0.0, 2 * np.pi, RIM_POINTS, endpoint=False)[:, None]
    ring = radius * (np.cos(a) * e1 + np.sin(a) * e2)
    return np.vstack([c - 0.5 * length * u + ring, c + 0.5 * length * u + ring])


@dataclass(frozen=True)
class PhotoQuality:
    """The figures of one inspection photo (see the module docstring)."""

    gsd_mm_px: float
    frame_share: float
    span_share: float
    whole_in_frame: bool
    motion_blur_px: float
    blur_within_limit: bool

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def _check_positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name}: must be finite and > 0, got {value}")


def photo_quality(camera: ir.CameraModel, T_c_w: np.ndarray, center: np.ndarray, axis: np.ndarray, *,
                  length: float, diameter: float = STRING_DIAMETER, speed: float = 0.0,
                  exposure: float = DEFAULT_EXPOSURE) -> PhotoQuality:
    """The figures of a photo of the insulator at ``center`` along ``axis`` (W) by ``camera`` at
    ``T_c_w`` (W -> camera optical frame). Raises ValueError naming a bad argument; an insulator
    (partly) behind the camera gives ``whole_in_frame`` False and an infinite GSD."""
    _check_positive("length", length)
    _check_positive("diameter", diameter)
    _check_positive("exposure", exposure)
    if not (math.isfinite(speed) and speed >= 0):
        raise ValueError(f"speed: must be finite and >= 0, got {speed}")
    T = np.asarray(T_c_w, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_c_w: must be a finite 4x4 matrix, got shape {T.shape}")
    c = np.asarray(center, dtype=np.float64).reshape(3)
    u = np.asarray(axis, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(u))) or np.linalg.norm(u) < 1e-9:
        raise ValueError("center/axis: must be finite and the axis non-zero")
    u = u / np.linalg.norm(u)
    # The string as its two end rims and its axis: enough for its box.
    ends = [c - 0.5 * length * u, c + 0.5 * length * u]
    pts = np.vstack([end_rims(c, u, length, 0.5 * diameter), np.stack(ends)])
    p_c = pts @ T[:3, :3].T + T[:3, 3]
    f = 0.5 * (camera.fx + camera.fy)
    depth = float(np.max(p_c[-2:, 2]))
    if np.any(p_c[:, 2] <= ir.NEAR_LIMIT):
        return PhotoQuality(math.inf, 0.0, 0.0, False, math.inf, False)
    # Pinhole pixels (no distortion: the GSD and box need no sub-pixel truth).
    uv = np.column_stack([camera.fx * p_c[:, 0] / p_c[:, 2] + camera.cx,
                          camera.fy * p_c[:, 1] / p_c[:, 2] + camera.cy])
    gsd_m = depth / f
    w, h = float(camera.width), float(camera.height)
    m = EDGE_MARGIN_PX
    whole = bool(np.all((uv[:, 0] >= m) & (uv[:, 0] <= w - 1 - m) & (uv[:, 1] >= m) & (uv[:, 1] <= h - 1 - m)))
    x1, y1 = np.clip(uv.min(axis=0), 0, [w, h])
    x2, y2 = np.clip(uv.max(axis=0), 0, [w, h])
    frame_share = float((x2 - x1) * (y2 - y1) / (w * h))
    span_share = float(max((x2 - x1) / w, (y2 - y1) / h))
    blur = speed * exposure / gsd_m
    return PhotoQuality(1000.0 * gsd_m, frame_share, span_share, whole, float(blur), bool(blur <= MAX_BLUR_PX))


def gsd_distance(camera: ir.CameraModel, max_gsd_mm: float = MAX_GSD_MM) -> float:
    """The farthest depth (m) at which ``camera`` resolves ``max_gsd_mm`` mm/px."""
    _check_positive("max_gsd_mm", max_gsd_mm)
    return 1e-3 * max_gsd_mm * 0.5 * (camera.fx + camera.fy)
