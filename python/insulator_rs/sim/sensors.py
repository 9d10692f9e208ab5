"""The simulator's :class:`~insulator_rs.ports.sensors.Sensors` adapter: camera and Mid-360 rendered
from the scene.

The sensors ride on the airframe's TRUE pose, which only the simulator knows: the wiring
hands in a ``pose`` callable (see :func:`kinematic_true_pose`, :func:`simulated_px4_true_pose`)
returning T_w_b at a vehicle time. Against an outside autopilot (a PX4 SITL with
``--sim-sensors``) there is no truth to ask, and :func:`reported_pose` renders at the pose
the autopilot reports.

* ``detection_frame(now)``: the detection camera (the rig's lens, scaled), no shadows.
* ``lidar_scan(now)``: one Mid-360 frame over ``[now - 0.1 s, now]``, each shot cast from
  the true pose at its own time, points in L at their own time, as the driver delivers them.
* ``photo(now, T_b_c)``: the full-resolution inspection camera, aimed by the gimbal.

Frames are stamped ``now`` (the vehicle clock the flight loop gives). The ground truth of
each rendered detection frame (its insulators' boxes) stays here, for the simulator-side
:class:`~insulator_rs.sim.ground_truth_detector.GroundTruthDetector` only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from insulator_rs.exceptions import SensorError
from insulator_rs.poses import pose_from_yaw
from insulator_rs.rig import SensorRig, scaled_camera
from insulator_rs.ports.sensors import CameraFrame, LidarScan
from insulator_rs.sim.camera_render import Camera, Lighting
from insulator_rs.sim.kinematics import KinematicVehicle
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.mesh import Mesh
from insulator_rs.ports.vehicle import Vehicle

#: T_w_b (4x4) of the airframe at a vehicle time (s), at or shortly before now.
PoseSource = Callable[[float], np.ndarray]


def kinematic_true_pose(vehicle: KinematicVehicle) -> PoseSource:
    """The in-process airframe's true pose (no odometry noise, no GPS glitch) at a time."""
    def pose(time: float) -> np.ndarray:
        return pose_from_yaw(*vehicle.true_pose_at(time))
    return pose


def simulated_px4_true_pose(simulator: Any) -> PoseSource:
    """The true pose of the airframe our simulated PX4 flies (read under its lock) at a time."""
    def pose(time: float) -> np.ndarray:
        return pose_from_yaw(*simulator.with_vehicle(lambda v: v.true_pose_at(time)))
    return pose


def reported_pose(vehicle: Vehicle) -> PoseSource:
    """The pose an outside autopilot reports (a SITL has no other truth to give), carried back
    to an earlier time along its reported velocity."""
    def pose(time: float) -> np.ndarray:
        st = vehicle.state()
        return pose_from_yaw(st.position - st.velocity * (st.time - time), st.yaw)
    return pose


class SimulatedSensors:
    """Renders the camera and the Mid-360 of ``rig`` in ``mesh`` at ``pose()`` (module docstring).

    ``detect_scale``/``photo_scale``: resolution of the detection and inspection images as a
    fraction of the rig camera's. Everything rendered is seeded from ``seed``.
    """

    def __init__(self, mesh: Mesh, pose: PoseSource, rig: SensorRig, *, detect_scale: float = 0.25,
                 photo_scale: float = 1.0, seed: int = 0) -> None:
        for name, value in (("detect_scale", detect_scale), ("photo_scale", photo_scale)):
            if not (math.isfinite(value) and 0 < value <= 1):
                raise ValueError(f"{name}: must be in (0, 1], got {value}")
        self.mesh = mesh
        self.pose = pose
        self.rig = rig
        self.detection_camera = Camera(scaled_camera(rig.camera, detect_scale), rig.T_b_c)
        self.photo_model = scaled_camera(rig.camera, photo_scale)
        self.lidar = Mid360(rig.T_b_l)
        self.seed = seed
        self.counts = {"detection_frames": 0, "scans": 0, "photos": 0, "errors": 0}
        self.truth: dict[int, dict[int, tuple[float, float, float, float]]] = {}  # id(image) -> boxes
        self.last_error: str | None = None

    def _fail(self, what: str, exc: ValueError) -> SensorError:
        self.counts["errors"] += 1
        self.last_error = f"{what}: {exc}"
        return SensorError(f"simulated {what}: {exc}")

    def detection_frame(self, now: float) -> CameraFrame | None:
        T_w_b = self.pose(now)
        n = self.counts["detection_frames"] = self.counts["detection_frames"] + 1
        try:
            frame = self.detection_camera.render(self.mesh, T_w_b, lighting=Lighting(shadows=False),
                                                 seed=self.seed + n, time=now)
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

    def photo(self, now: float, T_b_c: np.ndarray) -> CameraFrame | None:
        T_w_b = self.pose(now)
        n = self.counts["photos"] = self.counts["photos"] + 1
        try:
            frame = Camera(self.photo_model, T_b_c).render(self.mesh, T_w_b, seed=self.seed + 200_000 + n,
                                                           time=now)
        except ValueError as exc:
            raise self._fail("photo camera", exc) from exc
        return CameraFrame(now, np.ascontiguousarray(frame.rgb[:, :, ::-1]), self.photo_model,
                           np.asarray(T_b_c, dtype=np.float64))

    def ground_truth_boxes(self, image: np.ndarray) -> dict[int, tuple[float, float, float, float]]:
        """The true insulator boxes of a detection image this simulator rendered (the latest)."""
        boxes = self.truth.get(id(image))
        if boxes is None:
            raise ValueError("image: not the latest detection frame of this simulator (no ground truth for it)")
        return boxes

    def health(self) -> dict[str, object]:
        return {"source": "simulator", **self.counts, "last_error": self.last_error}

    def close(self) -> None:
        self.truth = {}
