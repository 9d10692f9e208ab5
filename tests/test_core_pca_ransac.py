"""pca against numpy.linalg.eigh; ransac_line on clean lines with outliers."""

from __future__ import annotations

import inspect

import numpy as np
import pytest
from helpers.reference_algorithms import canonical_direction, reference_pca

import insulator_rs as ir


def noisy_line(
    rng: np.random.Generator, n: int, noise: float, n_outliers: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points on a random 3 m segment with Gaussian noise, then uniform outliers; returns
    (points, true point on the line, true unit direction)."""
    point = rng.uniform(-5, 5, size=3)
    direction = canonical_direction(rng.normal(size=3))
    t = rng.uniform(-1.5, 1.5, size=n)
    on_line = point + np.outer(t, direction) + rng.normal(scale=noise, size=(n, 3))
    outliers = point + rng.uniform(-3, 3, size=(n_outliers, 3))
    return np.concatenate([on_line, outliers]), point, direction


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(min(1.0, abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b)))))


@pytest.mark.parametrize("seed", range(8))
def test_pca_matches_numpy_eigh(seed: int) -> None:
    """Reference: np.cov (N-1) + numpy.linalg.eigh, sorted descending. Tolerance: mean and
    eigenvalues 1e-9 relative (+1e-12 abs); eigenvectors equal up to sign within 1e-7."""
    rng = np.random.default_rng(seed)
    scales = np.sort(rng.uniform(0.1, 3.0, size=3))[::-1]
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    points = (rng.normal(size=(int(rng.integers(3, 2000)), 3)) * scales) @ rotation.T + rng.uniform(-50, 50, 3)
    got = ir.pca(points)
    mean, values, vectors = reference_pca(points)
    np.testing.assert_allclose(got.mean, mean, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.eigenvalues, values, rtol=1e-9, atol=1e-12)
    assert got.eigenvectors.shape == (3, 3)
    for k in range(3):
        assert abs(abs(got.eigenvectors[:, k] @ vectors[:, k]) - 1.0) < 1e-7
    np.testing.assert_allclose(got.eigenvectors.T @ got.eigenvectors, np.eye(3), atol=1e-12)
    assert got.n_points == len(points)


def test_pca_skips_nonfinite_and_needs_two_points() -> None:
    """Reference: numpy on the finite rows only; tolerance 1e-12."""
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [np.nan, 0, 0], [2, 0, 0], [0, np.inf, 0]])
    got = ir.pca(pts)
    assert got.n_points == 3
    np.testing.assert_allclose(got.mean, [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(got.eigenvalues, [1, 0, 0], atol=1e-12)
    assert abs(got.eigenvectors[0, 0]) == pytest.approx(1.0)
    for bad in (np.zeros((0, 3)), np.ones((1, 3)), np.array([[1.0, 2, 3], [np.nan, 0, 0]])):
        with pytest.raises(ValueError, match="^points: "):
            ir.pca(bad)


def test_pca_result_is_frozen_with_readable_repr() -> None:
    got = ir.pca(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]))
    assert repr(got).startswith("Pca(mean=[0.3333, 0.3333, 0.0000], eigenvalues=[")
    with pytest.raises(ValueError):
        got.mean[0] = 5.0  # read-only array
    with pytest.raises(AttributeError):
        got.n_points = 3  # type: ignore[misc]


@pytest.mark.parametrize("seed", range(6))
def test_ransac_finds_clean_line_among_outliers(seed: int) -> None:
    """Reference: the generating line. Tolerance: axis within 0.5 deg, the fitted point
    within 1 cm of the true line, inliers = every on-line point (noise 5 mm, threshold
    5 cm) and almost no outliers."""
    rng = np.random.default_rng(seed)
    points, true_point, true_dir = noisy_line(rng, 300, 0.005, 200)
    fit = ir.ransac_line(points, 0.05, seed=seed)
    assert angle_deg(fit.direction, true_dir) < 0.5
    offset = fit.point - true_point
    assert np.linalg.norm(offset - (offset @ true_dir) * true_dir) < 0.01
    assert np.linalg.norm(fit.direction) == pytest.approx(1.0)
    assert set(range(300)) <= set(fit.inliers.tolist())
    assert len(fit.inliers) < 300 + 20
    assert fit.inliers.dtype == np.int64 and np.all(np.diff(fit.inliers) > 0)
    assert 1 <= fit.iterations <= 1000
    np.testing.assert_allclose(fit.point, points[fit.inliers].mean(axis=0), atol=1e-12)


def test_ransac_is_deterministic_per_seed_and_respects_max_iterations(rng: np.random.Generator) -> None:
    points, _, _ = noisy_line(rng, 100, 0.01, 300)
    a = ir.ransac_line(points, 0.05, seed=11)
    b = ir.ransac_line(points, 0.05, seed=11)
    np.testing.assert_array_equal(a.inliers, b.inliers)
    np.testing.assert_array_equal(a.direction, b.direction)
    assert a.iterations == b.iterations
    assert ir.ransac_line(points, 0.05, max_iterations=3, seed=1).iterations <= 3
    # Different seeds agree on a clean line (the result does not hinge on the draw).
    c = ir.ransac_line(points, 0.05, seed=12345)
    assert angle_deg(a.direction, c.direction) < 1.0


def test_ransac_skips_nonfinite_and_keeps_input_indices() -> None:
    pts = np.array([[0.0, 0, 0], [np.nan, 1, 1], [1, 0, 0], [2, 0, 0], [5, 5, np.inf]])
    fit = ir.ransac_line(pts, 0.01)
    assert fit.inliers.tolist() == [0, 2, 3]
    np.testing.assert_allclose(np.abs(fit.direction), [1, 0, 0], atol=1e-12)
    assert repr(fit).startswith("LineFit(point=[1.0000, 0.0000, 0.0000], direction=[1.0000, ")


def test_ransac_signature_shows_the_core_defaults() -> None:
    params = inspect.signature(ir.ransac_line).parameters
    defaults = ir.localize_defaults()  # shares max_iterations, confidence and seed with RansacParams
    for name in ("max_iterations", "confidence", "seed"):
        assert params[name].default == defaults[name], name


@pytest.mark.parametrize(
    ("points", "kwargs", "exc", "name"),
    [
        (np.zeros((0, 3)), {}, ValueError, "points"),
        (np.ones((1, 3)), {}, ValueError, "points"),
        (np.ones((5, 3)), {}, ValueError, "points"),  # all coincide
        (np.eye(3), {"threshold": 0.0}, ValueError, "threshold"),
        (np.eye(3), {"threshold": float("nan")}, ValueError, "threshold"),
        (np.eye(3), {"max_iterations": 0}, ValueError, "max_iterations"),
        (np.eye(3), {"confidence": 1.0}, ValueError, "confidence"),
        (np.eye(3), {"confidence": float("nan")}, ValueError, "confidence"),
        (np.eye(3), {"seed": -1}, ValueError, "seed"),
        (np.eye(3), {"seed": 2**64}, ValueError, "seed"),
        (np.eye(3), {"seed": "1"}, TypeError, "seed"),
    ],
)
def test_ransac_bad_input_names_the_argument(
    points: np.ndarray, kwargs: dict[str, object], exc: type[Exception], name: str
) -> None:
    args: dict[str, object] = {"threshold": 0.05}
    args.update(kwargs)
    threshold = args.pop("threshold")
    with pytest.raises(exc, match=name):
        ir.ransac_line(points, threshold, **args)  # type: ignore[arg-type]
