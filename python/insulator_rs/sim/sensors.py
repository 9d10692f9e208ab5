"""The simulator's :class:`~insulator_rs.ports.sensors.Sensors` adapter: camera and Mid-360 rendered
from the scene.

The sensors ride on the airframe's TRUE pose (full attitude: tilted along its thrust, leaning
into the wind), which only the simulator knows: the wiring
hands in a ``pose`` callable (see :func:`kinematic_true_pose`, :func:`simulated_px4_true_pose`)
returning T_w_b at a vehicle time. Against an outside autopilot (a PX4 SITL with
``--sim-sensors``) there is no truth to ask, and :func:`reported_pose` renders at the pose
the autopilot reports.

* ``detection_frame(now)``: the detection camera (the rig's lens, scaled), no shadows.
* ``lidar_scan(now)``: one Mid-360 frame over ``[now - 0.1 s, now]``, each shot cast from
  the true pose at its own time, points in L at their own time, as the driver delivers them.
* ``photo(now, T_b_c, camera)``: the inspection camera (the rig's ``[inspection_camera]``, or
  the detection camera's lens in a rig without one) at the zoom asked for, aimed by the gimbal,
  rendered at ``photo_scale`` of its resolution with the intrinsics scaled to match
  (:func:`~insulator_rs.rig.scaled_camera`): the frame's ``camera`` is what was rendered. A full
  12 MP frame costs about 30 s of ray casting on one core; tests render at 0.2.

Frames are stamped ``now`` (the vehicle clock the flight loop gives). The ground truth of
each rendered detection frame and photo (its insulators' boxes) stays here, for the simulator-side
:class:`~insulator_rs.sim.ground_truth_detector.GroundTruthDetector` only.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from insulator_rs._core import CameraModel
from insulator_rs.exceptions import SensorError
from insulator_rs.rig import SensorRig, scaled_camera
from insulator_rs.ports.sensors import CameraFrame, LidarScan, StreamStatus
from insulator_rs.sim.camera_render import Camera, Lighting
from insulator_rs.sim.kinematics import KinematicVehicle
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.mesh import Mesh
from insulator_rs.ports.vehicle import Vehicle, VehicleState

#: m a multirotor's sensors stand above its body origin's ground pose on the landing gear (the
#: pre-flight probe's pose: the simulated airframe's body origin sits on the ground)
LANDING_GEAR_HEIGHT = 0.2
#: the pre-flight probe's seed offset: clear of the flight's frames (seed + n), scans (seed +
#: 100 000 + n) and photos (seed + 200 000 + n)
PROBE_SEED_OFFSET = 900_000
#: reported states :func:`reported_pose` keeps to interpolate between (at 20-50 Hz, 1-3 s: more
#: than a LiDAR frame and a camera's latency)
REPORTED_HISTORY = 64
#: T_w_b (4x4) of the airframe at a vehicle time (s), at or shortly before now.
PoseSource = Callable[[float], np.ndarray]


def standing(pose: PoseSource) -> PoseSource:
    """``pose`` raised by LANDING_GEAR_HEIGHT: where a pre-flight probe renders the sensors of
    an airframe on the ground."""
    def on_gear(time: float) -> np.ndarray:
        T = np.array(pose(time), dtype=np.float64)
        T[2, 3] += LANDING_GEAR_HEIGHT
        return T
    return on_gear


def resting_on(pose: PoseSource, ground_z: float) -> PoseSource:
    """``pose`` held at least LANDING_GEAR_HEIGHT above a ground plane at ``ground_z``: a pose
    estimate stands in for the airframe's true one (the live sensor head renders from PX4's), and
    an estimator's pose of an airframe on the ground wanders about it (PX4 SITL v1.16: 0.3 m below
    to 0.05 m above, on the ground before take-off), while the airframe itself stands on its gear.
    Rendered from the raw estimate, the sensors sat inside the ground and sent nothing."""
    floor = ground_z + LANDING_GEAR_HEIGHT

    def on_gear(time: float) -> np.ndarray:
        T = np.array(pose(time), dtype=np.float64)
        T[2, 3] = max(T[2, 3], floor)
        return T
    return on_gear


def kinematic_true_pose(vehicle: KinematicVehicle) -> PoseSource:
    """The in-process airframe's true pose (no odometry noise, no GPS glitch) at a time."""
    def pose(time: float) -> np.ndarray:
        return vehicle.true_pose_at(time)
    return pose


def simulated_px4_true_pose(simulator: Any) -> PoseSource:
    """The true pose of the airframe our simulated PX4 flies (read under its lock) at a time."""
    def pose(time: float) -> np.ndarray:
        T: np.ndarray = simulator.with_vehicle(lambda v: v.true_pose_at(time))
        return T
    return pose


