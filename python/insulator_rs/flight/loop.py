"""The flight loop: the single-flight inspection through the ports, a scheduler of behaviours.

The paper's online algorithm: take off, fly the exploration path (minimum-snap trajectories,
safety-checked), and every ``detect_period`` s hand a detection frame, its boxes and the LiDAR
points of that instant to perception (:class:`~insulator_rs.perception.runner.PerceptionRunner`,
the pairing shared with the replay); new insulators get inspection waypoints, which the state
machine visits, then the flight crosses over the top, finishes and lands. Recording wraps the
ports: the loop does not know it is recorded.

The loop owns the control tick (:meth:`FlightLoop.tick`: setpoint, pose log, perception, the
obstacle survey every SURVEY_PERIOD s, the abort policy) and the state machine. Every other job
is a behaviour that flies through the tick (:class:`~insulator_rs.flight.pilot.Pilot`): the legs
and their obstacle re-check (``leg_follower``), the second look (``second_look``), the photos
(``photo_session``), the autopilot's parameters, pre-flight gate, take-off and landing
(``autopilot_session``), the energy budget (``energy_budget``), the abort rules
(``abort_policy``), the way out after an abort (``safe_exit``: a safe route to a landing point
clear of the tower and the conductors, or a hold for the pilot, never a blind descent) and the
summary (``summary_assembly``). A vehicle failsafe aborts the mission and nothing more is sent to
the vehicle; a sensor error costs that detection event or photo, never the flight. The operator's
abort (:meth:`FlightLoop.request_abort`: Ctrl-C or the ground station's command in the air,
``flight/operator_abort.py``) is one more abort. The report folder is written as the flight
goes: an interruption (Ctrl-C on the ground) still leaves the summary, the photos taken and the
plot.
"""

from __future__ import annotations

import time as wallclock
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.exceptions import (ParameterError, PlanningError, PreflightRefused, SensorError, VehicleError,
                                     VehicleFailsafe)
from insulator_rs.flight.abort_policy import OPERATOR, AbortPolicy
from insulator_rs.flight.autopilot_session import AutopilotSession
from insulator_rs.flight.energy_budget import EnergyBudget
from insulator_rs.flight.home import at_vehicle_home
from insulator_rs.flight.leg_follower import LegFollower
from insulator_rs.flight.lidar_cue import LidarCue
from insulator_rs.flight.observers import ConsoleObserver, ObserverGroup
from insulator_rs.flight.photo_session import PhotoSession
from insulator_rs.flight.photos import InspectionPhotos
from insulator_rs.flight.pilot import CONTROL_PERIOD, LAND_HEIGHT
from insulator_rs.flight.safe_exit import SafeExit
from insulator_rs.flight.second_look import REFUSED_TRACK_MIN_CONFIDENT, SecondLookFlight
from insulator_rs.flight.settings import FlightSettings
from insulator_rs.flight.stall_watch import StallWatch
from insulator_rs.flight.summary_assembly import SummaryAssembly
from insulator_rs.geodesy import GeoPoint, enu_to_geodetic
from insulator_rs.mission.config import Mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import InspectionStateMachine, PlanItem, State
from insulator_rs.perception.pipeline import LocalizedInsulator
from insulator_rs.perception.stack import build_perception_stack
from insulator_rs.planning.abort import AbortRoute
from insulator_rs.planning.exploration import PlanKind
from insulator_rs.planning.pmm import rest_to_rest_times
from insulator_rs.ports.detector import BoxDetector
from insulator_rs.ports.observer import FlightObserver, InsulatorFound, PhaseChange
from insulator_rs.ports.sensors import PoseStamped, Sensors
from insulator_rs.ports.vehicle import FlightMode, Vehicle, VehicleState
from insulator_rs.report import FlightClock, ReportWriter
from insulator_rs.report.run_status import RunOutcome, RunStatus
from insulator_rs.report.summary import RunSummary
from insulator_rs.rig import SensorRig
from insulator_rs.tracking.registry import Insulator, InsulatorRegistry

__all__ = ["CONTROL_PERIOD", "FlightLoop", "FlightSettings"]

STATUS_PERIOD = 15.0  # s of flight between progress lines
SUMMARY_PERIOD = 5.0  # s of flight between summary rewrites


