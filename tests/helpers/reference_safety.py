"""Where a position stands against the mission's safety volumes, computed here from the boxes'
corners, independently of the planner: the reference the abort and return tests check against."""

from __future__ import annotations

import numpy as np

from insulator_rs.planning.safety import GROUND_DEPTH, SafetyVolumes


def footprint_distance(volumes: SafetyVolumes, points: np.ndarray) -> np.ndarray:
    """Horizontal distance of each point from the nearest box outline (0 over one), computed
    here from the boxes' corners, not by the planner's method."""
    best = np.full(len(points), np.inf)
    for box in volumes.boxes:
        a, b = box.half_extents[:2]
        corners = np.array([[-a, -b], [a, -b], [a, b], [-a, b]])
        ring = box.center[:2] + corners @ box.axes[:2, :2]
        xy = points[:, :2]
        # inside the (convex) outline: every cross product has the same sign
        cross = []
        for k in range(4):
            e, d = ring[(k + 1) % 4] - ring[k], xy - ring[k]
            cross.append(e[0] * d[:, 1] - e[1] * d[:, 0])
        inside = np.all(np.array(cross) >= 0, axis=0) | np.all(np.array(cross) <= 0, axis=0)
        dist = np.full(len(points), np.inf)
        for k in range(4):
            p, q = ring[k], ring[(k + 1) % 4]
            t = np.clip(((xy - p) @ (q - p)) / ((q - p) @ (q - p)), 0.0, 1.0)
            dist = np.minimum(dist, np.linalg.norm(xy - (p + t[:, None] * (q - p)), axis=1))
        best = np.minimum(best, np.where(inside, 0.0, dist))
    return best


def inside_any(volumes: SafetyVolumes, points: np.ndarray) -> np.ndarray:
    """Inside a box: over its footprint and below its top."""
    return (footprint_distance(volumes, points) <= 0.0) & (points[:, 2] <= volumes.top) \
        & (points[:, 2] >= -GROUND_DEPTH)


def cylinder_clearance(points: np.ndarray, start: np.ndarray, end: np.ndarray, radius: float) -> np.ndarray:
    """Distance (m) of each point (N, 3) from the surface of the solid cylinder round the axis
    ``start`` -> ``end`` of ``radius`` (0 inside): the axis's exact point-to-segment distance less
    the radius, computed here, not by the planner's method. A scene's obstacle is a polygon
    inscribed in that circle, so its true surface is never nearer than this."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    d = end - start
    t = np.clip((p - start) @ d / (d @ d), 0.0, 1.0)
    return np.maximum(np.linalg.norm(p - (start + t[:, None] * d), axis=1) - radius, 0.0)


def polyline_samples(points: np.ndarray, step: float = 0.01) -> np.ndarray:
    """The straight polyline through ``points`` (K, 3) sampled at most ``step`` m apart, ends included."""
    p = np.asarray(points, dtype=np.float64)
    out = [p[:1]]
    for a, b in zip(p[:-1], p[1:]):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        out.append(a + np.linspace(0.0, 1.0, n + 1)[1:, None] * (b - a))
    return np.concatenate(out)
