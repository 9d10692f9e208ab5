"""The core's DBSCAN checked against scikit-learn's (``sklearn.cluster.DBSCAN``, same eps and
min_samples): the one parity check every DBSCAN test shares."""

from __future__ import annotations

import numpy as np
from sklearn.cluster import DBSCAN  # type: ignore[import-untyped]
from sklearn.neighbors import NearestNeighbors  # type: ignore[import-untyped]

import insulator_rs as ir


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
    # Border points: the cluster of some core point within eps (sklearn's tree answers which
    # points are near; a norm over the whole cloud per border point is quadratic at 65k).
    border = np.flatnonzero(~core & (labels >= 0))
    if len(border):
        near = NearestNeighbors(radius=eps).fit(points[core]).radius_neighbors(points[border], return_distance=False)
        core_labels = labels[core]
        for i, nb in zip(border, near, strict=True):
            assert labels[i] in set(core_labels[nb].tolist())
    # Numbering: cluster k's first core point comes before cluster k+1's.
    n = labels.max() + 1 if len(labels) else 0
    firsts = [np.flatnonzero(core & (labels == k))[0] for k in range(n)]
    assert firsts == sorted(firsts)
    assert set(labels.tolist()) - {-1} == set(range(n))
    return labels
