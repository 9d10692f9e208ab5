"""dbscan against scikit-learn's DBSCAN."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from helpers.reference_dbscan import assert_same_as_sklearn
from helpers.tower_scans import tower_scan

import insulator_rs as ir
from insulator_rs.synthetic import line_clusters, tower_cloud


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


@pytest.mark.parametrize("n", [10_000, 30_000])
@pytest.mark.parametrize(("eps", "min_points"), [(0.3, 5), (0.5, 5), (0.15, 3)])
def test_sparse_tower_clouds_match_sklearn(n: int, eps: float, min_points: int) -> None:
    """Reference: sklearn.cluster.DBSCAN on the sparse tower-scale workload (a lattice tower
    and its conductors over 60 m, most grid cells holding fewer than 5 points); exact."""
    labels = assert_same_as_sklearn(tower_cloud(n, seed=7), eps, min_points)
    assert labels.max() >= 5 and (labels == -1).any()


@pytest.mark.parametrize("name", ["tower_a", "tower_b"])
def test_simulated_tower_scans_match_sklearn(name: str) -> None:
    """Reference: sklearn.cluster.DBSCAN on accumulated simulated Mid-360 scans of the shipped
    towers (20,000 returns off the ground, ~100 m along the line); exact."""
    points = tower_scan(name, 20_000)
    assert len(points) == 20_000
    for eps, min_points in [(0.3, 5), (0.5, 5)]:
        assert assert_same_as_sklearn(points, eps, min_points).max() >= 3


@settings(max_examples=30)
@given(
    n=st.integers(0, 4_000),
    seed=st.integers(0, 2**32 - 1),
    eps=st.floats(0.05, 1.2),
    min_points=st.integers(1, 12),
    scale=st.sampled_from([1.0, 0.25, 4.0]),
)
def test_sparse_tower_clouds_match_sklearn_property(n: int, seed: int, eps: float, min_points: int, scale: float) -> None:
    """Reference: sklearn.cluster.DBSCAN on tower clouds of any size, seed and scale (a 15 m
    to 240 m tower: from crowded cells to nearly empty ones), any eps/min_points; exact."""
    assert_same_as_sklearn(tower_cloud(n, seed=seed) * scale, eps, min_points)


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
