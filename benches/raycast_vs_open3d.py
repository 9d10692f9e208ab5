"""The simulator's ray caster against Open3D's ``RaycastingScene`` (Embree), side by side.

    python benches/raycast_vs_open3d.py [--repeats 5] [--quick]

On the sim's tower meshes (``load_tower("tower_a")``, ``"tower_b"``), the same rays are cast
by ``RaycastScene.cast`` (``mesh.raycaster``, what the cameras and the LiDAR use) and by
Open3D's ``RaycastingScene.cast_rays`` (Embree 3, float32), both on every core of the machine,
timed numpy-in to numpy-out, interleaved (ours, Open3D, ours, ...) so that a neighbour's load
falls on both; the minimum of the repeats is reported. Three ray sets per tower:

* ``photo``: the primary rays of the 12 MP inspection camera (4000x3000 at the widest zoom,
  subsampled to every 4th pixel in both directions: 750k rays) 8 m from an insulator;
* ``lidar``: ten Mid-360 frames (200k shots) from the same standpoint;
* ``random``: 500k rays from random points around the tower toward random vertices.

It prints rays per second and the ratio (ours / Open3D, > 1 = faster), checks that both find the
same surfaces (distances within 1e-4 m where both hit: Open3D works in float32), and times one
full 12 MP photo the way the simulator takes it (``Camera.render``, sun shadows on).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from insulator_rs.rig import simulator_rig
from insulator_rs.sim.camera_render import Camera
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.mesh import Mesh
from insulator_rs.sim.towers import Tower, load_tower

#: Open3D answers in float32: hits agree to this (m) where both see a surface.
FLOAT32_DISTANCE_TOL = 1e-4
#: Rays whose answers may differ (edge and grazing rays that float32 rounds the other way).
MAX_DISAGREEING = 1e-3
#: The photo standpoint: this far (m) from the first insulator, horizontally, level.
PHOTO_DISTANCE = 8.0
PHOTO_SUBSAMPLE = 4
RANDOM_RAYS = 500_000
LIDAR_FRAMES = 10


def photo_pose(tower: Tower) -> np.ndarray:
    """T_w_c of a level camera PHOTO_DISTANCE m from the first insulator, looking at it."""
    center = tower.insulators[0].center
    away = np.array([1.0, 0.3, 0.0]) / np.hypot(1.0, 0.3)
    z = -away  # optical axis toward the insulator
    x = np.cross([0.0, 0.0, -1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # down
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = center + PHOTO_DISTANCE * away
    return T


def ray_sets(tower: Tower, camera: Camera) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(origins, unit directions) in W per ray set."""
    T = photo_pose(tower)
    m = camera.model
    grid = camera.rays_c.reshape(m.height, m.width, 3)[::PHOTO_SUBSAMPLE, ::PHOTO_SUBSAMPLE].reshape(-1, 3)
    photo_dirs = grid @ T[:3, :3].T
    photo = (np.broadcast_to(T[:3, 3], photo_dirs.shape).copy(), photo_dirs)
    lidar = Mid360()
    dirs = np.vstack([lidar.shots(k * lidar.frame_period)[1] for k in range(LIDAR_FRAMES)])
    lidar_rays = (np.broadcast_to(T[:3, 3], dirs.shape).copy(), dirs)
    rng = np.random.default_rng(0)
    v = tower.mesh.vertices
    lo, hi = v.min(axis=0), v.max(axis=0)
    span = hi - lo
    origins = rng.uniform(lo - 0.3 * span, hi + 0.3 * span, size=(RANDOM_RAYS, 3))
    origins[:, 2] = np.abs(origins[:, 2]) + 0.5
    targets = v[rng.integers(0, len(v), RANDOM_RAYS)] + rng.normal(0.0, 0.05, (RANDOM_RAYS, 3))
    d = targets - origins
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return {"photo": photo, "lidar": lidar_rays, "random": (origins, d)}


def open3d_scene(mesh: Mesh) -> Any:
    try:
        import open3d as o3d
    except ImportError as exc:  # open3d is no dependency of the package: a bench-only extra
        raise SystemExit(f"this benchmark needs Open3D (pip install open3d): {exc}") from exc

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor.from_numpy(np.ascontiguousarray(mesh.vertices, np.float32)),
                        o3d.core.Tensor.from_numpy(np.ascontiguousarray(mesh.triangles, np.uint32)))
    return scene


