"""Point-cloud arguments: float32/float64, contiguous or strided, give identical results;
wrong types and shapes get a TypeError/ValueError naming the argument."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

import insulator_rs as ir
from insulator_rs.synthetic import insulator_cloud

CAM = ir.CameraModel(600.0, 600.0, 320.0, 240.0, 640, 480, dist=(-0.1, 0.01, 0.001, 0.0, 0.0))
T_C_L = np.array([[0.0, -1, 0, 0.1], [0, 0, -1, 0.2], [1, 0, 0, 0.0], [0, 0, 0, 1]])  # FLU L -> optical C
BOXES = np.array([[250.0, 150, 400, 330], [0, 0, 640, 480]])

# name -> (call taking the points, comparable result)
KERNELS: dict[str, Callable[[Any], Any]] = {
    "project_points": lambda p: ir.project_points(p, T_C_L, CAM),
    "points_in_boxes": lambda p: ir.points_in_boxes(p, T_C_L, CAM, BOXES),
    "dbscan": lambda p: ir.dbscan(p, 0.3, 5),
    "ransac_line": lambda p: (lambda f: (f.point, f.direction, f.inliers, f.iterations))(ir.ransac_line(p, 0.1)),
    "pca": lambda p: (lambda r: (r.mean, r.eigenvalues, r.eigenvectors, r.n_points))(ir.pca(p)),
    "localize": lambda p: (lambda r: (r.center, r.direction, r.n_points, r.n_clusters))(ir.localize(p)),
}


def layouts(points64: np.ndarray) -> dict[str, np.ndarray]:
    """The same float32-representable cloud in many memory layouts."""
    p = points64.astype(np.float32).astype(np.float64)
    n = len(p)
    big = np.zeros((2 * n, 7))
    big[::2, 1:4] = p
    reversed_view = p[::-1].copy()[::-1]
    packed = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("i", "u1")])
    for k, c in enumerate("xyz"):
        packed[c] = p[:, k]
    raw = np.frombuffer(b"\0" + np.ascontiguousarray(p).tobytes(), dtype=np.float64, offset=1).reshape(n, 3)
    return {
        "f64 C": np.ascontiguousarray(p),
        "f64 Fortran": np.asfortranarray(p),
        "f64 every other row of a wider array": big[::2, 1:4],
        "f64 reversed rows": reversed_view,
        "f64 read-only": np.frombuffer(np.ascontiguousarray(p).tobytes()).reshape(n, 3),
        "f64 misaligned buffer": raw,
        "f32 C": p.astype(np.float32),
        "f32 Fortran": np.asfortranarray(p.astype(np.float32)),
        "f32 transposed view": np.ascontiguousarray(p.T.astype(np.float32)).T,
        # 13-byte records: row stride not a whole float32 (read through one copy).
        "f32 packed record fields": np.ndarray((n, 3), np.float32, packed, strides=(13, 4)),
    }


def assert_same(a: Any, b: Any) -> None:
    if isinstance(a, (tuple, list)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            assert_same(x, y)
    else:
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("kernel", sorted(KERNELS))
def test_every_layout_gives_identical_results(kernel: str) -> None:
    """Reference: the C-contiguous float64 call. Tolerance: bit-identical (float32 input
    holds the same float32-representable values, widened exactly to float64)."""
    cloud = insulator_cloud(seed=5).points
    views = layouts(cloud)
    base = KERNELS[kernel](views["f64 C"])
    for name, view in views.items():
        np.testing.assert_array_equal(view, views["f64 C"], err_msg=name)
        assert_same(KERNELS[kernel](view), base)


def test_layouts_cover_what_they_claim() -> None:
    views = layouts(np.random.default_rng(0).normal(size=(10, 3)))
    assert views["f64 every other row of a wider array"].strides == (112, 8)
    assert views["f64 reversed rows"].strides[0] < 0
    assert not views["f64 read-only"].flags.writeable
    assert not views["f64 misaligned buffer"].flags.aligned
    assert views["f32 transposed view"].flags.f_contiguous
    assert views["f32 packed record fields"].strides == (13, 4)


def test_inputs_are_not_modified() -> None:
    cloud = insulator_cloud(seed=1).points
    before = cloud.copy()
    for call in KERNELS.values():
        call(cloud)
    np.testing.assert_array_equal(cloud, before)


ARG_NAMES = {
    "project_points": "points_l",
    "points_in_boxes": "points_l",
    "dbscan": "points",
    "ransac_line": "points",
    "pca": "points",
    "localize": "points_b",
}


@pytest.mark.parametrize("kernel", sorted(KERNELS))
@pytest.mark.parametrize(
    ("bad", "exc", "fragment"),
    [
        (np.zeros((5, 3), dtype=np.int64), TypeError, "expected dtype float32 or float64, got int64"),
        (np.zeros((5, 3), dtype=np.float16), TypeError, "got float16"),
        (np.zeros((5, 3), dtype=np.complex128), TypeError, "got complex128"),
        (np.zeros((5, 3), dtype=">f8"), TypeError, "got >f8"),
        (np.zeros((5, 3), dtype=object), TypeError, "got object"),
        (np.zeros((5, 2)), ValueError, r"expected shape \(N, 3\), got \(5, 2\)"),
        (np.zeros(3), ValueError, r"expected shape \(N, 3\), got \(3,\)"),
        (np.zeros((2, 5, 3)), ValueError, r"got \(2, 5, 3\)"),
        (np.float64(1.0), TypeError, "expected a numpy.ndarray"),
        ([[0.0, 0.0, 1.0]], TypeError, "expected a numpy.ndarray .* got list"),
        (None, TypeError, "got NoneType"),
    ],
)
def test_bad_clouds_name_the_argument(kernel: str, bad: Any, exc: type[Exception], fragment: str) -> None:
    with pytest.raises(exc, match=rf"^{ARG_NAMES[kernel]}: .*{fragment}"):
        KERNELS[kernel](bad)
