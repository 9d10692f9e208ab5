"""The inspection camera's 3-axis gimbal as the body sees it: pitch and yaw aimed, roll and
pitch stabilised against the airframe's tilt (its own IMU does what the autopilot's estimate
does here)."""

from __future__ import annotations

import math

import numpy as np

from insulator_rs.inspection_camera import GimbalLimits
from insulator_rs.poses import level_pose, yaw_of
from insulator_rs.ports.vehicle import wrap_angle


def gimballed_T_b_c(T_b_c: np.ndarray, pitch: float, yaw: float = 0.0) -> np.ndarray:
    """The camera mounted at ``T_b_c`` on a gimbal pitched by ``pitch`` rad (negative looks
    down) about the body y axis, then yawed by ``yaw`` rad (counter-clockwise) about the body z."""
    c, s = math.cos(-pitch), math.sin(-pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    R = np.eye(4)
    R[:3, :3] = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]]) @ np.array(
        [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return R @ T_b_c


def stabilised_T_b_c(T_w_b: np.ndarray, T_b_c: np.ndarray, pitch: float, yaw: float = 0.0) -> np.ndarray:
    """The inspection camera on its 3-axis gimbal, as the body sees it: the gimbal holds the
    camera level in roll and pitch whatever the airframe's tilt, at the body's heading plus
    ``yaw`` rad, pitched by ``pitch`` rad (negative looks down). ``T_w_b``: the body's attitude
    as the autopilot estimates it; ``T_b_c``: the mount on a level body."""
    T_b_level = np.linalg.inv(T_w_b) @ level_pose(T_w_b)  # a pure rotation: same origin
    T_b_level[:3, 3] = 0.0
    return T_b_level @ gimballed_T_b_c(T_b_c, pitch, yaw)


def aim_at(T_w_b: np.ndarray, T_b_c: np.ndarray, target: np.ndarray,
           limits: GimbalLimits) -> tuple[float, float, np.ndarray]:
    """(pitch, yaw, T_b_c) that aim the camera mounted at ``T_b_c`` from the body pose ``T_w_b``
    (W, as estimated at the shot) at ``target`` (W), within ``limits``: the heading error the
    vehicle settled with and its tilt are taken up by the gimbal, so the target stays at the
    image centre (where the limits allow)."""
    T_w_b = np.asarray(T_w_b, dtype=np.float64)
    origin = (T_w_b @ stabilised_T_b_c(T_w_b, T_b_c, 0.0))[:3, 3]
    d = np.asarray(target, dtype=np.float64) - origin
    yaw = wrap_angle(math.atan2(d[1], d[0]) - yaw_of(T_w_b))
    pitch = math.atan2(d[2], math.hypot(d[0], d[1]))
    pitch, yaw = limits.clamp(pitch, yaw)
    return pitch, yaw, stabilised_T_b_c(T_w_b, T_b_c, pitch, yaw)
