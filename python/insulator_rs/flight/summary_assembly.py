"""summary.json of a flight, assembled from what the loop and its behaviours know now: the
perception counts, the registry, the photos, the state machine's transitions and skips, the
abort and its way out, the battery, the obstacle map, the second looks, the pre-flight gate, the
autopilot's parameters, the companion's stalls. Nothing of ground truth.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from insulator_rs.exceptions import VehicleFailsafe
from insulator_rs.flight.autopilot_session import AutopilotSession
from insulator_rs.flight.energy_budget import EnergyBudget
from insulator_rs.flight.leg_follower import LegFollower
from insulator_rs.flight.photos import InspectionPhotos
from insulator_rs.flight.record import (camera_record, candidate_records, insulator_records, perception_record,
                                        setpoint_stream_record, timesync_record)
from insulator_rs.flight.safe_exit import SafeExit
from insulator_rs.flight.second_look import SecondLookFlight
from insulator_rs.flight.settings import FlightSettings
from insulator_rs.flight.stall_watch import StallWatch
from insulator_rs.geodesy import GeoPoint, enu_to_geodetic
from insulator_rs.mission.config import Mission
from insulator_rs.mission.state_machine import InspectionStateMachine
from insulator_rs.perception.runner import PerceptionRunner
from insulator_rs.ports.sensors import sensors_name
from insulator_rs.planning.safety import SafetyVolumes
from insulator_rs.planning.waypoints import InspectionWaypoint
from insulator_rs.ports.detector import BoxDetector, detections_dropped, detector_name
from insulator_rs.ports.sensors import Sensors
from insulator_rs.ports.vehicle import Vehicle
from insulator_rs.report import ReportWriter
from insulator_rs.report.run_status import RunOutcome
from insulator_rs.report.summary import FlightDetails, RunSummary
from insulator_rs.rig import SensorRig
from insulator_rs.tracking.registry import InsulatorRegistry


@dataclass(frozen=True)
class SummaryAssembly:
    """summary.json from what one flight is made of: the loop's parts and behaviours."""

    mission: Mission
    rig: SensorRig
    settings: FlightSettings
    vehicle: Vehicle
    sensors: Sensors
    detector: BoxDetector
    registry: InsulatorRegistry
    sm: InspectionStateMachine
    runner: PerceptionRunner
    report: ReportWriter
    photos: InspectionPhotos
    origin: GeoPoint
    autopilot: AutopilotSession
    energy: EnergyBudget
    legs: LegFollower
    looks: SecondLookFlight
    exit: SafeExit
    lidar_cue: Callable[[], dict[str, Any]]  # the LiDAR cue's record now (flight/lidar_cue.py)
    # the LiDAR cue's word on a camera find at a place in W (LidarCue.verdict; None: no cue)
    lidar_verdict: Callable[[np.ndarray], dict[str, Any]] | None = None

    def abort_record(self, reason: str | None, t_start: float) -> dict[str, Any] | None:
        """summary.json's ``abort``: why and when, the way out (its case, landing point in W and
        WGS-84, side, legs, the legs bent round the LiDAR's obstacle map and round what), the
        hand-over (the map's refusal named there) and what the plan still held; None without an
        abort."""
        ctx = self.sm.aborted
        if ctx is None:
            return None
        route = self.exit.route
        record: dict[str, Any] = {"reason": reason or ctx.reason, "time_s": ctx.time - t_start,
                                  "route": None, "landing_point": None, "landing_wgs84": None, "side": None,
                                  "legs": [], "bends": [], "handed_over": self.exit.handed_over,
                                  "left": self.exit.left}
        if route is not None:
            lat, lon, alt = enu_to_geodetic(route.landing, self.origin)[0]
            record.update(route=route.case.value, landing_point=route.landing.tolist(),
                          landing_wgs84=[float(lat), float(lon), float(alt)], side=route.side,
                          legs=[leg.tolist() for leg in route.legs], bends=[b.as_record() for b in route.bends])
        return record


    def summary(self, *, outcome: RunOutcome, t_start: float, abort_reason: str | None,
                    failsafe: VehicleFailsafe | None, sensor_errors: int, waypoints: list[InspectionWaypoint],
                    stall_watch: StallWatch | None) -> RunSummary:
        """What the flight knows now (summary.json). ``outcome``: how it ended (or that it runs);
        ``t_start``: vehicle time of the take-off; ``abort_reason``: the abort's (None: the state
        machine's); ``failsafe``: the vehicle's that stopped it; ``waypoints``: every inspection
        waypoint planned; ``stall_watch``: the companion's stalls (None: not watched)."""
        p = self
        st = p.vehicle.state()
        photos: dict[int, list[str]] = {}
        for rec in p.photos.records:
            photos.setdefault(rec["insulator_id"], []).append(rec["file"])
        setup, gate = p.autopilot.setup, p.autopilot.preflight_result
        details = FlightDetails(
            mission=str(p.mission.source), rig=str(p.rig.source), policy=p.settings.policy.value,
            time_allocation=p.settings.time_allocation, state=p.sm.state.value, vehicle=type(p.vehicle).__name__,
            sensors=sensors_name(p.sensors),
            failsafe=None if failsafe is None else {"reason": failsafe.reason, "action": failsafe.action},
            distance_m=p.report.distance_m,
            detections_dropped_by_sanitiser=detections_dropped(p.detector),
            abort=self.abort_record(abort_reason, t_start),
            inspections_skipped=[{"insulator_id": it.waypoint.insulator_id if it.waypoint is not None else None,
                                  "position": np.asarray(it.position).tolist(), "reason": reason}
                                 for it, reason in p.sm.skipped],
            photo_camera=camera_record(p.photos.camera),
            photo_checks=p.photos.check_summary([i.id for i in p.registry.insulators]),
            inspection_waypoints=[{"insulator_id": w.insulator_id, "position": w.position, "yaw": w.yaw,
                                   "gimbal_pitch": w.gimbal_pitch} for w in waypoints],
            transitions=[{"time_s": tr.time - t_start, "from": tr.source.value, "to": tr.target.value,
                          "reason": tr.reason} for tr in p.sm.transitions],
            timesync=timesync_record(p.vehicle, p.sensors),
            battery=p.energy.record(),
            obstacle_map=p.legs.record(),
            second_looks=[look.as_record() for look in p.looks.looks],
            lidar_cue=p.lidar_cue(),
            preflight=None if gate is None else gate.as_record(),
            px4_parameters=None if setup is None else setup.record(),
            companion_stalls=None if stall_watch is None else stall_watch.record(),
            setpoint_stream=setpoint_stream_record(p.vehicle))
        perception = perception_record(p.runner, sensor_errors)
        if p.lidar_verdict is not None:  # each track's evidence of both cues
            perception = replace(perception, tracks=[{**t, **p.lidar_verdict(np.asarray(t["center"], dtype=np.float64))}
                                                     for t in perception.tracks])
        refused = p.autopilot.refused  # nothing flew
        return RunSummary(run="flight", status=str(outcome), detector=detector_name(p.detector),
                          method=p.settings.method, flight_time_s=0.0 if refused else st.time - t_start,
                          perception=perception,
                          insulators=insulator_records(p.registry, photos), photos=p.photos.records,
                          candidates=candidate_records(p.registry),
                          sensors_health=p.sensors.health(), flight=details)

    def finish(self, run: RunSummary, volumes: SafetyVolumes, waypoints: list[InspectionWaypoint],
               reference: np.ndarray | None) -> dict[str, Any]:
        """Write the final summary ``run`` and the plot (the ``volumes``, the ``waypoints``, the
        finds and ``reference``: (K, 3) points drawn as ground truth, known only after the flight,
        or None), close the report; the summary as a dict."""
        self.report.write_summary(run)
        summary = run.as_dict()
        wps = np.array([w.position for w in waypoints]) if waypoints else np.zeros((0, 3))
        found = np.array([i.center for i in self.registry.insulators]) if len(self.registry) else np.zeros((0, 3))
        truth = np.zeros((0, 3)) if reference is None else np.asarray(reference, dtype=np.float64).reshape(-1, 3)
        self.report.plot(volumes, wps, found, truth,
                         f"{summary['status']}, flight {summary['flight_time_s']:.0f} s, "
                         f"{summary['insulators_inspected']}/{summary['insulators_found']} insulators inspected")
        self.report.close()
        return summary
