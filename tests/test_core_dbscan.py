"""dbscan against scikit-learn's DBSCAN."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import DBSCAN  # type: ignore[import-untyped]

import insulator_rs as ir
from insulator_rs.synthetic import line_clusters


def assert_same_as_sklearn(points: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """Compare ir.dbscan with sklearn.cluster.DBSCAN(eps, min_samples=min_points).

    Identical noise set; identical partition of sklearn's core points up to
    relabelling; every border point joins a cluster holding a core point within eps;
    clusters numbered in the order of their first core point.
    """
    labels = ir.dbscan(points, eps, min_points)
    finite = np.all(np.isfinite(points), axis=1)
    ref = np.full(len(points), -1)
    core = np.zeros(len(points), dtype=bool)
    if finite.any():
        fit = DBSCAN(eps=eps, min_samples=min_points).fit(points[finite])
        ref[finite] = fit.labels_
        core[np.flatnonzero(finite)[fit.core_sample_indices_]] = True
    assert labels.shape == (len(points),) and labels.dtype == np.int32
    np.testing.assert_array_equal(labels == -1, ref == -1, err_msg="noise sets differ")
    # Core partition: a bijection between our labels and sklearn's on core points.
    pairs = set(zip(labels[core].tolist(), ref[core].tolist(), strict=True))
    assert len(pairs) == len({a for a, _ in pairs}) == len({b for _, b in pairs})
    # Border points: the cluster of some core point within eps.
    for i in np.flatnonzero(~core & (labels >= 0)):
        near_core = core & (np.linalg.norm(points - points[i], axis=1) <= eps)
        assert labels[i] in set(labels[near_core].tolist())
    # Numbering: cluster k's first core point comes before cluster k+1's.
    n = labels.max() + 1
    firsts = [np.flatnonzero(core & (labels == k))[0] for k in range(n)]
    assert firsts == sorted(firsts)
    assert set(labels.tolist()) - {-1} == set(range(n))
    return labels


@pytest.mark.parametrize(("eps", "min_points"), [(0.3, 5), (0.15, 3), (0.5, 10), (0.05, 1)])
def test_line_clusters_match_sklearn(eps: float, min_points: int) -> None:
    """Reference: sklearn.cluster.DBSCAN, same eps/min_samples; exact (see helper)."""
    points = line_clusters(3000, seed=7)
    labels = assert_same_as_sklearn(points, eps, min_points)
    assert labels.max() >= 3


@pytest.mark.parametrize("seed", range(5))
def test_random_clouds_match_sklearn(seed: int) -> None:
    """Reference: sklearn.cluster.DBSCAN on uniform clouds of varying density; exact."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(0, 5, size=(int(rng.integers(50, 800)), 3))
    assert_same_as_sklearn(points, float(rng.uniform(0.1, 0.6)), int(rng.integers(1, 8)))


def test_distance_exactly_eps_counts_as_neighbour() -> None:
    """Reference: sklearn (neighbourhood dist <= eps). An integer grid with spacing eps:
    on a 4x4x4 grid the 8 interior points have exactly 6 neighbours at distance eps plus
    themselves (core at min_points 7); with them their 24 face neighbours form one cluster."""
    g = np.arange(4, dtype=np.float64)
    points = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    labels = assert_same_as_sklearn(points, 1.0, 7)
    assert (labels == 0).sum() == 8 + 24 and labels.max() == 0
    assert (assert_same_as_sklearn(points, 0.999, 7) == -1).all()


def test_many_equal_coordinates_do_not_break_the_tree() -> None:
    """LiDAR scan lines repeat coordinates; kiddo's mutable tree would panic here.
    Reference: sklearn; exact."""
    rng = np.random.default_rng(1)
    base = np.repeat(rng.uniform(0, 3, size=(20, 3)), 200, axis=0)
    line = np.zeros((500, 3))
    line[:, 0] = np.repeat(np.arange(5.0), 100)
    assert_same_as_sklearn(np.concatenate([base, line]), 0.2, 5)


def test_nonfinite_points_are_noise_and_do_not_cluster() -> None:
    """NaN/Inf rows are labelled -1 and the rest cluster as sklearn does without them."""
    points = line_clusters(600, seed=2)
    points[::17] = np.nan
    points[5, 2] = np.inf
    points[6, 0] = -np.inf
    labels = assert_same_as_sklearn(points, 0.3, 5)
    assert (labels[~np.all(np.isfinite(points), axis=1)] == -1).all()


def test_empty_and_tiny_clouds() -> None:
    assert ir.dbscan(np.zeros((0, 3)), 0.3, 5).shape == (0,)
    assert ir.dbscan(np.zeros((1, 3)), 0.3, 1).tolist() == [0]
    assert ir.dbscan(np.zeros((1, 3)), 0.3, 2).tolist() == [-1]
    assert ir.dbscan(np.full((4, 3), np.nan), 0.3, 1).tolist() == [-1] * 4


@pytest.mark.parametrize(
    ("eps", "min_points", "exc", "name"),
    [
        (0.0, 5, ValueError, "eps"),
        (-1.0, 5, ValueError, "eps"),
        (float("nan"), 5, ValueError, "eps"),
        (float("inf"), 5, ValueError, "eps"),
        (0.3, 0, ValueError, "min_points"),
        (0.3, -3, ValueError, "min_points"),
        (0.3, 10**30, ValueError, "min_points"),
        (0.3, 2.5, TypeError, "min_points"),
        ("0.3", 5, TypeError, "eps"),
    ],
)
def test_bad_parameters_name_the_argument(eps: object, min_points: object, exc: type[Exception], name: str) -> None:
    with pytest.raises(exc, match=name):
        ir.dbscan(np.zeros((4, 3)), eps, min_points)  # type: ignore[arg-type]
