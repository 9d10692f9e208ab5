"""The flight loop: fly the single-flight inspection through the ports (see ``__init__``).

The paper's online algorithm: take off, fly the exploration path (minimum-snap trajectories,
safety-checked), and every ``detect_period`` s take a detection frame from the sensors, run
the detector, and hand the frame, its boxes and the LiDAR points of that instant to the
perception pipeline (:class:`~insulator_rs.perception.runner.PerceptionRunner`: the one pairing
rule, shared with the replay of a recorded flight; paired and deskewed with the pose history
the loop feeds every control tick); new insulators get inspection waypoints, which the state
machine visits (a photo at each, from the companion computer's camera through
``Sensors.photo``, gimbal aimed), then the flight goes on, crosses over the top, finishes and
lands. Every leg is also checked against what the LiDAR saw outside the tower's
model (:mod:`insulator_rs.planning.obstacle_map`: a scan every SURVEY_PERIOD s into a voxel map),
bent round it or refused, and re-checked as the map grows while the leg is flown. The loop does not know whether it is recorded: recording wraps the ports.

A vehicle failsafe (link lost, the pilot took over, battery, position lost) aborts the mission:
the report says why and keeps everything found so far, and once the failsafe fired nothing more
is sent to the vehicle. Every other abort (a command the vehicle refuses, a leg no safe
trajectory can be planned for, the flight-time limit, the operator's abort, the battery reserve
(:mod:`insulator_rs.flight.reserve`: the rest of the plan no longer fits above the mission's
``battery_reserve``, and the way out is due), the camera silent, the LiDAR silent or the detector
failing (:meth:`PerceptionRunner.lost`)) stops the vehicle and flies
the safe route out that :mod:`insulator_rs.planning.abort` plans from what the state machine
knew (on across over the tower, back out beside an arm), then lands clear of the tower and the
conductor corridors; where no route can be planned the vehicle holds in the autopilot's HOLD
and the pilot is told to take over, never a blind descent. A sensor error costs that detection
event or photo, never the flight; only a camera or a LiDAR silent, or a detector failing, for
SENSOR_LOST_TIMEOUT s aborts.

The report folder (:mod:`insulator_rs.report`: photos with EXIF GPS, WGS-84, GeoJSON/KML) is
written as the flight goes; an interruption (Ctrl-C) still leaves the summary, the photos
taken and the plot.
"""

from __future__ import annotations

import math
import time as wallclock
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.exceptions import (ObstacleBlocked, ParameterError, PlanningError, PreflightRefused, SensorError,
                                     VehicleError, VehicleFailsafe)
from insulator_rs.geodesy import GeoPoint, enu_to_geodetic
from insulator_rs.flight.autopilot_setup import AutopilotSetup
from insulator_rs.flight.gimbal import aim_at, gimballed_T_b_c, stabilised_T_b_c  # noqa: F401 (their old home)
from insulator_rs.flight.observers import ConsoleObserver, ObserverGroup
from insulator_rs.flight.photos import InspectionPhotos
from insulator_rs.flight.preflight import PreflightResult, preflight_checks
from insulator_rs.flight.record import (camera_record, candidate_records, insulator_records, perception_record,
                                        setpoint_stream_record, timesync_record)
from insulator_rs.flight.reserve import TOUCHDOWN_TIME, BatteryReserve
from insulator_rs.flight.stall_watch import StallWatch
from insulator_rs.flight.second_look import (REFUSED_TRACK_MIN_CONFIDENT, SecondLook, look_events, look_target,
                                              look_viewpoints, near_a_known_string, observations_near,
                                              refused_track_candidate)
from insulator_rs.mission.config import Mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import InspectionStateMachine, PlanItem, Policy, State
from insulator_rs.perception.photo_check import PhotoCheck, check_photo, expected_view
from insulator_rs.perception.pairing import PAIRING_WAIT
from insulator_rs.perception.localization_method import DEFAULT_METHOD, LocalizationMethod
from insulator_rs.perception.pipeline import LocalizedInsulator, PerceptionPipeline
from insulator_rs.perception.runner import PerceptionRunner
from insulator_rs.planning.abort import AbortCase, AbortRoute, leg_trajectory, plan_abort_route, plan_stop
from insulator_rs.planning.energy import RouteDemand, route_demand
from insulator_rs.planning.exploration import MIN_PASS_HEIGHT, PlanKind
from insulator_rs.planning.framing import MIN_FILL
from insulator_rs.planning.minsnap import MinSnapTrajectory
from insulator_rs.planning.obstacle_map import ObstacleMap, SeenVolumes
from insulator_rs.planning.pmm import rest_to_rest_times
from insulator_rs.planning.px4_failsafes import tower_failsafe_parameters
from insulator_rs.planning.segments import SAFETY_CHECK_DT, plan_segment
from insulator_rs.planning.waypoints import InspectionWaypoint, inspection_waypoints
from insulator_rs.ports.detector import BoxDetector, detections_dropped, detector_name
from insulator_rs.ports.observer import FlightObserver, InsulatorFound, PhaseChange, PhotoTaken
from insulator_rs.ports.sensors import PoseStamped, Sensors
from insulator_rs.ports.vehicle import FlightMode, Vehicle, VehicleState, vehicle_parameters, wrap_angle
from insulator_rs.report import FlightClock, ReportWriter
from insulator_rs.report.summary import FlightDetails, RunSummary
from insulator_rs.rig import SensorRig
from insulator_rs.tracking.registry import Insulator, InsulatorRegistry

CONTROL_PERIOD = 0.05  # s: 20 Hz setpoint stream, as PX4 offboard wants
PHOTO_YAW_TOLERANCE = math.radians(3.0)
PHOTO_SPEED_TOLERANCE = 0.2  # m/s
PHOTO_SETTLE_TIMEOUT = 8.0  # s
# s held at the waypoint before a retake is settled: the gust or the swing that spoiled the
# photo has time to pass (the retake then re-aims from the pose it settled at)
RETAKE_HOLD = 1.0
HOLD_TIMEOUT = 10.0  # s in HOLD before the mission aborts
STATUS_PERIOD = 15.0  # s of flight between progress lines
SUMMARY_PERIOD = 5.0  # s of flight between summary rewrites
LAND_HEIGHT = 2.0  # m above the take-off point where the landing starts
TAKEOFF_TIMEOUT = 60.0  # s of vehicle time for the climb to the first pass height
LAND_TIMEOUT = 120.0  # s of vehicle time for the descent
SENSOR_LOST_TIMEOUT = 10.0  # s of flight without a new camera frame: the sensor is lost, abort
OFFBOARD_WARMUP = 0.5  # s of setpoints streamed before asking for OFFBOARD (PX4 wants a stream)
GROUND_STATION_WAIT = 2.5  # wall s to wait for a ground station's HEARTBEAT (1 Hz) before take-off
# s between LiDAR scans taken into the obstacle map (planning/obstacle_map.py); each is one
# 100 ms scan, so the map sees a fifth of the returns: a pole fills its voxels within seconds
SURVEY_PERIOD = 0.5
# s of vehicle time to wait, after the mission ends with the vehicle in the air (PX4's own return,
# a pilot holding), for the landing before the autopilot's old parameters are put back
RESTORE_WAIT = 300.0


@dataclass(frozen=True)
class FlightSettings:
    """How the loop flies: localization ``method``, buffering ``policy``, s between detection
    events, the flight-time limit (s), the min-snap ``time_allocation``, progress output."""

    method: LocalizationMethod = DEFAULT_METHOD  # the product's default (inspect --method): tests fly what users fly
    policy: Policy = Policy.IMMEDIATE
    detect_period: float = 1.0
    max_flight_time: float = 1800.0
    time_allocation: str = "pmm"
    quiet: bool = False
    # check every leg against the LiDAR's obstacle map as well as the GPS-derived safety
    # volumes (planning/obstacle_map.py); False flies the volumes only (inspect --no-obstacle-map:
    # what the map buys, measured)
    obstacle_map: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "policy", Policy(self.policy))  # a bad policy is refused, named


