"""``find_insulator_strings`` on tower-scale clouds (issue 47: 500k points in at most 0.5 s on
one core).

    taskset -c 0 pytest benches/bench_strings.py --benchmark-enable    # the ratio table
    taskset -c 0 python benches/bench_strings.py                        # time per call, printed

Clouds: simulated Mid-360 returns of towers A and B along the mission's exploration path
(``helpers.exploration_clouds``): one frame every survey period (the obstacle map's density,
120-160k points), and every frame the LiDAR makes (600-800k points), randomly cut (seeded) to
125k, 250k and 500k points. Each row first checks that every string of the tower is found, so a fast wrong answer
cannot pass for a result. The finder runs on one thread (no rayon in its path); ``taskset``
pins the process to one core all the same.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from helpers.exploration_clouds import exploration_cloud  # noqa: E402

import insulator_rs as ir  # noqa: E402
from insulator_rs.sim.lidar import Mid360  # noqa: E402
from insulator_rs.sim.towers import load_tower  # noqa: E402

SIZES = (125_000, 250_000, 500_000)
TARGET_S = 0.5  # s per call at 500k points, one core (issue 47)
MATCH_RADIUS = 0.5  # m


def every_return(name: str, n_points: int) -> np.ndarray:
    """``n_points`` of the returns of every LiDAR frame of one exploration (a seeded draw)."""
    _, cloud = exploration_cloud(name, period=Mid360().frame_period)
    if len(cloud) < n_points:
        raise ValueError(f"n_points: the exploration of {name} holds only {len(cloud)} returns")
    return cloud[np.random.default_rng(0).choice(len(cloud), n_points, replace=False)]


def strings_found(name: str, cloud: np.ndarray) -> int:
    """How many of the tower's true strings have a found string within MATCH_RADIUS."""
    found = np.array([s.center for s in ir.find_insulator_strings(cloud)]).reshape(-1, 3)
    truth = np.array([t.center for t in load_tower(name).insulators])
    if len(found) == 0:
        return 0
    d = np.linalg.norm(truth[:, None, :] - found[None, :, :], axis=2)
    return int((d.min(axis=1) <= MATCH_RADIUS).sum())


@pytest.mark.parametrize("n_points", SIZES)
@pytest.mark.parametrize("name", ["tower_a", "tower_b"])
def test_find_strings_every_return(benchmark: Any, name: str, n_points: int) -> None:
    cloud = every_return(name, n_points)
    assert strings_found(name, cloud) == len(load_tower(name).insulators)
    benchmark.group = f"find_insulator_strings, {name}, every LiDAR frame of one exploration"
    benchmark.extra_info.update(impl="insulator_rs", n_points=len(cloud))
    benchmark(ir.find_insulator_strings, cloud)


@pytest.mark.parametrize("name", ["tower_a", "tower_b"])
def test_find_strings_exploration(benchmark: Any, name: str) -> None:
    _, cloud = exploration_cloud(name)
    assert strings_found(name, cloud) == len(load_tower(name).insulators)
    benchmark.group = f"find_insulator_strings, {name} one exploration ({len(cloud)} points)"
    benchmark.extra_info.update(impl="insulator_rs", n_points=len(cloud),
                                target=f"<= {TARGET_S} s at 500k points")
    benchmark(ir.find_insulator_strings, cloud)


def main() -> None:
    """Time per call (best and median of 7), strings found, against the 0.5 s target."""
    rows: list[tuple[str, np.ndarray]] = []
    for name in ("tower_a", "tower_b"):
        rows += [(f"{name} every frame", every_return(name, n)) for n in SIZES]
        rows.append((f"{name} one exploration", exploration_cloud(name)[1]))
    for label, cloud in rows:
        name = label.split()[0]
        times = []
        for _ in range(7):
            t0 = time.perf_counter()
            ir.find_insulator_strings(cloud)
            times.append(time.perf_counter() - t0)
        best, median = min(times), float(np.median(times))
        found = strings_found(name, cloud)
        n_true = len(load_tower(name).insulators)
        verdict = f"   target <= {TARGET_S} s: {'met' if median <= TARGET_S else 'MISSED'}" if len(cloud) >= SIZES[-1] else ""
        print(f"{label:28s} {len(cloud):>7} points: {best * 1e3:7.1f} ms best, {median * 1e3:7.1f} ms median, "
              f"{median / len(cloud) * 1e9:6.0f} ns/point, strings {found}/{n_true}{verdict}")


if __name__ == "__main__":
    main()
