"""insulator_rs core kernels side by side with what a user would otherwise pick.

    pytest benches/ --benchmark-enable

One process, one run; benches/conftest.py prints the ratio table at the end.
Groups (each asserts once that the implementations agree before timing):

* project + cull, 20,000-point frame, 3 boxes: ``ir.points_in_boxes`` vs the same
  maths vectorised in numpy (target >= 5x) and vs ``cv2.projectPoints`` + numpy masks;
  projection alone: ``ir.project_points`` vs numpy vs cv2.
* DBSCAN, 3,000 points (insulator-like rods + 20 % noise, eps 0.3 m,
  min_points 5): ``ir.dbscan`` vs ``sklearn.cluster.DBSCAN`` (target >= 10x).
* DBSCAN scaling 1k..100k points at constant density.
* DBSCAN on sparse tower-scale clouds (issue 23): ``synthetic.tower_cloud`` at 10k, 30k
  and 65k points over 60 m, and 65k accumulated simulated Mid-360 returns of towers A and B
  (tests/tower_scans.py), eps 0.3 m, min_points 5: ``ir.dbscan`` vs scikit-learn (target
  >= 30x) and Open3D's ``cluster_dbscan`` (target >= 5x; the row is left out when
  ``open3d`` does not import; it runs on all cores, the others on one).
* ``ir.localize(method="dbscan+ransac")`` on a 2,000-point insulator cloud vs the
  numpy/sklearn reference of Algorithm 1 (tests/reference_algorithms.py).
* Python call overhead on a 10-point input.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest
import helpers.reference_algorithms as ref
from sklearn.cluster import DBSCAN  # type: ignore[import-untyped]

from helpers.tower_scans import tower_scan

import insulator_rs as ir
from insulator_rs.synthetic import insulator_cloud, lidar_frame, line_clusters, tower_cloud

CAM = ir.CameraModel(1200.0, 1200.0, 800.0, 600.0, 1600, 1200, dist=(-0.12, 0.05, 0.0005, -0.0003, -0.01))
# LiDAR (FLU) to camera optical frame, camera 10 cm below and 5 cm ahead of the LiDAR.
T_C_L = np.array([[0.0, -1, 0, 0.0], [0, 0, -1, -0.1], [1, 0, 0, -0.05], [0, 0, 0, 1]])
BOXES = np.array([[500.0, 300, 700, 700, 0.91], [900, 400, 1000, 900, 0.85], [100, 100, 400, 250, 0.6]])
FRAME = lidar_frame(20_000, seed=0).astype(np.float32)
EPS, MIN_POINTS = 0.3, 5


def numpy_project(points: np.ndarray, t_c_l: np.ndarray, cam: ir.CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """(u, v, in-front-and-in-image mask) with OpenCV's distortion model, vectorised."""
    p = points @ t_c_l[:3, :3].T.astype(points.dtype) + t_c_l[:3, 3].astype(points.dtype)
    p = p.astype(np.float64)
    z = p[:, 2]
    front = z > ir.NEAR_LIMIT
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = p[:, 0] / z, p[:, 1] / z
    k1, k2, p1, p2, k3 = cam.dist
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    u = cam.fx * (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)) + cam.cx
    v = cam.fy * (y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y) + cam.cy
    ok = front & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    return np.column_stack([u, v]), ok


def numpy_points_in_boxes(points: np.ndarray, t_c_l: np.ndarray, cam: ir.CameraModel, boxes: np.ndarray) -> list[np.ndarray]:
    uv, ok = numpy_project(points, t_c_l, cam)
    u, v = uv[:, 0], uv[:, 1]
    return [np.flatnonzero(ok & (u >= x1) & (u < x2) & (v >= y1) & (v < y2)) for x1, y1, x2, y2 in boxes[:, :4]]


RVEC = cv2.Rodrigues(T_C_L[:3, :3])[0]
K = CAM.camera_matrix()
DIST = np.asarray(CAM.dist)


def cv2_points_in_boxes(points: np.ndarray, t_c_l: np.ndarray, boxes: np.ndarray) -> list[np.ndarray]:
    """cv2.projectPoints for the pixels, numpy for depth, image and box masks."""
    uv = cv2.projectPoints(points, RVEC, t_c_l[:3, 3], K, DIST)[0].reshape(-1, 2)
    z = points @ t_c_l[2, :3] + t_c_l[2, 3]
    u, v = uv[:, 0], uv[:, 1]
    ok = (z > ir.NEAR_LIMIT) & (u >= 0) & (u < CAM.width) & (v >= 0) & (v < CAM.height)
    return [np.flatnonzero(ok & (u >= x1) & (u < x2) & (v >= y1) & (v < y2)) for x1, y1, x2, y2 in boxes[:, :4]]


