"""insulator_rs.synthetic: the generated clouds hold what their docstrings promise."""

from __future__ import annotations

import numpy as np
import pytest

from insulator_rs import synthetic as syn


@pytest.mark.parametrize("orientation", ["horizontal", "vertical", (0.3, 0.2, 1.0)])
def test_insulator_cloud_ground_truth(orientation: object) -> None:
    scene = syn.insulator_cloud(seed=4, orientation=orientation, distance=8.5, azimuth=0.3)  # type: ignore[arg-type]
    counts = np.bincount(scene.source, minlength=4)
    assert counts.tolist() == [300, 250, 40, 15]
    assert np.linalg.norm(scene.center) == pytest.approx(8.5)
    assert np.linalg.norm(scene.axis) == pytest.approx(1.0)
    assert scene.axis[np.argmax(np.abs(scene.axis))] > 0
    ins = scene.points[scene.source == syn.INSULATOR]
    rel = ins - scene.center
    along = rel @ scene.axis
    radial = np.linalg.norm(rel - np.outer(along, scene.axis), axis=1)
    assert np.abs(along).max() <= 0.6 + 0.1  # half length plus range noise
    assert np.median(radial) < scene.radius + 0.05
    # Only the side facing the UAV (at the origin) returns points.
    radial_vec = rel - np.outer(along, scene.axis)
    to_uav = -(scene.center + np.outer(along, scene.axis))
    to_uav -= np.outer(to_uav @ scene.axis, scene.axis)
    assert np.mean(np.sum(radial_vec * to_uav, axis=1) > 0) > 0.9
    # The tower lies beyond the insulator's tower end and farther from the UAV.
    tower = scene.points[scene.source == syn.TOWER]
    assert np.linalg.norm(tower, axis=1).mean() > np.linalg.norm(ins, axis=1).mean()


def test_insulator_cloud_is_deterministic_and_errors_measure_the_truth() -> None:
    a, b = syn.insulator_cloud(seed=9), syn.insulator_cloud(seed=9)
    np.testing.assert_array_equal(a.points, b.points)
    assert not np.array_equal(a.points, syn.insulator_cloud(seed=10).points)
    assert a.errors(a.center, -a.axis) == (0.0, 0.0)
    c_err, a_err = a.errors(a.center + [0.3, 0.4, 0.0], np.cross(a.axis, [0.0, 0.0, 1.0]) + a.axis * 1e-12)
    assert c_err == pytest.approx(0.5) and a_err == pytest.approx(90.0)


def test_insulator_cloud_rejects_bad_geometry() -> None:
    with pytest.raises(ValueError):
        syn.insulator_cloud(distance=0.0)
    with pytest.raises(ValueError, match="orientation"):
        syn.insulator_cloud(orientation="diagonal")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="line of sight"):
        syn.insulator_cloud(orientation=(1.0, 0.0, 0.0))


@pytest.mark.parametrize("n", [0, 10, 1000, 3000, 20_000])
def test_line_clusters_size_and_noise_share(n: int) -> None:
    points = syn.line_clusters(n, seed=1)
    assert points.shape == (n, 3) and np.all(np.isfinite(points))
    # Noise is the last int(0.2 n) rows, uniform over the grid box (|z| <= 2 m).
    assert np.all(np.abs(points[n - int(0.2 * n) :, 2]) <= 2.0)


def test_lidar_frame_covers_the_mid360_field_of_view() -> None:
    points = syn.lidar_frame(20_000, seed=0, min_range=1.0, max_range=40.0)
    r = np.linalg.norm(points, axis=1)
    assert r.min() >= 1.0 - 1e-9 and r.max() <= 40.0 + 1e-9
    elevation = np.degrees(np.arcsin(points[:, 2] / r))
    assert elevation.min() >= -7.0 - 1e-9 and elevation.max() <= 52.0 + 1e-9
    assert 0.2 < np.mean(points[:, 0] > np.abs(points[:, 1])) < 0.3  # ~a quarter ahead


@pytest.mark.parametrize("n", [0, 1, 10_000, 65_000])
def test_tower_cloud_size_extent_and_sparsity(n: int) -> None:
    """tower_cloud's docstring: n points, ~60 m along y, deterministic in the seed, and
    (the point of it) most eps/sqrt(3) grid cells at eps 0.3 m hold fewer than 5 points."""
    points = syn.tower_cloud(n, seed=3)
    assert points.shape == (n, 3) and np.isfinite(points).all()
    np.testing.assert_array_equal(points, syn.tower_cloud(n, seed=3))
    if n < 10_000:
        return
    assert not np.array_equal(points, syn.tower_cloud(n, seed=4))
    span = points.max(axis=0) - points.min(axis=0)
    assert 59.0 < span[1] < 61.0 and 20.0 < span[0] < 25.0 and 50.0 < span[2] < 52.0
    _, per_cell = np.unique(np.floor(points / (0.3 / np.sqrt(3))).astype(np.int64), axis=0, return_counts=True)
    assert np.median(per_cell) <= 3 and np.mean(per_cell < 5) > 0.6
    with pytest.raises(ValueError, match="n_points"):
        syn.tower_cloud(-1)
