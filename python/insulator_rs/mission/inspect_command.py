"""``insulator-rs inspect``: a whole single-flight inspection in the built-in simulator.

The simulated world is a scene of :mod:`insulator_rs.sim` (tower A by default).
The vehicle is flown through the :class:`~insulator_rs.vehicle.Vehicle`
protocol, one of two implementations: ``--vehicle sim`` (default) the
in-process kinematic multirotor, ``--vehicle mavlink`` the MAVLink offboard
client, by default against the simulated PX4 it starts on loopback (real UDP),
or with ``--connection`` against a real PX4 or its SITL. The simulated sensors
render from the airframe's true pose (the simulator's, not the odometry);
against an outside autopilot there is no simulator to ask, so that needs
``--sim-sensors`` (a SITL setup: the sensors render the scene at the pose the
autopilot reports; real camera/LiDAR drivers are out of scope).

A failsafe of the vehicle (link lost, the pilot took over, battery, position
lost) aborts the mission: the report says why (status ``aborted: <reason>``)
and keeps everything found so far; once the pilot has taken over, nothing more
is sent to the vehicle. The run follows the paper's
online algorithm: take off, fly the exploration path (minimum-snap
trajectories, safety-checked), and on every detection event render the
detection camera, turn its ground-truth boxes into detections with the
detector stand-in (or, with ``--detector``, run a YOLO network such as the
shipped ``insulator-sim`` on its pixels), cast a LiDAR frame, cull and accumulate the points and
localize with ``ir.localize``; new insulators get inspection waypoints, which
the state machine visits (a photo from the simulated camera, gimbal aimed, at
each), then the flight goes on, crosses over the top, finishes and lands.

The report folder (see :mod:`.report`) is written as the flight goes; an
interruption (Ctrl-C) still leaves the summary, the photos taken and the plot.
"""

from __future__ import annotations

import argparse
import math
import sys
import time as wallclock
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

import insulator_rs as ir
from insulator_rs.detection.commands import open_detector
from insulator_rs.detection.detector import Detector
from insulator_rs.exceptions import ConfigError, VehicleError
from insulator_rs.mission import bounds
from insulator_rs.mission.config import Mission, load_mission
from insulator_rs.mission.exploration import MIN_PASS_HEIGHT
from insulator_rs.mission.geodesy import GeoPoint
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.minsnap import TIME_ALLOCATIONS, MinSnapTrajectory, plan_min_snap_safe
from insulator_rs.mission.perception import OnboardPerception
from insulator_rs.mission.photo_quality import photo_quality
from insulator_rs.mission.registry import Insulator, InsulatorRegistry
from insulator_rs.mission.state_machine import POLICIES, InspectionStateMachine, PlanItem, State
from insulator_rs.mission.two_flight import route
from insulator_rs.mission.waypoints import InspectionWaypoint, inspection_waypoints
from insulator_rs.report import FlightClock, ReportWriter, check_out_folder, parse_out_folder
from insulator_rs.sim.camera_render import Camera, Lighting, default_camera_model, default_T_b_c
from insulator_rs.sim.detector_standin import DetectorStandin
from insulator_rs.sim.kinematics import KinematicVehicle, MotionLimits, VehicleFailsafe
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.towers import Tower, load_tower
from insulator_rs.sensors import CameraFrame, LidarScan, PoseStamped
from insulator_rs.vehicle import Vehicle, VehicleState

MISSIONS_DIR = Path(__file__).resolve().parents[1] / "missions"
CONTROL_PERIOD = 0.05  # s: 20 Hz setpoint stream, as PX4 offboard wants
SAFETY_CHECK_DT = 0.05  # s: sampling of planned trajectories for the safety check
# m: a min-snap curve straying further than this from its straight path gets extra waypoints
# (keeps the flight near the planned path, away from the conductors beyond it).
MAX_PATH_DEVIATION = 2.0
PHOTO_YAW_TOLERANCE = math.radians(3.0)
PHOTO_SPEED_TOLERANCE = 0.2  # m/s
PHOTO_SETTLE_TIMEOUT = 8.0  # s
HOLD_TIMEOUT = 10.0  # s in HOLD before the mission aborts
STATUS_PERIOD = 15.0  # s of flight between progress lines
SUMMARY_PERIOD = 5.0  # s of flight between summary rewrites
DETECT_CONF = 0.25  # detection-event confidence threshold of a network (Ultralytics predict default)
LAND_HEIGHT = 2.0  # m above the take-off point where the landing starts
TAKEOFF_TIMEOUT = 60.0  # s of vehicle time for the climb to the first pass height
LAND_TIMEOUT = 120.0  # s of vehicle time for the descent
MAX_MAVLINK_TIME_SCALE = 4.0  # the client's timeouts and the 20 Hz stream hold up to this speed-up
# The vehicle's own limits get this much headroom over the planning limits so the
# position loop can track the trajectory.
LIMIT_HEADROOM = 1.5
# m: a localized insulator this close to a true one counts as having found it.
MATCH_DISTANCE = 1.5


