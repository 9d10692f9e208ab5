"""Cost of the simulated sensors on tower A (``insulator_rs.sim``), side by side.

    pytest benches/bench_sensors.py --benchmark-enable

* One Mid-360 frame (20,000 shots, vehicle moving 3 m/s) 9 m from an insulator:
  the whole ``Mid360.scan`` (target < 20 ms) vs the bare ``RaycastScene.cast`` of
  the same rays (the Python share of a frame).
* The same frame as Mid-360 datagrams (``LivoxEmitter.add_frame``: 208 packets of 96 shots,
  what the SITL sensor head sends 10 times a second) vs encoding the 208 headers alone (the
  per-datagram floor: struct + CRC-32). The per-shot Python loop it had cost 366 ms a second of
  data on this box (106 ms after).
* One 1280x960 image from the same pose: ``Camera.render`` with sun shadows
  (target < 1 s) vs without shadow rays.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from insulator_rs.sim.camera_render import Camera, Lighting
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.livox_emitter import DOTS_PER_PACKET, LivoxEmitter, encode_datagram
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


FRAME = LIDAR.scan(MESH, (START, END), 0.0, seed=0)


def _emit_one_frame() -> int:
    emitter = LivoxEmitter()
    return len(emitter.add_frame(FRAME))


@pytest.mark.benchmark(group="Mid-360 frame as datagrams")
def test_emitter_frame(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="LivoxEmitter.add_frame")
    assert benchmark(_emit_one_frame) > 100


@pytest.mark.benchmark(group="Mid-360 frame as datagrams")
def test_emitter_headers_only(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="encode_datagram alone (the floor)")
    samples = bytes(14 * DOTS_PER_PACKET)
    n = _emit_one_frame()

    def headers() -> int:
        return len([encode_datagram(data_type=1, samples=samples, dot_num=DOTS_PER_PACKET, time_interval=4800,
                                    udp_cnt=i, frame_cnt=0, timestamp_ns=i) for i in range(n)])

    assert benchmark(headers) == n


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


def _inspection_photo(scale: float) -> Any:
    """One inspection photo of the string from the same pose: the simulator rig's 12 MP zoom at
    3.7x (the framing tower A and B's strings get from 6-9 m), the rays built per photo as the
    flight's are (each zoom is a new lens), at ``scale`` of 4000x3000."""
    from insulator_rs.flight.gimbal import aim_at
    from insulator_rs.rig import simulator_rig
    from insulator_rs.sim.sensors import SimulatedSensors

    rig = simulator_rig()
    cam = rig.inspection_camera()
    T_w_b = START.copy()
    sensors = SimulatedSensors(MESH, lambda t: T_w_b, rig, photo_scale=scale)
    _, _, T_b_c = aim_at(T_w_b, cam.T_b_c, CENTER, cam.gimbal)
    return sensors.photo(0.0, T_b_c, camera=cam.at_focal(10_800.0))


@pytest.mark.benchmark(group="inspection photo, 12 MP zoom, tower A")
def test_inspection_photo_full_12_mp(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="4000x3000 (photo scale 1.0)")
    frame = benchmark.pedantic(_inspection_photo, args=(1.0,), rounds=1, iterations=1)
    assert frame.image.shape == (3000, 4000, 3)


@pytest.mark.benchmark(group="inspection photo, 12 MP zoom, tower A")
def test_inspection_photo_scale_0_2(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="800x600 (photo scale 0.2, the tests')")
    frame = benchmark.pedantic(_inspection_photo, args=(0.2,), rounds=3, iterations=1)
    assert frame.image.shape == (600, 800, 3)
