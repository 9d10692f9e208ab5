"""The one summary schema: what a run (a flight, or the replay of a recorded flight) knows.

``summary.json`` of every report folder is a :class:`RunSummary`, written by
:meth:`~insulator_rs.report.writer.ReportWriter.write_summary` (atomically, through
:mod:`~insulator_rs.report.jsonfile`). Nothing of ground truth is in it: a scorer
(``insulator_rs.evaluation.scoring``) compares it with a scene afterwards, in ``score.json``.

The JSON is flat, as crews and scripts read it: the common fields, the perception counts, then
the flight's or the replay's own fields (:class:`FlightDetails`, :class:`ReplayDetails`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from insulator_rs.report.jsonfile import jsonable
from insulator_rs.timesync import TimesyncRecord


@dataclass
class InsulatorRecord:
    """One insulator the run found: ``center`` and unit ``axis`` in W (m), localizations fused,
    side of the tower (+1/-1), whether confirmed and inspected, its photos (files)."""

    id: int
    center: np.ndarray
    axis: np.ndarray
    observations: int
    side: int
    confirmed: bool
    inspected: bool
    photos: list[str] = field(default_factory=list)


@dataclass
class PerceptionRecord:
    """What perception did (the runner's and the pipeline's counts)."""

    detection_events: int = 0  # frames asked for
    frames_detected: int = 0  # frames run through the detector
    localizations: int = 0
    pairing_short: int = 0  # frames paired before the scans covered their whole window
    # the frames' waits for their points and how short of their window they went (FramePairing.timing)
    pairing_timing: dict[str, float | None] = field(default_factory=dict)
    sensor_errors: int = 0
    counters: dict[str, int] = field(default_factory=dict)  # PerceptionCounters
    refused_not_insulator: dict[str, int] = field(default_factory=dict)
    # each track that reached a localization attempt and its evidence (PerceptionPipeline.track_records);
    # with the LiDAR cue on, the geometry's word at its centre too (LidarCue.verdict: lidar,
    # lidar_distance_m, lidar_score, lidar_cover)
    tracks: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class FlightDetails:
    """What only a flight has."""

    mission: str
    rig: str
    policy: str
    time_allocation: str
    state: str
    vehicle: str
    sensors: str
    failsafe: dict[str, str] | None
    distance_m: float
    detections_dropped_by_sanitiser: dict[str, int] | None
    inspections_skipped: list[dict[str, Any]]
    photo_camera: dict[str, Any] | None
    inspection_waypoints: list[dict[str, Any]]
    transitions: list[dict[str, Any]]
    # an abort: its reason and flight time, the way out (route case, landing point in W and
    # WGS-84, side) or why the vehicle was left holding for the pilot; None when none
    abort: dict[str, Any] | None = None
    # how the companion knew vehicle time: source timesync / telemetry / none, offset_s,
    # drift_ppm, rtt_ms (median), exchanges, rejected (insulator_rs.timesync.TimesyncRecord)
    timesync: TimesyncRecord = field(default_factory=TimesyncRecord)
    # the battery reserve (flight/reserve.py): the reserve kept at landing, whether the vehicle
    # reported its charge (known; a note when no decision was possible), the charge at take-off
    # and last (at touchdown after a landing), the fitted consumption (per_s, per_m), the latest
    # weighing and the one at the decision to return (needed vs available, the routes); None
    # for a flight before this field
    battery: dict[str, Any] | None = None
    # the autopilot's own failsafes set for the tower (a PX4 vehicle; None otherwise):
    # ground_station (NAV_DLL_ACT set only with one), restore (restored / not restored: why), and
    # per parameter its name, why, old, set, restored values and error (flight/autopilot_setup.py)
    px4_parameters: dict[str, Any] | None = None
    # the pre-flight gate before arming (flight/preflight.py): passed, and per check its name,
    # outcome (passed / failed / not_applicable) and reason; None when the flight never got to it
    preflight: dict[str, Any] | None = None
    # the companion's own stalls while it flew an outside autopilot (flight/stall_watch.py):
    # threshold, count, longest, total, the longest few with their times, and the file of the
    # stacks written during them; None in process (nothing to fail safe) and before this field
    companion_stalls: dict[str, Any] | None = None
    # our offboard setpoint stream's gaps as PX4 counts them (mavlink/setpoint_gaps.py): setpoints
    # sent, the longest gap, the gaps of 0.5 s or more, and how many reached COM_OF_LOSS_T (each
    # a failsafe PX4 flew, if only for a moment: v1.16 clears it when setpoints resume, often
    # between two of its 1 Hz heartbeats); None without MAVLink and before this field
    setpoint_stream: dict[str, Any] | None = None
    # every photo checked on itself (perception/photo_check.py; flight/photos.py check_summary):
    # photos, fit, retakes, the detector's cost per check, and the insulators found without a fit
    # photo with why (their checks' reasons counted, the detector's errors); None before this field
    photo_checks: dict[str, Any] | None = None
    # the LiDAR's obstacle map (planning/obstacle_map.py): enabled, voxel size, returns and voxels
    # kept, occupied voxels, the margin, legs bent round an obstacle, left mid-way to re-plan, and
    # refused; None for a flight before this field
    obstacle_map: dict[str, Any] | None = None
    # the second looks at candidates before the search ended (flight/second_look.py): per look
    # the candidate's id (0 unless confirmed), centre, localizations before and after, whether
    # confirmed, and a note when cut short or not flown; None for a flight before this field
    second_looks: list[dict[str, Any]] | None = None
    # the LiDAR cue (flight/lidar_cue.py): enabled; when on, the cloud kept near the tower, the
    # finder's runs and wall time, its strings now, and per registry record (confirmed or not) the
    # evidence of both cues (camera localizations; the LiDAR's nearest string, the cover of the
    # place, string / no string-like structure / not covered, times held), then each LiDAR
    # string no camera track covers; None for a flight before this field
    lidar_cue: dict[str, Any] | None = None


@dataclass
class ReplayDetails:
    """What only a replay has: the recording, its topics, and how fast it went."""

    recording: str
    topics: dict[str, str]
    deskew: bool
    poses: int
    scans: int
    frames: int
    wall_time_s: float
    speed_vs_real_time: float | None
    rerun: str | None
    # "full": the recorded poses carry the airframe's roll and pitch; "yaw-only": every pose is
    # level (a recording from before the vehicle port reported the attitude): the replay then
    # takes the body as level, as the flight did
    attitude: str = "full"
    # network runs at once while reading ahead (None: not read ahead, or no network to run)
    network_threads: int | None = None


@dataclass
class RunSummary:
    """``summary.json`` (see the module docstring). ``status``: ``running``, ``finished``,
    ``aborted: ...``, ``interrupted`` or ``failed: ...`` (``error`` says what failed)."""

    run: str  # "flight" or "replay"
    status: str
    detector: str
    method: str
    flight_time_s: float
    perception: PerceptionRecord
    insulators: list[InsulatorRecord]
    photos: list[dict[str, Any]] = field(default_factory=list)
    sensors_health: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    flight: FlightDetails | None = None
    replay: ReplayDetails | None = None
    # localizations the registry holds without their confirmations: where a string may hang
    # that the run never confirmed (centre, axis, observations, side); the crew's places to look
    candidates: list[dict[str, Any]] = field(default_factory=list)

    @property
    def insulators_found(self) -> int:
        return len(self.insulators)

    @property
    def insulators_inspected(self) -> int:
        return sum(1 for r in self.insulators if r.inspected)

    def as_dict(self) -> dict[str, Any]:
        """The flat JSON object (plain values)."""
        p = self.perception
        out: dict[str, Any] = {
            "run": self.run, "status": self.status, "error": self.error, "detector": self.detector,
            "method": self.method, "flight_time_s": self.flight_time_s,
            "detection_events": p.detection_events, "frames_detected": p.frames_detected,
            "localizations": p.localizations, "pairing_short": p.pairing_short,
            "pairing_timing": dict(p.pairing_timing), "sensor_errors": p.sensor_errors,
            "perception": dict(p.counters), "refused_not_insulator": dict(p.refused_not_insulator),
            "tracks": list(p.tracks),
            "sensors_health": self.sensors_health,
        }
        for details in (self.flight, self.replay):
            if details is not None:
                out.update({f.name: getattr(details, f.name) for f in fields(details)})
        out.update({"insulators_found": self.insulators_found, "insulators_inspected": self.insulators_inspected,
                    "insulators": [jsonable(r) for r in self.insulators], "photos": self.photos,
                    "candidates": self.candidates})
        return jsonable(out)


def failed_summary(run: str, error: str, **replay_fields: Any) -> dict[str, Any]:
    """The summary of a run that could not start (a recording that cannot be opened, a bad
    option): status ``failed: <error>``, nothing found."""
    return {"run": run, "status": f"failed: {error}", "error": error, "insulators_found": 0, "insulators": [],
            **replay_fields}
