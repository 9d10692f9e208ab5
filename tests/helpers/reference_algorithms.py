"""Plain numpy reference implementations of the paper's four localization methods.

Independent of the Rust core: DBSCAN comes from scikit-learn, PCA from
``numpy.linalg.eigh``, RANSAC is a short numpy loop. Each method follows the
paper's Methodology section (Algorithms 1 and 2) line by line, with the
interpretations the fusion_core contract fixes:

* "center(c)" of a cluster is its centroid; "nearest" is the cluster whose
  centroid is nearest the origin of the body frame B (the UAV).
* "median(projection(P, line, tau))" is the point on the line at the median of
  the scalar projections ``(p - line.point) . line.direction`` of the points of
  P that lie within ``tau`` of the line.
* Directions are unit vectors with the largest-magnitude component positive.

Points with a NaN/Inf coordinate are dropped before anything else, as the core
skips them. Units: metres, B frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sklearn.cluster import DBSCAN  # type: ignore[import-untyped]


@dataclass(frozen=True)
class RefLine:
    """A 3-D line: ``point`` on it and unit ``direction``."""

    point: np.ndarray
    direction: np.ndarray


@dataclass(frozen=True)
class RefLocalization:
    """Centre (m, B frame), unit axis direction, number of points that set the centre;
    ``reclustered`` tells that Algorithm 2 took its |SC| > 1 branch."""

    center: np.ndarray
    direction: np.ndarray
    n_points: int
    reclustered: bool = False


def canonical_direction(v: np.ndarray) -> np.ndarray:
    """Unit vector along ``v`` whose largest-|component| is positive."""
    v = np.asarray(v, dtype=np.float64)
    v = v / np.linalg.norm(v)
    return -v if v[np.argmax(np.abs(v))] < 0 else v


def finite_rows(points: np.ndarray) -> np.ndarray:
    """The rows of an (N,3) array whose three coordinates are all finite, as float64."""
    pts = np.asarray(points, dtype=np.float64)
    return pts[np.all(np.isfinite(pts), axis=1)]


def reference_pca(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, eigenvalues descending, eigenvectors as columns) of the sample covariance (N-1)."""
    pts = finite_rows(points)
    mean = pts.mean(axis=0)
    cov = np.cov(pts, rowvar=False)
    values, vectors = np.linalg.eigh(cov)  # ascending
    order = np.argsort(values)[::-1]
    return mean, values[order], vectors[:, order]


def pca_line(points: np.ndarray) -> RefLine:
    """Least-squares 3-D line: through the centroid along the major principal axis."""
    mean, _, vectors = reference_pca(points)
    return RefLine(mean, canonical_direction(vectors[:, 0]))


def distance_to_line(points: np.ndarray, line: RefLine) -> np.ndarray:
    """Perpendicular distance (m) of each point to ``line``."""
    rel = points - line.point
    along = rel @ line.direction
    return np.linalg.norm(rel - np.outer(along, line.direction), axis=1)


def median_projection(points: np.ndarray, line: RefLine, tau: float) -> tuple[np.ndarray, int]:
    """Point on ``line`` at the median scalar projection of the points within ``tau`` of it."""
    near = points[distance_to_line(points, line) <= tau]
    if len(near) == 0:
        raise ValueError("no point within tau of the line")
    t = np.median((near - line.point) @ line.direction)
    return line.point + t * line.direction, len(near)


