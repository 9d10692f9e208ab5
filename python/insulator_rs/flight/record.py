"""The flight's summary: what the flight itself knows, nothing of ground truth.

This is ``summary.json`` of the report folder; a scorer (``insulator_rs.evaluation.scoring``)
compares it with a scene after the flight.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import TYPE_CHECKING, Any

import numpy as np

from insulator_rs.ports.detector import detections_dropped, detector_name

if TYPE_CHECKING:
    from insulator_rs.flight.loop import FlightLoop


def camera_record(camera: Any) -> dict[str, Any] | None:
    """A camera model as plain values (intrinsics in px, OpenCV distortion)."""
    if camera is None:
        return None
    return {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy, "width": camera.width,
            "height": camera.height, "dist": [float(k) for k in camera.dist]}


def flight_summary(loop: FlightLoop) -> dict[str, Any]:
    st = loop.vehicle.state()
    insulators = [{"id": ins.id, "center": ins.center, "axis": ins.axis, "observations": ins.observations,
                   "side": ins.side, "inspected": ins.inspected,
                   "photos": [p["file"] for p in loop.photos if p["insulator_id"] == ins.id]}
                  for ins in loop.registry.insulators]
    rep = loop.report
    traj = np.array([p[1:] for p in rep.trajectory]) if rep.trajectory else np.zeros((0, 3))
    s = loop.settings
    return {
        "status": loop.status,
        "mission": loop.mission.source,
        "rig": loop.rig.source,
        "method": s.method,
        "time_allocation": s.time_allocation,
        "detector": detector_name(loop.detector),
        "detections_dropped_by_sanitiser": detections_dropped(loop.detector),
        "policy": s.policy,
        "state": loop.sm.state.value,
        "vehicle": type(loop.vehicle).__name__,
        "sensors": type(loop.sensors).__name__,
        "failsafe": None if loop.failsafe is None else {"reason": loop.failsafe.reason,
                                                        "action": loop.failsafe.action},
        "flight_time_s": st.time - loop.t_start,
        "distance_m": float(np.sum(np.linalg.norm(np.diff(traj, axis=0), axis=1))) if len(traj) > 1 else 0.0,
        "detection_events": loop.events,
        "localizations": loop.localizations,
        "inspections_skipped": [{"insulator_id": it.waypoint.insulator_id if it.waypoint is not None else None,
                                 "position": np.asarray(it.position).tolist(), "reason": reason}
                                for it, reason in loop.sm.skipped],
        "perception": asdict(loop.perception.counters),
        "refused_not_insulator": dict(loop.perception.not_insulator),
        "sensor_errors": loop.sensor_errors,
        "pairing_short": loop.pairing_short,
        "sensors_health": loop.sensors.health(),
        "insulators_found": len(insulators),
        "insulators_inspected": sum(1 for r in insulators if r["inspected"]),
        "insulators": insulators,
        "photo_camera": camera_record(loop.photo_camera),
        "photos": loop.photos,
        "inspection_waypoints": [{"insulator_id": w.insulator_id, "position": w.position, "yaw": w.yaw,
                                  "gimbal_pitch": w.gimbal_pitch} for w in loop.waypoints],
        "transitions": [{"time_s": tr.time - loop.t_start, "from": tr.source.value, "to": tr.target.value,
                         "reason": tr.reason} for tr in loop.sm.transitions],
    }
