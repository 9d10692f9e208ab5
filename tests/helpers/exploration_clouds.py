"""The LiDAR cloud one exploration flight leaves of a shipped tower (the workload of
``insulator_rs.find_insulator_strings``, issue 47).

The sensor flies the mission's own exploration path (``MissionGeometry.from_mission`` of the
shipped ``missions/<tower>.toml``) at the mission's horizontal speed limit, facing the tower as
each waypoint says, and casts one simulated Mid-360 frame every ``SURVEY_PERIOD`` s, as the
flight's obstacle map surveys. Returns farther than ``SURVEY_RANGE`` from the sensor or lower
than ``GROUND_BAND`` above the ground are dropped, as the map drops them. ``frame_stride`` = 2
keeps every other frame: half an exploration's density. A shorter ``period`` keeps more of
the LiDAR's frames (every one at its frame period: about five times the map's density).
Deterministic.
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

import insulator_rs
from insulator_rs.flight.leg_follower import SURVEY_PERIOD
from insulator_rs.mission.config import load_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.planning.obstacle_map import GROUND_BAND, SURVEY_RANGE
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.scene import ObstacleSpec, load_scene
from insulator_rs.sim.towers import Tower, build_tower

MISSIONS_DIR = Path(insulator_rs.__file__).resolve().parent / "missions"


def _survey_poses(geom: MissionGeometry, speed: float, period: float) -> list[np.ndarray]:
    """T_w_b (4x4) every ``period`` s along the exploration path flown at ``speed`` m/s,
    level, with the yaw of the waypoint each leg flies to."""
    step = speed * period
    poses: list[np.ndarray] = []
    carry = 0.0  # m already flown past the last survey on the previous leg
    for a, b in zip(geom.path[:-1], geom.path[1:]):
        leg = b.position - a.position
        length = float(np.linalg.norm(leg))
        s = step - carry
        while s <= length:
            T = np.eye(4)
            T[:3, 3] = a.position + leg * (s / length)
            c, si = math.cos(b.yaw), math.sin(b.yaw)
            T[:2, :2] = [[c, -si], [si, c]]
            poses.append(T)
            s += step
        carry = length - (s - step)
    return poses


@functools.cache
def _survey_frames(name: str, period: float,
                   obstacles: tuple[ObstacleSpec, ...]) -> tuple[Tower, tuple[np.ndarray, ...]]:
    """The tower (with ``obstacles`` added to its scene) and the returns (W) of one frame every
    ``period`` s of one exploration, in flight order."""
    mission = load_mission(MISSIONS_DIR / f"{name}.toml")
    geom = MissionGeometry.from_mission(mission)
    scene = load_scene(name)
    tower = build_tower(replace(scene, obstacles=scene.obstacles + obstacles))
    lidar = Mid360()
    ground_z = float(geom.takeoff[2])
    frames: list[np.ndarray] = []
    for k, T_w_b in enumerate(_survey_poses(geom, float(mission.vehicle.v_max_horizontal), period)):
        if T_w_b[2, 3] < ground_z + GROUND_BAND:  # on the ground at take-off and landing
            continue
        frame = lidar.scan(tower.mesh, (T_w_b, T_w_b), period * k, seed=k)
        sensor = (T_w_b @ lidar.T_b_l)[:3, 3]
        pts = frame.points_w
        keep = (np.linalg.norm(pts - sensor, axis=1) <= SURVEY_RANGE) & (pts[:, 2] >= ground_z + GROUND_BAND)
        frames.append(pts[keep])
    return tower, tuple(frames)


def exploration_cloud(name: str, frame_stride: int = 1, *, period: float = SURVEY_PERIOD,
                      obstacles: tuple[ObstacleSpec, ...] = ()) -> tuple[Tower, np.ndarray]:
    """(tower, (N,3) float64 cloud in W) of one exploration of the shipped tower ``name``,
    keeping every ``frame_stride``-th frame of one every ``period`` s (default: the map's
    survey period; ``Mid360().frame_period`` keeps every return the flight's LiDAR makes);
    ``obstacles`` (clutter) are added to the scene, not to the mission."""
    tower, frames = _survey_frames(name, period, obstacles)
    return tower, np.concatenate(frames[::frame_stride])