class FlightLoop:
    """One single-flight inspection: state, perception, report (see the module docstring)."""

    def __init__(self, mission: Mission, vehicle: Vehicle, sensors: Sensors, detector: BoxDetector,
                 out: Path, *, rig: SensorRig, settings: FlightSettings = FlightSettings(),
                 overwrite: bool = False, observer: FlightObserver | None = None,
                 photo_camera: Any = None, photo_detector: BoxDetector | None = None) -> None:
        # takeoff = "home": the take-off point is where the vehicle stands, before anything is planned
        mission = at_vehicle_home(mission, vehicle)
        self.mission, self.vehicle, self.sensors, self.detector = mission, vehicle, sensors, detector
        self.rig, self.settings, self.out = rig, settings, out
        # who watches the flight: the console unless quiet, and what the caller adds (the GCS)
        self.observer = ObserverGroup(([] if settings.quiet else [ConsoleObserver()])
                                      + ([] if observer is None else [observer]))
        self.geom = geom = MissionGeometry.from_mission(mission)
        p, lim = mission.inspection, mission.vehicle
        self.v_max, self.a_max = lim.v_max(), lim.a_max()
        self.failsafe: VehicleFailsafe | None = None  # the failsafe that stopped the mission
        self.runner = build_perception_stack(rig, sensors, detector, method=settings.method,
                                             insulator_length=p.insulator_length,
                                             detect_period=settings.detect_period,
                                             on_sensor_error=self._sensor_error).runner
        # the LiDAR cue (flight/lidar_cue.py): its doubts hold a record for more evidence
        self.cue = (LidarCue(geom.line, mission.max_width, p.insulator_length, ground_z=float(geom.takeoff[2]))
                    if p.lidar_cue else None)
        self.registry = InsulatorRegistry(geom.line, p.registry_gate, p.confirmations,
                                          doubt=None if self.cue is None else self.cue.doubt)
        self.sm = InspectionStateMachine(geom.path, self.registry, lambda ins: self.shots.plan(ins),
                                         policy=settings.policy,
                                         cost=lambda a, b: float(rest_to_rest_times(a, b, self.v_max, self.a_max)))
        self.origin = GeoPoint(mission.tower.lat, mission.tower.lon, mission.tower.alt)
        self.report = ReportWriter(out, origin=self.origin, overwrite=overwrite)
        self.clock = FlightClock(vehicle.state().time)  # UTC of vehicle stamps; re-anchored at take-off
        self.photos = InspectionPhotos(self.report, p.insulator_length, exif_camera=rig.exif_camera(),
                                       inspection=rig.inspection)
        # the companion's stalls (flight/stall_watch.py), set by whoever flies an outside autopilot
        self.stall_watch: StallWatch | None = None
        self.outcome = RunOutcome(RunStatus.RUNNING)
        self.abort_reason: str | None = None
        self.t_start = 0.0
        self.sensor_errors = 0  # the runner's and the photos'
        self.airborne = False
        self._printed_transitions = 0
        self._next_status, self._next_summary = STATUS_PERIOD, SUMMARY_PERIOD
        self._wall0 = wallclock.perf_counter()
        limits = {"v_max": self.v_max, "a_max": self.a_max}
        self.legs = LegFollower(self, geom, clearance=p.crossing_clearance, margin=p.safety_margin,
                                time_allocation=settings.time_allocation, obstacle_map=settings.obstacle_map,
                                **limits)
        self.exit = SafeExit(self, geom, self.registry, crossing_clearance=p.crossing_clearance,
                             observer=self.observer, seen=self.legs.seen, **limits)
        self.energy = EnergyBudget(geom, reserve=p.battery_reserve, crossing_clearance=p.crossing_clearance,
                                   way_out=self.exit.route_from, **limits)
        self.abort_policy = AbortPolicy(self, self.runner, self.energy, max_flight_time=settings.max_flight_time)
        self.looks = SecondLookFlight(self, self.legs, registry=self.registry, runner=self.runner, geom=geom,
                                      mission=mission, detect_period=settings.detect_period, energy=self.energy,
                                      lidar_targets=None if self.cue is None else self._lidar_targets)
        # what checks each photo (perception/photo_check.py): the flight's detector unless the
        # composition root gives another (the simulator's stand-in on photos)
        self.shots = PhotoSession(self, geom, sensors=sensors, rig=rig, registry=self.registry, photos=self.photos,
                                  detector=detector if photo_detector is None else photo_detector, params=p,
                                  observer=self.observer, on_sensor_error=self._sensor_error,
                                  photo_camera=photo_camera)
        self.autopilot = AutopilotSession(self, geom, sensors=sensors, detector=detector,
                                          crossing_clearance=p.crossing_clearance, battery_reserve=p.battery_reserve,
                                          observer=self.observer, energy=self.energy, log_pose=self._log_pose)
        self.assembly = SummaryAssembly(mission, rig, settings, vehicle, sensors, detector, self.registry, self.sm,
                                        self.runner, self.report, self.photos, self.origin, self.autopilot,
                                        self.energy, self.legs, self.looks, self.exit, self._lidar_cue_record,
                                        None if self.cue is None else self.cue.verdict)

    @property
    def status(self) -> str:
        """summary.json's ``status`` (:attr:`outcome` rendered)."""
        return str(self.outcome)

    @property
    def abort_route(self) -> AbortRoute | None:
        return self.exit.route

    @property
    def handed_over(self) -> str | None:
        return self.exit.handed_over

    def say(self, text: str) -> None:
        self.observer.message(self.now(), text)

    def now(self) -> float:
        return self.vehicle.state().time - self.t_start

    def _log_pose(self, st: VehicleState) -> None:
        self.report.log_pose(st.time - self.t_start, st.position, st.yaw, self.sm.state.value)

    def _print_transitions(self) -> None:
        for tr in self.sm.transitions[self._printed_transitions:]:
            t = tr.time - self.t_start if tr.time >= self.t_start else tr.time
            self.observer.phase(PhaseChange(t, tr.source.value, tr.target.value, tr.reason))
        self._printed_transitions = len(self.sm.transitions)

    def _sensor_error(self, exc: SensorError) -> None:
        self.sensor_errors += 1
        if self.sensor_errors <= 3 or self.sensor_errors % 50 == 0:
            self.say(f"[{self.now():7.1f} s] sensor error ({self.sensor_errors} so far): {exc}")

    def _camera_places(self) -> tuple[list[Insulator], list[np.ndarray]]:
        """What covers a LiDAR string: every registry record, and the anchors (W) of the tracks the
        second look will look at anyway (boxed with confidence, every localization refused). A
        track of a box or two that never localized covers nothing: the string near it is still
        unfound (a network boxing it in fragments), and the LiDAR's look is its chance."""
        return (self.registry.insulators + self.registry.candidates,
                [t.anchor for t in self.runner.pipeline.refused_tracks(REFUSED_TRACK_MIN_CONFIDENT)])

    def _lidar_targets(self) -> list[Insulator]:
        assert self.cue is not None
        records, places = self._camera_places()
        return self.cue.look_targets(places, records)

    def _lidar_cue_record(self) -> dict[str, Any]:
        if self.cue is None:
            return {"enabled": False}
        records, places = self._camera_places()
        return self.cue.record(records, places)

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

    # -- the tick and the abort policy ---------------------------------------------------------
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
        self.energy.observe(st)
        self._log_pose(st)
        self.runner.add_pose(PoseStamped(st.time, st.T_w_b))  # the whole reported attitude
        surveyed = self.legs.survey(st, self.runner.survey, self.rig.T_b_l, wanted=self.cue is not None)
        if self.cue is not None:
            if surveyed is not None:
                self.cue.add(surveyed)
            self.cue.update(st.time)
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
                     f"{self.runner.counts.events} detection events, "
                     f"wall {wallclock.perf_counter() - self._wall0:.0f} s")
        if t >= self._next_summary:
            self._next_summary += SUMMARY_PERIOD
            self.report.flush()
            self.write_summary()
        if self.sm.state not in (State.ABORT, State.IDLE):
            reason = self.abort_policy.due(st, t)
            if reason is not None:
                self.abort(reason, st.time)
        self._print_transitions()
        return st

    def request_abort(self, reason: str = OPERATOR) -> None:
        """The operator aborts the mission (from another thread or a signal handler too): taken at
        the next control tick, then the safe route out and the landing, as for any abort.
        ``reason``: :func:`~insulator_rs.flight.abort_policy.operator_reason` of how it was asked."""
        self.abort_policy.request(reason)

    def abort(self, reason: str, time: float | None = None) -> None:
        if self.sm.aborted is None and self.sm.state != State.IDLE:
            self.exit.note_what_is_left()  # before the state machine drops the plan
        self.abort_reason = reason
        self.sm.abort(reason, self.vehicle.state().time if time is None else time)
        self.observer.aborted(self.now(), reason)

    def on_failsafe(self, exc: VehicleFailsafe) -> None:
        """The vehicle's failsafe fired: the autopilot now flies it (hold, land, return, or the
        pilot has the sticks), so the mission aborts and stops commanding."""
        self.failsafe = exc
        self.abort(f"vehicle failsafe: {exc.reason} ({exc.action})")
        self.write_summary()

    def _failed(self, reason: str) -> None:
        """A refused or unanswered command, or no safe trajectory from here: reported, and the
        mission aborts (then leaves safely)."""
        self.abort(reason)
        self.say(f"[{self.now():7.1f} s] {self.abort_reason}")
        self.write_summary()

    # -- legs --------------------------------------------------------------------------------
    def fly_segment(self, items: list[PlanItem]) -> bool:
        """Fly a min-snap trajectory through ``items`` (the plan's head); report each item reached
        to the state machine. Returns False if the plan changed on the way (re-plan)."""
        leg = self.legs.plan(items)
        k = 0
        version = self.sm.plan_version  # a change of the plan on the way means: re-plan
        # no trajectory: the vehicle is at the items already (a re-plan that came as it arrived,
        # tower A's second waypoint): it goes on to the photo, not round the same leg forever
        if leg.trajectory is None:
            for it in items[:-1]:
                if not self._reach(it):
                    return False
        for t, st in leg.fly(lambda: items[min(k, len(items) - 1)].yaw):
            if self.sm.state in (State.HOLD, State.ABORT) or not self.healthy():
                return False
            if leg.blocked(t):
                self.legs.legs_replanned += 1
                self.say(f"[{self.now():7.1f} s] the LiDAR sees an obstacle on the rest of the leg: re-planning")
                return False
            while k < len(items) - 1 and t >= leg.segment.item_times[k] - 1e-9:
                if not self._reach(items[k]):
                    return False
                k += 1
                if self.sm.plan_version != version:
                    return False
            if self.sm.plan_version != version:
                return False
        last = items[-1]
        if last.kind == PlanKind.INSPECT and last.waypoint is not None:
            self.shots.take_photo(last.waypoint)
        if self.sm.target() is last:
            return self._reach(last)
        return True

    def _reach(self, item: PlanItem) -> bool:
        """Report ``item`` reached, unless the search's end holds it (the second look, the wait for
        perception) or it is no longer the plan's head: a find during the tick that got there puts
        its inspection waypoints in front of it, and reaching the head then counted one of those
        as flown, its photo never taken (CI: a string photographed from one of its two waypoints
        and reported inspected). False: re-plan, the new waypoints first."""
        if not self.looks.may_end(item) or self.sm.target() is not item:
            return False
        self.sm.reached(self.vehicle.state().time, item)
        return True

    def healthy(self) -> bool:
        st = self.vehicle.state()
        if st.healthy and st.mode == FlightMode.OFFBOARD.value:
            return True
        self.sm.fault(st.fault or f"vehicle left offboard (mode {st.mode})", st.time)
        return False

    # -- the flight --------------------------------------------------------------------------
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
            self.autopilot.on_refused(exc)
        except VehicleFailsafe as exc:  # raised by a command rather than during a tick
            self.on_failsafe(exc)
        except ParameterError as exc:  # before arming: nothing flew
            self.abort(f"autopilot parameters not set ({exc})")
            self.say(f"[{self.now():7.1f} s] {self.abort_reason}")
        except VehicleError as exc:  # the vehicle refused a command or never answered it
            self._failed(f"vehicle command failed: {exc}")
        except PlanningError as exc:  # no safe trajectory from where the vehicle is
            self._failed(f"planning failed: {exc}")
        if refused is not None:
            self.outcome = RunOutcome(RunStatus.REFUSED_PREFLIGHT,
                                      "; ".join(f"{name}: {reason}" for name, reason in refused.failed))
        elif self.sm.state == State.ABORT:
            self.exit.leave()
            reason = self.abort_reason or "mission aborted"
            if self.exit.handed_over is not None:
                reason += f"; held for the pilot: {self.exit.handed_over}"
            self.outcome = RunOutcome(RunStatus.ABORTED, reason)
        else:
            self.outcome = RunOutcome(RunStatus.FINISHED)
        self.autopilot.restore()
        self._print_transitions()

    def _fly(self) -> None:
        self.autopilot.configure()
        self.autopilot.preflight()
        if self.autopilot.take_off():
            self.sm.start(self.vehicle.state().time)
            self.abort_policy.started(self.vehicle.state().time)
            self._print_transitions()
        while not self.sm.done:
            if self.sm.state == State.HOLD:
                self.abort_policy.hold()
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
                    raise  # the exploration itself cannot go on: abort (planning failed)
                # no safe trajectory to an inspection waypoint (a find inside a safety volume):
                # that photo is dropped, reported, and the mission goes on
                self.sm.skip(items[-1], self.vehicle.state().time, str(exc))
                wp = items[-1].waypoint
                self.say(f"[{self.now():7.1f} s] inspection waypoint of insulator "
                         f"{wp.insulator_id if wp is not None else None} skipped: no safe trajectory ({exc})")
                self.write_summary()

    def land(self) -> None:
        self.autopilot.land()

    # -- report ------------------------------------------------------------------------------
    def summary(self) -> RunSummary:
        """What the flight knows now (summary.json), nothing of ground truth."""
        return self.assembly.summary(outcome=self.outcome, t_start=self.t_start, abort_reason=self.abort_reason,
                                     failsafe=self.failsafe, sensor_errors=self.sensor_errors,
                                     waypoints=self.shots.waypoints, stall_watch=self.stall_watch)

    def write_summary(self) -> None:
        self.report.write_summary(self.summary())

    def finish_report(self, reference: np.ndarray | None = None) -> dict[str, Any]:
        """Write the final summary and the plot. ``reference``: (K, 3) points drawn as ground
        truth, known only after the flight (the evaluation's), or None."""
        self.report.flush()
        return self.assembly.finish(self.summary(), self.geom.volumes, self.shots.waypoints, reference)
