"""Look at a replayed flight in Rerun: an ``.rrd`` file next to the report (no viewer started).

Logged on the timeline ``flight_time`` (the vehicle clock): ``world/trajectory`` (the pose
stream as a line), ``world/body`` (the current pose), ``camera/image`` with
``camera/image/detections`` (boxes), ``world/lidar`` (the deskewed scan of each detection
event, in W), ``world/culled/box_<k>`` (the points culled to box k, in W) and
``world/insulators`` (the registry's insulators with their axes). Open with ``rerun FILE.rrd``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

import insulator_rs as ir
from insulator_rs.ports.sensors import CameraFrame, PoseStamped

TIMELINE = "flight_time"
INSULATOR_LENGTH = 2.0  # m drawn along each insulator's axis
_MAX_TRAJECTORY = 100_000


class RerunLog:
    """One recording stream saved to ``path``."""

    def __init__(self, path: Path, *, name: str = "replay") -> None:
        import rerun as rr

        self.rr = rr
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rec = rr.RecordingStream("insulator_rs", recording_id=f"replay-{name}")
        self.rec.save(str(self.path))
        self.trajectory: list[np.ndarray] = []
        self._T_w_b = np.eye(4)

    def _time(self, t: float) -> None:
        self.rr.set_time(TIMELINE, duration=float(t), recording=self.rec)

    def pose(self, p: PoseStamped) -> None:
        self._T_w_b = p.T_w_b
        if len(self.trajectory) < _MAX_TRAJECTORY:
            self.trajectory.append(p.T_w_b[:3, 3].copy())
        if len(self.trajectory) % 20 == 1:  # the line grows a second at a time (20 Hz poses)
            self._time(p.time)
            self.rr.log("world/trajectory", self.rr.LineStrips3D([np.array(self.trajectory)]), recording=self.rec)
            self.rr.log("world/body", self.rr.Transform3D(translation=p.T_w_b[:3, 3], mat3x3=p.T_w_b[:3, :3]),
                        recording=self.rec)

    def frame(self, frame: CameraFrame, boxes: np.ndarray) -> None:
        self._time(frame.time)
        self.rr.log("camera/image", self.rr.Image(np.ascontiguousarray(frame.image[:, :, ::-1])), recording=self.rec)
        self.rr.log("camera/image/detections",
                    self.rr.Boxes2D(array=np.asarray(boxes, dtype=np.float64).reshape(-1, 4),
                                    array_format=self.rr.Box2DFormat.XYXY),
                    recording=self.rec)

    def paired(self, frame: CameraFrame, boxes: np.ndarray, points_w: np.ndarray, T_w_b: np.ndarray) -> None:
        """The points paired with a frame (W, deskewed) and those culled to each box."""
        pts_w = np.asarray(points_w, dtype=np.float64)
        self.rr.log("world/lidar", self.rr.Points3D(pts_w[::4], radii=0.02), recording=self.rec)
        T_c_w = np.linalg.inv(np.asarray(T_w_b) @ frame.T_b_c)
        for k, idx in enumerate(ir.points_in_boxes(pts_w, T_c_w, frame.camera, boxes)):
            self.rr.log(f"world/culled/box_{k}", self.rr.Points3D(pts_w[idx], radii=0.04, class_ids=k),
                        recording=self.rec)

    def insulators(self, t: float, insulators: list[Any]) -> None:
        self._time(t)
        centers = np.array([i.center for i in insulators])
        axes = np.array([i.axis for i in insulators])
        half = 0.5 * INSULATOR_LENGTH * axes
        self.rr.log("world/insulators", self.rr.Points3D(centers, radii=0.15, labels=[f"#{i.id}" for i in insulators]),
                    recording=self.rec)
        self.rr.log("world/insulators/axes", self.rr.LineStrips3D(np.stack([centers - half, centers + half], axis=1)),
                    recording=self.rec)

    def close(self) -> None:
        if self.trajectory:
            self.rr.log("world/trajectory", self.rr.LineStrips3D([np.array(self.trajectory)]), recording=self.rec)
        self.rec.flush()
        self.rec.disconnect()
