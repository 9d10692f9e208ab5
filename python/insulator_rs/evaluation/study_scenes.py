"""What the localization studies share: the simulated sensors round a tower, the event's
flight and odometry, the flight's pipeline fed one event, and the errors against the truth.

The localization study (Tables I and II), the airframe study (a flown, tilting airframe)
and the motion study (deskew) draw their events alike: a UAV on the target's side of the
line flying along it (:func:`event_poses`), the Mid-360 and the camera at their default
mounts (:class:`StudyRig`), odometry at :data:`POSE_RATE_HZ` with Gaussian noise
(:func:`noisy_odometry`), and the flight's own perception pipeline (:func:`localize_event`,
built by :func:`insulator_rs.perception.stack.rig_pipeline`). The clutter study takes the
noise and the purity from here too. A study's settings reach these functions through
:class:`EventConfig` (the localization study's ``StudyConfig`` is one).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from insulator_rs.perception.localization_method import LocalizationMethod
from insulator_rs.perception.pipeline import LocalizedInsulator, PerceptionPipeline
from insulator_rs.perception.stack import rig_pipeline
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped
from insulator_rs.rig import SensorRig

if TYPE_CHECKING:
    from insulator_rs.sim.detector_standin import DetectorStandin
    from insulator_rs.sim.towers import InsulatorTruth, Tower

# Give up on an event when the target was not detected within this many images.
MAX_IMAGES_PER_EVENT = 10


class EventConfig(Protocol):
    """The settings an event is drawn with (units: m, s, degrees; see ``StudyConfig``)."""

    @property
    def speed(self) -> float: ...
    @property
    def event_interval(self) -> float: ...
    @property
    def along_spread(self) -> float: ...
    @property
    def height_range(self) -> tuple[float, float]: ...
    @property
    def yaw_jitter_deg(self) -> float: ...
    @property
    def odom_position_noise(self) -> float: ...
    @property
    def odom_yaw_noise_deg(self) -> float: ...
    @property
    def methods(self) -> Sequence[LocalizationMethod]: ...
    @property
    def localize_params(self) -> dict[str, Any]: ...


def yaw_pose(position: np.ndarray, yaw: float) -> np.ndarray:
    """4x4 T_w_b of a level UAV at ``position`` (W) with heading ``yaw`` (rad, ENU)."""
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = position
    return T


def noisy_pose(T: np.ndarray, rng: np.random.Generator, cfg: EventConfig) -> np.ndarray:
    """The odometry's estimate of ``T``: Gaussian position noise and heading noise."""
    yaw_err = math.radians(cfg.odom_yaw_noise_deg) * rng.standard_normal()
    c, s = math.cos(yaw_err), math.sin(yaw_err)
    out = T.copy()
    out[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + cfg.odom_position_noise * rng.standard_normal(3)
    return out


class StudyRig:
    """The simulated sensors of the UAV around one tower: a Mid-360 (sim.lidar) and the default
    camera (sim.camera_render), both at their default mounts on the body."""

    def __init__(self, tower_name: str, cfg: EventConfig, seed: int) -> None:
        from insulator_rs.sim.camera_render import Camera
        from insulator_rs.sim.lidar import Mid360
        from insulator_rs.sim.towers import load_tower

        self.tower = load_tower(tower_name)
        self.mesh = self.tower.mesh
        self.lidar = Mid360()
        self.camera = Camera()
        self.camera_model = self.camera.model
        self.image_size = (int(self.camera_model.width), int(self.camera_model.height))
        self.T_b_l = self.lidar.T_b_l
        # the flight's rig form of the same mounts (what the perception pipeline is built from)
        self.mounts = SensorRig("study rig", self.camera_model, self.camera.T_b_c, self.T_b_l)
        self.T_c_l = np.linalg.inv(self.camera.T_b_c) @ self.T_b_l
        self.cfg = cfg
        self.seed = seed

    def lidar_scan(self, trajectory: Callable[[float], np.ndarray], t_end: float, seed: int) -> LidarScan:
        """The Mid-360 frame ending at ``t_end`` (s), as the driver delivers it: points in L at
        their own timestamps (no motion compensation), per-point times."""
        frame = self.lidar.scan(self.mesh, trajectory, t_end - self.lidar.frame_period, seed=seed)
        return LidarScan(frame.points_l, frame.timestamps, self.T_b_l)

    def detected_target(self, T_w_b: np.ndarray, instance_id: int, detector: DetectorStandin) -> np.ndarray | None:
        """The boxes (K, 5) ``detector`` gives the insulator ``instance_id`` in the image taken at
        body pose ``T_w_b``; None when it is not visible or the detector missed it."""
        box = self.target_box(T_w_b, instance_id)
        if box is None:
            return None
        det = detector.detect(box[None, :], self.image_size, instance_ids=[instance_id])
        mine = det.boxes[det.instance_ids == instance_id]
        return mine if len(mine) else None

    def target_box(self, T_w_b: np.ndarray, instance_id: int) -> np.ndarray | None:
        """Ground-truth box (x1, y1, x2, y2) px of one insulator's visible pixels in the image
        taken at body pose ``T_w_b``, or None when fewer than MIN_BOX_PIXELS are visible.

        Only the window around the projection of the insulator's vertices (plus a margin) is
        rendered, at full resolution and through the same per-pixel rays as a full image, so
        the box is the one ``Camera.render`` gives, at a fraction of the cost (occlusion by
        anything in front is still ray-cast).
        """
        import insulator_rs as ir
        from insulator_rs.sim.camera_render import MIN_BOX_PIXELS, boxes_from_instance_image

        T_w_c = T_w_b @ self.camera.T_b_c
        tri = self.mesh.triangles[self.mesh.instance_ids == instance_id]
        verts = self.mesh.vertices[np.unique(tri)]
        uv, valid = ir.project_points(verts, np.linalg.inv(T_w_c), self.camera_model)
        if not np.any(valid):
            return None
        width, height = self.image_size
        margin = 4
        u0 = max(0, int(np.floor(uv[valid, 0].min())) - margin)
        u1 = min(width - 1, int(np.ceil(uv[valid, 0].max())) + margin)
        v0 = max(0, int(np.floor(uv[valid, 1].min())) - margin)
        v1 = min(height - 1, int(np.ceil(uv[valid, 1].max())) + margin)
        cw, ch = u1 - u0 + 1, v1 - v0 + 1
        rays = self.camera.rays_c.reshape(height, width, 3)[v0:v1 + 1, u0:u1 + 1].reshape(-1, 3)
        _, ids, _ = self.mesh.raycaster.render(
            T_w_c, np.ascontiguousarray(rays), cw, ch, self.mesh.albedo_table(),
            noise_sigma=0.0, shadows=False, max_range=1000.0)
        boxes, _ = boxes_from_instance_image(np.asarray(ids).reshape(ch, cw), [instance_id],
                                             min_pixels=MIN_BOX_PIXELS)
        if instance_id not in boxes:
            return None
        x1, y1, x2, y2 = boxes[instance_id]
        return np.array([x1 + u0, y1 + v0, x2 + u0, y2 + v0], dtype=np.float64)


def event_poses(tower: Tower, target: InsulatorTruth, standoff: float, rng: np.random.Generator,
                cfg: EventConfig) -> tuple[Callable[[float], np.ndarray], list[float]]:
    """The UAV's trajectory (t -> T_w_b) during one event and the times of its images (s).

    It flies along the line at ``cfg.speed`` on the target's side, ``standoff`` m out,
    level, facing the tower (with a yaw offset drawn once per event); image k is taken at
    t = t0 + (k + 1) * event_interval (t0 random), so a full LiDAR frame precedes the first one.
    """
    lateral = np.asarray(tower.spec.lateral_direction)
    along = np.asarray(tower.spec.line_direction)
    start = (target.center + target.side * standoff * lateral
             + rng.uniform(-cfg.along_spread, cfg.along_spread) * along
             + np.array([0.0, 0.0, rng.uniform(*cfg.height_range)]))
    velocity = cfg.speed * (1.0 if rng.random() < 0.5 else -1.0) * along
    yaw = (math.atan2(-target.side * lateral[1], -target.side * lateral[0])
           + math.radians(cfg.yaw_jitter_deg) * rng.uniform(-1.0, 1.0))

    # A random clock offset, so that every event meets a different part of the
    # non-repetitive scan pattern.
    t0 = float(rng.uniform(0.0, 1000.0))

    def trajectory(t: float) -> np.ndarray:
        return yaw_pose(start + velocity * (t - t0), yaw)

    period = max(cfg.event_interval, 0.1)
    times = [t0 + (k + 1) * period for k in range(MAX_IMAGES_PER_EVENT)]
    return trajectory, times


POSE_RATE_HZ = 20.0  # the flight loop feeds the pose history every control tick
ENVELOPE_MARGIN = 0.08  # m: 4 sigma of the 2 cm range noise around an insulator's true shape


def noisy_odometry(trajectory: Callable[[float], np.ndarray], t0: float, t1: float, rng: np.random.Generator,
                   cfg: EventConfig) -> list[PoseStamped]:
    """The odometry the pipeline gets between ``t0`` and ``t1``: poses at POSE_RATE_HZ, each
    with the configured noise."""
    times = np.arange(t0, t1 + 1e-9, 1.0 / POSE_RATE_HZ)
    return [PoseStamped(float(t), noisy_pose(trajectory(float(t)), rng, cfg)) for t in times]


def envelope_purity(points_w: np.ndarray, truth: InsulatorTruth) -> float:
    """Share of ``points_w`` inside the insulator's true envelope (axis, radius, length)."""
    if len(points_w) == 0:
        return math.nan
    rel = points_w - truth.center
    along = rel @ truth.axis
    radial = np.linalg.norm(rel - np.outer(along, truth.axis), axis=1)
    inside = (radial <= truth.radius + ENVELOPE_MARGIN) & (np.abs(along) <= truth.length / 2 + ENVELOPE_MARGIN)
    return float(np.mean(inside))


#: (t0, t1) -> the odometry each pose stream gets between t0 and t1: {stream name: poses}
Odometry = Callable[[float, float], dict[str, list[PoseStamped]]]
EventOutcome = tuple[LocalizedInsulator | None, str, int, float]


def localize_event(rig: StudyRig, target: InsulatorTruth, trajectory: Callable[[float], np.ndarray], times: Sequence[float],
                   detector: DetectorStandin, rng: np.random.Generator, cfg: EventConfig, insulator_length: float,
                   odometry: Odometry | None = None) -> dict[tuple[str, str], EventOutcome] | None:
    """One localization event through the flight's perception pipeline, one pipeline per
    method and pose stream fed the same sensor data: {(method, stream): (localization or None,
    outcome, accumulated points, purity)}. ``odometry`` gives the pose streams (default: one,
    "full", the trajectory with the configured noise). None when the images ran out before a
    localization was attempted."""
    if odometry is None:
        def odometry(t0: float, t1: float) -> dict[str, list[PoseStamped]]:
            return {"full": noisy_odometry(trajectory, t0, t1, rng, cfg)}
    pipelines: dict[tuple[str, str], PerceptionPipeline] = {}
    image = np.broadcast_to(np.zeros(3, np.uint8), (rig.image_size[1], rig.image_size[0], 3))
    period = rig.lidar.frame_period
    fed_until = times[0] - 1.0
    for t in times:
        mine = rig.detected_target(trajectory(t), target.instance_id, detector)
        if mine is None:
            continue
        # the scan ending at the image and the next one: the flight pairs a frame with +-100 ms
        scans = [rig.lidar_scan(trajectory, t_end, seed=int(rng.integers(2**31))) for t_end in (t, t + period)]
        streams = odometry(fed_until + 1.0 / POSE_RATE_HZ, t + period)
        if not pipelines:
            pipelines = {(m, name): rig_pipeline(rig.mounts, method=m, insulator_length=insulator_length,
                                                 localize_params=cfg.localize_params)
                         for name in streams for m in cfg.methods}
        fed_until = t + period
        frame = CameraFrame(t, image, rig.camera_model, rig.camera.T_b_c)
        results = {}
        for key, per in pipelines.items():
            poses = streams[key[1]]
            c = per.counters
            before = (c.localizations, c.failures, c.implausible, c.not_insulator)
            for pose in poses:
                per.add_pose(pose)
            for scan in scans:
                per.add_scan(scan)
            out = per.process(frame, mine[:1])
            after = (c.localizations, c.failures, c.implausible, c.not_insulator)
            if after == before:
                continue  # fewer than 3 detection events with LiDAR points so far
            outcome = "ok" if out else ("failed" if after[1] > before[1] else
                                        "implausible" if after[2] > before[2] else "not an insulator")
            track = max(per.tracks, key=lambda tr: len(tr.events))
            acc = np.vstack(list(track.events))
            results[key] = (out[0] if out else None, outcome, len(acc), envelope_purity(acc, target))
        if results:
            return results  # every pipeline saw the same data, so all attempted together
    return None


def localization_errors(center_w: np.ndarray, direction_w: np.ndarray,
                        truth: InsulatorTruth) -> tuple[float, float, float, float, float]:
    """Centre error (m): total, horizontal, vertical, along the true axis; axis angle (deg)."""
    d = center_w - truth.center
    cos = min(1.0, abs(float(np.dot(direction_w, truth.axis))))
    return (float(np.linalg.norm(d)), float(np.hypot(d[0], d[1])), float(abs(d[2])),
            math.degrees(math.acos(cos)), float(abs(np.dot(d, truth.axis))))