def _T_w_b(position: np.ndarray, yaw: float) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = position
    return T


def _gimballed_T_b_c(pitch: float) -> np.ndarray:
    """The camera on a gimbal pitched by ``pitch`` rad (negative looks down) about the body y axis."""
    c, s = math.cos(-pitch), math.sin(-pitch)
    R = np.eye(4)
    R[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    return R @ default_T_b_c()


def _scaled_camera(model: ir.CameraModel, scale: float) -> ir.CameraModel:
    w, h = max(16, int(round(model.width * scale))), max(12, int(round(model.height * scale)))
    sx, sy = w / model.width, h / model.height
    return ir.CameraModel(model.fx * sx, model.fy * sy, (w - 1) / 2, (h - 1) / 2, w, h,
                          dist=[float(k) for k in model.dist])


def _angle_wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def kinematic_vehicle(mission: Mission, seed: int) -> KinematicVehicle:
    """The simulated airframe at the mission's take-off point, limits with headroom over the plan's."""
    geom = MissionGeometry.from_mission(mission)
    lim = mission.vehicle
    return KinematicVehicle(
        start_position=geom.takeoff, start_yaw=geom.path[0].yaw, seed=seed,
        limits=MotionLimits(max_horizontal_speed=lim.v_max_horizontal * LIMIT_HEADROOM,
                            max_vertical_speed=lim.v_max_vertical * LIMIT_HEADROOM,
                            max_horizontal_acceleration=lim.a_max_horizontal * LIMIT_HEADROOM,
                            max_vertical_acceleration=lim.a_max_vertical * LIMIT_HEADROOM))


def mavlink_vehicle(mission: Mission, seed: int, *, connection: str | None, time_scale: float,
                    signing_key: Path | None) -> Vehicle:
    """The MAVLink offboard client: to the simulated PX4 (started here on loopback, flying
    :func:`kinematic_vehicle`) when ``connection`` is None, else to that autopilot with W's
    origin put at the tower base."""
    from insulator_rs.mavlink import connect_vehicle
    from insulator_rs.sim.px4 import connect_simulated_px4

    tower = mission.tower
    if connection is None:
        sim_options = {"vehicle": kinematic_vehicle(mission, seed), "origin": (tower.lat, tower.lon, tower.alt)}
        vehicle = connect_simulated_px4(time_scale=time_scale, signing_key=signing_key, sim_options=sim_options)
    else:
        vehicle = connect_vehicle(connection, time_scale=time_scale, signing_key=signing_key)
    if connection is not None:
        try:
            vehicle.set_world_origin(tower.lat, tower.lon, tower.alt)
        except BaseException:
            vehicle.close()
            raise
    return vehicle


def load_detector(model: str | None) -> Detector | None:
    """The YOLO network for detection events (a shipped model name or an ONNX file); None keeps
    the stand-in. Raises ValueError naming ``--detector``."""
    if model is None:
        return None
    try:
        return open_detector(model, conf=DETECT_CONF)
    except ValueError as exc:  # ModelError included: missing, truncated or not a YOLO export
        raise ValueError(f"--detector: {exc}") from exc


class InspectionRun:
    """One simulated single-flight inspection (state, sensors, report)."""

    def __init__(self, mission: Mission, tower: Tower, out: Path, *, method: str, policy: str,
                 seed: int, detect_period: float, detect_scale: float, photo_scale: float,
                 max_flight_time: float, quiet: bool = False, vehicle: Vehicle | None = None,
                 detector: Detector | None = None, time_allocation: str = "pmm", overwrite: bool = False,
                 recorder: Any = None) -> None:
        self.mission = mission
        self.tower = tower
        self.geom = MissionGeometry.from_mission(mission)
        self.quiet = quiet
        self.method = method
        self.policy = policy
        self.detect_period = detect_period
        self.max_flight_time = max_flight_time
        lim = mission.vehicle
        self.v_max, self.a_max = lim.v_max(), lim.a_max()
        self.vehicle: Vehicle = vehicle if vehicle is not None else kinematic_vehicle(mission, seed)
        self.failsafe: VehicleFailsafe | None = None  # the failsafe that stopped the mission
        base = default_camera_model()
        self.det_camera = Camera(_scaled_camera(base, detect_scale))
        self.photo_model = _scaled_camera(base, photo_scale)
        self.lidar = Mid360()
        self.standin = DetectorStandin(seed=seed)
        self.network = detector  # None: the stand-in turns ground-truth boxes into detections
        self.time_allocation = time_allocation
        self.recorder = recorder  # insulator_rs.recording.writer.McapRecorder (--record) or None
        self.perception = OnboardPerception(self.det_camera.model, self.det_camera.T_b_c,
                                            self.lidar.T_b_l, method=method,
                                            insulator_length=mission.inspection.insulator_length)
        self.registry = InsulatorRegistry(self.geom.line, mission.inspection.registry_gate,
                                          mission.inspection.confirmations)
        self.fov = 2 * math.atan((self.photo_model.height / 2) / self.photo_model.fy)
        self.sm = InspectionStateMachine(self.geom.path, self.registry, self._waypoints, policy=policy,
                                         cost=self._cost)
        self.report = ReportWriter(out, origin=GeoPoint(mission.tower.lat, mission.tower.lon, mission.tower.alt),
                                   overwrite=overwrite)
        self.clock = FlightClock(self.vehicle.state().time)  # re-anchored at take-off
        self.out = out
        self.seed = seed
        self.photos: list[dict[str, Any]] = []
        self.waypoints: list[InspectionWaypoint] = []
        self.status = "running"
        self.abort_reason: str | None = None
        self.t_start = 0.0
        self.events = 0
        self.localizations = 0
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
        from insulator_rs.mission.pmm import rest_to_rest_times

        return float(rest_to_rest_times(a, b, self.v_max, self.a_max))

    def say(self, text: str) -> None:
        if not self.quiet:
            print(text, flush=True)

    def now(self) -> float:
        return self.vehicle.state().time - self.t_start

    def _print_transitions(self) -> None:
        for tr in self.sm.transitions[self._printed_transitions:]:
            self.say(f"[{tr.time - self.t_start if tr.time >= self.t_start else tr.time:7.1f} s] "
                     f"{tr.source.value} -> {tr.target.value}: {tr.reason}")
        self._printed_transitions = len(self.sm.transitions)

    # -- sensing -------------------------------------------------------------------------
    def _sensor_T_w_b(self, st: VehicleState) -> np.ndarray:
        """Where the simulated sensors are (T_w_b): the simulator's true airframe pose, not the
        odometry the mission flies on. Against an outside autopilot (``--sim-sensors``) the
        reported pose is all there is."""
        simulator = getattr(self.vehicle, "simulator", None)
        if simulator is not None:
            position, yaw, _ = simulator.true_pose()
            return _T_w_b(position, yaw)
        if isinstance(self.vehicle, KinematicVehicle):
            return _T_w_b(self.vehicle.model.position, self.vehicle.model.yaw)
        return _T_w_b(st.position, st.yaw)

    def detection_event(self, st: VehicleState) -> None:
        """Render the detection camera, detect, cast a LiDAR frame, localize, tell the state machine."""
        self.events += 1
        T_w_b = _T_w_b(st.position, st.yaw)  # the estimate: what onboard perception knows
        T_true = self._sensor_T_w_b(st)
        frame = self.det_camera.render(self.tower.mesh, T_true, lighting=Lighting(shadows=False),
                                       seed=self.seed + self.events, time=st.time)
        if self.recorder is not None:  # the raw stream: every frame and its scan, boxes or not
            scan = self.lidar.scan(self.tower.mesh, (T_true, T_true), st.time, seed=self.seed + self.events)
            # This simulator casts a frame from one pose (T_true at st.time): every point is as if
            # measured then, so that is the time recorded (a replay's deskew is then the identity).
            snapshot = np.full(len(scan.timestamps), st.time)
            self.recorder.scan(LidarScan(scan.points_l, snapshot, self.lidar.T_b_l), self.det_camera.T_b_c)
            self.recorder.frame(CameraFrame(st.time, np.ascontiguousarray(frame.rgb[:, :, ::-1]),
                                            self.det_camera.model, self.det_camera.T_b_c), self.lidar.T_b_l)
        if not frame.boxes:
            return
        boxes = self._detect(frame)
        if len(boxes) == 0:
            return
        scan = self.lidar.scan(self.tower.mesh, (T_true, T_true), st.time, seed=self.seed + self.events)
        for loc in self.perception.event(boxes, scan.points_l, T_w_b):
            self.localizations += 1
            outcome = self.sm.localized(loc.center, loc.axis, st.position, st.time)
            if outcome in ("new", "deferred"):
                ins, _ = self.registry.nearest(loc.center)
                err = self._gt_match(ins)[1] if ins is not None else float("nan")
                self.say(f"[{self.now():7.1f} s] insulator {ins.id if ins else '?'} localized at "
                         f"{np.round(loc.center, 2).tolist()} ({loc.n_points} points, error "
                         f"{err:.2f} m vs ground truth) -> {outcome}")
                self.write_summary()

    def _detect(self, frame: Any) -> np.ndarray:
        """Detection boxes (M, 4) in the detection image: the network's on the rendered pixels,
        or the stand-in's from the ground-truth boxes."""
        if self.network is not None:
            return self.network(np.ascontiguousarray(frame.rgb[:, :, ::-1])).boxes
        ids = list(frame.boxes)
        det = self.standin.detect(np.array([frame.boxes[i] for i in ids]),
                                  (self.det_camera.model.width, self.det_camera.model.height), ids)
        return det.boxes

    def _gt_match(self, ins: Insulator) -> tuple[int | None, float, float]:
        """(GT instance id, centre error m, axis error deg) of the nearest true insulator."""
        if not self.tower.insulators:
            return None, float("nan"), float("nan")
        d = [float(np.linalg.norm(t.center - ins.center)) for t in self.tower.insulators]
        k = int(np.argmin(d))
        gt = self.tower.insulators[k]
        ang = math.degrees(math.acos(min(1.0, abs(float(gt.axis @ ins.axis)))))
        return gt.instance_id, d[k], ang

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
        if self.recorder is not None:
            self.recorder.pose(PoseStamped(st.time, _T_w_b(st.position, st.yaw)), st.velocity)
        if self.sm.state not in (State.IDLE, State.FINISH, State.ABORT) and st.time >= self._next_detect:
            self._next_detect = st.time + self.detect_period
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
        if t > self.max_flight_time and self.sm.state != State.ABORT:
            self.abort_reason = f"flight time limit of {self.max_flight_time:.0f} s"
            self.sm.abort(f"flight time limit of {self.max_flight_time:.0f} s", st.time)
        self._print_transitions()
        return st

    def on_failsafe(self, exc: VehicleFailsafe) -> None:
        """The vehicle's failsafe fired: the autopilot now flies it (hold, land, return, or the
        pilot has the sticks), so the mission aborts and stops commanding."""
        self.failsafe = exc
        self.abort_reason = f"vehicle failsafe: {exc.reason} ({exc.action})"
        self.sm.abort(self.abort_reason, self.vehicle.state().time)
        self.write_summary()

    def polyline(self, start: np.ndarray, items: list[PlanItem]) -> np.ndarray:
        pts = [start]
        clearance = self.mission.inspection.crossing_clearance
        for it in items:
            r = route(self.geom.line, self.geom.volumes, pts[-1], it.position, clearance)
            pts.extend(r[1:])
        keep = [pts[0]]
        for p in pts[1:]:
            if np.linalg.norm(p - keep[-1]) > 1e-3:
                keep.append(p)
        return np.array(keep)

    def fly_segment(self, items: list[PlanItem]) -> bool:
        """Fly a min-snap trajectory through ``items`` (the plan's head); report each item reached
        to the state machine. Returns False if the plan changed on the way (re-plan)."""
        st = self.vehicle.state()
        pts = self.polyline(st.position, items)
        if len(pts) < 2:
            return True
        v0 = np.clip(st.velocity, -self.v_max, self.v_max)
        traj: MinSnapTrajectory = plan_min_snap_safe(pts, self.v_max, self.a_max, self.geom.volumes,
                                                     dt=SAFETY_CHECK_DT, v_start=v0,
                                                     max_deviation=MAX_PATH_DEVIATION,
                                                     time_allocation=self.time_allocation)
        # the time at which the trajectory passes each item (items are among its waypoints)
        knots = np.concatenate([[0.0], np.cumsum(traj.durations)])
        item_times = []
        j = 0
        for it in items:
            while j < len(traj.waypoints) and np.linalg.norm(traj.waypoints[j] - it.position) > 1e-6:
                j += 1
            item_times.append(knots[min(j, len(knots) - 1)])
        k = 0
        t = 0.0
        t0 = st.time
        plan_ids = [id(it) for it in self.sm.plan]
        while t < traj.total_time - 1e-9:
            # by vehicle time, not ticks: through MAVLink a period ends on a telemetry sample, and
            # rendering takes wall time while the vehicle flies on
            t = min(max(st.time - t0, t) + CONTROL_PERIOD, traj.total_time)
            pos = traj.evaluate(np.array([t]), 0)[0]
            vel = traj.evaluate(np.array([t]), 1)[0]
            st = self.tick(pos, vel, items[min(k, len(items) - 1)].yaw)
            if self.sm.state in (State.HOLD, State.ABORT) or not self._healthy():
                return False
            while k < len(items) - 1 and t >= item_times[k] - 1e-9:
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
        if st.healthy and st.mode == "OFFBOARD":
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
            if st.healthy and st.mode != "OFFBOARD":
                try:
                    self.vehicle.start_offboard()
                except Exception as exc:  # the autopilot refused: keep holding
                    self.say(f"[{self.now():7.1f} s] offboard refused: {exc}")
            if st.healthy and st.mode == "OFFBOARD":
                self.sm.resume(st.time)
            elif st.time - t0 > HOLD_TIMEOUT:
                self.abort_reason = f"fault did not clear within {HOLD_TIMEOUT:.0f} s"
                self.sm.abort(self.abort_reason, st.time)

    def take_photo(self, wp: InspectionWaypoint) -> None:
        """Settle on the waypoint with the camera aimed, trigger, render and save the photo."""
        t0 = self.vehicle.state().time
        while True:
            st = self.tick(wp.position, None, wp.yaw)
            if self.sm.state == State.ABORT:
                return
            settled = (abs(_angle_wrap(st.yaw - wp.yaw)) < PHOTO_YAW_TOLERANCE
                       and np.linalg.norm(st.velocity) < PHOTO_SPEED_TOLERANCE)
            if settled or st.time - t0 > PHOTO_SETTLE_TIMEOUT:
                break
        cam = Camera(self.photo_model, _gimballed_T_b_c(wp.gimbal_pitch))
        frame = cam.render(self.tower.mesh, self._sensor_T_w_b(st), seed=self.seed + len(self.photos),
                           time=st.time)
        n = sum(1 for p in self.photos if p["insulator_id"] == wp.insulator_id)
        name = f"insulator_{wp.insulator_id:02d}_{n + 1}.jpg"
        record = self.report.save_photo(name, np.ascontiguousarray(frame.rgb[:, :, ::-1]),
                                        time_utc=self.clock.at(st.time), position_enu=st.position,
                                        yaw_enu=st.yaw, gimbal_pitch=wp.gimbal_pitch,
                                        description=f"insulator {wp.insulator_id}, photo {n + 1}")
        gt = int(np.argmin([np.linalg.norm(t.center - wp.target) for t in self.tower.insulators]))
        gt_id = self.tower.insulators[gt].instance_id
        box = frame.boxes.get(gt_id)
        w, h = self.photo_model.width, self.photo_model.height
        whole = box is not None and box[0] > 0 and box[1] > 0 and box[2] < w and box[3] < h
        # The photo's figures as the flight knows them: odometry pose, gimbal, the localized string.
        ins = next((i for i in self.registry.insulators if i.id == wp.insulator_id), None)
        axis = ins.axis if ins is not None else np.array([0.0, 0.0, 1.0])
        T_c_w = np.linalg.inv(_T_w_b(st.position, st.yaw) @ _gimballed_T_b_c(wp.gimbal_pitch))
        quality = photo_quality(self.photo_model, T_c_w, wp.target, axis,
                                length=self.mission.inspection.insulator_length,
                                speed=float(np.linalg.norm(st.velocity)))
        self.photos.append({**record, "insulator_id": wp.insulator_id,
                            "time_s": st.time - self.t_start, "position": st.position, "yaw": st.yaw,
                            "gimbal_pitch": wp.gimbal_pitch, "gt_instance_id": gt_id,
                            "insulator_visible": box is not None, "insulator_whole_in_frame": whole,
                            "quality": quality.as_dict(), "planned_gsd_mm": wp.planned_gsd_mm})
        self.say(f"[{self.now():7.1f} s] photo {name}: insulator {'whole' if whole else 'partly' if box else 'not'}"
                 f" in frame, GSD {quality.gsd_mm_px:.1f} mm/px, blur {quality.motion_blur_px:.2f} px")
        self.write_summary()

    def takeoff(self) -> None:
        st = self.vehicle.state()
        target = st.position + np.array([0.0, 0.0, MIN_PASS_HEIGHT])
        self.vehicle.send_setpoint(target, None, st.yaw)
        self.vehicle.arm()
        self.t_start = st.time
        self.clock = FlightClock(st.time)
        self.vehicle.takeoff(MIN_PASS_HEIGHT)
        yaw = st.yaw
        while st.time - self.t_start < TAKEOFF_TIMEOUT:
            st = self.tick(target, None, yaw)
            if self.sm.state == State.ABORT:
                return  # a failsafe or the flight time limit during the climb
            if st.mode != "TAKEOFF" and abs(st.position[2] - target[2]) < 0.4:
                break
        self.vehicle.start_offboard()
        self.sm.start(self.vehicle.state().time)
        self._print_transitions()

    def on_command_failure(self, exc: VehicleError) -> None:
        """The vehicle refused a command or never answered it (arm, take-off, a mode switch):
        reported, and the mission aborts (then lands, see :meth:`land`)."""
        self.abort_reason = f"vehicle command failed: {exc}"
        self.say(f"[{self.now():7.1f} s] {self.abort_reason}")
        if self.sm.state != State.ABORT:
            self.sm.abort(self.abort_reason, self.vehicle.state().time)
        self.write_summary()

    def land(self) -> None:
        if self.failsafe is not None:
            return  # the autopilot flies its failsafe (or the pilot flies): command nothing
        st = self.vehicle.state()
        if st.landed and not st.armed:
            return  # never took off (e.g. arming was refused)
        try:
            self.vehicle.land()
        except VehicleFailsafe as exc:
            self.on_failsafe(exc)
            return
        except VehicleError as exc:  # refused or unanswered: PX4's own failsafes keep the vehicle
            self.abort_reason = f"{self.abort_reason or 'mission aborted'}; landing command failed: {exc}"
            self.say(f"[{self.now():7.1f} s] landing command failed: {exc}")
            return
        st = self.vehicle.state()
        t0 = st.time
        while not st.landed and st.time - t0 < LAND_TIMEOUT:
            try:
                st = self.vehicle.advance(CONTROL_PERIOD)
            except VehicleFailsafe as exc:
                self.on_failsafe(exc)
                return
            self.report.log_pose(st.time - self.t_start, st.position, st.yaw, self.sm.state.value)

    def fly(self) -> None:
        self.say(f"inspecting {self.tower.spec.name} ({len(self.tower.insulators)} insulators in the scene) "
                 f"with mission {self.mission.source}; report -> {self.out}"
                 + (f" (written in {self.report.layout.path}, replaces the old report when the run ends)"
                    if self.report.layout.staged else ""))
        for left in self.report.layout.leftovers():
            self.say(f"note: {left} is what an earlier run killed mid-way left (kept; delete it when done)")
        try:
            self.takeoff()
            self._fly_plan()
        except VehicleFailsafe as exc:  # raised by a command rather than during a tick
            self.on_failsafe(exc)
        except VehicleError as exc:
            self.on_command_failure(exc)
        if self.sm.state == State.ABORT:
            self.land()
            self.status = f"aborted: {self.abort_reason or 'mission aborted'}"
        else:
            self.status = "finished"
        self._print_transitions()

    def _fly_plan(self) -> None:
        """Fly the state machine's plan until it is done (finished or aborted)."""
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
            self.fly_segment(items)

    # -- report --------------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        st = self.vehicle.state()
        insulators: list[dict[str, Any]] = []
        errors: list[float] = []
        for ins in self.registry.insulators:
            gt_id, err, ang = self._gt_match(ins)
            insulators.append({
                "id": ins.id, "center": ins.center, "axis": ins.axis, "observations": ins.observations,
                "side": ins.side, "inspected": ins.inspected,
                "photos": [p["file"] for p in self.photos if p["insulator_id"] == ins.id],
                "gt_instance_id": gt_id, "error_m": err, "axis_error_deg": ang})
            if gt_id is not None:
                errors.append(err)
        found_gt = {r["gt_instance_id"] for r in insulators if r["error_m"] < MATCH_DISTANCE}
        traj = np.array([p[1:] for p in self.report.trajectory]) if self.report.trajectory else np.zeros((0, 3))
        return {
            "status": self.status,
            "scene": self.tower.spec.name,
            "mission": self.mission.source,
            "method": self.method,
            "time_allocation": self.time_allocation,
            "detector": self.network.path.stem if self.network is not None else "stand-in (ground-truth boxes)",
            "policy": self.policy,
            "state": self.sm.state.value,
            "vehicle": type(self.vehicle).__name__,
            "failsafe": None if self.failsafe is None else {"reason": self.failsafe.reason,
                                                            "action": self.failsafe.action},
            "flight_time_s": st.time - self.t_start,
            "distance_m": float(np.sum(np.linalg.norm(np.diff(traj, axis=0), axis=1))) if len(traj) > 1 else 0.0,
            "detection_events": self.events,
            "localizations": self.localizations,
            "refused_not_insulator": dict(self.perception.not_insulator),
            "insulators_found": len(insulators),
            "insulators_in_scene": len(self.tower.insulators),
            "insulators_matched": len(found_gt),
            "insulators_inspected": sum(1 for r in insulators if r["inspected"]),
            "mean_error_m": float(np.mean(errors)) if errors else None,
            "insulators": insulators,
            "photos": self.photos,
            "inspection_waypoints": [{"insulator_id": w.insulator_id, "position": w.position, "yaw": w.yaw,
                                      "gimbal_pitch": w.gimbal_pitch} for w in self.waypoints],
            "ground_truth": [{"instance_id": t.instance_id, "center": t.center, "axis": t.axis, "side": t.side}
                             for t in self.tower.insulators],
            "transitions": [{"time_s": tr.time - self.t_start, "from": tr.source.value, "to": tr.target.value,
                             "reason": tr.reason} for tr in self.sm.transitions],
        }

    def write_summary(self) -> None:
        self.report.write_summary(self.summary())

    def finish_report(self) -> dict[str, Any]:
        self.report.flush()
        summary = self.summary()
        self.report.write_summary(summary)
        wps = np.array([w.position for w in self.waypoints]) if self.waypoints else np.zeros((0, 3))
        found = np.array([i.center for i in self.registry.insulators]) if len(self.registry) else np.zeros((0, 3))
        truth = np.array([t.center for t in self.tower.insulators]) if self.tower.insulators else np.zeros((0, 3))
        self.report.plot(self.geom.volumes, wps, found, truth,
                         f"{self.tower.spec.name}: {summary['status']}, flight {summary['flight_time_s']:.0f} s, "
                         f"{summary['insulators_inspected']}/{summary['insulators_in_scene']} insulators inspected")
        self.report.close()
        return summary


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("inspect", help="fly a whole single-flight inspection in the built-in simulator",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default="tower_a",
                   help="built-in scene name (tower_a, tower_b) or a scene TOML file (default tower_a)")
    p.add_argument("--mission", type=Path, default=None,
                   help="mission file (TOML/YAML); default: the example mission of a built-in scene")
    p.add_argument("--out", type=parse_out_folder, default=Path("inspection_report"),
                   help="report folder (created; one that holds files is refused unless --overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the report in --out: the new run is written beside it and swapped in "
                        "when it ends, so the old report stays whole until then")
    p.add_argument("--method", default="dbscan+ransac",
                   choices=("dbscan", "ransac", "dbscan+ransac", "dbscan+pca", "bounded"),
                   help="localization: the paper's four, or bounded (the LiDAR line, its ends from the boxes)")
    p.add_argument("--policy", default="immediate", choices=POLICIES,
                   help="buffering: visit at once (paper) or insert where cheapest")
    p.add_argument("--seed", type=bounds.option("--seed"), default=0)
    p.add_argument("--detector", default=None,
                   help="a shipped model name (e.g. insulator-sim) or an ONNX file: run that YOLO network "
                        "on the rendered detection images (default: the detector stand-in on the "
                        "ground-truth boxes)")
    p.add_argument("--time-allocation", default="pmm", choices=TIME_ALLOCATIONS,
                   help="min-snap segment times: pmm (point-mass proportions, default) or snap "
                        "(redistributed to minimise snap, Richter et al.; slower to plan)")
    p.add_argument("--detect-period", type=bounds.option("--detect-period"), default=1.0, help="s between detection events (default 1)")
    p.add_argument("--detect-scale", type=bounds.option("--detect-scale"), default=0.25,
                   help="detection camera resolution as a fraction of the 1280x960 camera (default 0.25)")
    p.add_argument("--photo-scale", type=bounds.option("--photo-scale"), default=1.0,
                   help="inspection photo resolution as a fraction of 1280x960 (default 1)")
    p.add_argument("--v-max", type=bounds.option("--v-max"), default=None, help="override the mission's velocity limits (m/s)")
    p.add_argument("--a-max", type=bounds.option("--a-max"), default=None, help="override the mission's acceleration limits (m/s^2)")
    p.add_argument("--max-flight-time", type=bounds.option("--max-flight-time"), default=1800.0, help="abort after this many s of flight")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--record", type=Path, default=None,
                   help="record the raw sensor stream (LiDAR, detection camera, pose, extrinsics) as ROS 2 "
                        "messages in this MCAP file (replay it with `insulator-rs replay`)")
    p.add_argument("--vehicle", choices=("sim", "mavlink"), default=None,
                   help="sim: the in-process kinematic vehicle (default); mavlink: the MAVLink offboard "
                        "client, to the simulated PX4 it starts on loopback unless --connection is given")
    p.add_argument("--connection", default=None,
                   help="MAVLink connection of a real PX4 or its SITL, e.g. udpin:0.0.0.0:14540 or "
                        "/dev/ttyTHS1:921600 (implies --vehicle mavlink; needs --sim-sensors)")
    p.add_argument("--sim-sensors", action="store_true",
                   help="with --connection: the camera and LiDAR are simulated from the scene at the pose the "
                        "autopilot reports (a SITL setup); real camera/LiDAR drivers are not supported")
    p.add_argument("--time-scale", type=float, default=None,
                   help=f"MAVLink only: speed-up of the simulated PX4 (default 1, at most "
                        f"{MAX_MAVLINK_TIME_SCALE:g}; give the SITL's speed factor with --connection)")
    p.add_argument("--signing-key", type=Path, default=None,
                   help="MAVLink only: file with the 32-byte MAVLink 2 signing key (both ends sign)")
    p.set_defaults(func=run)


