"""Do a flight's photos cover every string well enough for a defect inspection? Checked from the
scene's ground truth through each photo's own camera pose and intrinsics (issue 20's "done
when"), never through the flight's own quality figures.

For each true insulator and each photo (its ``T_w_c``, or the pose it was taken from:
``position``/``yaw`` and ``T_b_c``; the intrinsics of ``photo_camera`` or the photo's own
``camera``), the string's axis is sampled (:data:`SAMPLES` points, end to end) and projected with
the camera model (``ir.project_points``, distortion included). The part in the image (in front
of the camera, inside the frame) is measured:

* ``span_share``: the pixel length of that part over the frame's long side;
* ``gsd_mm``: depth / focal length at its farthest point (mm/px);
* ``visible``: the interval of the string (0 = one end, 1 = the other) it covers;
* ``whole_in_frame``: the whole string is in the picture: every axis point and the rims of its
  end sheds lie in front of the camera and inside the frame. The rims are drawn at the string's
  ``radius`` (its largest shed's) at its very ends: the envelope of the string, a little larger
  than the real end sheds (they sit a shed's thickness inside the ends), so a string whose end
  grazes the border within a few pixels counts as cut: the conservative answer.

The same figures answer the scorer (:mod:`~insulator_rs.evaluation.scoring`) whether the string a
photo was taken for is in it at all (``visible``) and whole: one projection, no render.

A photo *qualifies* for a string when ``span_share >= MIN_SPAN_SHARE`` (60 %) and ``gsd_mm <=
MAX_GSD_MM`` (2 mm/px). A string is *covered* when the qualifying photos' intervals together
cover at least :data:`COVERED_FRACTION` of it. Occlusion by the tower is not checked here (the
projection says where the string is in the frame, not whether steel hides part of it).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

import insulator_rs as ir
from insulator_rs.perception.photo_quality import end_rims

MIN_SPAN_SHARE = 0.60
MAX_GSD_MM = 2.0
COVERED_FRACTION = 0.99
SAMPLES = 201


def _camera(rec: Mapping[str, Any]) -> ir.CameraModel:
    return ir.CameraModel(rec["fx"], rec["fy"], rec["cx"], rec["cy"], rec["width"], rec["height"],
                          dist=tuple(rec.get("dist", (0.0,) * 5)))


def _yaw_pose(position: Iterable[float], yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = np.asarray(list(position), dtype=np.float64)
    return T


def photo_pose(photo: Mapping[str, Any]) -> np.ndarray:
    """T_w_c of a photo record: its own ``T_w_c``, else ``position``/``yaw`` (W) and ``T_b_c``."""
    if photo.get("T_w_c") is not None:
        return np.asarray(photo["T_w_c"], dtype=np.float64).reshape(4, 4)
    return _yaw_pose(photo["position"], float(photo["yaw"])) @ np.asarray(photo["T_b_c"], dtype=np.float64)


def string_in_photo(camera: ir.CameraModel, T_w_c: np.ndarray, center: np.ndarray, axis: np.ndarray,
                    length: float, *, radius: float = 0.0) -> dict[str, Any]:
    """The figures of one string (``length`` m along ``axis`` about ``center``, W; sheds of
    ``radius`` m, 0: its axis alone) in one photo by ``camera`` at ``T_w_c`` (module docstring)."""
    if not (np.isfinite(length) and length > 0):
        raise ValueError(f"length: must be finite and > 0, got {length}")
    if not (np.isfinite(radius) and radius >= 0):
        raise ValueError(f"radius: must be finite and >= 0, got {radius}")
    u = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    c = np.asarray(center, dtype=np.float64)
    t = np.linspace(0.0, 1.0, SAMPLES)
    pts = c + (t[:, None] - 0.5) * length * u
    if radius > 0:
        pts = np.vstack([pts, end_rims(c, u, length, radius)])
    T_c_w = np.linalg.inv(T_w_c)
    depth = pts @ T_c_w[:3, :3].T[:, 2] + T_c_w[2, 3]
    uv, valid = ir.project_points(pts, T_c_w, camera)
    w, h = float(camera.width), float(camera.height)
    inside_all = valid & (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    whole = bool(inside_all.all())
    inside, uv, depth = inside_all[:SAMPLES], uv[:SAMPLES], depth[:SAMPLES]
    if not inside.any():
        return {"visible": None, "visible_fraction": 0.0, "span_share": 0.0, "gsd_mm": None,
                "whole_in_frame": False}
    idx = np.flatnonzero(inside)
    a, b = int(idx[0]), int(idx[-1])  # a straight string in a pinhole image: one interval
    span_px = float(np.linalg.norm(uv[b] - uv[a]))
    f = 0.5 * (camera.fx + camera.fy)
    return {"visible": [float(t[a]), float(t[b])], "visible_fraction": float(t[b] - t[a]),
            "span_share": span_px / max(w, h), "gsd_mm": 1000.0 * float(depth[inside].max()) / f,
            "whole_in_frame": whole}


def string_in_photo_record(photo: Mapping[str, Any], insulator: Any,
                           default_camera: Mapping[str, Any] | None = None) -> dict[str, Any] | None:
    """:func:`string_in_photo` of the true ``insulator`` (``center``, ``axis``, ``length`` and
    ``radius`` when it has one, as :class:`~insulator_rs.sim.towers.InsulatorTruth`) in a
    summary's ``photo`` record, through the photo's own pose and intrinsics (its ``camera``, else
    ``default_camera``: the summary's ``photo_camera``); None when neither gives intrinsics."""
    cam_rec = photo.get("camera") or default_camera
    if cam_rec is None:
        return None
    return string_in_photo(_camera(cam_rec), photo_pose(photo), insulator.center, insulator.axis,
                           float(insulator.length), radius=float(getattr(insulator, "radius", 0.0)))


def _union_length(intervals: list[list[float]]) -> float:
    total, end = 0.0, -np.inf
    for a, b in sorted(intervals):
        if a > end:
            total += b - a
            end = b
        elif b > end:
            total += b - end
            end = b
    return total


def photo_coverage(summary: Mapping[str, Any], insulators: Iterable[Any]) -> dict[str, Any]:
    """Per true insulator (``instance_id``, ``center``, ``axis``, ``length``, as
    :class:`~insulator_rs.sim.towers.InsulatorTruth`): each photo's figures, whether it
    qualifies, the covered fraction, and whether the string is covered."""
    default_cam = summary.get("photo_camera")
    photos = list(summary.get("photos", []))
    rows = []
    for ins in insulators:
        per_photo, good = [], []
        for p in photos:
            fig = string_in_photo_record(p, ins, default_cam)
            if fig is None:
                continue
            fig["qualifies"] = bool(fig["gsd_mm"] is not None and fig["span_share"] >= MIN_SPAN_SHARE
                                    and fig["gsd_mm"] <= MAX_GSD_MM)
            if fig["visible"] is not None:
                per_photo.append({"file": p.get("file"), **fig})
            if fig["qualifies"]:
                good.append(fig["visible"])
        covered = _union_length(good)
        best = max(per_photo, key=lambda r: r["span_share"], default=None)
        rows.append({"instance_id": getattr(ins, "instance_id", None), "covered_fraction": covered,
                     "covered": covered >= COVERED_FRACTION, "qualifying_photos": len(good),
                     "best_span_share": None if best is None else best["span_share"],
                     "best_gsd_mm": min((r["gsd_mm"] for r in per_photo), default=None),
                     "photos": per_photo})
    return {"min_span_share": MIN_SPAN_SHARE, "max_gsd_mm": MAX_GSD_MM,
            "insulators_in_scene": len(rows), "insulators_covered": sum(r["covered"] for r in rows),
            "insulators": rows}
