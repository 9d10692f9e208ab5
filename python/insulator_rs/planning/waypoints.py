"""Inspection viewpoints for one localized insulator.

Viewpoints lie on a circle round the insulator's centre in the plane
perpendicular to its axis, at the inspection distance (raised if needed so the
camera sees the insulator whole), fanned symmetrically about the direction that
points out of the tower on the insulator's side (the near side), and pushed
further out if a viewpoint would fall in a safety volume. Each carries the yaw
and gimbal pitch that aim the camera at the centre. All in W.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

import insulator_rs as ir
from insulator_rs.geodesy import LineFrame
from insulator_rs.inspection_camera import InspectionCamera
from insulator_rs.perception.photo_quality import MAX_GSD_MM, STRING_DIAMETER
from insulator_rs.planning.framing import frame_string
from insulator_rs.planning.safety import SafetyVolumes

# Fraction of the field of view the insulator may fill (the rest is margin for the localization error).
FILL_FRACTION = 0.7
# Step (m) when pushing a viewpoint out of a safety volume, and the clearance kept beyond it.
PUSH_STEP = 0.25
PUSH_CLEARANCE = 0.5


@dataclass(frozen=True)
class InspectionWaypoint:
    """A viewpoint in W: ``position`` (3,) m, ``yaw`` rad (body x from W x, CCW), ``gimbal_pitch``
    rad (negative looks down), ``target`` the insulator centre it aims at, ``insulator_id``
    the registry id, ``side`` the tower side it is on."""

    position: np.ndarray
    yaw: float
    gimbal_pitch: float
    target: np.ndarray
    insulator_id: int
    side: int
    # mm/px the photo camera resolves on the insulator from here (None: no camera given).
    planned_gsd_mm: float | None = None
    # the inspection camera's focal length (px, mean of fx and fy) for this shot; None: the
    # camera's only one (no dedicated inspection camera)
    focal_px: float | None = None
    tile: int = 0  # which of the string's overlapping tiles (0-based) this shot frames
    tiles: int = 1


def aim(position: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """(yaw, pitch) in rad that point the camera from ``position`` at ``target`` (W)."""
    d = np.asarray(target, dtype=np.float64) - np.asarray(position, dtype=np.float64)
    return math.atan2(d[1], d[0]), math.atan2(d[2], math.hypot(d[0], d[1]))


def viewing_distance(length: float, fov: float, inspection_distance: float) -> float:
    """Distance (m) at least ``inspection_distance`` at which an insulator ``length`` m long fills at
    most FILL_FRACTION of a field of view ``fov`` rad (the narrower one of the camera)."""
    need = (length / 2) / math.tan(FILL_FRACTION * fov / 2)
    return max(inspection_distance, need)


def framing_distance(camera: ir.CameraModel, length: float, axis: np.ndarray,
                     diameter: float = STRING_DIAMETER) -> float:
    """Distance (m) at which a string ``length`` x ``diameter`` m along ``axis`` (W), seen level
    and square-on by ``camera``, fills at most FILL_FRACTION of the image along each image axis:
    its horizontal extent against the horizontal field of view, its vertical extent against the
    vertical one (a horizontal string uses the frame's long side)."""
    u = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    vertical = abs(float(u[2]))
    ext_h = length * math.sqrt(max(0.0, 1.0 - vertical**2)) + diameter
    ext_v = length * vertical + diameter
    half_h = math.atan((camera.width / 2) / camera.fx)
    half_v = math.atan((camera.height / 2) / camera.fy)
    return max((ext_h / 2) / math.tan(FILL_FRACTION * half_h), (ext_v / 2) / math.tan(FILL_FRACTION * half_v))


def inspection_waypoints(center: np.ndarray, axis: np.ndarray, *, insulator_id: int, line: LineFrame,
                         volumes: SafetyVolumes, count: int, inspection_distance: float,
                         insulator_length: float, fov: float, fan: float = math.radians(60.0),
                         side: int | None = None, camera: ir.CameraModel | None = None,
                         max_gsd_mm: float = MAX_GSD_MM,
                         inspection: InspectionCamera | None = None) -> list[InspectionWaypoint]:
    """``count`` viewpoints for the insulator at ``center`` with unit ``axis`` (W).

    ``fan`` (rad) is the angle spanned by the viewpoints round the axis; ``side``
    defaults to the side of the centre. With the photo ``camera``, the distance is the closest
    that keeps the string whole in frame (:func:`framing_distance`, never nearer than
    ``inspection_distance``, the safety minimum), which gives the finest GSD the camera can get
    with the whole string; each waypoint carries that GSD (``planned_gsd_mm``; above
    ``max_gsd_mm`` the camera cannot reach the inspection's GSD with the string whole, and the
    photo records say so). Without it, ``fov`` (rad) frames the string as before.

    With a dedicated ``inspection`` camera (a zoom on a gimbal) the shots are framed by
    :func:`~insulator_rs.planning.framing.frame_string` instead: each viewpoint of the fan
    becomes one waypoint per tile, square-on to its tile at the closest safe distance, with the
    focal length that makes the tile fill the planned share of the frame from where it ends up
    (pushed out of a safety volume, it zooms in), and the gimbal pitch within its limits.
    Raises ValueError on a bad argument.
    """
    c = np.asarray(center, dtype=np.float64).reshape(3)
    u = np.asarray(axis, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(u))) or np.linalg.norm(u) < 1e-9:
        raise ValueError("center/axis: must be finite and the axis non-zero")
    if count < 1:
        raise ValueError(f"count: must be >= 1, got {count}")
    if not 0 < fov < math.pi:
        raise ValueError(f"fov: must lie in (0, pi) rad, got {fov}")
    u = u / np.linalg.norm(u)
    s = line.side(c) if side is None else side
    out = s * line.lateral
    e1 = out - (out @ u) * u
    if np.linalg.norm(e1) < 1e-6:  # axis across the line: look from along the outward side instead
        e1 = np.array([0.0, 0.0, 1.0]) - u[2] * u
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    if inspection is not None:
        return _framed_waypoints(c, u, e1, e2, out, s, insulator_id=insulator_id, volumes=volumes, count=count,
                                 fan=fan, inspection_distance=inspection_distance, length=insulator_length,
                                 camera=inspection, max_gsd_mm=max_gsd_mm)
    if camera is None:
        r = viewing_distance(insulator_length, fov, inspection_distance)
        gsd = None
    else:
        r = max(inspection_distance, framing_distance(camera, insulator_length, u))
        gsd = 1000.0 * r / (0.5 * (camera.fx + camera.fy))
        if not math.isfinite(max_gsd_mm) or max_gsd_mm <= 0:
            raise ValueError(f"max_gsd_mm: must be finite and > 0, got {max_gsd_mm}")
    result = []
    for direction in _fan(e1, e2, count, fan):
        p = _pushed_clear(c + r * direction, out, volumes)
        yaw, pitch = aim(p, c)
        result.append(InspectionWaypoint(p, yaw, pitch, c.copy(), insulator_id, s,
                                         None if gsd is None else gsd * float(np.linalg.norm(p - c)) / r))
    return result


