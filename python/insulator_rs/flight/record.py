"""The flight's summary (:class:`~insulator_rs.report.summary.RunSummary`): what the flight
itself knows, nothing of ground truth; a scorer (``insulator_rs.evaluation.scoring``) compares
it with a scene after the flight."""

from __future__ import annotations

from dataclasses import asdict
from typing import TYPE_CHECKING, Any

import numpy as np

from insulator_rs.ports.detector import detections_dropped, detector_name
from insulator_rs.report.summary import FlightDetails, InsulatorRecord, PerceptionRecord, RunSummary

if TYPE_CHECKING:
    from insulator_rs.flight.loop import FlightLoop
    from insulator_rs.perception.runner import PerceptionRunner
    from insulator_rs.tracking.registry import InsulatorRegistry


def camera_record(camera: Any) -> dict[str, Any] | None:
    """A camera model as plain values (intrinsics in px, OpenCV distortion)."""
    if camera is None:
        return None
    return {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy, "width": camera.width,
            "height": camera.height, "dist": [float(k) for k in camera.dist]}


def perception_record(runner: PerceptionRunner, sensor_errors: int | None = None) -> PerceptionRecord:
    """The runner's and its pipeline's counts (``sensor_errors``: the caller's total, photos included)."""
    c = runner.counts
    return PerceptionRecord(detection_events=c.events, frames_detected=c.frames, localizations=c.localizations,
                            pairing_short=runner.pairing_short,
                            sensor_errors=c.sensor_errors if sensor_errors is None else sensor_errors,
                            counters=asdict(runner.pipeline.counters),
                            refused_not_insulator=dict(runner.pipeline.not_insulator))


def insulator_records(registry: InsulatorRegistry, photos: dict[int, list[str]]) -> list[InsulatorRecord]:
    return [InsulatorRecord(ins.id, ins.center, ins.axis, ins.observations, ins.side, ins.confirmed,
                            ins.inspected, photos.get(ins.id, []))
            for ins in registry.insulators]


def flight_summary(loop: FlightLoop) -> RunSummary:
    st = loop.vehicle.state()
    photos: dict[int, list[str]] = {}
    for p in loop.photos.records:
        photos.setdefault(p["insulator_id"], []).append(p["file"])
    rep = loop.report
    traj = np.array([p[1:] for p in rep.trajectory]) if rep.trajectory else np.zeros((0, 3))
    s = loop.settings
    details = FlightDetails(
        mission=str(loop.mission.source), rig=str(loop.rig.source), policy=str(s.policy.value),
        time_allocation=s.time_allocation, state=loop.sm.state.value, vehicle=type(loop.vehicle).__name__,
        sensors=type(loop.sensors).__name__,
        failsafe=None if loop.failsafe is None else {"reason": loop.failsafe.reason, "action": loop.failsafe.action},
        distance_m=float(np.sum(np.linalg.norm(np.diff(traj, axis=0), axis=1))) if len(traj) > 1 else 0.0,
        detections_dropped_by_sanitiser=detections_dropped(loop.detector),
        inspections_skipped=[{"insulator_id": it.waypoint.insulator_id if it.waypoint is not None else None,
                              "position": np.asarray(it.position).tolist(), "reason": reason}
                             for it, reason in loop.sm.skipped],
        photo_camera=camera_record(loop.photos.camera),
        inspection_waypoints=[{"insulator_id": w.insulator_id, "position": w.position, "yaw": w.yaw,
                               "gimbal_pitch": w.gimbal_pitch} for w in loop.waypoints],
        transitions=[{"time_s": tr.time - loop.t_start, "from": tr.source.value, "to": tr.target.value,
                      "reason": tr.reason} for tr in loop.sm.transitions])
    return RunSummary(run="flight", status=loop.status, detector=detector_name(loop.detector), method=s.method,
                      flight_time_s=st.time - loop.t_start,
                      perception=perception_record(loop.runner, loop.sensor_errors),
                      insulators=insulator_records(loop.registry, photos), photos=loop.photos.records,
                      sensors_health=loop.sensors.health(), flight=details)
