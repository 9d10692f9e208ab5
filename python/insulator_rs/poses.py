"""Rigid poses: checks, quaternions, the level frame at a heading, interpolation, and a pose history.

Quaternions are (w, x, y, z), Hamilton, unit, w >= 0 where we make them (ROS, PX4 and Eigen's
storage order is x, y, z, w for ROS, w, x, y, z for PX4 and here). The vehicle's attitude is the
quaternion of R_w_b (body FLU -> world ENU): ``p_w = R(q) @ p_b + t``.

``T_a_b`` is a 4x4 float64 homogeneous matrix mapping coordinates in frame b to frame a
(DESIGN.md). Interpolation between two poses is linear in translation and geodesic in
rotation (constant angular velocity about one axis), which is what a multirotor does
between two 20 Hz odometry samples to well under a millimetre.

:class:`PoseHistory` is what the perception pipeline deskews a LiDAR scan with: the
vehicle's estimated poses, stamped in the vehicle clock, kept for a few seconds.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from numpy.typing import ArrayLike

from insulator_rs.ports.sensors import PoseStamped


_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_I3 = np.eye(3)


def check_pose(name: str, T: ArrayLike) -> np.ndarray:
    """A finite 4x4 rigid transform as float64, or ValueError naming ``name``."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"{name}: expected shape (4, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError(f"{name}: contains NaN or Inf")
    R = T[:3, :3]
    # np.allclose's test, written out: allclose's own overhead (~50 us a call) was a third of the
    # SITL sensor head's LiDAR rendering, which checks every pose it samples
    if (np.any(np.abs(T[3] - _LAST_ROW) > 1e-8 + 1e-5 * _LAST_ROW)
            or np.any(np.abs(R @ R.T - _I3) > 1e-6 + 1e-5 * _I3) or np.linalg.det(R) <= 0):
        raise ValueError(f"{name}: not a rigid transform (rotation must be orthonormal, last row 0 0 0 1)")
    return T


def pose_from_yaw(position: ArrayLike, yaw: float) -> np.ndarray:
    """T_w_x of a LEVEL frame at ``position`` (W, m) heading ``yaw`` (rad from east, CCW).

    Not the body's pose (a multirotor tilts atan(a/g) when it accelerates and leans into the
    wind: :attr:`insulator_rs.ports.vehicle.VehicleState.T_w_b` is the full attitude); this is
    the frame a roll/pitch-stabilised gimbal holds, and the yaw-only pose a comparison needs."""
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = np.asarray(position, dtype=np.float64)
    return T


def yaw_of(R: ArrayLike) -> float:
    """The heading (rad from east, CCW; the Z-Y-X Euler yaw) of a rotation R_w_b (3x3 or 4x4)."""
    R = np.asarray(R, dtype=np.float64)
    return math.atan2(float(R[1, 0]), float(R[0, 0]))


def level_pose(T_w_b: ArrayLike) -> np.ndarray:
    """The level frame at the body's position and heading (the body's roll and pitch removed)."""
    T = np.asarray(T_w_b, dtype=np.float64)
    return pose_from_yaw(T[:3, 3], yaw_of(T))


def tilt_of(R: ArrayLike) -> float:
    """The angle (rad) between the body z axis and W's vertical."""
    R = np.asarray(R, dtype=np.float64)
    return math.acos(max(-1.0, min(1.0, float(R[2, 2]))))


def quaternion_from_rotation(R: ArrayLike) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = float(np.trace(R[:3, :3]))
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R[:3, :3])))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    qa = np.array(q, dtype=np.float64)
    qa /= np.linalg.norm(qa)
    return -qa if qa[0] < 0 else qa


def rotation_from_quaternion(q: ArrayLike) -> np.ndarray:
    """Rotation matrix of a (w, x, y, z) quaternion (normalised first); ValueError if it is
    not finite or has no length."""
    qa = np.asarray(q, dtype=np.float64)
    n = float(np.linalg.norm(qa)) if qa.shape == (4,) else math.nan
    if not (math.isfinite(n) and n > 1e-9):
        raise ValueError(f"quaternion: expected 4 finite components with a length, got {qa!r}")
    w, x, y, z = qa / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def pose_from_quaternion(position: ArrayLike, q: ArrayLike) -> np.ndarray:
    """T_w_b at ``position`` (W, m) with attitude ``q`` (w, x, y, z) of R_w_b."""
    T = np.eye(4)
    T[:3, :3] = rotation_from_quaternion(q)
    T[:3, 3] = np.asarray(position, dtype=np.float64)
    return T