def reported_pose(vehicle: Vehicle) -> PoseSource:
    """The pose an outside autopilot reports (a SITL has no other truth to give), full attitude:
    between two reported states the pose interpolated (slerp, lerp), before the oldest kept one
    or after the newest carried along its reported velocity and body rates.

    The attitude matters: a sensor renders a 100 ms frame at times either side of the newest
    state, and braking pitches a multirotor at 60+ deg/s. With the newest attitude for every
    time (the position alone carried back), the simulated Mid-360 put a braking frame's ground
    (12-25 m off) 0.5-3.5 m high, 7 degrees of pitch, which the obstacle map then kept as an
    obstacle beside the landing approach (session 16, test_live_inspection)."""
    history: deque[tuple[float, np.ndarray]] = deque(maxlen=REPORTED_HISTORY)

    def carried(st: VehicleState, time: float) -> np.ndarray:
        dt = st.time - time
        T = st.T_w_b
        T[:3, 3] = st.position - st.velocity * dt
        if st.angular_velocity is not None and st.has_attitude:
            # body rates in B: R_w_b(now - dt) = R_w_b(now) exp(-[w] dt)
            T[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(-np.asarray(st.angular_velocity, dtype=np.float64) * dt).as_matrix()
        return T

    def pose(time: float) -> np.ndarray:
        st = vehicle.state()
        if not history or st.time > history[-1][0]:
            history.append((st.time, st.T_w_b))
        if len(history) < 2 or not history[0][0] <= time <= history[-1][0]:
            return carried(st, time)
        times = [t for t, _ in history]
        i = max(1, bisect.bisect_left(times, time))
        (t0, T0), (t1, T1) = history[i - 1], history[i]
        f = 0.0 if t1 <= t0 else (time - t0) / (t1 - t0)
        T = np.eye(4)
        T[:3, :3] = T0[:3, :3] @ Rotation.from_rotvec(Rotation.from_matrix(T0[:3, :3].T @ T1[:3, :3]).as_rotvec() * f).as_matrix()
        T[:3, 3] = T0[:3, 3] + f * (T1[:3, 3] - T0[:3, 3])
        return T
    return pose


#: the detection camera's resolution as a fraction of the rig camera's (the flight's 320 x 240)
DETECT_SCALE = 0.25


class SimulatedSensors:
    """Renders the camera and the Mid-360 of ``rig`` in ``mesh`` at ``pose()`` (module docstring).

    ``detect_scale``/``photo_scale``: resolution of the detection and inspection images as a
    fraction of the rig camera's. Everything rendered is seeded from ``seed``.
    ``camera_latency_s``: a late camera: the detection frame handed out at ``now`` was exposed
    ``camera_latency_s`` earlier (rendered at that instant's pose) and is stamped ``now``, as a
    driver that stamps arrivals stamps it (what ``insulator-rs calibrate time-offset`` finds).
    """

    def __init__(self, mesh: Mesh, pose: PoseSource, rig: SensorRig, *, detect_scale: float = DETECT_SCALE,
                 photo_scale: float = 1.0, seed: int = 0, camera_latency_s: float = 0.0) -> None:
        for name, value in (("detect_scale", detect_scale), ("photo_scale", photo_scale)):
            if not (math.isfinite(value) and 0 < value <= 1):
                raise ValueError(f"{name}: must be in (0, 1], got {value}")
        if not (math.isfinite(camera_latency_s) and 0 <= camera_latency_s <= 0.5):
            raise ValueError(f"camera_latency_s: must be in [0, 0.5] s, got {camera_latency_s}")
        self.camera_latency_s = float(camera_latency_s)
        self.mesh = mesh
        self.pose = pose
        self.rig = rig
        self.detection_camera = Camera(scaled_camera(rig.camera, detect_scale), rig.T_b_c)
        self.photo_scale = float(photo_scale)
        self.photo_model = scaled_camera(rig.inspection_camera().camera, photo_scale)  # at the widest zoom
        self.lidar = Mid360(rig.T_b_l, fov_down_deg=rig.lidar_fov_deg[0], fov_up_deg=rig.lidar_fov_deg[1])
        self.seed = seed
        self.counts = {"detection_frames": 0, "scans": 0, "photos": 0, "errors": 0}
        self.truth: dict[int, dict[int, tuple[float, float, float, float]]] = {}  # id(image) -> boxes
        self.photo_image: np.ndarray | None = None
        self.photo_truth: dict[int, tuple[float, float, float, float]] = {}
        self.last_error: str | None = None

    def _fail(self, what: str, exc: ValueError) -> SensorError:
        self.counts["errors"] += 1
        self.last_error = f"{what}: {exc}"
        return SensorError(f"simulated {what}: {exc}")

    def detection_frame(self, now: float) -> CameraFrame | None:
        exposure = now - self.camera_latency_s
        T_w_b = self.pose(exposure)
        n = self.counts["detection_frames"] = self.counts["detection_frames"] + 1
        try:
            frame = self.detection_camera.render(self.mesh, T_w_b, lighting=Lighting(shadows=False),
                                                 seed=self.seed + n, time=exposure)
        except ValueError as exc:  # the camera inside geometry
            raise self._fail("camera", exc) from exc
        image = np.ascontiguousarray(frame.rgb[:, :, ::-1])
        self.truth = {id(image): dict(frame.boxes)}  # only the latest frame's truth is kept
        return CameraFrame(now, image, self.detection_camera.model, self.detection_camera.T_b_c)

    def lidar_scan(self, now: float) -> LidarScan | None:
        t0 = now - self.lidar.frame_period
        n = self.counts["scans"] = self.counts["scans"] + 1
        try:
            scan = self.lidar.scan(self.mesh, self.pose, t0, seed=self.seed + 100_000 + n)
        except ValueError as exc:
            raise self._fail("LiDAR", exc) from exc
        return LidarScan(scan.points_l, scan.timestamps, self.lidar.T_b_l, window_end=now)

    def photo(self, now: float, T_b_c: np.ndarray, camera: CameraModel | None = None) -> CameraFrame | None:
        T_w_b = self.pose(now)
        n = self.counts["photos"] = self.counts["photos"] + 1
        model = self.photo_model if camera is None else scaled_camera(camera, self.photo_scale)
        try:
            frame = Camera(model, T_b_c).render(self.mesh, T_w_b, seed=self.seed + 200_000 + n, time=now)
        except ValueError as exc:
            raise self._fail("photo camera", exc) from exc
        image = np.ascontiguousarray(frame.rgb[:, :, ::-1])
        # only the latest photo's (what its check asks), held by the image itself: a freed image's
        # id() is reused by the next array, and a detection frame must never pass for the photo
        self.photo_image, self.photo_truth = image, dict(frame.boxes)
        return CameraFrame(now, image, model, np.asarray(T_b_c, dtype=np.float64))

    def ground_truth_boxes(self, image: np.ndarray) -> dict[int, tuple[float, float, float, float]]:
        """The true insulator boxes of a detection image or a photo this simulator rendered (the
        latest of each)."""
        boxes = self.photo_truth if self.is_photo(image) else self.truth.get(id(image))
        if boxes is None:
            raise ValueError("image: not the latest detection frame or photo of this simulator (no ground truth for it)")
        return boxes

    def streams(self, now: float) -> list[StreamStatus]:
        """The pre-flight view of the camera and the Mid-360 at ``now``. The simulator renders on
        demand, so a stream here is a probe: one detection frame and one scan rendered at the
        airframe's pose of ``now`` (as the flight's own asks would be), on a seed of their own and
        outside ``counts``, so the flight's frames, their noise and a recording are as without
        the probe. A render that fails (the camera inside geometry) is the stream's error. The
        simulated airframe stands with its body origin on the ground, its camera in the ground
        plane; a real one stands on its landing gear: the probe renders from
        LANDING_GEAR_HEIGHT above the pose."""
        out = []
        on_gear = standing(self.pose)
        T_w_b = on_gear(now - self.camera_latency_s)
        try:
            self.detection_camera.render(self.mesh, T_w_b, lighting=Lighting(shadows=False), seed=self.seed + PROBE_SEED_OFFSET,
                                         time=now - self.camera_latency_s)
            out.append(StreamStatus("camera", self.counts["detection_frames"] + 1, now))
        except ValueError as exc:
            out.append(StreamStatus("camera", self.counts["detection_frames"], None, error=str(exc)))
        try:
            self.lidar.scan(self.mesh, on_gear, now - self.lidar.frame_period, seed=self.seed + PROBE_SEED_OFFSET)
            out.append(StreamStatus("lidar", self.counts["scans"] + 1, now))
        except ValueError as exc:
            out.append(StreamStatus("lidar", self.counts["scans"], None, error=str(exc)))
        return out

    def is_photo(self, image: np.ndarray) -> bool:
        """Whether ``image`` is the latest inspection photo this simulator rendered."""
        return image is self.photo_image

    def health(self) -> dict[str, object]:
        return {"source": "simulator", **self.counts, "last_error": self.last_error}

    def close(self) -> None:
        self.truth = {}
        self.photo_image, self.photo_truth = None, {}
