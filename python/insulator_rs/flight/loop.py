"""The flight loop: fly the single-flight inspection through the ports (see ``__init__``).

The paper's online algorithm: take off, fly the exploration path (minimum-snap trajectories,
safety-checked), and every ``detect_period`` s take a detection frame from the sensors, run
the detector, and hand the frame, its boxes and the LiDAR points of that instant to the
perception pipeline (:class:`~insulator_rs.perception.runner.PerceptionRunner`: the one pairing
rule, shared with the replay of a recorded flight; paired and deskewed with the pose history
the loop feeds every control tick); new insulators get inspection waypoints, which the state
machine visits (a photo at each, from the companion computer's camera through
``Sensors.photo``, gimbal aimed), then the flight goes on, crosses over the top, finishes and
lands. The loop does not know whether it is recorded: recording wraps the ports.

A vehicle failsafe (link lost, the pilot took over, battery, position lost) aborts the
mission: the report says why and keeps everything found so far, and once the failsafe fired
nothing more is sent to the vehicle. A command the vehicle refuses, or a leg no safe trajectory
can be planned for, aborts the mission cleanly (landing if airborne and the vehicle still takes
commands); a sensor error costs that detection event or photo, never the flight.

The report folder (:mod:`insulator_rs.report`: photos with EXIF GPS, WGS-84, GeoJSON/KML) is
written as the flight goes; an interruption (Ctrl-C) still leaves the summary, the photos
taken and the plot.
"""

from __future__ import annotations

import math
import time as wallclock
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.exceptions import PlanningError, SensorError, VehicleError, VehicleFailsafe
from insulator_rs.geodesy import GeoPoint, enu_to_geodetic
from insulator_rs.flight.observers import ConsoleObserver, ObserverGroup
from insulator_rs.flight.photos import InspectionPhotos
from insulator_rs.flight.record import camera_record, insulator_records, perception_record
from insulator_rs.mission.config import Mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import InspectionStateMachine, PlanItem, Policy, State
from insulator_rs.perception.pipeline import BOUNDED, LocalizedInsulator, PerceptionPipeline
from insulator_rs.perception.runner import PerceptionRunner
from insulator_rs.planning.exploration import MIN_PASS_HEIGHT, PlanKind
from insulator_rs.planning.pmm import rest_to_rest_times
from insulator_rs.planning.segments import plan_segment
from insulator_rs.planning.waypoints import InspectionWaypoint, inspection_waypoints
from insulator_rs.ports.detector import BoxDetector, detections_dropped, detector_name
from insulator_rs.ports.observer import FlightObserver, InsulatorFound, PhaseChange, PhotoTaken
from insulator_rs.ports.sensors import PoseStamped, Sensors
from insulator_rs.ports.vehicle import FlightMode, Vehicle, VehicleState, wrap_angle
from insulator_rs.report import FlightClock, ReportWriter
from insulator_rs.report.summary import FlightDetails, RunSummary
from insulator_rs.rig import SensorRig
from insulator_rs.tracking.registry import Insulator, InsulatorRegistry

CONTROL_PERIOD = 0.05  # s: 20 Hz setpoint stream, as PX4 offboard wants
PHOTO_YAW_TOLERANCE = math.radians(3.0)
PHOTO_SPEED_TOLERANCE = 0.2  # m/s
PHOTO_SETTLE_TIMEOUT = 8.0  # s
HOLD_TIMEOUT = 10.0  # s in HOLD before the mission aborts
STATUS_PERIOD = 15.0  # s of flight between progress lines
SUMMARY_PERIOD = 5.0  # s of flight between summary rewrites
LAND_HEIGHT = 2.0  # m above the take-off point where the landing starts
TAKEOFF_TIMEOUT = 60.0  # s of vehicle time for the climb to the first pass height
LAND_TIMEOUT = 120.0  # s of vehicle time for the descent


@dataclass(frozen=True)
class FlightSettings:
    """How the loop flies: localization ``method``, buffering ``policy``, s between detection
    events, the flight-time limit (s), the min-snap ``time_allocation``, progress output."""

    method: str = BOUNDED  # the product's default (inspect --method): tests fly what users fly
    policy: Policy = Policy.IMMEDIATE
    detect_period: float = 1.0
    max_flight_time: float = 1800.0
    time_allocation: str = "pmm"
    quiet: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "policy", Policy(self.policy))  # a bad policy is refused, named


