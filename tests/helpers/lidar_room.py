"""A room for the simulated Mid-360 to scan (a floor and four walls, ``half`` m from the centre)
and a level body pose (position and yaw): the scene and the poses the simulated sensors' tests
(the live LiDAR path, the Livox driver, the camera render) use."""

from __future__ import annotations

import numpy as np

from insulator_rs.sim.mesh import InstanceInfo, Mesh, plane


def room(half: float = 12.0) -> Mesh:
    walls = [
        plane([half, 0, 10], [-1, 0, 0], (40, 40), instance_id=1),
        plane([-half, 0, 10], [1, 0, 0], (40, 40), instance_id=2),
        plane([0, half, 10], [0, -1, 0], (40, 40), instance_id=3),
        plane([0, -half, 10], [0, 1, 0], (40, 40), instance_id=4),
    ]
    floor = plane([0, 0, 0], [0, 0, 1], (40, 40), instance_id=0, info=InstanceInfo("floor", "ground"))
    return Mesh.concatenate([floor, *walls])


def body_pose(position: np.ndarray, yaw: float) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = position
    return T
