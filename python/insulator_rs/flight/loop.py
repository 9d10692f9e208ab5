"""The flight loop: fly the single-flight inspection through the ports (see ``__init__``).

The paper's online algorithm: take off, fly the exploration path (minimum-snap trajectories,
safety-checked), and every ``detect_period`` s take a detection frame from the sensors, run
the detector, and hand the frame, its boxes and the LiDAR points of that instant (the scans
up to it and those after it, until the sensors have delivered the points of the whole pairing
window, see :meth:`FlightLoop._pair_pending`) to the perception pipeline (paired and deskewed
with the pose history the loop feeds every control tick); new insulators get inspection waypoints, which the state machine visits (a photo at
each, from the companion computer's camera through ``Sensors.photo``, gimbal aimed), then the
flight goes on, crosses over the top, finishes and lands.

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
from insulator_rs.ports.detector import BoxDetector
from insulator_rs.planning.segments import plan_segment
from insulator_rs.mission.config import Mission
from insulator_rs.planning.exploration import MIN_PASS_HEIGHT
from insulator_rs.geodesy import GeoPoint, enu_to_geodetic
from insulator_rs.ports.observer import InsulatorFound, PhaseChange, PhotoTaken
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.perception.pipeline import PerceptionPipeline
from insulator_rs.perception.photo_quality import photo_quality
from insulator_rs.planning.pmm import rest_to_rest_times
from insulator_rs.tracking.registry import Insulator, InsulatorRegistry
from insulator_rs.mission.state_machine import InspectionStateMachine, PlanItem, State
from insulator_rs.planning.waypoints import InspectionWaypoint, inspection_waypoints
from insulator_rs.poses import pose_from_yaw
from insulator_rs.report import FlightClock, ReportWriter
from insulator_rs.rig import SensorRig
from insulator_rs.ports.sensors import LidarScan, PoseStamped, Sensors
from insulator_rs.ports.vehicle import FlightMode, Vehicle, VehicleState, wrap_angle

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
# s past the pairing window a frame may wait for the scan that covers the window's end: a live
# 10 Hz LiDAR delivers a scan once its 100 ms window is closed (plus the driver's reorder grace
# and the link's latency); a frame still short after that goes to perception with what is there
PAIRING_WAIT = 0.3
# s: a scan ending this close before the window's end covers it (the last shots of a window
# may have no return; shots are 5 us apart; a source that knows its window says so:
# LidarScan.window_end)
PAIRING_SLACK = 0.01


@dataclass(frozen=True)
class FlightSettings:
    """How the loop flies: localization ``method``, buffering ``policy``, s between detection
    events, the flight-time limit (s), the min-snap ``time_allocation``, progress output."""

    method: str = "dbscan+ransac"
    policy: str = "immediate"
    detect_period: float = 1.0
    max_flight_time: float = 1800.0
    time_allocation: str = "pmm"
    quiet: bool = False


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
                 overwrite: bool = False, recorder: Any = None, photo_camera: Any = None,
                 observer: Any = None) -> None:
        self.observer = observer  # a ports.observer.FlightObserver (the GCS's view) or None
        self.mission = mission
        self.vehicle = vehicle
        self.sensors = sensors
        self.detector = detector
        self.rig = rig
        self.settings = settings
        self.recorder = recorder  # insulator_rs.recording.writer.McapRecorder (--record) or None
        self.geom = MissionGeometry.from_mission(mission)
        lim = mission.vehicle
        self.v_max, self.a_max = lim.v_max(), lim.a_max()
        self.failsafe: VehicleFailsafe | None = None  # the failsafe that stopped the mission
        self.perception = PerceptionPipeline(rig.camera, rig.T_b_c, rig.T_b_l, method=settings.method,
                                             insulator_length=mission.inspection.insulator_length)
        self.registry = InsulatorRegistry(self.geom.line, mission.inspection.registry_gate,
                                          mission.inspection.confirmations)
        # the photos' intrinsics (the rig camera's unless the sensors deliver another resolution)
        # frame the insulator from the waypoints and give the planned GSD
        self.photo_model = rig.camera if photo_camera is None else photo_camera
        self.fov = 2 * math.atan((self.photo_model.height / 2) / self.photo_model.fy)
        self.sm = InspectionStateMachine(self.geom.path, self.registry, self._waypoints,
                                         policy=settings.policy, cost=self._cost)
        tower = mission.tower
        self.report = ReportWriter(out, origin=GeoPoint(tower.lat, tower.lon, tower.alt), overwrite=overwrite)
        self.clock = FlightClock(self.vehicle.state().time)  # UTC of vehicle stamps; re-anchored at take-off
        self.out = out
        self.photos: list[dict[str, Any]] = []
        self.photo_camera: Any = None  # intrinsics of the photos taken (the sensors say)
        self.waypoints: list[InspectionWaypoint] = []
        self.status = "running"
        self.abort_reason: str | None = None
        self.t_start = 0.0
        self.events = 0
        self.localizations = 0
        self.sensor_errors = 0
        self._airborne = False
        self._pending: list[tuple[Any, np.ndarray]] = []  # detection frames and their boxes, oldest first
        self._scan_horizon = -math.inf  # vehicle time of the newest LiDAR point handed to perception
        self.pairing_short = 0  # frames handed over before the scans covered their whole window
        self._printed_transitions = 0
        self._next_detect = 0.0
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
        if not self.settings.quiet:
            print(text, flush=True)

    def now(self) -> float:
        return self.vehicle.state().time - self.t_start

    def _print_transitions(self) -> None:
        for tr in self.sm.transitions[self._printed_transitions:]:
            self.say(f"[{tr.time - self.t_start if tr.time >= self.t_start else tr.time:7.1f} s] "
                     f"{tr.source.value} -> {tr.target.value}: {tr.reason}")
            t_tr = tr.time - self.t_start if tr.time >= self.t_start else tr.time
            self._notify("phase", PhaseChange(t_tr, tr.source.value, tr.target.value, tr.reason))
            if tr.target == State.ABORT:
                self._notify("aborted", t_tr, tr.reason)
        self._printed_transitions = len(self.sm.transitions)

    def _notify(self, event: str, *args: Any) -> None:
        """Tell the observer (if any); a watcher's failure never stops the flight."""
        if self.observer is not None:
            try:
                getattr(self.observer, event)(*args)
            except Exception as exc:  # noqa: BLE001
                self.say(f"observer {event}: {exc}")

    def _sensor_error(self, exc: SensorError) -> None:
        self.sensor_errors += 1
        if self.sensor_errors <= 3 or self.sensor_errors % 50 == 0:
            self.say(f"[{self.now():7.1f} s] sensor error ({self.sensor_errors} so far): {exc}")

    # -- sensing -------------------------------------------------------------------------
    def detection_event(self, st: VehicleState) -> None:
        """Take a detection frame and run the detector; a frame with boxes waits for the LiDAR
        points of its instant (see :meth:`_pair_pending`)."""
        self.events += 1
        try:
            frame = self.sensors.detection_frame(st.time)
            if frame is None:
                return
            boxes = np.asarray(self.detector(frame.image), dtype=np.float64)
            # the recorder keeps the raw stream: every frame and its scan, boxes or not
            scan = self.sensors.lidar_scan(st.time) if len(boxes) or self.recorder is not None else None
        except SensorError as exc:
            self._sensor_error(exc)
            return
        scan = self._take_scan(scan, frame.T_b_c)
        if self.recorder is not None:
            self.recorder.frame(frame, scan.T_b_l if scan is not None else self.rig.T_b_l)
        if len(boxes) == 0:
            return
        self._pending.append((frame, boxes))

    def _take_scan(self, scan: Any, T_b_c: np.ndarray) -> Any:
        """Hand perception (and the recorder) the points of ``scan`` it does not have yet: a live
        source returns the same newest scan until the next is complete, and the simulator's
        scans may overlap; None when nothing in it is new."""
        if scan is None or not scan.covered_until > self._scan_horizon:  # nan (no point, no window): nothing
            return None
        if scan.time_start <= self._scan_horizon:
            new = np.asarray(scan.times) > self._scan_horizon
            scan = LidarScan(np.asarray(scan.points_l)[new], np.asarray(scan.times)[new], scan.T_b_l,
                             None if scan.intensity is None else np.asarray(scan.intensity)[new],
                             window_end=scan.window_end)
        self._scan_horizon = scan.covered_until
        self.perception.add_scan(scan)
        if self.recorder is not None:
            self.recorder.scan(scan, T_b_c)
        return scan

    def _pair_pending(self, st: VehicleState) -> None:
        """Pair the pending frames with the LiDAR points of both sides of their instant (+- the
        pairing window) and tell the state machine of each localization.

        Driven by the data: once the window past a frame is over, the newest scan is asked for
        every control tick and its new points go to perception, until a scan reaches the
        window's end (a live 10 Hz driver delivers the scan covering it up to a frame period
        and its reorder grace later; the simulator renders it at once). A frame still short
        ``PAIRING_WAIT`` s after its window goes with what is there, counted in
        ``pairing_short`` (a LiDAR that stopped delivering costs the pairing, never the flight)."""
        window = self.perception.pairing_window
        if not self._pending or st.time < self._pending[0][0].time + window - 1e-9:
            return
        try:
            self._take_scan(self.sensors.lidar_scan(st.time), self._pending[0][0].T_b_c)
        except SensorError as exc:
            self._sensor_error(exc)
        while self._pending:
            frame, boxes = self._pending[0]
            due = frame.time + window
            if st.time < due - 1e-9:
                break
            if self._scan_horizon < due - PAIRING_SLACK:
                if st.time < due + PAIRING_WAIT:
                    break
                self.pairing_short += 1
            self._pending.pop(0)
            self._localize(frame, boxes, st)

    def _localize(self, frame: Any, boxes: np.ndarray, st: VehicleState) -> None:
        for loc in self.perception.process(frame, boxes):
            self.localizations += 1
            outcome = self.sm.localized(loc.center, loc.axis, st.position, st.time)
            if outcome in ("new", "deferred"):
                ins, _ = self.registry.nearest(loc.center)
                self.say(f"[{self.now():7.1f} s] insulator {ins.id if ins else '?'} localized at "
                         f"{np.round(loc.center, 2).tolist()} ({loc.n_points} points) -> {outcome}")
                if ins is not None:
                    geo = enu_to_geodetic(ins.center, self.report.origin)[0]
                    self._notify("insulator_found", InsulatorFound(self.now(), ins.id, ins.center,
                                                                   tuple(float(g) for g in geo), outcome))
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
        pose = PoseStamped(st.time, pose_from_yaw(st.position, st.yaw))
        self.perception.add_pose(pose)
        if self.recorder is not None:
            self.recorder.pose(pose, st.velocity)
        if self.sm.state not in (State.IDLE, State.FINISH, State.ABORT):
            self._pair_pending(st)
            if st.time >= self._next_detect:
                self._next_detect = st.time + self.settings.detect_period
                self.detection_event(st)
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
        seg = plan_segment(self.geom, st.position, st.velocity, items, v_max=self.v_max, a_max=self.a_max,
                           clearance=self.mission.inspection.crossing_clearance,
                           time_allocation=self.settings.time_allocation)
        traj = seg.trajectory
        if traj is None:
            return True
        k = 0
        t = 0.0
        t0 = st.time
        plan_ids = [id(it) for it in self.sm.plan]
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
                plan_ids = plan_ids[1:]  # what the plan is unless reaching it changed it
                if [id(it) for it in self.sm.plan] != plan_ids:
                    return False
            if [id(it) for it in self.sm.plan] != plan_ids:
                return False
        last = items[-1]
        if last.kind == "inspect" and last.waypoint is not None:
            self.take_photo(last.waypoint)
        if self.sm.plan and self.sm.plan[0] is last:
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
        n = sum(1 for p in self.photos if p["insulator_id"] == wp.insulator_id)
        name = f"insulator_{wp.insulator_id:02d}_{n + 1}.jpg"
        record = self.report.save_photo(name, frame.image, time_utc=self.clock.at(frame.time),
                                        position_enu=st.position, yaw_enu=st.yaw, gimbal_pitch=wp.gimbal_pitch,
                                        description=f"insulator {wp.insulator_id}, photo {n + 1}")
        self.photo_camera = frame.camera
        # the photo's figures as the flight knows them: odometry pose, gimbal, the localized string
        ins = next((i for i in self.registry.insulators if i.id == wp.insulator_id), None)
        axis = ins.axis if ins is not None else np.array([0.0, 0.0, 1.0])
        T_c_w = np.linalg.inv(pose_from_yaw(st.position, st.yaw) @ frame.T_b_c)
        quality = photo_quality(frame.camera, T_c_w, wp.target, axis,
                                length=self.mission.inspection.insulator_length,
                                speed=float(np.linalg.norm(st.velocity)))
        self.photos.append({**record, "insulator_id": wp.insulator_id,
                            "time_s": frame.time - self.t_start, "position": st.position, "yaw": st.yaw,
                            "gimbal_pitch": wp.gimbal_pitch, "T_b_c": frame.T_b_c,
                            "quality": quality.as_dict(), "planned_gsd_mm": wp.planned_gsd_mm})
        self._notify("photo_taken", PhotoTaken(
            frame.time - self.t_start, self.clock.at(frame.time).timestamp(), wp.insulator_id, len(self.photos),
            record["file"], np.asarray(st.position, dtype=np.float64),
            (record["wgs84"]["lat"], record["wgs84"]["lon"], record["wgs84"]["alt"]), st.yaw, wp.gimbal_pitch))
        self.say(f"[{self.now():7.1f} s] photo {name}: GSD {quality.gsd_mm_px:.1f} mm/px, "
                 f"blur {quality.motion_blur_px:.2f} px")
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
            if head.kind == "land":
                above = PlanItem("land", head.position + np.array([0.0, 0.0, LAND_HEIGHT]), head.yaw, head.side)
                if head.side != self.sm.side and self.sm.deferred.get(head.side):
                    # Far-side finds are owed on the landing side, and the state machine releases
                    # them on arrival there: arrive above the landing point first, not on the ground.
                    self.sm.plan.insert(0, PlanItem("scan", above.position, head.yaw, head.side))
                    continue
                if self.fly_segment([above]):
                    self.land()
                    self.sm.reached(self.vehicle.state().time)
                continue
            items: list[PlanItem] = []
            for it in self.sm.plan:
                if it.kind == "land":
                    break
                items.append(it)
                if it.kind == "inspect":
                    break
            try:
                self.fly_segment(items)
            except PlanningError as exc:
                if items[-1].kind != "inspect":
                    raise  # the exploration itself cannot go on: abort (on_planning_failure)
                self.skip_inspection(items[-1], exc)

    # -- report --------------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        from insulator_rs.flight.record import flight_summary

        return flight_summary(self)

    def write_summary(self) -> None:
        self.report.write_summary(self.summary())

    def finish_report(self, reference: np.ndarray | None = None) -> dict[str, Any]:
        """Write the final summary and the plot. ``reference``: (K, 3) points drawn as ground
        truth, known only after the flight (the evaluation's), or None."""
        self.report.flush()
        summary = self.summary()
        self.report.write_summary(summary)
        wps = np.array([w.position for w in self.waypoints]) if self.waypoints else np.zeros((0, 3))
        found = np.array([i.center for i in self.registry.insulators]) if len(self.registry) else np.zeros((0, 3))
        truth = np.zeros((0, 3)) if reference is None else np.asarray(reference, dtype=np.float64).reshape(-1, 3)
        self.report.plot(self.geom.volumes, wps, found, truth,
                         f"{summary['status']}, flight {summary['flight_time_s']:.0f} s, "
                         f"{summary['insulators_inspected']}/{summary['insulators_found']} insulators inspected")
        self.report.close()
        return summary
