"""Does a localized cluster look like an insulator? The false-find filter of onboard perception.

A detector's false box on tower steel still gives ``localize`` a line to fit: a lattice member
or a conductor seen through the box. Before a localization counts, the points that determined
it (the DBSCAN cluster's points within tau of the fitted line, as ``localize`` takes them) and
the box must look like a string of the mission's insulators:

* **length**: the points' extent along the axis (2.5-97.5 percentile) lies between
  :data:`MIN_LENGTH_FRACTION` and :data:`MAX_LENGTH_FRACTION` of the insulator's length (the
  LiDAR may see only part of a string, never much more than all of it);
* **linearity**: PCA ``(l1 - l2) / l1`` at least :data:`MIN_LINEARITY` (a plate or a lattice node
  is planar or compact, a string is a line);
* **diameter**: the RMS distance of the points from the axis at most :data:`MAX_SPREAD_FRACTION`
  of the string's diameter (a wider object is not a string);
* **relief**: the spread of the points along the line of sight (after removing the line) at
  least :data:`MIN_RELIEF`. Sheds stand ~0.1 m proud of the core, so a string's visible surface
  is corrugated in depth; a steel member's flat face or a 27 mm conductor shows only the range
  noise (2 cm for a Mid-360). This is what tells a horizontal lattice strut, which is as long and
  straight as a string, from the string;
* **box aspect** (when the box and camera are given): the box's width/height against those of
  an insulator of the known length and diameter at the localized centre and axis, projected,
  within a factor :data:`ASPECT_TOLERANCE` (a vertical member boxed as a horizontal insulator).

The thresholds were set on the simulated Mid-360 (2 cm range noise, 3 accumulated events) with
the shipped ``insulator-sim`` network on towers A and B: see docs/results/insulator_shape.md for
the distributions and the per-track counts. They are sensor-dependent: a LiDAR with much larger
range noise needs a larger :data:`MIN_RELIEF`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

import insulator_rs as ir
from insulator_rs.perception.photo_quality import STRING_DIAMETER

# Length window, as fractions of the mission's insulator length.
MIN_LENGTH_FRACTION = 0.3
MAX_LENGTH_FRACTION = 1.5
# PCA linearity (l1 - l2) / l1 of a string seen from 4-20 m: 0.95-0.998 in simulation.
MIN_LINEARITY = 0.95
# RMS distance from the axis, as a fraction of the diameter: the visible half-surface of a
# string gives 0.1-0.4 of it; 0.5 leaves room for noise and a fitting at the end.
MAX_SPREAD_FRACTION = 0.5
# m: depth spread (std along the line of sight, the line removed), as the median over a track's
# localizations (one localization's figure from 10-50 points is noisy). In simulation (Mid-360,
# 2 cm range noise, insulator-sim network) the track medians of strings are 0.034-0.037 on towers
# A and B, those of the false tracks on tower A's steel 0.018-0.025. A string seen only three
# times at 12-16 points can still score 0.024 (its first three figures): such a string is
# confirmed only once later localizations lift its median.
MIN_RELIEF = 0.026
# A track's relief is judged from its 3rd localization on, as the median of its first ones: one
# figure from 10-50 points is too noisy to tell a strut from a string, and the registry confirms an
# insulator at its 4th localization (the mission's default confirmations), so the confirming
# localization carries the evidence of three or more. A string gets tens of localizations in a pass.
MIN_RELIEF_SAMPLES = 3
# The box's aspect (width/height) may differ from the predicted one by this factor. The network's
# boxes round true strings in simulation: 0.43-2.09 of the prediction (1st-99th percentile
# 0.61-1.58); a box round a lattice node, whose fitted line is the upright leg: 2.8-3.5.
ASPECT_TOLERANCE = 2.5
# Fewer points than this and no shape can be told: refused.
MIN_SHAPE_POINTS = 8


@dataclass(frozen=True)
class ClusterShape:
    """The shape of the points that determined a localization (metres).

    ``length``: 2.5-97.5 percentile extent along the principal axis; ``linearity``: PCA
    (l1 - l2) / l1; ``spread``: RMS distance from the axis; ``relief``: std along the line of
    sight after removing the line; ``n_points``.
    """

    n_points: int
    length: float
    linearity: float
    spread: float
    relief: float


@dataclass(frozen=True)
class ShapeVerdict:
    """Whether the cluster looks like an insulator; ``reasons`` names each failed check."""

    ok: bool
    reasons: tuple[str, ...]
    shape: ClusterShape | None
    aspect_ratio: float | None


def line_members(points_b: np.ndarray, center_b: np.ndarray, axis_b: np.ndarray) -> np.ndarray:
    """The points of ``points_b`` (N, 3, B) that ``localize`` used for the line through
    ``center_b`` along ``axis_b``: those within tau of it, in the DBSCAN cluster that holds most
    of them (``localize``'s default eps, min_points and tau)."""
    d = ir.localize_defaults()
    pts = np.asarray(points_b, dtype=np.float64).reshape(-1, 3)
    u = np.asarray(axis_b, dtype=np.float64) / np.linalg.norm(axis_b)
    v = pts - np.asarray(center_b, dtype=np.float64)
    perp = np.linalg.norm(v - np.outer(v @ u, u), axis=1)
    labels = ir.dbscan(pts, float(d["eps"]), int(d["min_points"]))
    near = (perp <= float(d["tau"])) & (labels >= 0)
    if not np.any(near):
        return pts[:0]
    best = int(np.bincount(labels[near]).argmax())
    return pts[near & (labels == best)]


def cluster_shape(members: np.ndarray, sensor: np.ndarray | None = None) -> ClusterShape | None:
    """Shape of a cluster (N, 3) seen from ``sensor`` (default the origin of its frame); None
    for fewer than :data:`MIN_SHAPE_POINTS` points."""
    m = np.asarray(members, dtype=np.float64).reshape(-1, 3)
    if len(m) < MIN_SHAPE_POINTS:
        return None
    c = m.mean(axis=0)
    w, vecs = np.linalg.eigh(np.cov((m - c).T))
    w = np.maximum(w[::-1], 0.0)
    axis = vecs[:, -1]
    ray = c - (np.zeros(3) if sensor is None else np.asarray(sensor, dtype=np.float64))
    ray /= max(float(np.linalg.norm(ray)), 1e-9)
    across = np.cross(axis, ray)
    if np.linalg.norm(across) < 1e-6:  # seen end-on: no depth direction apart from the axis
        depth = ray
    else:
        depth = np.cross(across / np.linalg.norm(across), axis)
    t = (m - c) @ axis
    return ClusterShape(
        n_points=len(m),
        length=float(np.percentile(t, 97.5) - np.percentile(t, 2.5)),
        linearity=float((w[0] - w[1]) / w[0]) if w[0] > 0 else 0.0,
        spread=float(math.sqrt(w[1] + w[2])),
        relief=float(np.std((m - c) @ depth)),
    )


def box_aspect_ratio(center_w: np.ndarray, axis_w: np.ndarray, box: np.ndarray, T_c_w: np.ndarray,
                     camera: ir.CameraModel, *, length: float, diameter: float = STRING_DIAMETER) -> float | None:
    """(box width / height) over the predicted (width / height) of a string ``length`` x
    ``diameter`` m at ``center_w`` along ``axis_w`` (W) seen by ``camera`` at ``T_c_w``; 1 is a
    perfect match. None when an end projects behind the camera."""
    u = np.asarray(axis_w, dtype=np.float64) / np.linalg.norm(axis_w)
    c = np.asarray(center_w, dtype=np.float64)
    ends = np.stack([c - 0.5 * length * u, c + 0.5 * length * u, c])
    uv, _ = ir.project_points(ends, np.asarray(T_c_w, dtype=np.float64), camera)
    if not np.all(np.isfinite(uv)):
        return None
    z = float((np.asarray(T_c_w)[:3, :3] @ c + np.asarray(T_c_w)[:3, 3])[2])
    d_px = diameter * 0.5 * (camera.fx + camera.fy) / z
    pw = abs(uv[1, 0] - uv[0, 0]) + d_px
    ph = abs(uv[1, 1] - uv[0, 1]) + d_px
    mw, mh = float(box[2] - box[0]), float(box[3] - box[1])
    if mw <= 0 or mh <= 0:
        return None
    return (mw / mh) / (pw / ph)


def check_insulator_shape(shape: ClusterShape | None, *, insulator_length: float,
                          diameter: float = STRING_DIAMETER, aspect_ratio: float | None = None,
                          relief_history: Sequence[float] | None = None) -> ShapeVerdict:
    """The verdict on a cluster's shape (see the module docstring for the checks).

    ``relief_history``: the reliefs of this object's localizations so far (this one included);
    their median is checked instead of this localization's own, once there are
    :data:`MIN_RELIEF_SAMPLES` of them (before that the relief is not checked)."""
    if not (math.isfinite(insulator_length) and insulator_length > 0):
        raise ValueError(f"insulator_length: must be finite and > 0, got {insulator_length}")
    if not (math.isfinite(diameter) and diameter > 0):
        raise ValueError(f"diameter: must be finite and > 0, got {diameter}")
    reasons: list[str] = []
    if shape is None:
        return ShapeVerdict(False, (f"fewer than {MIN_SHAPE_POINTS} points",), None, aspect_ratio)
    if shape.length < MIN_LENGTH_FRACTION * insulator_length:
        reasons.append(f"too short ({shape.length:.2f} m)")
    if shape.length > MAX_LENGTH_FRACTION * insulator_length + diameter:
        reasons.append(f"too long ({shape.length:.2f} m)")
    if shape.linearity < MIN_LINEARITY:
        reasons.append(f"not linear ({shape.linearity:.3f})")
    if shape.spread > MAX_SPREAD_FRACTION * diameter:
        reasons.append(f"too wide ({shape.spread:.3f} m from the axis)")
    relief = float(np.median(relief_history)) if relief_history is not None and len(relief_history) else shape.relief
    if relief_history is not None and len(relief_history) < MIN_RELIEF_SAMPLES:
        pass  # not judged yet: too few figures (see MIN_RELIEF_SAMPLES)
    elif relief < MIN_RELIEF:
        reasons.append(f"no shed relief ({relief:.3f} m)")
    if aspect_ratio is not None and not (1 / ASPECT_TOLERANCE <= aspect_ratio <= ASPECT_TOLERANCE):
        reasons.append(f"box aspect ({aspect_ratio:.2f}x the predicted one)")
    return ShapeVerdict(not reasons, tuple(reasons), shape, aspect_ratio)
