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