def _fan(e1: np.ndarray, e2: np.ndarray, count: int, fan: float) -> list[np.ndarray]:
    """``count`` unit directions fanned over ``fan`` rad about ``e1``, in the plane of e1, e2."""
    angles = [0.0] if count == 1 else list(np.linspace(-fan / 2, fan / 2, count))
    return [math.cos(t) * e1 + math.sin(t) * e2 for t in angles]


def _pushed_clear(p: np.ndarray, out: np.ndarray, volumes: SafetyVolumes) -> np.ndarray:
    """``p`` pushed along ``out`` until it is PUSH_CLEARANCE clear of every safety volume."""
    pushed = 0.0
    while not volumes.points_clear(p[None], inflate=PUSH_CLEARANCE)[0]:
        p = p + PUSH_STEP * out
        pushed += PUSH_STEP
        if pushed > 100.0:
            raise ValueError("center: no viewpoint outside the safety volumes within 100 m")
    return p


def _framed_waypoints(c: np.ndarray, u: np.ndarray, e1: np.ndarray, e2: np.ndarray, out: np.ndarray, side: int,
                      *, insulator_id: int, volumes: SafetyVolumes, count: int, fan: float,
                      inspection_distance: float, length: float, camera: InspectionCamera,
                      max_gsd_mm: float) -> list[InspectionWaypoint]:
    """The dedicated inspection camera's waypoints (see :func:`inspection_waypoints`)."""
    framing = frame_string(c, u, length, camera, max_gsd_mm=max_gsd_mm)
    r = framing.distance(camera, inspection_distance)
    result = []
    for direction in _fan(e1, e2, count, fan):
        for k, tile in enumerate(framing.tiles):
            p = _pushed_clear(tile.target + r * direction, out, volumes)
            yaw, pitch = aim(p, tile.target)
            pitch = camera.gimbal.clamp(pitch, 0.0)[0]
            distance = float(np.linalg.norm(p - tile.target))
            focal = framing.focal_px(camera, distance)
            result.append(InspectionWaypoint(p, yaw, pitch, tile.target.copy(), insulator_id, side,
                                             1000.0 * distance / focal, focal, k, len(framing.tiles)))
    return result
