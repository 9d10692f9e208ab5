"""The flight's inspection photos: each one named, saved through the report (JPEG with EXIF
GPS), measured (:func:`~insulator_rs.perception.photo_quality.photo_quality` from the
odometry pose, the gimbal and the localized string), checked on itself
(:mod:`~insulator_rs.perception.photo_check`: the detector's box on the photo; ``check``, and
``attempt``: 1 for the first shot of a waypoint, 2.. for its retakes) and kept as a record of the
summary; :meth:`InspectionPhotos.check_summary` says which insulators have no fit photo, and why."""

from __future__ import annotations

import statistics
from collections import Counter
from datetime import datetime
from typing import Any

import numpy as np

from insulator_rs.inspection_camera import InspectionCamera
from insulator_rs.perception.photo_check import PhotoCheck
from insulator_rs.perception.photo_quality import photo_quality
from insulator_rs.perception.photo_verdict import fit_tally, verdict_of_record
from insulator_rs.planning.waypoints import InspectionWaypoint
from insulator_rs.ports.sensors import CameraFrame
from insulator_rs.report import ReportWriter

VERTICAL = np.array([0.0, 0.0, 1.0])


def photo_name(insulator_id: int, n: int) -> str:
    """The file of the ``n``-th photo (1-based) of insulator ``insulator_id``."""
    return f"insulator_{insulator_id:02d}_{n}.jpg"


class InspectionPhotos:
    """The photos of one flight, in the order taken (``records``: the summary's ``photos``)."""

    def __init__(self, report: ReportWriter, insulator_length: float,
                 exif_camera: dict[str, Any] | None = None, inspection: InspectionCamera | None = None) -> None:
        self.report = report
        self.exif_camera = exif_camera or {}  # make, model, focal_length_mm (SensorRig.exif_camera)
        self.inspection = inspection  # the rig's dedicated inspection camera (None: the detection camera's photos)
        self.insulator_length = insulator_length
        self.records: list[dict[str, Any]] = []
        self.failures: dict[int, list[str]] = {}  # insulator id -> why each photo asked for gave none
        self.camera: Any = None  # intrinsics of the photos taken (the sensors say)

    def __len__(self) -> int:
        return len(self.records)

    def missing(self, insulator_id: int, why: str) -> None:
        """A photo of ``insulator_id`` asked for gave no frame, for the reason ``why``."""
        self.failures.setdefault(insulator_id, []).append(why)

    def of(self, insulator_id: int) -> list[dict[str, Any]]:
        return [p for p in self.records if p["insulator_id"] == insulator_id]

    def save(self, wp: InspectionWaypoint, frame: CameraFrame, *, time_utc: datetime, time_s: float,
             position: np.ndarray, yaw: float, T_w_b: np.ndarray, velocity: np.ndarray,
             axis: np.ndarray | None, gimbal: tuple[float, float] | None = None,
             check: PhotoCheck | None = None, attempt: int = 1) -> dict[str, Any]:
        """Save the photo taken for ``wp`` at the vehicle's ``position``/``yaw`` and full pose
        ``T_w_b`` (W, odometry; the frame's ``T_b_c`` is the gimbal's at that attitude);
        ``axis``: the localized string's (None: vertical); ``gimbal``: the (pitch, yaw) rad it
        was aimed at (None: the waypoint's pitch, no yaw). Returns its record: the report's
        fields, the figures, the camera pose ``T_w_c`` and the intrinsics as rendered
        (``camera``), and with a dedicated inspection camera the zoom chosen
        (``focal_length_px`` at full resolution, ``focal_length_mm``, ``zoom`` over the widest);
        ``check``: the photo checked on itself (None: not checked), ``attempt`` its shot's try."""
        n = len(self.of(wp.insulator_id)) + 1
        name = photo_name(wp.insulator_id, n)
        pitch, gimbal_yaw = (wp.gimbal_pitch, 0.0) if gimbal is None else gimbal
        lens = dict(self.exif_camera)
        if self.inspection is not None and wp.focal_px is not None:
            lens = self.inspection.exif(wp.focal_px)
        record = self.report.save_photo(name, frame.image, time_utc=time_utc, position_enu=position, yaw_enu=yaw,
                                        gimbal_pitch=pitch,
                                        description=f"insulator {wp.insulator_id}, photo {n}", **lens)
        self.camera = frame.camera
        T_w_c = np.asarray(T_w_b, dtype=np.float64) @ frame.T_b_c  # the photo's camera pose (odometry)
        T_c_w = np.linalg.inv(T_w_c)
        quality = photo_quality(frame.camera, T_c_w, wp.target, VERTICAL if axis is None else axis,
                                length=self.insulator_length, speed=float(np.linalg.norm(velocity)))
        record = {**record, "insulator_id": wp.insulator_id, "time_s": time_s, "position": position, "yaw": yaw,
                  "gimbal_pitch": pitch, "gimbal_yaw": gimbal_yaw, "T_b_c": frame.T_b_c,
                  "quality": quality.as_dict(), "attempt": attempt,
                  "check": None if check is None else check.as_dict(),
                  "planned_gsd_mm": wp.planned_gsd_mm, "T_w_c": T_w_c,
                  "camera": {"fx": frame.camera.fx, "fy": frame.camera.fy, "cx": frame.camera.cx,
                             "cy": frame.camera.cy, "width": frame.camera.width, "height": frame.camera.height,
                             "dist": [float(k) for k in frame.camera.dist]}}
        if self.inspection is not None and wp.focal_px is not None:
            record.update(focal_length_px=wp.focal_px, focal_length_mm=lens["focal_length_mm"],
                          zoom=wp.focal_px / self.inspection.focal_px[0], tile=wp.tile, tiles=wp.tiles)
        self.records.append(record)
        return record

    def check_summary(self, insulator_ids: list[int]) -> dict[str, Any]:
        """The photo checks of the flight: photos checked and fit, retakes, the detector's wall
        seconds per check (median, max), and each of ``insulator_ids`` (those found) that has no
        photo whose check is fit, with why: ``reasons`` (each reason's count over its photos'
        checks and over the photos asked for that gave no frame, as the sensors said why: a
        payload's faults; or "no photo taken") and the detector's ``errors``."""
        checks = [p["check"] for p in self.records if p.get("check") is not None]
        cost = [c["detect_s"] for c in checks]
        fit, fit_ids = fit_tally(self.records)  # read off the one verdict each record carries
        without = []
        for iid in insulator_ids:
            if iid in fit_ids:
                continue
            mine = [p for p in self.of(iid) if p.get("check") is not None]
            verdicts = [v for p in mine if (v := verdict_of_record(p)) is not None]
            reasons = Counter(r for v in verdicts for r in v.unfit_reasons) + Counter(self.failures.get(iid, []))
            if not mine and not reasons:
                reasons = Counter({"no photo taken": 1})
            without.append({"insulator_id": iid, "photos": len(mine), "reasons": dict(reasons),
                            "errors": sorted({p["check"]["error"] for p in mine if p["check"].get("error")})})
        return {"photos": len(checks), "fit": fit,
                "retakes": sum(1 for p in self.records if p.get("attempt", 1) > 1),
                "detect_s_median": statistics.median(cost) if cost else None,
                "detect_s_max": max(cost) if cost else None,
                "insulators_without_fit_photo": without}
