"""One stray far LiDAR return must cost no more than a near one (issue 13 item 6).

``pytest benches/bench_far_point.py --benchmark-enable``. Each group times the same cloud
without and with ONE point 1e7 m away. Before the gap cut in
``crates/fusion_core/src/dbscan/mod.rs`` the far point sent the whole cloud to the kd-tree
(dbscan: 34 s and 6.4 GB; localize: 7 s and 1.8 GB); now both rows should be about equal.
The regression test (behaviour, memory cap) is ``tests/test_core_far_point.py``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import insulator_rs as ir
from insulator_rs.synthetic import insulator_cloud

FAR = np.array([[1e7, 0.0, 0.0]])
EPS, MIN_POINTS = 0.3, 5

# 60,000 points in a 0.4 m cube: every grid cell is dense (the kd-tree's worst case).
DENSE_60K = np.random.default_rng(0).uniform(0.0, 0.4, size=(60_000, 3))
_cloud = insulator_cloud(seed=1, n_insulator=24_000, n_tower=5_000, n_stray=1_000).points
CLOUD_30K = _cloud[np.argsort(_cloud[:, 0])][:30_000]


@pytest.mark.parametrize("far", [False, True], ids=["near only", "plus one far point"])
@pytest.mark.benchmark(group="dbscan, 60,000 dense points")
def test_dbscan_far_point(benchmark: Any, far: bool) -> None:
    benchmark.extra_info.update(impl="insulator_rs" if not far else "insulator_rs + far point")
    points = np.vstack([DENSE_60K, FAR]) if far else DENSE_60K
    labels = benchmark(ir.dbscan, points, EPS, MIN_POINTS)
    assert (labels[:60_000] == 0).all()


@pytest.mark.parametrize("far", [False, True], ids=["near only", "plus one far point"])
@pytest.mark.benchmark(group="localize dbscan+ransac, 30,000 points")
def test_localize_far_point(benchmark: Any, far: bool) -> None:
    benchmark.extra_info.update(impl="insulator_rs" if not far else "insulator_rs + far point")
    points = np.vstack([CLOUD_30K, FAR]) if far else CLOUD_30K
    benchmark(ir.localize, points, "dbscan+ransac")
