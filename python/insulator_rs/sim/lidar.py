"""The simulated Livox Mid-360 LiDAR: a non-repetitive scan cast from a moving sensor.

The sensor model
----------------
* Field of view 360 deg horizontal, -7 deg to +52 deg vertical (in the L frame:
  x forward, y left, z up; elevation measured from the x-y plane).
* 200,000 points/s; a frame is 0.1 s (10 Hz), 20,000 points. Shot ``k`` (counted
  from t = 0) fires at ``t_k = k / point_rate``.
* Scan pattern (a model with the Mid-360's statistics, not Livox's proprietary
  pattern): four interleaved channels; shot ``k`` uses channel ``c = k mod 4``.
  The head spins at 10 rev/s (azimuth ``2 pi f_az t + c pi / 2``) while each
  channel's elevation sweeps the vertical field as a triangle wave at
  ``f_el = (50 + sqrt 2) f_az``, phase-shifted by ``c / 4``. The ratio of the two
  rates is irrational, so the pattern never repeats: each 0.1 s frame covers the
  whole field at about 1 point per square degree (~0.9 deg between sweeps,
  ~1.2 deg along a sweep) and the coverage fills in as frames accumulate, as the
  real sensor's non-repetitive pattern does.
* Range noise: Gaussian, 2 cm (1 sigma) by default. Returns closer than
  ``min_range`` (0.1 m) or beyond ``max_range`` (40 m) are lost.
* Lost returns: a return from a solid surface survives with probability
  ``return_probability`` of its instance times an incidence factor that is 1 up to
  ``grazing_start_deg`` and falls linearly to 0 at ``grazing_end_deg``. On thin
  instances (``InstanceInfo.thin``: conductors) the facet normal means nothing at
  the beam footprint's scale, so only ``return_probability`` (the share of the
  footprint on the wire) applies.
* Motion: every shot is cast from the sensor pose at its own time,
  ``T_w_l(t) = T_w_b(t) @ T_b_l``, and the point is reported in the L frame of
  that instant, as the driver delivers it (no motion compensation). A vehicle
  moving during the frame therefore distorts it as a real one does.

Everything is seeded: the same seed, trajectory and scene give the same frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from insulator_rs.poses import PoseTrack, check_pose
from insulator_rs.rig import MID360_VERTICAL_FOV_DEG, simulator_rig
from insulator_rs.sim.camera_render import check_outside
from insulator_rs.sim.mesh import Mesh

#: A trajectory: body pose T_w_b (4x4) as a function of time (s), or the body poses
#: at the start and the end of the frame (interpolated in between).
Trajectory = Callable[[float], np.ndarray] | tuple[ArrayLike, ArrayLike]

N_CHANNELS = 4
#: Head spin rate, rev/s, and the irrational multiple the elevation sweeps run at.
AZIMUTH_RATE_HZ = 10.0
ELEVATION_RATE_RATIO = 50.0 + math.sqrt(2.0)
#: Poses sampled per frame from a callable trajectory (interpolated in between).
POSE_SAMPLES_PER_FRAME = 21
POSE_SAMPLE_SPACING = 0.005  # s: (21 - 1) samples over the Mid-360's 100 ms frame


@dataclass(frozen=True)
class LidarFrame:
    """One LiDAR frame.

    ``points_l`` (N, 3) float64: each point in the L frame at its own timestamp
    (what the driver delivers). ``timestamps`` (N,) float64 s. ``instance_id``
    (N,) int32: what each point hit (ground truth). ``points_w`` (N, 3): the same
    noisy points in W (ground truth of where the sensor was). ``t_start``/``t_end``
    bound the frame; ``T_w_l_start``/``T_w_l_end`` are the sensor poses then.
    """

    points_l: np.ndarray
    timestamps: np.ndarray
    instance_id: np.ndarray
    points_w: np.ndarray
    t_start: float
    t_end: float
    T_w_l_start: np.ndarray
    T_w_l_end: np.ndarray

    def __len__(self) -> int:
        return int(self.points_l.shape[0])


def default_T_b_l() -> np.ndarray:
    """Where the simulated Mid-360 sits on the body, from the shipped simulator rig (10 cm above
    the body origin, axes aligned with the body)."""
    return simulator_rig().T_b_l


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name}: must be a finite number > 0, got {value}")
    return value


class Mid360:
    """A Livox Mid-360 model (see the module docstring) mounted on the body by ``T_b_l``.

    Units: metres, seconds, degrees for the angle settings.
    """

    def __init__(self, T_b_l: ArrayLike | None = None, *, point_rate: float = 200_000.0,
                 frame_rate: float = 10.0, min_range: float = 0.1, max_range: float = 40.0,
                 range_noise: float = 0.02, fov_down_deg: float = MID360_VERTICAL_FOV_DEG[0],
                 fov_up_deg: float = MID360_VERTICAL_FOV_DEG[1],
                 grazing_start_deg: float = 65.0, grazing_end_deg: float = 88.0) -> None:
        self.T_b_l = check_pose("T_b_l", default_T_b_l() if T_b_l is None else T_b_l)
        self.point_rate = _positive("point_rate", point_rate)
        self.frame_rate = _positive("frame_rate", frame_rate)
        self.max_range = _positive("max_range", max_range)
        if not (math.isfinite(min_range) and 0 <= min_range < self.max_range):
            raise ValueError(f"min_range: must be in [0, max_range), got {min_range}")
        self.min_range = float(min_range)
        if not (math.isfinite(range_noise) and range_noise >= 0):
            raise ValueError(f"range_noise: must be a finite number >= 0, got {range_noise}")
        self.range_noise = float(range_noise)
        if not (-90 <= fov_down_deg < fov_up_deg <= 90):
            raise ValueError(
                f"fov_down_deg/fov_up_deg: need -90 <= down < up <= 90, got {fov_down_deg}, {fov_up_deg}"
            )
        self.fov_down = math.radians(fov_down_deg)
        self.fov_up = math.radians(fov_up_deg)
        if not (0 <= grazing_start_deg < grazing_end_deg <= 90):
            raise ValueError(
                "grazing_start_deg/grazing_end_deg: need 0 <= start < end <= 90, "
                f"got {grazing_start_deg}, {grazing_end_deg}"
            )
        self.cos_grazing_start = math.cos(math.radians(grazing_start_deg))
        self.cos_grazing_end = math.cos(math.radians(grazing_end_deg))
        self.points_per_frame = int(round(self.point_rate / self.frame_rate))
        if self.points_per_frame < 1:
            raise ValueError("point_rate/frame_rate: a frame must hold at least one shot")

    @property
    def frame_period(self) -> float:
        return 1.0 / self.frame_rate

    def shots(self, t_start: float) -> tuple[np.ndarray, np.ndarray]:
        """The shots of the frame starting at ``t_start`` (s).

        Returns (timestamps (N,) s, unit directions (N, 3) in L). Shot times are on
        the global grid ``k / point_rate``, so consecutive frames continue the pattern.
        """
        if not math.isfinite(t_start):
            raise ValueError(f"t_start: must be finite, got {t_start}")
        k0 = math.ceil(t_start * self.point_rate - 1e-9)
        k = k0 + np.arange(self.points_per_frame, dtype=np.int64)
        t = k / self.point_rate
        channel = k % N_CHANNELS
        azimuth = 2.0 * np.pi * (AZIMUTH_RATE_HZ * t + channel / N_CHANNELS)
        sweep = AZIMUTH_RATE_HZ * ELEVATION_RATE_RATIO * t + channel / N_CHANNELS
        triangle = 1.0 - np.abs(2.0 * (sweep % 1.0) - 1.0)  # in [0, 1]
        elevation = self.fov_down + (self.fov_up - self.fov_down) * triangle
        cos_el = np.cos(elevation)
        dirs = np.column_stack([cos_el * np.cos(azimuth), cos_el * np.sin(azimuth), np.sin(elevation)])
        return t, dirs

    def scan(self, mesh: Mesh, trajectory: Trajectory, t_start: float, *, seed: int) -> LidarFrame:
        """Casts one frame starting at ``t_start`` from the sensor carried along ``trajectory``.

        ``trajectory`` is a callable ``t -> T_w_b`` (4x4) or a pair (T_w_b at
        t_start, T_w_b at t_start + frame period). Raises ValueError when the
        sensor sits inside geometry at the frame start.
        """
        t, dirs_l = self.shots(t_start)
        t_end = float(t_start) + self.frame_period
        track = _pose_track(trajectory, float(t_start), t_end)
        # Rotate vectors rather than build a matrix per shot: this is the hot path.
        n = len(t)
        both = track.rotate(np.concatenate([t, t]), np.vstack([
            dirs_l @ self.T_b_l[:3, :3].T, np.broadcast_to(self.T_b_l[:3, 3], dirs_l.shape)]))
        dirs_w, origins = both[:n], track.position(t) + both[n:]
        check_outside(mesh, origins[0], "LiDAR")
        hits = mesh.raycaster.cast(origins, dirs_w, self.max_range)

        rng = np.random.default_rng(seed)
        ids = hits.instance_id
        hit = ids >= 0
        cos_inc = np.abs(np.einsum("ij,ij->i", hits.normal, dirs_w))
        incidence_keep = np.clip(
            (cos_inc - self.cos_grazing_end) / (self.cos_grazing_start - self.cos_grazing_end), 0.0, 1.0
        )
        thin = np.zeros(len(mesh.return_probability_table()), bool)
        for key, info in mesh.instances.items():
            thin[key] = info.thin
        safe_ids = np.where(hit, ids, 0)
        keep_p = np.where(hit, mesh.return_probability_table()[safe_ids], 0.0)
        keep_p = keep_p * np.where(thin[safe_ids], 1.0, incidence_keep)
        # Draws happen for every shot (hit or not) so the stream does not depend on the scene.
        survive = rng.random(len(t)) < keep_p
        ranges = hits.distance + self.range_noise * rng.standard_normal(len(t))
        keep = hit & survive & (hits.distance >= self.min_range) & (ranges > 0)

        points_l = dirs_l[keep] * ranges[keep, None]
        points_w = origins[keep] + dirs_w[keep] * ranges[keep, None]
        return LidarFrame(
            points_l=points_l, timestamps=t[keep], instance_id=ids[keep].astype(np.int32),
            points_w=points_w, t_start=float(t_start), t_end=t_end,
            T_w_l_start=track.pose(float(t_start)) @ self.T_b_l,
            T_w_l_end=track.pose(t_end) @ self.T_b_l,
        )


def _pose_track(trajectory: Trajectory, t_start: float, t_end: float) -> PoseTrack:
    """The frame's body poses, sampled from a callable or given as a start/end pair."""
    if callable(trajectory):
        # one sample per 5 ms, as POSE_SAMPLES_PER_FRAME over a 100 ms frame (the SITL sensor
        # head renders 20 ms slices: 21 samples each were a fifth of its LiDAR's cost)
        n = max(2, min(POSE_SAMPLES_PER_FRAME, math.ceil((t_end - t_start) / POSE_SAMPLE_SPACING - 1e-9) + 1))
        knots_t = np.linspace(t_start, t_end, n)
        knots_T = np.stack([check_pose(f"trajectory({time:.4f})", trajectory(float(time)))
                            for time in knots_t])
        return PoseTrack(knots_t, knots_T)
    try:
        start, end = trajectory
    except (TypeError, ValueError):
        raise TypeError(
            "trajectory: expected a callable t -> T_w_b or a pair (T_w_b_start, T_w_b_end)"
        ) from None
    knots_T = np.stack([check_pose("trajectory[0]", start), check_pose("trajectory[1]", end)])
    return PoseTrack(np.array([t_start, t_end]), knots_T)
