"""One stray far return must not cost more than a near one (issue 13 item 6).

``ir.dbscan`` on 60,000 dense points plus ONE point 1e7 m away used to take 34 s and 6.4 GB:
the grid's packed cell keys could not span the bounding box, so the whole cloud went to the
kd-tree. Now the cloud is cut at gaps wider than eps and each part is gridded (exact: nothing
is dropped, see ``crates/fusion_core/src/dbscan/mod.rs``).

Behaviour, not time: the labels equal scikit-learn's (reference: ``sklearn.cluster.DBSCAN``,
same eps/min_samples; exact, see ``assert_same_as_sklearn``) and those without the far point,
and the call completes in a child process whose address space is capped at 3 GiB (the old path
needed 6.4 GB for dbscan, 1.8 GB on top of the interpreter for localize). Timings are in
``benches/bench_far_point.py``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from helpers.reference_dbscan import assert_same_as_sklearn

import insulator_rs as ir
from insulator_rs.synthetic import insulator_cloud, line_clusters

# where the insulator_rs under test was imported from (the source tree, or site-packages in CI)
PACKAGE_PARENT = Path(ir.__file__).resolve().parents[1]
FAR_POINTS = [(1e7, 0.0, 0.0), (0.0, -1e7, 2.0), (3.0, 1.0, 1e12), (-1e300, 0.0, 0.0)]
MEMORY_CAP = 3 << 30  # bytes of address space for the child (the old path needed 6.4 GB)
CHILD_TIMEOUT = 300  # s: only so a regression cannot hang the suite


def with_far(points: np.ndarray, far: tuple[float, float, float], at: int) -> np.ndarray:
    return np.insert(points, at, np.array(far), axis=0)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # the helper's norms at 1e300
@pytest.mark.parametrize("far", FAR_POINTS)
def test_dbscan_with_a_far_point_matches_sklearn(far: tuple[float, float, float]) -> None:
    """Reference: sklearn.cluster.DBSCAN on line clusters plus one far point; exact."""
    points = with_far(line_clusters(3000, seed=11), far, 1500)
    labels = assert_same_as_sklearn(points, 0.3, 5)
    assert labels[1500] == -1


def test_far_clusters_and_border_points_match_sklearn() -> None:
    """Reference: sklearn.cluster.DBSCAN. Whole clusters 1e8 m apart (the cloud is cut into
    parts clustered separately, then renumbered by first core point over the whole cloud)."""
    rng = np.random.default_rng(5)
    parts = [line_clusters(400, seed=s) + offset
             for s, offset in enumerate([(0, 0, 0), (1e8, 0, 0), (0, -1e8, 0), (1e8, 1e8, 5)])]
    points = np.concatenate(parts)
    points = points[rng.permutation(len(points))]  # interleave the parts in index order
    for eps, min_points in ((0.3, 5), (0.5, 10), (0.15, 2)):
        assert_same_as_sklearn(points, eps, min_points)


def test_one_far_point_leaves_the_other_labels_alone() -> None:
    """Reference: the same cloud without the far point (ir.dbscan is sklearn-exact there)."""
    rng = np.random.default_rng(3)
    dense = rng.uniform(0.0, 1.0, size=(20_000, 3)) * [2.0, 0.5, 0.5]
    alone = ir.dbscan(dense, 0.3, 10)
    for far in FAR_POINTS:
        labels = ir.dbscan(with_far(dense, far, 777), 0.3, 10)
        assert labels[777] == -1
        np.testing.assert_array_equal(np.delete(labels, 777), alone)


def test_localize_ignores_one_far_point() -> None:
    """Reference: ir.localize on the same cloud without the far point; identical result."""
    cloud = insulator_cloud(seed=4, n_insulator=3000, n_tower=500, n_stray=100).points
    for method in ("dbscan", "dbscan+ransac", "dbscan+pca"):
        want = ir.localize(cloud, method)
        got = ir.localize(with_far(cloud, (1e7, 0.0, 0.0), 10), method)
        np.testing.assert_array_equal(got.center, want.center)
        np.testing.assert_array_equal(got.direction, want.direction)


CHILD = textwrap.dedent("""
    import resource, sys
    import numpy as np
    resource.setrlimit(resource.RLIMIT_AS, ({cap}, {cap}))
    import insulator_rs as ir
    from insulator_rs.synthetic import insulator_cloud
    rng = np.random.default_rng(0)
    # 60,000 points in a 0.4 m cube: every cell is dense, the kd-tree would list them all.
    dense = rng.uniform(0.0, 0.4, size=(60_000, 3))
    labels = ir.dbscan(np.vstack([dense, [[1e7, 0.0, 0.0]]]), 0.3, 5)
    assert (labels[:-1] == 0).all() and labels[-1] == -1, "dbscan labels"
    cloud = insulator_cloud(seed=1, n_insulator=24_000, n_tower=5_000, n_stray=1_000).points
    cloud = cloud[np.argsort(cloud[:, 0])][:30_000]
    far = ir.localize(np.vstack([cloud, [[1e7, 0.0, 0.0]]]), "dbscan+ransac")
    near = ir.localize(cloud, "dbscan+ransac")
    assert np.array_equal(far.center, near.center), "localize centre"
    print("ok")
""")


def test_far_point_needs_no_more_memory() -> None:
    """The 60k-dense-plus-one-far dbscan and the 30k-plus-one-far localize complete under a
    3 GiB address-space cap (before: 6.4 GB and 1.8 GB through the kd-tree fallback)."""
    env = {**os.environ, "PYTHONPATH": str(PACKAGE_PARENT), "OPENBLAS_NUM_THREADS": "1",
           "OMP_NUM_THREADS": "1", "RAYON_NUM_THREADS": "2"}
    proc = subprocess.run([sys.executable, "-c", CHILD.format(cap=MEMORY_CAP)], env=env,
                          capture_output=True, text=True, timeout=CHILD_TIMEOUT)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr[-2000:]
