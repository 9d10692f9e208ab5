"""Deskew + project + cull of a 20,000-point, 100 ms scan to 3 boxes, side by side.

    pytest benches/bench_deskew.py --benchmark-enable

``ir.deskew_points_in_boxes`` (Rust, one fused pass) vs the same maths in numpy/scipy
(scipy ``Slerp`` of the pose stream per point, numpy chaining, then the numpy projection
and box masks of ``bench_core``); ``ir.deskew`` alone; ``ir.points_in_boxes`` without
deskew for scale. The implementations are checked to agree (1e-9 m, same indices) once.
Target (issue 10): <= 60 us for the fused kernel on the 2-core dev box.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from bench_core import numpy_points_in_boxes
from scipy.spatial.transform import Rotation, Slerp

import insulator_rs as ir
from insulator_rs.synthetic import lidar_frame

CAM = ir.CameraModel(1200.0, 1200.0, 800.0, 600.0, 1600, 1200, dist=(-0.12, 0.05, 0.0005, -0.0003, -0.01))
T_C_L = np.array([[0.0, -1, 0, 0.0], [0, 0, -1, -0.1], [1, 0, 0, -0.05], [0, 0, 0, 1]])
BOXES = np.array([[500.0, 300, 700, 700], [900, 400, 1000, 900], [100, 100, 400, 250]])
N = 20_000
FRAME = lidar_frame(N, seed=0).astype(np.float32)
TIMES = np.linspace(0.0, 0.1, N)
POSE_TIMES = np.linspace(0.0, 0.1, 6)
T_B_L = np.eye(4)
T_B_L[:3, 3] = [0.1, 0.0, -0.1]


def _pose(t: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.02 * t, -0.05 * t, 1.0 + 4.0 * t]).as_matrix()
    T[:3, 3] = [3.0 * t, 0.5 * t, 10.0 + t]
    return T


POSES = np.stack([_pose(t) for t in POSE_TIMES])


def numpy_deskew(points: np.ndarray, times: np.ndarray, t_ref: float) -> np.ndarray:
    slerp = Slerp(POSE_TIMES, Rotation.from_matrix(POSES[:, :3, :3]))
    R = slerp(times).as_matrix()
    p = np.stack([np.interp(times, POSE_TIMES, POSES[:, j, 3]) for j in range(3)], axis=1)
    T_ref = np.eye(4)
    T_ref[:3, :3] = slerp([t_ref]).as_matrix()[0]
    T_ref[:3, 3] = [np.interp(t_ref, POSE_TIMES, POSES[:, j, 3]) for j in range(3)]
    M = np.linalg.inv(T_ref @ T_B_L)
    pts_b = points.astype(np.float64) @ T_B_L[:3, :3].T + T_B_L[:3, 3]
    pts_w = np.einsum("nij,nj->ni", R, pts_b) + p
    return pts_w @ M[:3, :3].T + M[:3, 3]


def numpy_deskew_cull(points: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    d = numpy_deskew(points, TIMES, 0.1)
    return d, numpy_points_in_boxes(d, T_C_L, CAM, BOXES)


def rust_deskew_cull(points: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    return ir.deskew_points_in_boxes(points, TIMES, POSE_TIMES, POSES, 0.1, T_B_L, T_C_L, CAM, BOXES)


def test_deskew_cull_insulator_rs(benchmark: Any) -> None:
    benchmark.group = "deskew + project + cull 20k pts, 3 boxes"
    d, idx = benchmark(rust_deskew_cull, FRAME)
    ref, ref_idx = numpy_deskew_cull(FRAME)
    assert np.max(np.abs(d - ref)) < 1e-9
    assert all(np.array_equal(a, b) for a, b in zip(idx, ref_idx)) and sum(map(len, idx)) > 100


def test_deskew_cull_numpy(benchmark: Any) -> None:
    benchmark.group = "deskew + project + cull 20k pts, 3 boxes"
    benchmark(numpy_deskew_cull, FRAME)


def test_cull_without_deskew_insulator_rs(benchmark: Any) -> None:
    benchmark.group = "deskew + project + cull 20k pts, 3 boxes"
    benchmark(ir.points_in_boxes, FRAME, T_C_L, CAM, BOXES)


def test_deskew_only_insulator_rs(benchmark: Any) -> None:
    benchmark.group = "deskew 20k pts"
    benchmark(ir.deskew, FRAME, TIMES, POSE_TIMES, POSES, 0.1, T_B_L)


def test_deskew_only_numpy(benchmark: Any) -> None:
    benchmark.group = "deskew 20k pts"
    benchmark(numpy_deskew, FRAME, TIMES, 0.1)
