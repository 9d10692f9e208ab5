"""Accumulated simulated Livox Mid-360 scans of the shipped towers (the sparse tower-scale
DBSCAN workload of issue 23, beside ``insulator_rs.synthetic.tower_cloud``).

The sensor hovers at standpoints round the tower (``ring`` m from its axis, at 30, 55 and
80 % of its height in turn, facing it; up to ``MAX_STANDPOINTS``) and casts one frame at each; the returns off the
ground are dropped (a dense plane is not the workload) and the rest accumulated in W until
``n_points``. Deterministic for ``seed``. Shared by tests/test_core_dbscan.py and
benches/bench_core.py.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.towers import GROUND_ID, load_tower

MAX_STANDPOINTS = 160
HEIGHTS = (0.3, 0.55, 0.8)


@functools.cache
def tower_scan(name: str, n_points: int, *, ring: float = 10.0, seed: int = 0) -> np.ndarray:
    """(N,3) float64 in W, N <= n_points (fewer only if every standpoint was used)."""
    tower = load_tower(name)
    lidar = Mid360()
    chunks: list[np.ndarray] = []
    total = 0
    for k in range(MAX_STANDPOINTS):
        height = HEIGHTS[k % len(HEIGHTS)] * tower.max_height
        # Golden-angle steps, so any prefix of standpoints is spread round the tower.
        bearing = k * math.pi * (3.0 - math.sqrt(5.0))
        c, s = math.cos(bearing), math.sin(bearing)
        T_w_b = np.eye(4)
        T_w_b[:3, 3] = [ring * c, ring * s, height]
        yaw = bearing + math.pi  # face the tower's axis
        T_w_b[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        frame = lidar.scan(tower.mesh, (T_w_b, T_w_b), 0.1 * k, seed=seed + k)
        pts = frame.points_w[frame.instance_id != GROUND_ID]
        chunks.append(pts)
        total += len(pts)
        if total >= n_points:
            break
    return np.concatenate(chunks)[:n_points]