def _vehicle_kind(args: argparse.Namespace) -> str:
    """Check the vehicle options together; "sim" or "mavlink"."""
    kind = args.vehicle or ("mavlink" if args.connection is not None else "sim")
    if kind == "sim":
        for flag, value in (("--connection", args.connection), ("--time-scale", args.time_scale),
                            ("--signing-key", args.signing_key)):
            if value is not None:
                raise ValueError(f"{flag}: only applies to --vehicle mavlink")
        if args.sim_sensors:
            raise ValueError("--sim-sensors: only applies with --connection")
        return kind
    if args.time_scale is not None and not (math.isfinite(args.time_scale)
                                            and 0 < args.time_scale <= MAX_MAVLINK_TIME_SCALE):
        raise ValueError(f"--time-scale: must be in (0, {MAX_MAVLINK_TIME_SCALE:g}], got {args.time_scale}")
    if args.connection is not None:
        if not args.connection.strip():
            raise ValueError("--connection: must not be empty")
        if not args.sim_sensors:
            raise ValueError("--connection: the camera and LiDAR of a real vehicle are not supported (no drivers); "
                             "add --sim-sensors to fly a SITL autopilot with the sensors simulated from the scene")
    elif args.sim_sensors:
        raise ValueError("--sim-sensors: only applies with --connection (the built-in simulated PX4 "
                         "always has simulated sensors)")
    if args.signing_key is not None and not args.signing_key.is_file():
        raise ValueError(f"--signing-key: no such file: {args.signing_key}")
    return kind


