"""Big inputs finish, and the GIL is released while Rust works."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import insulator_rs as ir
from insulator_rs.synthetic import lidar_frame

CAM = ir.CameraModel(600.0, 600.0, 320.0, 240.0, 640, 480)
T_C_L = np.array([[0.0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]])  # FLU L -> optical C


@pytest.mark.slow
def test_one_million_points_through_project_cull_dbscan() -> None:
    """A 1,000,000-point Mid-360-like frame (float32) goes through project_points,
    points_in_boxes and dbscan; results are consistent with each other."""
    points = lidar_frame(1_000_000, seed=0).astype(np.float32)
    uv, valid = ir.project_points(points, T_C_L, CAM)
    assert uv.shape == (1_000_000, 2) and 10_000 < valid.sum() < 500_000
    boxes = np.array([[0.0, 0, 640, 480]])
    whole, = ir.points_in_boxes(points, T_C_L, CAM, boxes)
    np.testing.assert_array_equal(whole, np.flatnonzero(valid))
    labels = ir.dbscan(points, 0.3, 5)
    assert labels.shape == (1_000_000,) and labels.max() > 100
    counts = np.bincount(labels[labels >= 0])
    assert counts.min() >= 1 and counts.sum() == (labels >= 0).sum()


def test_gil_is_released_during_dbscan() -> None:
    """While one thread runs a long dbscan, the main thread keeps executing Python:
    its ticks land inside the middle half of the call's time window."""
    points = lidar_frame(200_000, seed=1, max_range=15.0)
    window: dict[str, float] = {}

    def worker() -> None:
        window["start"] = time.perf_counter()
        ir.dbscan(points, 0.3, 5)
        window["end"] = time.perf_counter()

    thread = threading.Thread(target=worker)
    ticks: list[float] = []
    thread.start()
    while thread.is_alive():
        ticks.append(time.perf_counter())
        time.sleep(0.001)
    thread.join()
    duration = window["end"] - window["start"]
    assert duration > 0.05, "dbscan finished too fast to observe the GIL"
    lo, hi = window["start"] + 0.25 * duration, window["end"] - 0.25 * duration
    inside = [t for t in ticks if lo <= t <= hi]
    # Holding the GIL would starve the main thread for the whole call (no ticks inside).
    assert len(inside) >= 5, f"{len(inside)} main-thread ticks during a {duration:.3f} s dbscan"