class PoseTrack:
    """Rigid body poses between knots: linear in translation, geodesic in rotation.

    ``knots_t`` (K,) strictly increasing times, ``knots_T`` (K, 4, 4) poses;
    times outside the knots are clamped to the ends.
    """

    def __init__(self, knots_t: np.ndarray, knots_T: np.ndarray) -> None:
        self.knots_t = np.asarray(knots_t, dtype=np.float64)
        self.knots_T = np.asarray(knots_T, dtype=np.float64)
        R0 = self.knots_T[:-1, :3, :3]
        self._R0 = R0
        self._omega = _log_so3(np.einsum("kji,kjl->kil", R0, self.knots_T[1:, :3, :3]))

    def _segments(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        kt = self.knots_t
        seg = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, len(kt) - 2)
        s = np.clip((t - kt[seg]) / (kt[seg + 1] - kt[seg]), 0.0, 1.0)
        return seg, s

    def position(self, t: np.ndarray) -> np.ndarray:
        """(N, 3) positions at times ``t`` (N,)."""
        seg, s = self._segments(t)
        p = self.knots_T[:, :3, 3]
        return p[seg] + (p[seg + 1] - p[seg]) * s[:, None]

    def rotate(self, t: np.ndarray, v: np.ndarray) -> np.ndarray:
        """R(t_i) @ v_i for every row: (N,) times, (N, 3) vectors -> (N, 3).

        Within a segment the relative rotation keeps one axis, so Rodrigues' formula about that
        axis, turned by the segment's angle times the fraction reached, gives it; all rows at
        once (a LiDAR frame's 20 segments one by one, each a boolean mask over the frame's
        points, were a third of the simulated Mid-360's cost).
        """
        seg, s = self._segments(t)
        v = np.asarray(v, dtype=np.float64)
        angle_k = np.linalg.norm(self._omega, axis=1)
        turning = angle_k >= 1e-12
        axis_k = np.zeros_like(self._omega)
        axis_k[turning] = self._omega[turning] / angle_k[turning, None]
        axis = axis_k[seg]
        angle = (angle_k * turning)[seg] * s
        cos, sin = np.cos(angle)[:, None], np.sin(angle)[:, None]
        local = (v * cos + np.cross(axis, v) * sin
                 + axis * np.einsum("ij,ij->i", axis, v)[:, None] * (1.0 - cos))
        return np.einsum("nij,nj->ni", self._R0[seg], local)

    def pose(self, time: float) -> np.ndarray:
        """The 4x4 pose at ``time``."""
        return interpolate_poses(self.knots_t, self.knots_T, np.array([time]))[0]




