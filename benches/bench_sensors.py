"""Cost of the simulated sensors on tower A (``insulator_rs.sim``), side by side.

    pytest benches/bench_sensors.py --benchmark-enable

* One Mid-360 frame (20,000 shots, vehicle moving 3 m/s) 9 m from an insulator:
  the whole ``Mid360.scan`` (target < 20 ms) vs the bare ``RaycastScene.cast`` of
  the same rays (the Python share of a frame).
* One 1280x960 image from the same pose: ``Camera.render`` with sun shadows
  (target < 1 s) vs without shadow rays.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from insulator_rs.sim.camera_render import Camera, Lighting
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.towers import load_tower

TOWER = load_tower("tower_a")
MESH = TOWER.mesh
_ = MESH.raycaster  # build the BVH outside the timings
CENTER = TOWER.insulators[0].center
START = np.eye(4)
START[:3, :3] = [[-1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]]  # looking back at the tower (-x)
START[:3, 3] = CENTER + [9.0, 0.0, -1.0]
END = START.copy()
END[0, 3] -= 0.3
LIDAR = Mid360()
CAMERA = Camera()
_ = CAMERA.rays_c  # per-camera ray table, computed once


@pytest.mark.benchmark(group="Mid-360 frame, 20k shots, tower A")
def test_lidar_scan(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="insulator_rs", target="< 20 ms")
    frame = benchmark(LIDAR.scan, MESH, (START, END), 0.0, seed=0)
    assert len(frame) > 100


@pytest.mark.benchmark(group="Mid-360 frame, 20k shots, tower A")
def test_lidar_cast_only(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="RaycastScene.cast alone")
    t, dirs_l = LIDAR.shots(0.0)
    origins = np.tile(START[:3, 3] + START[:3, :3] @ LIDAR.T_b_l[:3, 3], (len(t), 1))
    dirs_w = dirs_l @ (START[:3, :3] @ LIDAR.T_b_l[:3, :3]).T
    hits = benchmark(MESH.raycaster.cast, origins, dirs_w, LIDAR.max_range)
    assert len(hits) == len(t)


@pytest.mark.benchmark(group="camera image 1280x960, tower A")
def test_camera_shadows(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="insulator_rs", target="< 1 s")
    frame = benchmark.pedantic(CAMERA.render, args=(MESH, START), kwargs={"lighting": Lighting()},
                               rounds=3, iterations=1)
    assert frame.boxes


@pytest.mark.benchmark(group="camera image 1280x960, tower A")
def test_camera_no_shadows(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="no shadow rays")
    frame = benchmark.pedantic(CAMERA.render, args=(MESH, START),
                               kwargs={"lighting": Lighting(shadows=False)}, rounds=3, iterations=1)
    assert frame.boxes