def best_of(repeats: int, runs: list[Callable[[], Any]]) -> list[float]:
    """Min wall time (s) of each run, interleaved repeat by repeat."""
    best = [np.inf] * len(runs)
    for _ in range(repeats):
        for i, run in enumerate(runs):
            t0 = time.perf_counter()
            run()
            best[i] = min(best[i], time.perf_counter() - t0)
    return best


def compare(name: str, mesh: Mesh, o3d_scene: Any, origins: np.ndarray, dirs: np.ndarray,
            repeats: int) -> float:
    """Times both casters on the rays, checks they agree; returns ours / Open3D in rays/s."""
    import open3d as o3d

    rays32 = np.hstack([origins, dirs]).astype(np.float32)

    def ours() -> np.ndarray:
        return np.asarray(mesh.raycaster.cast(origins, dirs, np.inf).distance)

    def theirs() -> np.ndarray:
        out = o3d_scene.cast_rays(o3d.core.Tensor.from_numpy(rays32), nthreads=0)
        return np.asarray(out["t_hit"].numpy())

    t_ours, t_theirs = best_of(repeats, [ours, theirs])
    d_ours, d_theirs = ours(), theirs().astype(np.float64)
    both = np.isfinite(d_ours) & np.isfinite(d_theirs)
    far = np.abs(d_ours[both] - d_theirs[both]) > FLOAT32_DISTANCE_TOL * np.maximum(1.0, d_ours[both])
    one_only = np.isfinite(d_ours) != np.isfinite(d_theirs)
    disagree = (int(far.sum()) + int(one_only.sum())) / len(d_ours)
    n = len(origins)
    ratio = t_theirs / t_ours
    print(f"  {name:7s} {n:8d} rays ({both.mean():5.1%} hit): ours {n / t_ours / 1e6:6.2f} Mrays/s, "
          f"Open3D {n / t_theirs / 1e6:6.2f} Mrays/s, ratio {ratio:5.2f}x   disagree {disagree:.2e}")
    if disagree > MAX_DISAGREEING:
        raise SystemExit(f"{name}: the casters disagree on {disagree:.2%} of the rays")
    return ratio


def photo_render_seconds(tower: Tower, camera: Camera, repeats: int) -> float:
    """Min wall time (s) of one full-resolution photo rendered as the simulator does."""
    T_w_c = photo_pose(tower)
    return min(best_of(repeats, [lambda: camera.render(tower.mesh, T_w_c)]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="tower A only, 3 repeats")
    args = parser.parse_args()
    repeats = 3 if args.quick else args.repeats
    model = simulator_rig().inspection_camera().camera
    camera = Camera(model, np.eye(4))  # T_b_c = I: the poses below are camera poses
    print(f"{os.cpu_count()} cores; inspection camera {model.width}x{model.height}; "
          f"min of {repeats} interleaved repeats")
    ratios = []
    for name in ["tower_a"] if args.quick else ["tower_a", "tower_b"]:
        tower = load_tower(name)
        t0 = time.perf_counter()
        _ = tower.mesh.raycaster
        t_build = time.perf_counter() - t0
        t0 = time.perf_counter()
        scene = open3d_scene(tower.mesh)
        scene.cast_rays(np.zeros((1, 6), np.float32))  # Embree builds its BVH on the first cast
        t_o3d_build = time.perf_counter() - t0
        print(f"{name}: {tower.mesh.n_triangles} triangles; build ours {t_build * 1e3:.0f} ms, "
              f"Open3D {t_o3d_build * 1e3:.0f} ms")
        for set_name, (o, d) in ray_sets(tower, camera).items():
            ratios.append(compare(set_name, tower.mesh, scene, o, d, repeats))
        seconds = photo_render_seconds(tower, camera, max(1, repeats // 2))
        print(f"  12 MP photo ({model.width}x{model.height}, shadows): {seconds:.2f} s")
    print(f"ratio ours / Open3D (geometric mean over ray sets): {np.exp(np.mean(np.log(ratios))):.2f}x, "
          f"min {min(ratios):.2f}x")


if __name__ == "__main__":
    main()
