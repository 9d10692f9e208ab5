"""The parts of a run's summary (:class:`~insulator_rs.report.summary.RunSummary`) that the
flight and the replay build alike: the camera, the perception counts, the insulators found.
Nothing of ground truth: a scorer (``insulator_rs.evaluation.scoring``) compares the summary
with a scene after the run."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any


from insulator_rs.perception.runner import PerceptionRunner
from insulator_rs.ports.capabilities import MapsClock, ReportsSetpointStream
from insulator_rs.report.summary import InsulatorRecord, PerceptionRecord
from insulator_rs.timesync import TimesyncRecord
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
                            pairing_timing={**runner.pairing.timing(), "lidar_clock_steps_back": runner.intake.steps_back},
                            sensor_errors=c.sensor_errors if sensor_errors is None else sensor_errors,
                            counters=asdict(runner.pipeline.counters),
                            refused_not_insulator=dict(runner.pipeline.not_insulator),
                            tracks=runner.pipeline.track_records())


def insulator_records(registry: InsulatorRegistry, photos: dict[int, list[str]]) -> list[InsulatorRecord]:
    return [InsulatorRecord(ins.id, ins.center, ins.axis, ins.observations, ins.side, ins.confirmed,
                            ins.inspected, photos.get(ins.id, []))
            for ins in registry.insulators]


def candidate_records(registry: InsulatorRegistry) -> list[dict[str, Any]]:
    """The registry's unconfirmed localizations, most observed first."""
    return [{"center": ins.center.tolist(), "axis": ins.axis.tolist(), "observations": ins.observations,
             "side": ins.side}
            for ins in sorted(registry.candidates, key=lambda ins: -ins.observations)]


def setpoint_stream_record(vehicle: Any) -> dict[str, Any] | None:
    """The MAVLink client's setpoint-stream gaps (``summary.json`` ``setpoint_stream``); None for
    a vehicle without a setpoint stream (the in-process simulator)."""
    return vehicle.setpoint_gaps.record() if isinstance(vehicle, ReportsSetpointStream) else None


def timesync_record(vehicle: Any, sensors: Any) -> TimesyncRecord:
    """How the companion knew vehicle time: the clock live sensors were stamped with (TIMESYNC
    or its telemetry fallback), else the MAVLink client's TIMESYNC map, else source ``none``
    (an in-process vehicle: its clock is the host's)."""
    for port in (sensors, vehicle):
        if isinstance(port, MapsClock):
            return port.timesync_record()
    return TimesyncRecord()