def reference_ransac_line(
    points: np.ndarray,
    threshold: float,
    *,
    max_iterations: int = 1000,
    confidence: float = 0.99,
    seed: int = 0,
) -> tuple[RefLine, np.ndarray]:
    """RANSAC 3-D line: two-point hypotheses, adaptive stop, PCA refit on the inliers
    (repeated until the inlier set is stable, at most 5 rounds).

    Returns the refit line and the indices (into the finite rows) of the points
    within ``threshold`` of it.
    """
    pts = finite_rows(points)
    rng = np.random.default_rng(seed)
    n = len(pts)
    best: np.ndarray | None = None
    needed = max_iterations
    k = 0
    while k < min(needed, max_iterations):
        k += 1
        i, j = rng.choice(n, size=2, replace=False)
        d = pts[j] - pts[i]
        norm = np.linalg.norm(d)
        if norm == 0.0:
            continue
        inliers = np.flatnonzero(distance_to_line(pts, RefLine(pts[i], d / norm)) <= threshold)
        if best is None or len(inliers) > len(best):
            best = inliers
            w = len(inliers) / n
            miss = 1.0 - w * w
            if miss <= 0.0:
                needed = k
            else:
                needed = int(np.ceil(np.log(1.0 - confidence) / np.log(miss)))
    if best is None or len(best) < 2:
        raise ValueError("RANSAC found no line")
    # Least-squares refit on the inliers, inliers recomputed, until stable (at most 5 rounds).
    for _ in range(5):
        line = pca_line(pts[best])
        refit = np.flatnonzero(distance_to_line(pts, line) <= threshold)
        if len(refit) < 2 or np.array_equal(refit, best):
            break
        best = refit
    return line, np.flatnonzero(distance_to_line(pts, line) <= threshold)


def clusters_of(points: np.ndarray, eps: float, min_points: int) -> list[np.ndarray]:
    """scikit-learn DBSCAN clusters (noise dropped), each as an (K,3) array."""
    if len(points) == 0:
        return []
    labels = DBSCAN(eps=eps, min_samples=min_points).fit_predict(points)
    return [points[labels == c] for c in range(labels.max() + 1)]


def nearest_cluster(clusters: list[np.ndarray]) -> np.ndarray:
    """The cluster whose centroid is nearest the origin (the UAV in B)."""
    if not clusters:
        raise ValueError("no cluster")
    return min(clusters, key=lambda c: float(np.linalg.norm(c.mean(axis=0))))


def localize_dbscan(points: np.ndarray, eps: float, min_points: int) -> RefLocalization:
    """DBSCAN method: nearest cluster, its centroid and its PCA major axis."""
    nearest = nearest_cluster(clusters_of(finite_rows(points), eps, min_points))
    line = pca_line(nearest)
    return RefLocalization(line.point, line.direction, len(nearest))


def localize_ransac(
    points: np.ndarray, tau: float, threshold: float, *, seed: int = 0
) -> RefLocalization:
    """RANSAC method: a line through the whole cloud, centre at the median projection."""
    pts = finite_rows(points)
    line, _ = reference_ransac_line(pts, threshold, seed=seed)
    center, n = median_projection(pts, line, tau)
    return RefLocalization(center, line.direction, n)


def localize_dbscan_ransac(
    points: np.ndarray, eps: float, min_points: int, tau: float, threshold: float, *, seed: int = 0
) -> RefLocalization:
    """Algorithm 1 (DBSCAN + RANSAC)."""
    nearest = nearest_cluster(clusters_of(finite_rows(points), eps, min_points))  # lines 1-2
    line, inliers = reference_ransac_line(nearest, threshold, seed=seed)  # line 3
    center, n = median_projection(nearest[inliers], line, tau)  # line 4
    return RefLocalization(center, line.direction, n)  # lines 5-6


def localize_dbscan_pca(
    points: np.ndarray, eps: float, min_points: int, tau: float
) -> RefLocalization:
    """Algorithm 2 (DBSCAN + PCA), including the re-clustering of S and its |SC| > 1 branch."""
    nearest = nearest_cluster(clusters_of(finite_rows(points), eps, min_points))  # lines 1-2
    first = pca_line(nearest)  # line 4: v, c
    s = nearest[distance_to_line(nearest, first) <= tau]  # line 5
    sc = clusters_of(s, eps, min_points)  # line 6
    if len(sc) > 1:  # line 7
        t = max(sc, key=len)  # line 9 (ties: the lowest label, as max keeps the first)
        refined = pca_line(t)  # line 10: c' = centroid(T), v' = PCA(T)
        center, n = median_projection(nearest, refined, tau)  # lines 11-12
        return RefLocalization(center, refined.direction, n, reclustered=True)
    return RefLocalization(first.point, first.direction, len(nearest))  # line 16