def same_lists(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return all(len(np.setxor1d(x, y)) <= 2 for x, y in zip(a, b, strict=True))  # edge ties only


# --- project + cull ------------------------------------------------------------------


@pytest.mark.benchmark(group="project + cull, 20k points, 3 boxes")
def test_cull_insulator_rs(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="insulator_rs", target="< 100 µs")
    out = benchmark(ir.points_in_boxes, FRAME, T_C_L, CAM, BOXES)
    assert same_lists(out, numpy_points_in_boxes(FRAME, T_C_L, CAM, BOXES)) and sum(map(len, out)) > 100


@pytest.mark.benchmark(group="project + cull, 20k points, 3 boxes")
def test_cull_numpy(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="numpy (same maths)", target_ratio=5)
    benchmark(numpy_points_in_boxes, FRAME, T_C_L, CAM, BOXES)


@pytest.mark.benchmark(group="project + cull, 20k points, 3 boxes")
def test_cull_cv2(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="cv2.projectPoints + numpy")
    frame64 = FRAME.astype(np.float64)  # cv2 wants one dtype for points and pose
    out = benchmark(cv2_points_in_boxes, frame64, T_C_L, BOXES)
    assert same_lists(out, ir.points_in_boxes(FRAME, T_C_L, CAM, BOXES))


@pytest.mark.benchmark(group="project only, 20k points")
def test_project_insulator_rs(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="insulator_rs")
    uv, valid = benchmark(ir.project_points, FRAME, T_C_L, CAM)
    uv_np, ok = numpy_project(FRAME, T_C_L, CAM)
    np.testing.assert_allclose(uv[ok], uv_np[ok], rtol=1e-6, atol=1e-3)


@pytest.mark.benchmark(group="project only, 20k points")
def test_project_numpy(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="numpy (same maths)")
    benchmark(numpy_project, FRAME, T_C_L, CAM)


@pytest.mark.benchmark(group="project only, 20k points")
def test_project_cv2(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="cv2.projectPoints")
    frame64 = FRAME.astype(np.float64)
    benchmark(cv2.projectPoints, frame64, RVEC, T_C_L[:3, 3], K, DIST)


# --- DBSCAN -------------------------------------------------------------------------

CLUSTERS_3K = line_clusters(3000, seed=1)


def sklearn_dbscan(points: np.ndarray) -> np.ndarray:
    return DBSCAN(eps=EPS, min_samples=MIN_POINTS).fit_predict(points)


@pytest.mark.benchmark(group="dbscan, 3,000 points")
def test_dbscan_insulator_rs(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="insulator_rs", target="< 1 ms")
    labels = benchmark(ir.dbscan, CLUSTERS_3K, EPS, MIN_POINTS)
    np.testing.assert_array_equal(labels == -1, sklearn_dbscan(CLUSTERS_3K) == -1)


@pytest.mark.benchmark(group="dbscan, 3,000 points")
def test_dbscan_sklearn(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="sklearn.cluster.DBSCAN", target_ratio=10)
    benchmark(sklearn_dbscan, CLUSTERS_3K)


@pytest.mark.parametrize("n", [1_000, 3_000, 10_000, 30_000, 100_000])
@pytest.mark.benchmark(group="dbscan scaling (constant density)")
def test_dbscan_scaling(benchmark: Any, n: int) -> None:
    benchmark.extra_info.update(impl="insulator_rs", n_points=n)
    points = line_clusters(n, seed=2)
    benchmark(ir.dbscan, points, EPS, MIN_POINTS)


# --- DBSCAN on sparse tower-scale clouds ----------------------------------------------

TOWER_SIZES = (10_000, 30_000, 65_000)
TOWER_SCAN_POINTS = 65_000


def tower_workload(kind: str) -> np.ndarray:
    """"synthetic-N" (the generator's tower at N points) or "tower_a"/"tower_b" (scans)."""
    if kind.startswith("synthetic-"):
        return tower_cloud(int(kind.split("-")[1]), seed=7)
    return tower_scan(kind, TOWER_SCAN_POINTS)


TOWER_KINDS = [f"synthetic-{n}" for n in TOWER_SIZES] + ["tower_a", "tower_b"]


def open3d_dbscan(points: np.ndarray) -> np.ndarray:
    import open3d as o3d  # type: ignore[import-not-found, import-untyped]  # noqa: PLC0415

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    return np.asarray(cloud.cluster_dbscan(EPS, MIN_POINTS, print_progress=False))


def same_clustering(a: np.ndarray, b: np.ndarray) -> bool:
    """Same noise set and as many clusters (the border points may go either way)."""
    return bool(np.array_equal(a == -1, b == -1) and a.max() == b.max())


@pytest.mark.parametrize("kind", TOWER_KINDS)
def test_dbscan_tower_insulator_rs(benchmark: Any, kind: str) -> None:
    points = tower_workload(kind)
    benchmark.group = f"dbscan, sparse tower {kind}"
    benchmark.extra_info.update(impl="insulator_rs", n_points=len(points))
    labels = benchmark(ir.dbscan, points, EPS, MIN_POINTS)
    assert same_clustering(labels, sklearn_dbscan(points))


@pytest.mark.parametrize("kind", TOWER_KINDS)
def test_dbscan_tower_sklearn(benchmark: Any, kind: str) -> None:
    points = tower_workload(kind)
    benchmark.group = f"dbscan, sparse tower {kind}"
    benchmark.extra_info.update(impl="sklearn.cluster.DBSCAN", n_points=len(points), target_ratio=30)
    benchmark.pedantic(sklearn_dbscan, (points,), rounds=3, iterations=1)


@pytest.mark.parametrize("kind", TOWER_KINDS)
def test_dbscan_tower_open3d(benchmark: Any, kind: str) -> None:
    pytest.importorskip("open3d")
    points = tower_workload(kind)
    benchmark.group = f"dbscan, sparse tower {kind}"
    benchmark.extra_info.update(impl="open3d cluster_dbscan", n_points=len(points), target_ratio=5)
    labels = benchmark.pedantic(open3d_dbscan, (points,), rounds=3, iterations=1)
    assert same_clustering(labels, ir.dbscan(points, EPS, MIN_POINTS))


# --- localize -------------------------------------------------------------------------

# As fusion_core's criterion bench: a 2 m, 0.12 m-radius insulator (80 %), a lattice member
# behind its end (15 %), stray returns (5 %).
INSULATOR_2K = insulator_cloud(
    seed=3, length=2.0, radius=0.12, n_insulator=1600, n_tower=300, conductor=False, n_stray=100
).points


@pytest.mark.benchmark(group="localize dbscan+ransac, 2,000 points")
def test_localize_insulator_rs(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="insulator_rs", target="< 1 ms")
    assert len(INSULATOR_2K) == 2000
    est = benchmark(ir.localize, INSULATOR_2K, "dbscan+ransac")
    d = ir.localize_defaults()
    want = ref.localize_dbscan_ransac(INSULATOR_2K, d["eps"], int(d["min_points"]), d["tau"], d["ransac_threshold"])
    assert np.linalg.norm(est.center - want.center) < 0.02


@pytest.mark.benchmark(group="localize dbscan+ransac, 2,000 points")
def test_localize_python_reference(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="numpy + sklearn reference")
    d = ir.localize_defaults()
    benchmark(ref.localize_dbscan_ransac, INSULATOR_2K, d["eps"], int(d["min_points"]), d["tau"], d["ransac_threshold"])


# --- Python call overhead ------------------------------------------------------------

TEN = np.ascontiguousarray(FRAME[:10], dtype=np.float64) + np.array([5.0, 0, 0])


@pytest.mark.benchmark(group="call overhead, 10 points: project_points")
def test_overhead_project_insulator_rs(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="insulator_rs")
    benchmark(ir.project_points, TEN, T_C_L, CAM)


@pytest.mark.benchmark(group="call overhead, 10 points: project_points")
def test_overhead_project_numpy(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="numpy (same maths)")
    benchmark(numpy_project, TEN, T_C_L, CAM)


@pytest.mark.benchmark(group="call overhead, 10 points: project_points")
def test_overhead_project_cv2(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="cv2.projectPoints")
    benchmark(cv2.projectPoints, TEN, RVEC, T_C_L[:3, 3], K, DIST)


@pytest.mark.benchmark(group="call overhead, 10 points: dbscan")
def test_overhead_dbscan_insulator_rs(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="insulator_rs")
    benchmark(ir.dbscan, TEN, EPS, MIN_POINTS)


@pytest.mark.benchmark(group="call overhead, 10 points: dbscan")
def test_overhead_dbscan_sklearn(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="sklearn.cluster.DBSCAN")
    benchmark(sklearn_dbscan, TEN)