class FlightLoop:
    """One single-flight inspection: state, perception, report (see the module docstring)."""

    def __init__(self, mission: Mission, vehicle: Vehicle, sensors: Sensors, detector: BoxDetector,
                 out: Path, *, rig: SensorRig, settings: FlightSettings = FlightSettings(),
                 overwrite: bool = False, observer: FlightObserver | None = None,
                 photo_camera: Any = None, photo_detector: BoxDetector | None = None) -> None:
        self.mission = mission
        self.vehicle = vehicle
        self.sensors = sensors
        self.detector = detector
        # what checks each photo (perception/photo_check.py): the flight's detector unless the
        # composition root gives another (the simulator's stand-in on photos)
        self.photo_detector = detector if photo_detector is None else photo_detector
        self.rig = rig
        self.settings = settings
        # who watches the flight: the console unless quiet, and what the caller adds (the GCS)
        watchers: list[FlightObserver] = [] if settings.quiet else [ConsoleObserver()]
        if observer is not None:
            watchers.append(observer)
        self.observer = ObserverGroup(watchers)
        self.geom = MissionGeometry.from_mission(mission)
        lim = mission.vehicle
        self.v_max, self.a_max = lim.v_max(), lim.a_max()
        self.failsafe: VehicleFailsafe | None = None  # the failsafe that stopped the mission
        self.perception = PerceptionPipeline(rig.camera, rig.T_b_c, rig.T_b_l, method=settings.method,
                                             insulator_length=mission.inspection.insulator_length)
        self.runner = PerceptionRunner(sensors, detector, self.perception, detect_period=settings.detect_period,
                                       on_sensor_error=self._sensor_error)
        self.registry = InsulatorRegistry(self.geom.line, mission.inspection.registry_gate,
                                          mission.inspection.confirmations)
        # the photos' intrinsics (the rig camera's unless the sensors deliver another resolution)
        # frame the insulator from the waypoints and give the planned GSD
        self.photo_model = rig.camera if photo_camera is None else photo_camera
        self.fov = 2 * math.atan((self.photo_model.height / 2) / self.photo_model.fy)
        # the rig's dedicated inspection camera (zoom, gimbal) frames the shots; a rig without
        # one photographs with the detection camera as before (None)
        self.inspection = rig.inspection
        self.sm = InspectionStateMachine(self.geom.path, self.registry, self._waypoints,
                                         policy=settings.policy, cost=self._cost)
        tower = mission.tower
        self.origin = GeoPoint(tower.lat, tower.lon, tower.alt)
        self.report = ReportWriter(out, origin=self.origin, overwrite=overwrite)
        self.clock = FlightClock(self.vehicle.state().time)  # UTC of vehicle stamps; re-anchored at take-off
        self.out = out
        self.photos = InspectionPhotos(self.report, mission.inspection.insulator_length,
                                       exif_camera=rig.exif_camera(), inspection=rig.inspection)
        self.waypoints: list[InspectionWaypoint] = []
        self.second_looks: list[SecondLook] = []  # flight/second_look.py
        # the companion's stalls (flight/stall_watch.py), set by whoever flies an outside autopilot
        self.stall_watch: StallWatch | None = None
        self._looked: list[Insulator] = []  # the candidates looked at (the records themselves)
        # look targets made for the pipeline's refused tracks, one per track (``_looked`` holds them)
        self._refused_targets: dict[int, Insulator] = {}
        self._search_end: PlanItem | None = None  # the item where the search ended, once caught up
        self.status = "running"
        self.abort_reason: str | None = None
        self.abort_route: AbortRoute | None = None  # the safe route out an abort flew
        self.handed_over: str | None = None  # why the vehicle was left holding for the pilot
        self._abort_request: str | None = None  # the operator's (request_abort), taken by tick
        self._frames_seen = (0, 0.0)  # camera frames so far, and when that count last grew
        self.t_start = 0.0
        self.sensor_errors = 0  # the runner's and the photos'
        self._airborne = False
        self.autopilot_setup: AutopilotSetup | None = None  # the tower's PX4 parameters (a PX4 vehicle)
        self._printed_transitions = 0
        self._next_status = STATUS_PERIOD
        self._next_summary = SUMMARY_PERIOD
        self._wall0 = wallclock.perf_counter()
        self.battery = BatteryReserve(mission.inspection.battery_reserve)
        self.left: dict[str, Any] | None = None  # what an abort left of the plan (the report's)
        self.preflight_result: PreflightResult | None = None  # the gate before arming (flight/preflight.py)
        # what the LiDAR saw outside the safety volumes, kept for the planner (None: not kept)
        self.obstacles = (ObstacleMap(known=self.geom.volumes, ground_z=float(self.geom.takeoff[2]))
                          if settings.obstacle_map else None)
        # the first survey a period in: a scan asked for at once would reach back before the clock's
        # start (the simulator renders the 100 ms before; a recording refuses negative stamps)
        self._next_survey = self.vehicle.state().time + SURVEY_PERIOD
        self.legs_bent = 0  # legs planned round an obstacle of the map
        self.legs_replanned = 0  # legs left mid-way because the map saw their rest blocked
        self.legs_refused = 0  # legs no detour round the map's obstacles cleared

    # -- helpers -------------------------------------------------------------------------
    def _waypoints(self, ins: Insulator) -> list[InspectionWaypoint]:
        wps = self._viewpoints(ins)
        self.waypoints.extend(wps)
        return wps

    def _viewpoints(self, ins: Insulator) -> list[InspectionWaypoint]:
        """The inspection waypoints of ``ins`` (PlanningError when none is safe)."""
        p = self.mission.inspection
        return inspection_waypoints(ins.center, ins.axis, insulator_id=ins.id, line=self.geom.line,
                                   volumes=self.geom.volumes, count=p.waypoints_per_insulator,
                                   inspection_distance=p.inspection_distance,
                                   insulator_length=p.insulator_length, fov=self.fov,
                                   camera=self.photo_model, inspection=self.inspection)

    def _cost(self, a: np.ndarray, b: np.ndarray) -> float:
        return float(rest_to_rest_times(a, b, self.v_max, self.a_max))

    def say(self, text: str) -> None:
        self.observer.message(self.now(), text)

    def now(self) -> float:
        return self.vehicle.state().time - self.t_start

    def _print_transitions(self) -> None:
        for tr in self.sm.transitions[self._printed_transitions:]:
            t = tr.time - self.t_start if tr.time >= self.t_start else tr.time
            self.observer.phase(PhaseChange(t, tr.source.value, tr.target.value, tr.reason))
        self._printed_transitions = len(self.sm.transitions)

    def _sensor_error(self, exc: SensorError) -> None:
        self.sensor_errors += 1
        if self.sensor_errors <= 3 or self.sensor_errors % 50 == 0:
            self.say(f"[{self.now():7.1f} s] sensor error ({self.sensor_errors} so far): {exc}")

    # -- sensing -------------------------------------------------------------------------
    @property
    def events(self) -> int:
        """Detection events so far (the runner's)."""
        return self.runner.counts.events

    @property
    def localizations(self) -> int:
        return self.runner.counts.localizations

    @property
    def pairing_short(self) -> int:
        return self.runner.pairing_short

    def _localized(self, fix: LocalizedInsulator, st: VehicleState) -> None:
        """Tell the state machine of a localization; a new insulator is reported."""
        outcome = self.sm.localized(fix.center, fix.axis, st.position, st.time)
        if outcome not in ("new", "deferred"):
            return
        ins, _ = self.registry.nearest(fix.center)
        self.say(f"[{self.now():7.1f} s] insulator {ins.id if ins else '?'} localized at "
                 f"{np.round(fix.center, 2).tolist()} ({fix.n_points} points) -> {outcome}")
        if ins is not None:
            lat, lon, alt = enu_to_geodetic(ins.center, self.origin)[0]
            self.observer.insulator_found(InsulatorFound(self.now(), ins.id, ins.center.copy(),
                                                         (float(lat), float(lon), float(alt)), outcome))
        self.write_summary()

    # -- flying --------------------------------------------------------------------------
    def tick(self, position: np.ndarray, velocity: np.ndarray | None, yaw: float) -> VehicleState:
        """Stream one setpoint, let one control period pass, log, sense, watch health.

        A failsafe aborts the mission (see :meth:`on_failsafe`); nothing is sent after it."""
        if self.failsafe is not None:
            return self.vehicle.state()
        try:
            self.vehicle.send_setpoint(position, velocity, yaw)
            st = self.vehicle.advance(CONTROL_PERIOD)
        except VehicleFailsafe as exc:
            self.on_failsafe(exc)
            st = self.vehicle.state()
        t = st.time - self.t_start
        self.battery.observe(st)
        self.report.log_pose(t, st.position, st.yaw, self.sm.state.value)
        self.runner.add_pose(PoseStamped(st.time, st.T_w_b))  # the whole reported attitude
        if self.obstacles is not None and st.time >= self._next_survey:
            self._next_survey = st.time + SURVEY_PERIOD
            self.obstacles.insert(self.runner.survey(st.time), sensor_w=(st.T_w_b @ self.rig.T_b_l)[:3, 3])
        if self.sm.state not in (State.IDLE, State.FINISH, State.ABORT):
            for fix in self.runner.step(st.time):
                self._localized(fix, st)
        elif self.runner.waiting:
            # the search is over: a frame of it still waiting for its points goes with what there
            # is, and what it localizes refines the registry (no waypoints now). Dropped, as it
            # was, a replay of the flight, which pairs it, counted and localized one frame more.
            for fix in self.runner.finish(st.time):
                self.registry.observe(fix.center, fix.axis)
        if t >= self._next_status:
            self._next_status += STATUS_PERIOD
            self.say(f"[{t:7.1f} s] {self.sm.state.value}: at {np.round(st.position, 1).tolist()}, "
                     f"{len(self.registry)} insulators, {len(self.photos)} photos, "
                     f"{self.events} detection events, wall {wallclock.perf_counter() - self._wall0:.0f} s")
        if t >= self._next_summary:
            self._next_summary += SUMMARY_PERIOD
            self.report.flush()
            self.write_summary()
        if self.sm.state not in (State.ABORT, State.IDLE):
            reason = self._abort_due(st, t)
            if reason is not None:
                self.abort(reason, st.time)
        self._print_transitions()
        return st

    def _abort_due(self, st: VehicleState, t: float) -> str | None:
        """Why the mission must abort now, if it must: the operator asked, the flight-time
        limit, the battery reserve, the camera silent, the LiDAR silent or the detector failing."""
        if self._abort_request is not None:
            return self._abort_request
        if t > self.settings.max_flight_time:
            return f"flight time limit of {self.settings.max_flight_time:.0f} s"
        reason = self.battery.check(st, t, lambda: self._battery_demands(st))
        if reason is not None:
            return reason
        frames, since = self._frames_seen
        if self.runner.counts.frames != frames or self.sm.state == State.FINISH:
            self._frames_seen = (self.runner.counts.frames, st.time)
        elif st.time - since > SENSOR_LOST_TIMEOUT:
            return f"sensor lost: no camera frame for {SENSOR_LOST_TIMEOUT:.0f} s"
        if self.sm.state != State.FINISH:  # on the way home perception is over
            return self.runner.lost(st.time, SENSOR_LOST_TIMEOUT)  # the LiDAR silent, the detector failing
        return None

    def _battery_demands(self, st: VehicleState) -> tuple[RouteDemand, RouteDemand]:
        """What the battery reserve weighs: (the rest of the plan, the way out from here), each
        to the touchdown. The rest of the plan: the plan's items in order (scan, inspect,
        return, cross, then above the landing point), each deferred far-side waypoint as a
        detour there and back from the nearest plan point on its side, a photo stop
        (PHOTO_SETTLE_TIMEOUT, the longest a settle may take) at every inspection waypoint.
        The way out: the safe route an abort here would fly (:func:`plan_abort_route`), or,
        where none can be planned now, the way home over the crossing height."""
        lim = (self.v_max, self.a_max)
        here = np.asarray(st.position, dtype=np.float64)
        touchdown = RouteDemand(TOUCHDOWN_TIME, LAND_HEIGHT)
        points = [here]
        stops = 0
        for it in self.sm.plan:
            if it.kind == PlanKind.LAND:
                points.append(it.position + np.array([0.0, 0.0, LAND_HEIGHT]))
                break
            points.append(np.asarray(it.position, dtype=np.float64))
            stops += it.kind == PlanKind.INSPECT
        rest = route_demand(np.array(points), *lim, stops=stops, stop_time=PHOTO_SETTLE_TIMEOUT) + touchdown
        for side, wps in self.sm.deferred.items():
            on_side = [p for p, it in zip(points[1:], self.sm.plan) if it.side == side] or [points[-1]]
            for w in wps:
                near = min(on_side, key=lambda p: float(np.linalg.norm(p - w.position)))
                rest = rest + route_demand(np.array([near, w.position, near]), *lim, stops=1,
                                           stop_time=PHOTO_SETTLE_TIMEOUT)
        try:
            route = self._abort_route(here)
            way = [here] + [leg[1] for leg in route.legs]
        except PlanningError:
            up = max(here[2], self.geom.volumes.top + self.mission.inspection.crossing_clearance)
            home = np.asarray(self.geom.takeoff, dtype=np.float64)
            way = [here, np.array([here[0], here[1], up]), np.array([home[0], home[1], up]),
                   home + np.array([0.0, 0.0, LAND_HEIGHT])]
        return rest, route_demand(np.array(way), *lim) + touchdown

    def _abort_route(self, position: np.ndarray) -> AbortRoute:
        """The safe route out from ``position`` (at rest) that an abort flies, from what the state
        machine knows (the abort's context once aborted, else what an abort now would keep)."""
        ctx = self.sm.aborted or self.sm.exit_context("battery reserve", self.vehicle.state().time)
        return plan_abort_route(self.geom.line, self.geom.volumes, position, toward_side=ctx.toward_side,
                                back_to=ctx.back_to, ground_z=float(self.geom.takeoff[2]),
                                land_height=LAND_HEIGHT,
                                crossing_clearance=self.mission.inspection.crossing_clearance)

    def _left_of_plan(self) -> dict[str, Any]:
        """What the plan still held (the moment of an abort): the insulators found and not yet
        inspected, the inspection waypoints not flown (buffered and deferred), the exploration
        path not flown (its waypoints and length)."""
        plan = self.sm.plan
        scan = [np.asarray(it.position, dtype=np.float64) for it in plan
                if it.kind in (PlanKind.SCAN, PlanKind.CROSS)]
        length = float(np.sum(np.linalg.norm(np.diff(np.array(scan), axis=0), axis=1))) if len(scan) > 1 else 0.0
        return {"insulators_uninspected": [i.id for i in self.registry.insulators if not i.inspected],
                "inspection_waypoints": sum(it.kind == PlanKind.INSPECT for it in plan)
                + sum(len(w) for w in self.sm.deferred.values()),
                "exploration_waypoints": len(scan), "exploration_left_m": length}

    def request_abort(self, reason: str = "operator abort") -> None:
        """The operator aborts the mission (from another thread too): taken at the next control
        tick, then the safe route out and the landing, as for any abort."""
        self._abort_request = reason

    def abort(self, reason: str, time: float | None = None) -> None:
        if self.sm.aborted is None and self.sm.state != State.IDLE:
            self.left = self._left_of_plan()  # before the state machine drops the plan
        self.abort_reason = reason
        self.sm.abort(reason, self.vehicle.state().time if time is None else time)
        self.observer.aborted(self.now(), reason)

    def on_failsafe(self, exc: VehicleFailsafe) -> None:
        """The vehicle's failsafe fired: the autopilot now flies it (hold, land, return, or the
        pilot has the sticks), so the mission aborts and stops commanding."""
        self.failsafe = exc
        self.abort(f"vehicle failsafe: {exc.reason} ({exc.action})")
        self.write_summary()

    def fly_segment(self, items: list[PlanItem]) -> bool:
        """Fly a min-snap trajectory through ``items`` (the plan's head); report each item reached
        to the state machine. Returns False if the plan changed on the way (re-plan)."""
        st = self.vehicle.state()
        seen = self._seen()
        try:
            seg = plan_segment(self.geom.line, self.geom.volumes, st.position, st.velocity, items, v_max=self.v_max,
                               a_max=self.a_max, clearance=self.mission.inspection.crossing_clearance,
                               time_allocation=self.settings.time_allocation, seen=seen)
        except ObstacleBlocked:
            self.legs_refused += 1
            raise
        self.legs_bent += seg.detours > 0
        traj = seg.trajectory
        k = 0
        version = self.sm.plan_version  # a change of the plan on the way means: re-plan
        seen_version = -1 if self.obstacles is None else self.obstacles.version
        # no trajectory: the vehicle is at the items already (a re-plan that came as it arrived,
        # tower A's second waypoint): it goes on to the photo, not round the same leg forever
        if traj is None:
            for it in items[:-1]:
                if not self._search_may_end(it) or not self._still_head(it):
                    return False
                self.sm.reached(st.time, it)
        for t, st in ([] if traj is None else self._follow(traj, lambda: items[min(k, len(items) - 1)].yaw)):
            if self.sm.state in (State.HOLD, State.ABORT) or not self._healthy():
                return False
            if (traj is not None and seen is not None and self.obstacles is not None
                    and self.obstacles.version != seen_version):  # new occupied voxels: the rest re-checked
                seen_version = self.obstacles.version
                if not self._rest_clear(traj, t, seen):
                    self.legs_replanned += 1
                    self.say(f"[{self.now():7.1f} s] the LiDAR sees an obstacle on the rest of the leg: re-planning")
                    return False
            while k < len(items) - 1 and t >= seg.item_times[k] - 1e-9:
                if not self._search_may_end(items[k]) or not self._still_head(items[k]):
                    return False
                self.sm.reached(self.vehicle.state().time, items[k])
                k += 1
                if self.sm.plan_version != version:
                    return False
            if self.sm.plan_version != version:
                return False
        last = items[-1]
        if last.kind == PlanKind.INSPECT and last.waypoint is not None:
            self.take_photo(last.waypoint)
        if self.sm.target() is last:
            if not self._search_may_end(last) or not self._still_head(last):
                return False
            self.sm.reached(self.vehicle.state().time, last)
        return True

    def _still_head(self, item: PlanItem) -> bool:
        """Whether ``item``, just flown to, is still the plan's head. Why: a find during the
        tick that got there (or the hover of :meth:`_search_may_end`) puts its inspection
        waypoints in front of it; reaching the head then counted one of those as flown, its
        photo never taken (CI, session 12: a string photographed from one of its two waypoints
        and reported inspected). False: re-plan, the new waypoints first."""
        return self.sm.target() is item

    def _seen(self) -> SeenVolumes | None:
        """The safety volumes with the obstacle map, at the mission's margin (None: no map)."""
        if self.obstacles is None:
            return None
        return SeenVolumes.of(self.geom.volumes, self.obstacles, self.mission.inspection.safety_margin)

    def _rest_clear(self, traj: MinSnapTrajectory, t: float, seen: SeenVolumes) -> bool:
        """Whether ``traj`` from its time ``t`` on stays clear of the volumes and the map as it is
        now (sampled as the planner checks: SAFETY_CHECK_DT, at the limits' speed)."""
        times = np.append(np.arange(t, traj.total_time, SAFETY_CHECK_DT), traj.total_time)
        return seen.samples_clear(traj.evaluate(times, 0), float(np.linalg.norm(self.v_max)) * SAFETY_CHECK_DT)

    def _search_may_end(self, item: PlanItem) -> bool:
        """Before ``item``, the plan's head, is reported reached: True to go on. Where reaching it
        ends the search (only crossings back and the landing follow) and perception still holds
        frames taken up to now, the vehicle first hovers at ``item`` until they are handed on
        (:meth:`_perception_caught_up`), and False says: re-plan from there (a find of those
        frames is inspected first; else the item is reached at once). Once per item. Then, there
        and where a side's passes end, a candidate the passes saw too few times gets a second
        look (:meth:`_second_look`, flight/second_look.py), and False: re-plan."""
        ends_search = self.sm.head_ends_search()
        if not ends_search and not self.sm.head_ends_side():
            return True
        if ends_search and self._search_end is not item:
            self._search_end = item
            arrival = self.vehicle.state().time
            if not self.runner.caught_up(arrival):
                self._perception_caught_up(item, arrival)
                return False
        # where a side's passes end (perception caught up where the search ends): a string they
        # saw too few times is looked at again, one a call (False: re-plan from the viewpoint,
        # back here or to the find's waypoints)
        position = self.vehicle.state().position
        target = look_target(self.registry.candidates, self.geom.line, position, self.mission.max_width, self._looked)
        if target is None:  # then a track confidently boxed whose every localization was refused
            target = look_target(self._refused_candidates(), self.geom.line, position, self.mission.max_width,
                                 self._looked)
        if target is None:
            return True
        self._looked.append(target)
        self._second_look(target)
        return False

    def _refused_candidates(self) -> list[Insulator]:
        """Look targets for the pipeline's tracks boxed REFUSED_TRACK_MIN_CONFIDENT times with
        confidence whose every localization the gates refused, at their anchors (the same record
        for a track at every call, so ``_looked`` knows it), the most confident first; not those
        anchored on a string the registry already holds (a known string seen from its steel)."""
        known = self.registry.insulators + self.registry.candidates
        length = self.mission.inspection.insulator_length
        tracks = [t for t in self.runner.pipeline.refused_tracks(REFUSED_TRACK_MIN_CONFIDENT)
                  if not near_a_known_string(t.anchor, known, length)]
        tracks.sort(key=lambda t: -t.evidence.confident_boxes)
        for track in tracks:
            if id(track) not in self._refused_targets:
                self._refused_targets[id(track)] = refused_track_candidate(track.anchor, self.geom.line)
        return [self._refused_targets[id(t)] for t in tracks]

    def _is_refused_target(self, candidate: Insulator) -> bool:
        return any(candidate is target for target in self._refused_targets.values())

    def _second_look(self, candidate: Insulator) -> None:
        """Watch ``candidate`` from its look viewpoints in turn (flight/second_look.py), each
        for :func:`look_events` detection events once settled, then wait for their LiDAR points;
        ended by a find (the plan changes: its waypoints come first), cut short by a hold, an
        abort, lost health or an obstacle on the way. The look goes into summary.json."""
        before = candidate.observations
        source = "refused track" if self._is_refused_target(candidate) else "candidate"
        try:
            views = look_viewpoints(candidate.center, self.geom.line, self.geom.volumes,
                                    min_height=float(self.geom.takeoff[2]) + MIN_PASS_HEIGHT)
        except PlanningError as exc:
            self.second_looks.append(SecondLook(candidate.id, candidate.center.copy(), before, before,
                                                candidate.confirmed, f"not flown: {exc}", source=source))
            return
        seen = (f"seen {before} times" if source == "candidate"
                else "boxed with confidence, every localization refused")
        self.say(f"[{self.now():7.1f} s] a second look at a {source} ({seen}) at "
                 f"{np.round(candidate.center, 2).tolist()}")
        version = self.sm.plan_version
        note, flown = None, 0
        for position, yaw in views:
            if note is not None or self.sm.plan_version != version:
                break  # cut short, or a find: its inspection follows (the look did its job)
            view = PlanItem(PlanKind.SCAN, position, yaw, candidate.side)
            note = self._watch_from(view, candidate, version)
            flown += 1
        st = self.vehicle.state()
        watched = st.time
        deadline = watched + self.runner.pipeline.pairing_window + PAIRING_WAIT
        # the last view's LiDAR points (a frame's come up to PAIRING_WAIT s after its window)
        while (note is None and self.sm.plan_version == version and st.time < deadline
               and not self.runner.caught_up(watched)):
            st = self.tick(view.position, None, view.yaw)
            note = self._look_cut_short(version)
        after, confirmed = candidate.observations, candidate.confirmed
        if source == "refused track":  # what the registry now holds where the track was
            gate = self.registry.gate
            after = observations_near(self.registry.insulators + self.registry.candidates, candidate.center, gate)
            confirmed = observations_near(self.registry.insulators, candidate.center, gate) > 0
        self.second_looks.append(SecondLook(candidate.id, candidate.center.copy(), before, after, confirmed, note,
                                            flown, source=source))

    def _look_cut_short(self, version: int) -> str | None:
        """Why a look stops here (None: it goes on, or a find changed the plan ``version``)."""
        if self.sm.plan_version != version:
            return None
        if self.sm.state in (State.HOLD, State.ABORT) or not self._healthy():
            return f"cut short: {self.sm.state.value}"
        return None

    def _watch_from(self, view: PlanItem, candidate: Insulator, version: int) -> str | None:
        """Fly to ``view`` (the obstacle map rechecked on the way), settle (a braking, turning
        body's frames box a string badly) and watch ``candidate`` for :func:`look_events` events,
        in vehicle time too (a detector that stops asking must not hold the vehicle here).
        Why the look stopped early (None: watched to the end, or a find)."""
        st = self.vehicle.state()
        seen = self._seen()
        try:
            seg = plan_segment(self.geom.line, self.geom.volumes, st.position, st.velocity, [view],
                               v_max=self.v_max, a_max=self.a_max,
                               clearance=self.mission.inspection.crossing_clearance,
                               time_allocation=self.settings.time_allocation, seen=seen)
        except PlanningError as exc:
            return f"not flown: {exc}"
        seen_version = -1 if self.obstacles is None else self.obstacles.version
        if seg.trajectory is not None:
            for t, _ in self._follow(seg.trajectory, lambda: view.yaw):
                note = self._look_cut_short(version)
                if note is not None or self.sm.plan_version != version:
                    return note
                if seen is not None and self.obstacles is not None and self.obstacles.version != seen_version:
                    seen_version = self.obstacles.version
                    if not self._rest_clear(seg.trajectory, t, seen):
                        return "cut short: the LiDAR sees an obstacle on the way"
        if self.sm.plan_version != version:
            return None
        if self._settle(view, 0.0) is None:
            return "cut short: abort"
        events0 = self.runner.counts.events
        budget = look_events(self.mission.inspection.confirmations, candidate.observations)
        st = self.vehicle.state()
        limit = st.time + budget * max(self.settings.detect_period, CONTROL_PERIOD) + PHOTO_SETTLE_TIMEOUT
        while self.sm.plan_version == version and st.time < limit and self.runner.counts.events - events0 < budget:
            st = self.tick(view.position, None, view.yaw)
            note = self._look_cut_short(version)
            if note is not None:
                return note
        return None

    def _perception_caught_up(self, item: PlanItem, arrival: float) -> None:
        """Hover at ``item`` until perception has handed on every frame taken up to ``arrival``,
        at most the pairing window plus PAIRING_WAIT; sooner when the plan changes (a find) or
        the mission holds or aborts. Why: a frame's LiDAR points come up to PAIRING_WAIT s after
        its window (a loaded computer: 1.3-1.5 s at the median against PX4 SITL), and once the
        search is over a find only refines the registry, so a string seen in the last pass's
        last seconds was reported without a photo, or never confirmed."""
        deadline = arrival + self.runner.pipeline.pairing_window + PAIRING_WAIT + CONTROL_PERIOD
        version = self.sm.plan_version
        while not self.runner.caught_up(arrival):
            st = self.tick(item.position, None, item.yaw)
            if self.sm.plan_version != version or self.sm.state in (State.HOLD, State.ABORT) or st.time >= deadline:
                return

    def _follow(self, traj: MinSnapTrajectory, yaw: Callable[[], float]) -> Iterator[tuple[float, VehicleState]]:
        """Stream ``traj`` from its start, one tick at a time, at heading ``yaw()``; yields the
        trajectory time and the vehicle's state after each tick (the caller stops when it must)."""
        st = self.vehicle.state()
        t, t0 = 0.0, st.time
        while t < traj.total_time - 1e-9:
            # by vehicle time, not ticks: through MAVLink a period ends on a telemetry sample, and
            # sensing takes wall time while the vehicle flies on
            t = min(max(st.time - t0, t) + CONTROL_PERIOD, traj.total_time)
            pos = traj.evaluate(np.array([t]), 0)[0]
            vel = traj.evaluate(np.array([t]), 1)[0]
            st = self.tick(pos, vel, yaw())
            yield t, st

    def _healthy(self) -> bool:
        st = self.vehicle.state()
        if st.healthy and st.mode == FlightMode.OFFBOARD.value:
            return True
        self.sm.fault(st.fault or f"vehicle left offboard (mode {st.mode})", st.time)
        return False

    def hold(self) -> None:
        """HOLD: keep position; resume when the vehicle is healthy in offboard again, else abort."""
        st = self.vehicle.state()
        here, yaw, t0 = st.position.copy(), st.yaw, st.time
        while self.sm.state == State.HOLD:
            st = self.tick(here, None, yaw)
            if self.sm.state != State.HOLD:
                break  # a failsafe aborted the mission
            if st.healthy and st.mode != FlightMode.OFFBOARD.value:
                try:
                    self.vehicle.start_offboard()
                except VehicleError as exc:  # the autopilot refused: keep holding
                    self.say(f"[{self.now():7.1f} s] offboard refused: {exc}")
            if st.healthy and st.mode == FlightMode.OFFBOARD.value:
                self.sm.resume(st.time)
            elif st.time - t0 > HOLD_TIMEOUT:
                self.abort(f"fault did not clear within {HOLD_TIMEOUT:.0f} s", st.time)

    def take_photo(self, wp: InspectionWaypoint) -> None:
        """Take the photo of ``wp`` (:meth:`_shoot`) and check it on itself; an unfit one is taken
        again, re-settled and re-aimed, at most ``[inspection] photo_retakes`` times, when the rig
        has an inspection camera. Every attempt is saved and recorded (its ``attempt`` and ``check``).

        Without an inspection camera the photo is the detection camera's frame: no zoom to frame
        the string, no gimbal to re-aim, the view perception already has at 1 Hz. A retake then
        repeats the same view and holds the vehicle at the waypoint for nothing: measured on the
        live path against PX4 SITL (session 15's soak, 10 small-scene flights), 0-1 of 12-18 such
        photos a flight were fit, with both retakes taken nearly every time, and those hovers
        (10-28 s at a string's viewpoints) were where the network's boxes on the tower's peak
        gathered into 3 false finds. The photo is kept with its check."""
        retakes = self.mission.inspection.photo_retakes if self.inspection is not None else 0
        for attempt in range(1, retakes + 2):
            check = self._shoot(wp, attempt)
            if check is None or check.fit:
                return
            if attempt <= retakes:
                self.say(f"[{self.now():7.1f} s] photo of insulator {wp.insulator_id} unfit "
                         f"({', '.join(check.reasons)}): retake {attempt} of {retakes}")

    def _settle(self, wp: InspectionWaypoint | PlanItem, hold: float) -> VehicleState | None:
        """Hold ``wp`` for at least ``hold`` s until settled (heading, speed) or PHOTO_SETTLE_TIMEOUT;
        the settled state, None when the mission aborted meanwhile."""
        t0 = self.vehicle.state().time
        while True:
            st = self.tick(wp.position, None, wp.yaw)
            if self.sm.state == State.ABORT:
                return None
            settled = (abs(wrap_angle(st.yaw - wp.yaw)) < PHOTO_YAW_TOLERANCE
                       and np.linalg.norm(st.velocity) < PHOTO_SPEED_TOLERANCE)
            if (settled and st.time - t0 >= hold) or st.time - t0 > PHOTO_SETTLE_TIMEOUT:
                return st

    def _shoot(self, wp: InspectionWaypoint, attempt: int) -> PhotoCheck | None:
        """Settle on the waypoint with the camera aimed, take the photo through the sensors,
        check it (the detector once on the photo), save it; its check, None without a photo."""
        st = self._settle(wp, 0.0 if attempt == 1 else RETAKE_HOLD)
        if st is None:
            return None
        zoom = None
        ins = next((i for i in self.registry.insulators if i.id == wp.insulator_id), None)
        # a single shot aims at the string's centre as the registry knows it now: the localizations
        # since the waypoint was planned moved it (measured: 8 cm, 3.6 % of a frame the string
        # fills to 90 %); a tile keeps its planned place along the string
        target = ins.center if ins is not None and wp.tiles == 1 else wp.target
        if self.inspection is None:
            pitch, gimbal_yaw = wp.gimbal_pitch, 0.0
            T_b_c = stabilised_T_b_c(st.T_w_b, self.rig.T_b_c, wp.gimbal_pitch)
        else:  # aimed from where the vehicle settled, at the zoom the shot was framed for
            pitch, gimbal_yaw, T_b_c = aim_at(st.T_w_b, self.inspection.T_b_c, target, self.inspection.gimbal)
            if wp.focal_px is not None:
                zoom = self.inspection.at_focal(wp.focal_px)
        try:
            frame = self.sensors.photo(st.time, T_b_c, camera=zoom)
        except SensorError as exc:
            self._sensor_error(exc)
            frame = None
        if frame is None:
            self.say(f"[{self.now():7.1f} s] photo of insulator {wp.insulator_id}: no image from the camera")
            return None
        axis = None if ins is None else ins.axis
        T_c_w = np.linalg.inv(st.T_w_b @ frame.T_b_c)
        view = expected_view(frame.camera, T_c_w, target, wp.target if ins is None else ins.center,
                             np.array([0.0, 0.0, 1.0]) if axis is None else axis,
                             self.mission.inspection.insulator_length, required_span=MIN_FILL,
                             tiled=wp.tiles > 1)
        check = check_photo(self.photo_detector, frame.image, view)
        time_utc = self.clock.at(frame.time)
        record = self.photos.save(wp, frame, time_utc=time_utc, time_s=frame.time - self.t_start,
                                  position=st.position, yaw=st.yaw, T_w_b=st.T_w_b, velocity=st.velocity,
                                  axis=axis, gimbal=(pitch, gimbal_yaw), check=check, attempt=attempt)
        q = record["quality"]
        verdict = "fit" if check.fit else f"unfit: {', '.join(check.reasons)}"
        self.say(f"[{self.now():7.1f} s] photo {record['file']}: GSD {q['gsd_mm_px']:.1f} mm/px, "
                 f"blur {q['motion_blur_px']:.2f} px; checked on the photo: {verdict}"
                 + (f" ({check.error})" if check.error else ""))
        w = record["wgs84"]  # where the GCS draws the photo's marker
        self.observer.photo_taken(PhotoTaken(record["time_s"], time_utc.timestamp(), wp.insulator_id,
                                             len(self.photos), record["file"], st.position.copy(),
                                             (w["lat"], w["lon"], w["alt"]),
                                             wrap_angle(st.yaw + gimbal_yaw), pitch))
        self.write_summary()
        return check

    def configure_autopilot(self) -> None:
        """Before arming: the autopilot's own failsafes set for this tower and verified (a vehicle
        with parameters only; see :mod:`insulator_rs.planning.px4_failsafes`); home is where the
        vehicle stands (PX4 sets it at arming). A parameter that cannot be read or set raises
        ParameterError: the mission aborts before anything flies."""
        store = vehicle_parameters(self.vehicle)
        if store is None:
            return
        gcs = store.ground_station(GROUND_STATION_WAIT)
        settings = tower_failsafe_parameters(self.geom.volumes, self.vehicle.state().position,
                                             self.geom.path_points(),
                                             crossing_clearance=self.mission.inspection.crossing_clearance,
                                             ground_station=gcs, vehicle_return_alt=store.read("RTL_RETURN_ALT"))
        self.autopilot_setup = AutopilotSetup(store, settings, ground_station=gcs)
        try:
            self.autopilot_setup.apply()
        finally:
            self.write_summary()
        self.say("autopilot parameters set and verified: " + ", ".join(f"{s.name} {s.value:g}" for s in settings)
                 + ("" if gcs else "; no ground station heard: NAV_DLL_ACT left as it was"))

    def preflight(self) -> None:
        """Before arming, after the autopilot's parameters are set: the pre-flight gate
        (:mod:`insulator_rs.flight.preflight`), each check said; PreflightRefused naming every
        failed check refuses the flight before the arm command."""
        p = self.mission.inspection
        result = preflight_checks(self.vehicle, self.sensors, self.detector, demand=self._mission_demand(),
                                  reserve=p.battery_reserve, volumes=self.geom.volumes,
                                  mission_points=self.geom.path_points())
        self.preflight_result = result
        for c in result.checks:
            self.say(f"pre-flight {c.check.value}: {c.outcome.value.replace('_', ' ')} ({c.reason})")
        if not result.passed:
            raise result.refusal()

    def _mission_demand(self) -> RouteDemand:
        """What the battery pays for the mission before anything is found: the exploration path
        from the take-off point to above the landing point, and the touchdown."""
        points = np.vstack([self.vehicle.state().position, self.geom.path_points()])
        return route_demand(points, self.v_max, self.a_max) + RouteDemand(TOUCHDOWN_TIME, LAND_HEIGHT)

    def on_preflight_refused(self, exc: PreflightRefused) -> None:
        """The gate refused: the operator and the GCS are told each failed check; nothing armed."""
        self.observer.preflight_failed(self.now(), exc.failed)
        self.say(f"refused to arm: {exc}")
        self.write_summary()

    def restore_autopilot(self) -> None:
        """After the flight: the autopilot's old parameters back, once the vehicle is on the
        ground (waiting up to RESTORE_WAIT s of vehicle time while PX4 returns or lands by
        itself); while it still flies, the tower's values stay set and the report says so."""
        setup = self.autopilot_setup
        if setup is None or not setup.pending:
            return
        st = self.vehicle.state()
        waited = 0.0
        # only PX4's own return or landing ends on the ground by itself; a hover (HOLD, the
        # pilot's POSCTL) is someone's to end, so the values stay for them
        landing_modes = (FlightMode.RTL.value, FlightMode.LAND.value)
        while not st.landed and st.mode in landing_modes and waited < RESTORE_WAIT:
            before = st.time
            try:
                st = self.vehicle.advance(1.0)
            except VehicleFailsafe as exc:  # PX4's own failsafe flies on: keep waiting for its landing
                self.say(f"[{self.now():7.1f} s] waiting for the landing to restore parameters: {exc}")
                st = self.vehicle.state()
            except VehicleError:
                break
            if st.time <= before:
                break  # no telemetry any more: the vehicle cannot be seen landing
            waited += st.time - before
            self.report.log_pose(st.time - self.t_start, st.position, st.yaw, self.sm.state.value)
        if st.landed:
            setup.restore()
        else:
            setup.keep(f"the vehicle is still in the air (mode {st.mode}): the tower's values stay set")
        self.say(f"[{self.now():7.1f} s] autopilot parameters: {setup.restore_status}")
        self.write_summary()

    def takeoff(self) -> None:
        st = self.vehicle.state()
        target = st.position + np.array([0.0, 0.0, MIN_PASS_HEIGHT])
        self.vehicle.send_setpoint(target, None, st.yaw)
        self.t_start = st.time
        self.clock = FlightClock(st.time)
        self.vehicle.arm()
        self._airborne = True
        self.vehicle.takeoff(MIN_PASS_HEIGHT)
        yaw = st.yaw
        while st.time - self.t_start < TAKEOFF_TIMEOUT:
            st = self.tick(target, None, yaw)
            if self.sm.state == State.ABORT:
                return  # a failsafe or the flight time limit during the climb
            if st.mode != FlightMode.TAKEOFF.value and abs(st.position[2] - target[2]) < 0.4:
                break
        self.vehicle.start_offboard()
        self.sm.start(self.vehicle.state().time)
        self._frames_seen = (self.runner.counts.frames, self.vehicle.state().time)
        self._print_transitions()

    def land(self) -> None:
        """Land where the vehicle is, unless a failsafe has the vehicle or it never flew. A refused
        or unanswered land command is reported; the autopilot's own failsafes keep the vehicle."""
        if self.failsafe is not None or not self._airborne:
            return  # the autopilot flies its failsafe (or the pilot flies), or nothing took off
        st = self.vehicle.state()
        if st.landed and not st.armed:
            return
        try:
            self.vehicle.land()
        except VehicleFailsafe as exc:
            self.on_failsafe(exc)
            return
        except VehicleError as exc:
            self.abort_reason = f"{self.abort_reason or 'mission aborted'}; landing command failed: {exc}"
            self.say(f"[{self.now():7.1f} s] landing command failed: {exc}")
            return
        t0 = st.time
        while not st.landed and st.time - t0 < LAND_TIMEOUT:
            try:
                st = self.vehicle.advance(CONTROL_PERIOD)
            except VehicleFailsafe as exc:
                self.on_failsafe(exc)
                return
            self.battery.observe(st)  # the descent drains the pack too, down to the charge at touchdown
            self.report.log_pose(st.time - self.t_start, st.position, st.yaw, self.sm.state.value)

    def leave_safely(self) -> None:
        """After an abort: stop, fly the safe route out (:mod:`insulator_rs.planning.abort`, from
        what the state machine knew: the side a crossing was heading for, where a detour began)
        and land at its end; where no route can be planned, or the vehicle will not fly it, hold
        and hand over to the pilot. Nothing when a failsafe has the vehicle or it never flew."""
        if self.failsafe is not None or not self._airborne:
            return
        st = self.vehicle.state()
        if st.landed:
            return
        offboard = st.mode == FlightMode.OFFBOARD.value
        yaw = st.yaw
        try:
            stop = plan_stop(self.geom.volumes, st.position, st.velocity, self.a_max)
            if stop is not None and offboard and not self._fly_abort_leg(stop, yaw):
                return
            st = self.vehicle.state()
            route = self._abort_route(st.position)
        except PlanningError as exc:
            self.hand_over(f"no safe route to land: {exc}")
            return
        self.abort_route = route
        self.say(f"[{self.now():7.1f} s] abort: {route.case} to the landing point "
                 f"{np.round(route.landing, 1).tolist()} ({len(route.legs)} legs)")
        self.write_summary()
        if route.case == AbortCase.DESCEND and not offboard:
            self.land()  # straight down is clear: the autopilot's own landing, no offboard needed
            return
        if not offboard and not self._take_offboard():
            return
        for leg in route.legs:
            try:
                traj = leg_trajectory(leg, self.geom.volumes, v_max=self.v_max, a_max=self.a_max,
                                      dt=SAFETY_CHECK_DT)
            except PlanningError as exc:
                self.hand_over(f"no safe trajectory along the route out: {exc}")
                return
            if not self._fly_abort_leg(traj, yaw):
                return
        self.land()

    def _fly_abort_leg(self, traj: MinSnapTrajectory, yaw: float) -> bool:
        """Fly one trajectory of the way out; False (and the vehicle handed over, unless a
        failsafe has it) when the vehicle stops taking setpoints on the way."""
        for _, st in self._follow(traj, lambda: yaw):
            if self.failsafe is not None:
                return False
            if not st.healthy or st.mode != FlightMode.OFFBOARD.value:
                self.hand_over(st.fault or f"the vehicle left offboard on the way out (mode {st.mode})")
                return False
        return True

    def _take_offboard(self) -> bool:
        """Back into offboard for the way out (setpoints streamed here first, as PX4 wants);
        False, and the vehicle handed over, when the autopilot refuses."""
        st = self.vehicle.state()
        here, t0 = st.position.copy(), st.time
        while st.time - t0 < OFFBOARD_WARMUP and self.failsafe is None:
            st = self.tick(here, None, st.yaw)
        try:
            self.vehicle.start_offboard()
        except VehicleError as exc:
            self.hand_over(f"offboard refused for the way out: {exc}")
            return False
        return self.failsafe is None

    def hand_over(self, reason: str) -> None:
        """No safe way on: hold in the autopilot's HOLD where the vehicle is (never a blind
        descent), say so to the pilot (the GCS's STATUSTEXT), stop commanding."""
        self.handed_over = reason
        try:
            self.vehicle.hold()
        except VehicleError as exc:
            reason += f"; the hold command failed too: {exc}"
            self.handed_over = reason
        self.observer.handed_over(self.now(), reason)
        self.say(f"[{self.now():7.1f} s] holding for the pilot: {reason}")
        self.write_summary()

    def on_command_failure(self, exc: VehicleError) -> None:
        """The vehicle refused a command or never answered it (arm, take-off, a mode switch):
        reported, and the mission aborts (then lands, see :meth:`land`)."""
        self.abort(f"vehicle command failed: {exc}")
        self.say(f"[{self.now():7.1f} s] {self.abort_reason}")
        self.write_summary()

    def skip_inspection(self, item: PlanItem, exc: PlanningError) -> None:
        """No safe trajectory to an inspection waypoint (a find inside a safety volume, or one
        the vehicle cannot reach without entering one): that photo is dropped, reported, and the
        mission goes on; one unreachable waypoint must not cost the rest of the tower."""
        self.sm.skip(item, self.vehicle.state().time, str(exc))
        iid = item.waypoint.insulator_id if item.waypoint is not None else None
        self.say(f"[{self.now():7.1f} s] inspection waypoint of insulator {iid} skipped: no safe trajectory ({exc})")
        self.write_summary()

    def on_planning_failure(self, exc: PlanningError) -> None:
        """No safe trajectory from where the vehicle is (it cannot stop before a safety volume, or
        the route cannot be cleared): reported, and the mission aborts (then lands, see
        :meth:`land`) rather than fly on without a plan."""
        self.abort(f"planning failed: {exc}")
        self.say(f"[{self.now():7.1f} s] {self.abort_reason}")
        self.write_summary()

    def fly(self) -> None:
        """The whole flight; a refused command aborts it cleanly (see the module docstring)."""
        layout = self.report.layout
        self.say(f"inspecting with mission {self.mission.source}; report -> {self.out}"
                 + (f" (written in {layout.path}, replaces the old report when the run ends)"
                    if layout.staged else ""))
        for left in layout.leftovers():
            self.say(f"note: {left} is what an earlier run killed mid-way left (kept; delete it when done)")
        refused: PreflightRefused | None = None
        try:
            self._fly()
        except PreflightRefused as exc:  # before arming: nothing flew, nothing was armed
            refused = exc
            self.on_preflight_refused(exc)
        except VehicleFailsafe as exc:  # raised by a command rather than during a tick
            self.on_failsafe(exc)
        except ParameterError as exc:  # before arming: nothing flew
            self.abort(f"autopilot parameters not set ({exc})")
            self.say(f"[{self.now():7.1f} s] {self.abort_reason}")
        except VehicleError as exc:
            self.on_command_failure(exc)
        except PlanningError as exc:
            self.on_planning_failure(exc)
        if refused is not None:
            self.status = "refused_preflight: " + "; ".join(f"{name}: {reason}" for name, reason in refused.failed)
        elif self.sm.state == State.ABORT:
            self.leave_safely()
            self.status = f"aborted: {self.abort_reason or 'mission aborted'}"
            if self.handed_over is not None:
                self.status += f"; held for the pilot: {self.handed_over}"
        else:
            self.status = "finished"
        self.restore_autopilot()
        self._print_transitions()

    def _fly(self) -> None:
        self.configure_autopilot()
        self.preflight()
        self.takeoff()
        while not self.sm.done:
            if self.sm.state == State.HOLD:
                self.hold()
                continue
            head = self.sm.target()
            if head is None:
                break
            if head.kind == PlanKind.LAND:
                if self.sm.approach_landing(LAND_HEIGHT) is not None:
                    continue  # far-side finds are owed on the landing side: arrive above it first
                above = PlanItem(PlanKind.LAND, head.position + np.array([0.0, 0.0, LAND_HEIGHT]), head.yaw,
                                 head.side)
                if self.fly_segment([above]):
                    self.land()
                    self.sm.reached(self.vehicle.state().time)
                continue
            items = self.sm.next_leg()
            try:
                self.fly_segment(items)
            except PlanningError as exc:
                if items[-1].kind != PlanKind.INSPECT:
                    raise  # the exploration itself cannot go on: abort (on_planning_failure)
                self.skip_inspection(items[-1], exc)

    # -- report --------------------------------------------------------------------------
    def summary(self) -> RunSummary:
        """What the flight knows now (summary.json), nothing of ground truth."""
        st = self.vehicle.state()
        photos: dict[int, list[str]] = {}
        for p in self.photos.records:
            photos.setdefault(p["insulator_id"], []).append(p["file"])
        s = self.settings
        details = FlightDetails(
            mission=str(self.mission.source), rig=str(self.rig.source), policy=s.policy.value,
            time_allocation=s.time_allocation, state=self.sm.state.value, vehicle=type(self.vehicle).__name__,
            sensors=type(self.sensors).__name__,
            failsafe=None if self.failsafe is None else {"reason": self.failsafe.reason,
                                                         "action": self.failsafe.action},
            distance_m=self.report.distance_m,
            detections_dropped_by_sanitiser=detections_dropped(self.detector),
            abort=self._abort_record(),
            inspections_skipped=[{"insulator_id": it.waypoint.insulator_id if it.waypoint is not None else None,
                                  "position": np.asarray(it.position).tolist(), "reason": reason}
                                 for it, reason in self.sm.skipped],
            photo_camera=camera_record(self.photos.camera),
            photo_checks=self.photos.check_summary([i.id for i in self.registry.insulators]),
            inspection_waypoints=[{"insulator_id": w.insulator_id, "position": w.position, "yaw": w.yaw,
                                   "gimbal_pitch": w.gimbal_pitch} for w in self.waypoints],
            transitions=[{"time_s": tr.time - self.t_start, "from": tr.source.value, "to": tr.target.value,
                          "reason": tr.reason} for tr in self.sm.transitions],
            timesync=timesync_record(self.vehicle, self.sensors),
            battery=self.battery.record(),
            obstacle_map=self._obstacle_record(),
            second_looks=[look.as_record() for look in self.second_looks],
            preflight=None if self.preflight_result is None else self.preflight_result.as_record(),
            px4_parameters=None if self.autopilot_setup is None else self.autopilot_setup.record(),
            companion_stalls=None if self.stall_watch is None else self.stall_watch.record(),
            setpoint_stream=setpoint_stream_record(self.vehicle))
        refused = self.preflight_result is not None and not self.preflight_result.passed
        return RunSummary(run="flight", status=self.status, detector=detector_name(self.detector),
                          method=s.method, flight_time_s=0.0 if refused else st.time - self.t_start,
                          perception=perception_record(self.runner, self.sensor_errors),
                          insulators=insulator_records(self.registry, photos), photos=self.photos.records,
                          candidates=candidate_records(self.registry),
                          sensors_health=self.sensors.health(), flight=details)

    def _obstacle_record(self) -> dict[str, Any]:
        """What the obstacle map held and did (summary.json)."""
        if self.obstacles is None:
            return {"enabled": False}
        return {"enabled": True, **self.obstacles.record(), "margin_m": self.mission.inspection.safety_margin,
                "legs_bent": self.legs_bent, "legs_replanned": self.legs_replanned,
                "legs_refused": self.legs_refused}

    def _abort_record(self) -> dict[str, Any] | None:
        ctx = self.sm.aborted
        if ctx is None:
            return None
        route = self.abort_route
        record: dict[str, Any] = {"reason": self.abort_reason or ctx.reason, "time_s": ctx.time - self.t_start,
                                  "route": None, "landing_point": None, "landing_wgs84": None, "side": None,
                                  "legs": [], "handed_over": self.handed_over, "left": self.left}
        if route is not None:
            lat, lon, alt = enu_to_geodetic(route.landing, self.origin)[0]
            record.update(route=route.case.value, landing_point=route.landing.tolist(),
                          landing_wgs84=[float(lat), float(lon), float(alt)], side=route.side,
                          legs=[leg.tolist() for leg in route.legs])
        return record

    def write_summary(self) -> None:
        self.report.write_summary(self.summary())

    def finish_report(self, reference: np.ndarray | None = None) -> dict[str, Any]:
        """Write the final summary and the plot. ``reference``: (K, 3) points drawn as ground
        truth, known only after the flight (the evaluation's), or None."""
        self.report.flush()
        run = self.summary()
        self.report.write_summary(run)
        summary = run.as_dict()
        wps = np.array([w.position for w in self.waypoints]) if self.waypoints else np.zeros((0, 3))
        found = np.array([i.center for i in self.registry.insulators]) if len(self.registry) else np.zeros((0, 3))
        truth = np.zeros((0, 3)) if reference is None else np.asarray(reference, dtype=np.float64).reshape(-1, 3)
        self.report.plot(self.geom.volumes, wps, found, truth,
                         f"{summary['status']}, flight {summary['flight_time_s']:.0f} s, "
                         f"{summary['insulators_inspected']}/{summary['insulators_found']} insulators inspected")
        self.report.close()
        return summary