def run(args: argparse.Namespace) -> int:
    # The numeric options were checked by argparse against insulator_rs.mission.bounds.
    try:
        mavlink = _vehicle_kind(args) == "mavlink"
        tower = load_tower(args.scene)
        mission_path = args.mission
        if mission_path is None:
            mission_path = MISSIONS_DIR / f"{tower.spec.name}.toml"
            if not mission_path.is_file():
                raise ConfigError(f"--mission: scene {tower.spec.name!r} has no example mission; give one")
        mission = load_mission(mission_path)
        MissionGeometry.from_mission(mission)  # path and volumes: refuse before anything flies
        check_out_folder(args.out, overwrite=args.overwrite)
        detector = load_detector(args.detector)
    except (ConfigError, ValueError) as exc:
        print(f"insulator-rs inspect: error: {exc}", file=sys.stderr)
        return 2
    if args.v_max is not None or args.a_max is not None:
        v = mission.vehicle
        mission = replace(mission, vehicle=replace(
            v, v_max_horizontal=args.v_max or v.v_max_horizontal, v_max_vertical=args.v_max or v.v_max_vertical,
            a_max_horizontal=args.a_max or v.a_max_horizontal, a_max_vertical=args.a_max or v.a_max_vertical))
    if mavlink:
        try:
            vehicle = mavlink_vehicle(mission, args.seed, connection=args.connection,
                                      time_scale=args.time_scale or 1.0, signing_key=args.signing_key)
        except (VehicleError, ConfigError) as exc:  # no autopilot answering, a bad key file
            print(f"insulator-rs inspect: error: MAVLink vehicle: {exc}", file=sys.stderr)
            return 2
    else:
        vehicle = kinematic_vehicle(mission, args.seed)
    recorder = None
    if args.record is not None:
        from insulator_rs.recording.metadata import RECORD_NAME, FlightMetadata
        from insulator_rs.recording.writer import McapRecorder

        recorder = McapRecorder(args.record)
        recorder.metadata(RECORD_NAME, FlightMetadata(
            mission_text=Path(mission_path).read_text(encoding="utf-8"), mission_suffix=Path(mission_path).suffix,
            mission_source=str(mission_path),
            scene=str(Path(args.scene).resolve()) if Path(args.scene).is_file() else args.scene).as_record())
    try:
        runner = InspectionRun(mission, tower, args.out, method=args.method, policy=args.policy, seed=args.seed,
                               detect_period=args.detect_period, detect_scale=args.detect_scale,
                               photo_scale=args.photo_scale, max_flight_time=args.max_flight_time,
                               quiet=args.quiet, vehicle=vehicle, detector=detector,
                               time_allocation=args.time_allocation, overwrite=args.overwrite,
                               recorder=recorder)
        code = 0
        try:
            runner.fly()
        except KeyboardInterrupt:
            runner.status = "interrupted"
            code = 130
        except Exception:
            runner.status = "failed"
            runner.finish_report()
            raise
        summary = runner.finish_report()
    finally:
        vehicle.close()  # MAVLink: stops the threads and the simulated PX4 it started
        if recorder is not None:
            recorder.close()
    if summary["status"].startswith("aborted"):
        code = 1
    print(f"{summary['status']}: flight {summary['flight_time_s']:.1f} s, "
          f"{summary['insulators_found']} insulators found ({summary['insulators_matched']} of "
          f"{summary['insulators_in_scene']} matched), {summary['insulators_inspected']} inspected, "
          f"{len(summary['photos'])} photos, mean error "
          f"{summary['mean_error_m'] if summary['mean_error_m'] is None else round(summary['mean_error_m'], 3)} m; "
          f"report in {args.out}", file=sys.stdout)
    return code
