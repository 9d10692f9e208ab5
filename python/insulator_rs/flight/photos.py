"""The flight's inspection photos: each one named, saved through the report (JPEG with EXIF
GPS), measured (:func:`~insulator_rs.perception.photo_quality.photo_quality` from the
odometry pose, the gimbal and the localized string) and kept as a record of the summary."""

from __future__ import annotations

from datetime import datetime
from typing import Any

import numpy as np

from insulator_rs.perception.photo_quality import photo_quality
from insulator_rs.planning.waypoints import InspectionWaypoint
from insulator_rs.ports.sensors import CameraFrame
from insulator_rs.poses import pose_from_yaw
from insulator_rs.report import ReportWriter

VERTICAL = np.array([0.0, 0.0, 1.0])


def photo_name(insulator_id: int, n: int) -> str:
    """The file of the ``n``-th photo (1-based) of insulator ``insulator_id``."""
    return f"insulator_{insulator_id:02d}_{n}.jpg"


class InspectionPhotos:
    """The photos of one flight, in the order taken (``records``: the summary's ``photos``)."""

    def __init__(self, report: ReportWriter, insulator_length: float,
                 exif_camera: dict[str, Any] | None = None) -> None:
        self.report = report
        self.exif_camera = exif_camera or {}  # make, model, focal_length_mm (SensorRig.exif_camera)
        self.insulator_length = insulator_length
        self.records: list[dict[str, Any]] = []
        self.camera: Any = None  # intrinsics of the photos taken (the sensors say)

    def __len__(self) -> int:
        return len(self.records)

    def of(self, insulator_id: int) -> list[dict[str, Any]]:
        return [p for p in self.records if p["insulator_id"] == insulator_id]

    def save(self, wp: InspectionWaypoint, frame: CameraFrame, *, time_utc: datetime, time_s: float,
             position: np.ndarray, yaw: float, velocity: np.ndarray, axis: np.ndarray | None) -> dict[str, Any]:
        """Save the photo taken for ``wp`` at the vehicle's ``position``/``yaw`` (W, odometry);
        ``axis``: the localized string's (None: vertical). Returns its record."""
        n = len(self.of(wp.insulator_id)) + 1
        name = photo_name(wp.insulator_id, n)
        record = self.report.save_photo(name, frame.image, time_utc=time_utc, position_enu=position, yaw_enu=yaw,
                                        gimbal_pitch=wp.gimbal_pitch,
                                        description=f"insulator {wp.insulator_id}, photo {n}",
                                        **self.exif_camera)
        self.camera = frame.camera
        T_w_c = pose_from_yaw(position, yaw) @ frame.T_b_c  # the photo's camera pose (odometry)
        T_c_w = np.linalg.inv(T_w_c)
        quality = photo_quality(frame.camera, T_c_w, wp.target, VERTICAL if axis is None else axis,
                                length=self.insulator_length, speed=float(np.linalg.norm(velocity)))
        record = {**record, "insulator_id": wp.insulator_id, "time_s": time_s, "position": position, "yaw": yaw,
                  "gimbal_pitch": wp.gimbal_pitch, "T_b_c": frame.T_b_c, "quality": quality.as_dict(),
                  "planned_gsd_mm": wp.planned_gsd_mm, "T_w_c": T_w_c,
                  "camera": {"fx": frame.camera.fx, "fy": frame.camera.fy, "cx": frame.camera.cx,
                             "cy": frame.camera.cy, "width": frame.camera.width, "height": frame.camera.height,
                             "dist": [float(k) for k in frame.camera.dist]}}
        self.records.append(record)
        return record
