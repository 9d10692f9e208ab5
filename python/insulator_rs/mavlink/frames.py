"""Frame conversions at the MAVLink boundary, and nowhere else.

The project works in W = local ENU (x east, y north, z up) with body FLU; PX4
speaks local NED (x north, y east, z down) with body FRD. Both conversions
swap/negate axes: ENU<->NED is (x, y, z) -> (y, x, -z) and FLU<->FRD is
(x, y, z) -> (x, -y, -z); each is its own inverse. Yaw: ENU yaw is measured
from east counter-clockwise, NED yaw from north clockwise, so
yaw_ned = pi/2 - yaw_enu.
"""

from __future__ import annotations

import math

import numpy as np

from insulator_rs.poses import quaternion_from_rotation, rotation_from_quaternion
from insulator_rs.ports.vehicle import wrap_angle as wrap_pi

# p_ned = ENU_TO_NED @ p_enu; det = +1 (the x/y swap and the z flip together
# form a proper rotation), and it is symmetric, so it is its own inverse.
ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])


def _vectors(values: object, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.shape[-1:] != (3,):
        raise ValueError(f"{name} must have shape (..., 3), got {array.shape}")
    return array


# Axis swaps by indexing, not matrix products: a NaN component (PX4's "ignored")
# must stay in its own axis instead of spreading through 0 * NaN.
_SWAP_XY = [1, 0, 2]
_FLIP_Z = np.array([1.0, 1.0, -1.0])
_FLIP_YZ = np.array([1.0, -1.0, -1.0])


def enu_to_ned(vector: object) -> np.ndarray:
    """Position/velocity (..., 3) from ENU to NED."""
    return _vectors(vector, "vector")[..., _SWAP_XY] * _FLIP_Z


def ned_to_enu(vector: object) -> np.ndarray:
    """Position/velocity (..., 3) from NED to ENU (the same axis swap)."""
    return _vectors(vector, "vector")[..., _SWAP_XY] * _FLIP_Z


def flu_to_frd(vector: object) -> np.ndarray:
    """Body vector (..., 3) from FLU to FRD."""
    return _vectors(vector, "vector") * _FLIP_YZ


def frd_to_flu(vector: object) -> np.ndarray:
    """Body vector (..., 3) from FRD to FLU."""
    return _vectors(vector, "vector") * _FLIP_YZ


def yaw_enu_to_ned(yaw_enu: float) -> float:
    """Heading from east CCW (rad) -> heading from north CW (rad), in [-pi, pi)."""
    return wrap_pi(math.pi / 2.0 - yaw_enu)


def yaw_ned_to_enu(yaw_ned: float) -> float:
    """Heading from north CW (rad) -> heading from east CCW (rad), in [-pi, pi)."""
    return wrap_pi(math.pi / 2.0 - yaw_ned)


def rotation_from_euler_ned_frd(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R_ned_frd from PX4's ATTITUDE (ZYX Tait-Bryan: yaw, then pitch, then roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def attitude_ned_frd_to_enu_flu(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R_enu_flu (3x3, maps body FLU vectors to W) from PX4 roll/pitch/yaw (rad)."""
    return ENU_TO_NED.T @ rotation_from_euler_ned_frd(roll, pitch, yaw) @ FLU_TO_FRD


def attitude_enu_flu_to_ned_frd(rotation_enu_flu: np.ndarray) -> tuple[float, float, float]:
    """PX4 (roll, pitch, yaw) in rad from R_enu_flu (the inverse of the above)."""
    r = ENU_TO_NED @ np.asarray(rotation_enu_flu, dtype=np.float64) @ FLU_TO_FRD
    pitch = -math.asin(max(-1.0, min(1.0, r[2, 0])))
    roll = math.atan2(r[2, 1], r[2, 2])
    yaw = math.atan2(r[1, 0], r[0, 0])
    return roll, pitch, yaw


def attitude_quaternion_ned_frd_to_enu_flu(q_ned_frd: object) -> np.ndarray:
    """R_enu_flu (3x3) from PX4's ATTITUDE_QUATERNION / VehicleOdometry q: (w, x, y, z) of
    R_ned_frd (FRD body -> NED)."""
    return ENU_TO_NED.T @ rotation_from_quaternion(np.asarray(q_ned_frd, dtype=np.float64)) @ FLU_TO_FRD


def quaternion_ned_frd_from_enu_flu(rotation_enu_flu: np.ndarray) -> np.ndarray:
    """PX4's (w, x, y, z) quaternion of R_ned_frd from R_enu_flu (the inverse of the above)."""
    return quaternion_from_rotation(ENU_TO_NED @ np.asarray(rotation_enu_flu, dtype=np.float64) @ FLU_TO_FRD)


def local_origin_in_w(home_geodetic: tuple[float, float, float], home_local_ned: object,
                      origin_geodetic: tuple[float, float, float]) -> np.ndarray:
    """Where PX4's local frame starts, in W (ENU at ``origin_geodetic``: deg, deg, m AMSL).

    HOME_POSITION carries home both as ``home_geodetic`` (deg, deg, m) and in the local frame
    (``home_local_ned``, m): local_origin_w = ENU(home wrt origin, pymap3d) - ENU(home local), so
    that W = local_origin_w + ned_to_enu(p_local) for every position PX4 reports."""
    import pymap3d

    home_w = np.array(pymap3d.geodetic2enu(*home_geodetic, *origin_geodetic), dtype=np.float64)
    return home_w - ned_to_enu(home_local_ned)


# p_frd = FRD_FROM_OPTICAL @ p_c: a camera's MAVLink frame (x along the optical axis, y right,
# z down, as a gimbal's or CAMERA_IMAGE_CAPTURED's attitude is given) from OpenCV's optical frame
# (z along the axis, x right, y down).
FRD_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def quaternion_yaw_pitch(yaw_ned: float, pitch: float) -> list[float]:
    """(w, x, y, z) of a yaw ``yaw_ned`` (rad, clockwise seen from above) then a pitch ``pitch``
    (rad, positive up), no roll: q_z(yaw) * q_y(pitch), MAVLink's order for a gimbal or a camera."""
    cy, sy = math.cos(yaw_ned / 2), math.sin(yaw_ned / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    return [cy * cp, -sy * sp, cy * sp, sy * cp]


def yaw_pitch_of_quaternion(q: object) -> tuple[float, float]:
    """(yaw, pitch) rad of a (w, x, y, z) quaternion in MAVLink's Z-Y-X order (the roll dropped):
    the inverse of :func:`quaternion_yaw_pitch` for a roll-free attitude."""
    r = rotation_from_quaternion(np.asarray(q, dtype=np.float64))
    pitch = -math.asin(max(-1.0, min(1.0, float(r[2, 0]))))
    return math.atan2(r[1, 0], r[0, 0]), pitch


def camera_rotation_w(q_ned: object) -> np.ndarray:
    """R_w_c (3x3: the camera optical frame in W, ENU) from a camera attitude quaternion (w, x, y,
    z) in NED, x along the optical axis (CAMERA_IMAGE_CAPTURED.q)."""
    return ENU_TO_NED.T @ rotation_from_quaternion(np.asarray(q_ned, dtype=np.float64)) @ FRD_FROM_OPTICAL


def camera_quaternion_ned(R_w_c: np.ndarray) -> np.ndarray:
    """The (w, x, y, z) NED quaternion of a camera whose optical frame has the attitude ``R_w_c``
    in W (the inverse of :func:`camera_rotation_w`)."""
    return quaternion_from_rotation(ENU_TO_NED @ np.asarray(R_w_c, dtype=np.float64)[:3, :3] @ FRD_FROM_OPTICAL.T)