def interpolate_poses(knots_t: np.ndarray, knots_T: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Piecewise interpolation of rigid poses: linear in translation, geodesic in rotation.

    ``knots_t`` (K,) increasing, ``knots_T`` (K, 4, 4), ``t`` (N,) -> (N, 4, 4);
    times outside the knots are clamped to the ends.
    """
    seg = np.clip(np.searchsorted(knots_t, t, side="right") - 1, 0, len(knots_t) - 2)
    span = knots_t[seg + 1] - knots_t[seg]
    s = np.clip((t - knots_t[seg]) / span, 0.0, 1.0)
    R0 = knots_T[:-1, :3, :3]
    R_rel = np.einsum("kji,kjl->kil", R0, knots_T[1:, :3, :3])  # R0^T R1 per segment
    omega = _log_so3(R_rel)  # (K-1, 3)
    R = np.einsum("nij,njl->nil", R0[seg], _exp_so3(omega[seg] * s[:, None]))
    p0, p1 = knots_T[:-1, :3, 3], knots_T[1:, :3, 3]
    out = np.zeros((len(t), 4, 4))
    out[:, :3, :3] = R
    out[:, :3, 3] = p0[seg] + (p1[seg] - p0[seg]) * s[:, None]
    out[:, 3, 3] = 1.0
    return out


def _log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vectors of (K, 3, 3) rotations (angles < pi assumed between knots)."""
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    vee = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    sin = np.sin(angle)
    scale = np.where(sin > 1e-9, angle / (2.0 * np.where(sin > 1e-9, sin, 1.0)), 0.5)
    return vee * scale[:, None]


def _exp_so3(w: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) of rotation vectors (N, 3) (Rodrigues' formula)."""
    angle = np.linalg.norm(w, axis=1)
    safe = np.where(angle > 1e-12, angle, 1.0)
    k = w / safe[:, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -k[:, 2], k[:, 1]
    K[:, 1, 0], K[:, 1, 2] = k[:, 2], -k[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -k[:, 1], k[:, 0]
    sin = np.where(angle > 1e-12, np.sin(angle), 0.0)[:, None, None]
    one_minus_cos = np.where(angle > 1e-12, 1.0 - np.cos(angle), 0.0)[:, None, None]
    return np.eye(3) + sin * K + one_minus_cos * (K @ K)


# s of poses a history keeps: a scan (0.1 s) paired with a frame up to a second old fits easily.
POSE_HISTORY_SECONDS = 5.0
# s a point or frame may lie past the newest pose and still be placed by it (clamped): one pose
# period of a 10 Hz odometry. Past that, at 5 m/s, the clamped pose would be 0.5 m off.
POSE_GAP_S = 0.1
# s: stamps on one clock compared (float sums of control periods)
TIME_TOLERANCE = 1e-9


class PoseHistory:
    """The vehicle's recent poses (vehicle clock), for deskewing and pairing sensor data.

    ``add`` takes poses in time order (an older or equal stamp is ignored: a repeated
    telemetry sample); poses older than ``span`` s before the newest are dropped.
    """

    def __init__(self, span: float = POSE_HISTORY_SECONDS) -> None:
        if not (math.isfinite(span) and span > 0):
            raise ValueError(f"span: must be a finite number > 0, got {span!r}")
        self.span = float(span)
        self._times: deque[float] = deque()
        self._poses: deque[np.ndarray] = deque()

    def __len__(self) -> int:
        return len(self._times)

    def add(self, pose: PoseStamped) -> None:
        t = float(pose.time)
        if not math.isfinite(t):
            raise ValueError(f"pose.time: must be finite, got {t!r}")
        if self._times and t <= self._times[-1]:
            return
        self._times.append(t)
        self._poses.append(check_pose("pose.T_w_b", pose.T_w_b))
        while self._times[0] < t - self.span:
            self._times.popleft()
            self._poses.popleft()

    def covers(self, time: float, gap: float = POSE_GAP_S) -> bool:
        """Whether ``time`` lies within the history, or at most ``gap`` s past its newest pose
        (the next pose is on its way): outside, :meth:`pose_at` would clamp, a wrong pose."""
        return bool(self.covering(np.array([float(time)]), gap)[0])

    def covering(self, times: np.ndarray, gap: float = POSE_GAP_S) -> np.ndarray:
        """:meth:`covers` for each of ``times`` (N,) -> (N,) bool."""
        if not self._times:
            return np.zeros(len(times), dtype=bool)
        return (times >= self._times[0] - TIME_TOLERANCE) & (times <= self._times[-1] + gap)

    @property
    def newest(self) -> PoseStamped | None:
        return PoseStamped(self._times[-1], self._poses[-1]) if self._times else None

    def knots(self) -> tuple[np.ndarray, np.ndarray]:
        """The history as interpolation knots: times (K,) strictly increasing and poses (K, 4, 4),
        K >= 2. Needs one pose."""
        if not self._times:
            raise ValueError("pose history: empty (no pose received yet)")
        t = np.array(self._times)
        T = np.stack(list(self._poses))
        if len(t) == 1:  # one pose: the vehicle stands there at every time
            t, T = np.array([t[0], t[0] + 1.0]), np.stack([T[0], T[0]])
        return t, T

    def track(self) -> PoseTrack:
        """The history as a :class:`PoseTrack` (clamped outside its span). Needs one pose."""
        return PoseTrack(*self.knots())

    def pose_at(self, time: float) -> np.ndarray:
        """T_w_b at ``time`` (interpolated; clamped to the first/last pose outside the span)."""
        knots_t, knots_T = self.knots()
        return interpolate_poses(knots_t, knots_T, np.array([float(time)]))[0]