def gimballed_T_b_c(T_b_c: np.ndarray, pitch: float) -> np.ndarray:
    """The camera mounted at ``T_b_c`` on a gimbal pitched by ``pitch`` rad (negative looks
    down) about the body y axis."""
    c, s = math.cos(-pitch), math.sin(-pitch)
    R = np.eye(4)
    R[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    return R @ T_b_c


class FlightLoop:
    """One single-flight inspection: state, perception, report (see the module docstring)."""

    def __init__(self, mission: Mission, vehicle: Vehicle, sensors: Sensors, detector: BoxDetector,
                 out: Path, *, rig: SensorRig, settings: FlightSettings = FlightSettings(),
                 overwrite: bool = False, observer: FlightObserver | None = None,
                 photo_camera: Any = None) -> None:
        self.mission = mission
        self.vehicle = vehicle
        self.sensors = sensors
        self.detector = detector
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
        self.sm = InspectionStateMachine(self.geom.path, self.registry, self._waypoints,
                                         policy=settings.policy, cost=self._cost)
        tower = mission.tower
        self.origin = GeoPoint(tower.lat, tower.lon, tower.alt)
        self.report = ReportWriter(out, origin=self.origin, overwrite=overwrite)
        self.clock = FlightClock(self.vehicle.state().time)  # UTC of vehicle stamps; re-anchored at take-off
        self.out = out
        self.photos = InspectionPhotos(self.report, mission.inspection.insulator_length,
                                       exif_camera=rig.exif_camera())
        self.waypoints: list[InspectionWaypoint] = []
        self.status = "running"
        self.abort_reason: str | None = None
        self.t_start = 0.0
        self.sensor_errors = 0  # the runner's and the photos'
        self._airborne = False
        self._printed_transitions = 0
        self._next_status = STATUS_PERIOD
        self._next_summary = SUMMARY_PERIOD
        self._wall0 = wallclock.perf_counter()

    # -- helpers -------------------------------------------------------------------------
    def _waypoints(self, ins: Insulator) -> list[InspectionWaypoint]:
        p = self.mission.inspection
        wps = inspection_waypoints(ins.center, ins.axis, insulator_id=ins.id, line=self.geom.line,
                                   volumes=self.geom.volumes, count=p.waypoints_per_insulator,
                                   inspection_distance=p.inspection_distance,
                                   insulator_length=p.insulator_length, fov=self.fov,
                                   camera=self.photo_model)
        self.waypoints.extend(wps)
        return wps

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
        self.report.log_pose(t, st.position, st.yaw, self.sm.state.value)
        self.runner.add_pose(PoseStamped(st.time, st.T_w_b))  # the whole reported attitude
        if self.sm.state not in (State.IDLE, State.FINISH, State.ABORT):
            for fix in self.runner.step(st.time):
                self._localized(fix, st)
        if t >= self._next_status:
            self._next_status += STATUS_PERIOD
            self.say(f"[{t:7.1f} s] {self.sm.state.value}: at {np.round(st.position, 1).tolist()}, "
                     f"{len(self.registry)} insulators, {len(self.photos)} photos, "
                     f"{self.events} detection events, wall {wallclock.perf_counter() - self._wall0:.0f} s")
        if t >= self._next_summary:
            self._next_summary += SUMMARY_PERIOD
            self.report.flush()
            self.write_summary()
        if t > self.settings.max_flight_time and self.sm.state != State.ABORT:
            self.abort(f"flight time limit of {self.settings.max_flight_time:.0f} s", st.time)
        self._print_transitions()
        return st

    def abort(self, reason: str, time: float | None = None) -> None:
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
        seg = plan_segment(self.geom.line, self.geom.volumes, st.position, st.velocity, items, v_max=self.v_max, a_max=self.a_max,
                           clearance=self.mission.inspection.crossing_clearance,
                           time_allocation=self.settings.time_allocation)
        traj = seg.trajectory
        if traj is None:
            return True
        k = 0
        t = 0.0
        t0 = st.time
        version = self.sm.plan_version  # a change of the plan on the way means: re-plan
        while t < traj.total_time - 1e-9:
            # by vehicle time, not ticks: through MAVLink a period ends on a telemetry sample, and
            # sensing takes wall time while the vehicle flies on
            t = min(max(st.time - t0, t) + CONTROL_PERIOD, traj.total_time)
            pos = traj.evaluate(np.array([t]), 0)[0]
            vel = traj.evaluate(np.array([t]), 1)[0]
            st = self.tick(pos, vel, items[min(k, len(items) - 1)].yaw)
            if self.sm.state in (State.HOLD, State.ABORT) or not self._healthy():
                return False
            while k < len(items) - 1 and t >= seg.item_times[k] - 1e-9:
                self.sm.reached(self.vehicle.state().time)
                k += 1
                if self.sm.plan_version != version:
                    return False
            if self.sm.plan_version != version:
                return False
        last = items[-1]
        if last.kind == PlanKind.INSPECT and last.waypoint is not None:
            self.take_photo(last.waypoint)
        if self.sm.target() is last:
            self.sm.reached(self.vehicle.state().time)
        return True

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
        """Settle on the waypoint with the camera aimed, take the photo through the sensors, save it."""
        t0 = self.vehicle.state().time
        while True:
            st = self.tick(wp.position, None, wp.yaw)
            if self.sm.state == State.ABORT:
                return
            settled = (abs(wrap_angle(st.yaw - wp.yaw)) < PHOTO_YAW_TOLERANCE
                       and np.linalg.norm(st.velocity) < PHOTO_SPEED_TOLERANCE)
            if settled or st.time - t0 > PHOTO_SETTLE_TIMEOUT:
                break
        T_b_c = gimballed_T_b_c(self.rig.T_b_c, wp.gimbal_pitch)
        try:
            frame = self.sensors.photo(st.time, T_b_c)
        except SensorError as exc:
            self._sensor_error(exc)
            frame = None
        if frame is None:
            self.say(f"[{self.now():7.1f} s] photo of insulator {wp.insulator_id}: no image from the camera")
            return
        ins = next((i for i in self.registry.insulators if i.id == wp.insulator_id), None)
        time_utc = self.clock.at(frame.time)
        record = self.photos.save(wp, frame, time_utc=time_utc, time_s=frame.time - self.t_start,
                                  position=st.position, yaw=st.yaw, velocity=st.velocity,
                                  axis=None if ins is None else ins.axis)
        q = record["quality"]
        self.say(f"[{self.now():7.1f} s] photo {record['file']}: GSD {q['gsd_mm_px']:.1f} mm/px, "
                 f"blur {q['motion_blur_px']:.2f} px")
        w = record["wgs84"]  # where the GCS draws the photo's marker
        self.observer.photo_taken(PhotoTaken(record["time_s"], time_utc.timestamp(), wp.insulator_id,
                                             len(self.photos), record["file"], st.position.copy(),
                                             (w["lat"], w["lon"], w["alt"]), st.yaw, wp.gimbal_pitch))
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
            self.report.log_pose(st.time - self.t_start, st.position, st.yaw, self.sm.state.value)

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
        try:
            self._fly()
        except VehicleFailsafe as exc:  # raised by a command rather than during a tick
            self.on_failsafe(exc)
        except VehicleError as exc:
            self.on_command_failure(exc)
        except PlanningError as exc:
            self.on_planning_failure(exc)
        if self.sm.state == State.ABORT:
            self.land()
            self.status = f"aborted: {self.abort_reason or 'mission aborted'}"
        else:
            self.status = "finished"
        self._print_transitions()

    def _fly(self) -> None:
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
        traj = np.array([p[1:] for p in self.report.trajectory]) if self.report.trajectory else np.zeros((0, 3))
        s = self.settings
        details = FlightDetails(
            mission=str(self.mission.source), rig=str(self.rig.source), policy=s.policy.value,
            time_allocation=s.time_allocation, state=self.sm.state.value, vehicle=type(self.vehicle).__name__,
            sensors=type(self.sensors).__name__,
            failsafe=None if self.failsafe is None else {"reason": self.failsafe.reason,
                                                         "action": self.failsafe.action},
            distance_m=float(np.sum(np.linalg.norm(np.diff(traj, axis=0), axis=1))) if len(traj) > 1 else 0.0,
            detections_dropped_by_sanitiser=detections_dropped(self.detector),
            inspections_skipped=[{"insulator_id": it.waypoint.insulator_id if it.waypoint is not None else None,
                                  "position": np.asarray(it.position).tolist(), "reason": reason}
                                 for it, reason in self.sm.skipped],
            photo_camera=camera_record(self.photos.camera),
            inspection_waypoints=[{"insulator_id": w.insulator_id, "position": w.position, "yaw": w.yaw,
                                   "gimbal_pitch": w.gimbal_pitch} for w in self.waypoints],
            transitions=[{"time_s": tr.time - self.t_start, "from": tr.source.value, "to": tr.target.value,
                          "reason": tr.reason} for tr in self.sm.transitions])
        return RunSummary(run="flight", status=self.status, detector=detector_name(self.detector),
                          method=s.method, flight_time_s=st.time - self.t_start,
                          perception=perception_record(self.runner, self.sensor_errors),
                          insulators=insulator_records(self.registry, photos), photos=self.photos.records,
                          sensors_health=self.sensors.health(), flight=details)

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
