"""The autopilot's side of one flight: before it, the tower's failsafe parameters set and
verified (:class:`~insulator_rs.flight.autopilot_setup.AutopilotSetup`, a vehicle with a
parameter store only) and the pre-flight gate (:mod:`insulator_rs.flight.preflight`) that refuses
the arm command; the take-off (arm, PX4's TAKEOFF to the first pass height, then OFFBOARD) and
the landing (PX4's LAND); after the flight the old parameters put back once the vehicle is on
the ground (while PX4 still flies, its own return or a pilot holding, the tower's values stay).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import KW_ONLY, dataclass, field

import numpy as np

from insulator_rs.exceptions import PreflightRefused, VehicleError, VehicleFailsafe
from insulator_rs.flight.autopilot_setup import AutopilotSetup
from insulator_rs.flight.energy_budget import EnergyBudget
from insulator_rs.flight.pilot import CONTROL_PERIOD, Pilot
from insulator_rs.flight.preflight import PreflightResult, preflight_checks
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import State
from insulator_rs.planning.exploration import MIN_PASS_HEIGHT
from insulator_rs.planning.px4_failsafes import tower_failsafe_parameters
from insulator_rs.ports.detector import BoxDetector
from insulator_rs.ports.observer import FlightObserver
from insulator_rs.ports.sensors import Sensors
from insulator_rs.ports.vehicle import FlightMode, VehicleState, vehicle_parameters
from insulator_rs.report import FlightClock

GROUND_STATION_WAIT = 2.5  # wall s to wait for a ground station's HEARTBEAT (1 Hz) before take-off
# s of vehicle time to wait, after the mission ends with the vehicle in the air (PX4's own return,
# a pilot holding), for the landing before the autopilot's old parameters are put back
RESTORE_WAIT = 300.0
TAKEOFF_TIMEOUT = 60.0  # s of vehicle time for the climb to the first pass height
LAND_TIMEOUT = 120.0  # s of vehicle time for the descent


@dataclass(eq=False)
class AutopilotSession:
    """Parameters, pre-flight gate, take-off, landing and restore of one flight (see the module
    docstring). ``energy``: the flight's energy budget (what the mission needs, what the descent
    drains); ``log_pose(state)``: the report's pose log, fed while the vehicle lands."""

    pilot: Pilot
    geom: MissionGeometry
    _: KW_ONLY
    sensors: Sensors
    detector: BoxDetector
    crossing_clearance: float  # m above the tower where the sides are crossed
    battery_reserve: float  # fraction of the pack kept at landing
    observer: FlightObserver
    energy: EnergyBudget
    log_pose: Callable[[VehicleState], None]
    setup: AutopilotSetup | None = field(default=None, init=False)  # the tower's PX4 parameters (a PX4 vehicle)
    preflight_result: PreflightResult | None = field(default=None, init=False)  # the gate before arming

    def configure(self) -> None:
        """Before arming: the autopilot's own failsafes set for this tower and verified (a vehicle
        with parameters only; see :mod:`insulator_rs.planning.px4_failsafes`); home is where the
        vehicle stands (PX4 sets it at arming). A parameter that cannot be read or set raises
        ParameterError: the mission aborts before anything flies."""
        vehicle = self.pilot.vehicle
        store = vehicle_parameters(vehicle)
        if store is None:
            return
        gcs = store.ground_station(GROUND_STATION_WAIT)
        settings = tower_failsafe_parameters(self.geom.volumes, vehicle.state().position, self.geom.path_points(),
                                             crossing_clearance=self.crossing_clearance,
                                             ground_station=gcs, vehicle_return_alt=store.read("RTL_RETURN_ALT"))
        self.setup = AutopilotSetup(store, settings, ground_station=gcs)
        try:
            self.setup.apply()
        finally:
            self.pilot.write_summary()
        self.pilot.say("autopilot parameters set and verified: "
                       + ", ".join(f"{s.name} {s.value:g}" for s in settings)
                       + ("" if gcs else "; no ground station heard: NAV_DLL_ACT left as it was"))

    def preflight(self) -> None:
        """Before arming, after the autopilot's parameters are set: the pre-flight gate, each
        check said; PreflightRefused naming every failed check refuses the flight before the arm
        command."""
        vehicle = self.pilot.vehicle
        result = preflight_checks(vehicle, self.sensors, self.detector,
                                  demand=self.energy.mission_demand(vehicle.state().position),
                                  reserve=self.battery_reserve, volumes=self.geom.volumes,
                                  mission_points=self.geom.path_points(), takeoff=self.geom.takeoff,
                                  origin=self.geom.mission.tower)
        self.preflight_result = result
        for c in result.checks:
            self.pilot.say(f"pre-flight {c.check.value}: {c.outcome.value.replace('_', ' ')} ({c.reason})")
        if not result.passed:
            raise result.refusal()

    @property
    def refused(self) -> bool:
        """Whether the pre-flight gate refused the flight (nothing was armed)."""
        return self.preflight_result is not None and not self.preflight_result.passed

    def on_refused(self, exc: PreflightRefused) -> None:
        """The gate refused: the operator and the GCS are told each failed check; nothing armed."""
        self.observer.preflight_failed(self.pilot.now(), exc.failed)
        self.pilot.say(f"refused to arm: {exc}")
        self.pilot.write_summary()

    def restore(self) -> None:
        """After the flight: the autopilot's old parameters back, once the vehicle is on the
        ground (waiting up to RESTORE_WAIT s of vehicle time while PX4 returns or lands by
        itself); while it still flies, the tower's values stay set and the report says so."""
        setup = self.setup
        if setup is None or not setup.pending:
            return
        pilot = self.pilot
        st = pilot.vehicle.state()
        waited = 0.0
        # only PX4's own return or landing ends on the ground by itself; a hover (HOLD, the
        # pilot's POSCTL) is someone's to end, so the values stay for them
        landing_modes = (FlightMode.RTL.value, FlightMode.LAND.value)
        while not st.landed and st.mode in landing_modes and waited < RESTORE_WAIT:
            before = st.time
            try:
                st = pilot.vehicle.advance(1.0)
            except VehicleFailsafe as exc:  # PX4's own failsafe flies on: keep waiting for its landing
                pilot.say(f"[{pilot.now():7.1f} s] waiting for the landing to restore parameters: {exc}")
                st = pilot.vehicle.state()
            except VehicleError:
                break
            if st.time <= before:
                break  # no telemetry any more: the vehicle cannot be seen landing
            waited += st.time - before
            self.log_pose(st)
        if st.landed:
            setup.restore()
        else:
            setup.keep(f"the vehicle is still in the air (mode {st.mode}): the tower's values stay set")
        pilot.say(f"[{pilot.now():7.1f} s] autopilot parameters: {setup.restore_status}")
        pilot.write_summary()

    def take_off(self) -> bool:
        """Arm, take off to the first pass height (PX4's TAKEOFF, setpoints streamed meanwhile) and
        switch to OFFBOARD; the take-off anchors the flight's clock. False when the mission aborted
        during the climb (a failsafe, the flight-time limit)."""
        pilot = self.pilot
        st = pilot.vehicle.state()
        target = st.position + np.array([0.0, 0.0, MIN_PASS_HEIGHT])
        pilot.vehicle.send_setpoint(target, None, st.yaw)
        pilot.t_start = st.time
        pilot.clock = FlightClock(st.time)
        pilot.vehicle.arm()
        pilot.airborne = True
        pilot.vehicle.takeoff(MIN_PASS_HEIGHT)
        yaw = st.yaw
        while st.time - pilot.t_start < TAKEOFF_TIMEOUT:
            st = pilot.tick(target, None, yaw)
            if pilot.sm.state == State.ABORT:
                return False
            if st.mode != FlightMode.TAKEOFF.value and abs(st.position[2] - target[2]) < 0.4:
                break
        pilot.vehicle.start_offboard()
        return True

    def land(self) -> None:
        """Land where the vehicle is, unless a failsafe has the vehicle or it never flew. A refused
        or unanswered land command is reported; the autopilot's own failsafes keep the vehicle."""
        pilot = self.pilot
        if pilot.failsafe is not None or not pilot.airborne:
            return  # the autopilot flies its failsafe (or the pilot flies), or nothing took off
        st = pilot.vehicle.state()
        if st.landed and not st.armed:
            return
        try:
            pilot.vehicle.land()
        except VehicleFailsafe as exc:
            pilot.on_failsafe(exc)
            return
        except VehicleError as exc:
            pilot.abort_reason = f"{pilot.abort_reason or 'mission aborted'}; landing command failed: {exc}"
            pilot.say(f"[{pilot.now():7.1f} s] landing command failed: {exc}")
            return
        t0 = st.time
        while not st.landed and st.time - t0 < LAND_TIMEOUT:
            try:
                st = pilot.vehicle.advance(CONTROL_PERIOD)
            except VehicleFailsafe as exc:
                pilot.on_failsafe(exc)
                return
            self.energy.observe(st)  # the descent drains the pack too, down to the charge at touchdown
            self.log_pose(st)
