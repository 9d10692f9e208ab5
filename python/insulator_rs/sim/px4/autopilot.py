"""The simulated PX4's autopilot: the PX4-like rules of
``insulator_rs.sim.kinematics.KinematicVehicle`` behind PX4's MAVLink command surface
(COMMAND_LONG / COMMAND_INT with PX4 v1.16.0 SITL's answers, SET_POSITION_TARGET_LOCAL_NED
with PX4's type_mask), command faults, the pilot's switch, and the simulation thread that
ties the link (``transport``) and the streams (``telemetry``) together.
"""

from __future__ import annotations

import math
import random
import select
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from insulator_rs.exceptions import CommandRejected, VehicleFailsafe
from insulator_rs.mavlink import px4_modes
from insulator_rs.mavlink.frames import ned_to_enu, yaw_ned_to_enu
from insulator_rs.mavlink.signing import configure_signing
from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.ports.vehicle import FlightMode
from insulator_rs.sim.kinematics import KinematicVehicle, Setpoint
from insulator_rs.sim.px4.datalink import DataLinkLoss
from insulator_rs.sim.px4.parameters import Px4Parameters
from insulator_rs.sim.px4.telemetry import DEFAULT_RATES_HZ, Px4Telemetry
from insulator_rs.sim.px4_gcs import GcsLink
from insulator_rs.sim.px4.transport import (LOOP_PERIOD_S, MAX_STEP_VEHICLE_S, UNSIGNED_ALLOWED, LinkFaults,
                                            Px4Transport, SimStats)

M = mavlink2
# Commands PX4 SITL (SIH) leaves without any COMMAND_ACK: its gimbal/mount modules do not run.
UNANSWERED_COMMANDS = frozenset({M.MAV_CMD_DO_MOUNT_CONTROL, M.MAV_CMD_DO_MOUNT_CONFIGURE,
                                 M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE})

# type_mask bits of SET_POSITION_TARGET_*: ignore flags.
_POS_IGNORE = (M.POSITION_TARGET_TYPEMASK_X_IGNORE, M.POSITION_TARGET_TYPEMASK_Y_IGNORE,
               M.POSITION_TARGET_TYPEMASK_Z_IGNORE)
_VEL_IGNORE = (M.POSITION_TARGET_TYPEMASK_VX_IGNORE, M.POSITION_TARGET_TYPEMASK_VY_IGNORE,
               M.POSITION_TARGET_TYPEMASK_VZ_IGNORE)


def setpoint_from_target_local_ned(msg: Any) -> Setpoint:
    """PX4's reading of SET_POSITION_TARGET_LOCAL_NED (frame LOCAL_NED) as an ENU Setpoint.

    Ignored position/velocity fields become NaN (that axis is not controlled);
    a position block or velocity block entirely ignored is None. Yaw wins over
    yaw rate; with both ignored the heading is held.
    """
    mask = int(msg.type_mask)
    pos = np.array([math.nan if mask & bit else v for bit, v in zip(_POS_IGNORE, (msg.x, msg.y, msg.z))])
    vel = np.array([math.nan if mask & bit else v for bit, v in zip(_VEL_IGNORE, (msg.vx, msg.vy, msg.vz))])
    yaw = None if mask & M.POSITION_TARGET_TYPEMASK_YAW_IGNORE or not math.isfinite(msg.yaw) \
        else yaw_ned_to_enu(msg.yaw)
    yaw_rate = None if mask & M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE or not math.isfinite(msg.yaw_rate) \
        else -float(msg.yaw_rate)  # NED yaw rate is clockwise: ENU's is its negative
    return Setpoint(
        position=None if np.all(np.isnan(pos)) else ned_to_enu(pos),
        velocity=None if np.all(np.isnan(vel)) else ned_to_enu(vel),
        yaw=yaw,
        yaw_rate=None if yaw is not None else yaw_rate,
    )


class SimulatedPx4(Px4Transport, Px4Telemetry):
    """A PX4-like vehicle on 127.0.0.1:``port`` (0 picks a free port; see ``address``).

    Use as a context manager or call ``start()``/``stop()``. Fault injection and
    inspection methods are thread-safe.
    """

    def __init__(
        self,
        *,
        port: int = 0,
        remote: tuple[str, int] | None = None,
        vehicle: KinematicVehicle | None = None,
        time_scale: float = 1.0,
        rates_hz: dict[str, float] | None = None,
        origin: tuple[float, float, float] = (47.397742, 8.545594, 488.0),
        system_id: int = 1,
        component_id: int = 1,
        signing_key: bytes | None = None,
        seed: int = 0,
        gcs_port: int | None = None,
        answer_timesync: bool = True,
    ) -> None:
        if not (math.isfinite(time_scale) and 0.0 < time_scale <= 100.0):
            raise ValueError(f"time_scale must be in (0, 100], got {time_scale!r}")
        if not 0 <= port <= 65535:
            raise ValueError(f"port must be in [0, 65535], got {port!r}")
        self.vehicle = vehicle or KinematicVehicle()
        self.time_scale = float(time_scale)
        self.rates_hz = dict(DEFAULT_RATES_HZ)
        for name, rate in (rates_hz or {}).items():
            if name not in DEFAULT_RATES_HZ or not (math.isfinite(rate) and rate >= 0.0):
                raise ValueError(f"rates_hz[{name!r}] must be a known message with a rate >= 0, got {rate!r}")
            self.rates_hz[name] = float(rate)
        self.origin = origin
        self.system_id = system_id
        self.component_id = component_id
        self.faults = LinkFaults()
        self.stats = SimStats()
        self._lock = threading.RLock()
        self._rng = random.Random(seed)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", port))
        self._sock.setblocking(False)
        self._peers: list[tuple[str, int]] = [remote] if remote else []
        self._mav = M.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._mav.robust_parsing = True
        if signing_key is not None:
            configure_signing(self._mav, signing_key, link_id=0, allow_unsigned=UNSIGNED_ALLOWED)
        self._next_send: dict[str, float] = {name: 0.0 for name in self.rates_hz}
        self._delayed: list[tuple[float, int, str, bytes, tuple[str, int] | None]] = []
        self._sequence = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        # No RC transmitter in SITL: PX4 refuses the manual modes over MAVLink. The pilot's
        # switch (``pilot_mode_change``) models a transmitter and bypasses this.
        self.rc_connected = False
        self.answer_timesync = bool(answer_timesync)  # False: TIMESYNC requests go unanswered (a fault)
        self._command_faults: dict[int, int | None] = {}
        # PX4's GCS link and its forwarding between links (sim/px4_gcs.py), when a port is given
        self.gcs = GcsLink(gcs_port) if gcs_port is not None else None
        # PX4's parameters (sim/px4/parameters.py): answered as PX4 does, the airframe's honoured
        self.parameters = Px4Parameters(self._send, lambda: self.vehicle.params,
                                        lambda params: setattr(self.vehicle, "params", params))
        # PX4's GCS connection loss failsafe (NAV_DLL_ACT: sim/px4/datalink.py), on vehicle time
        self.datalink = DataLinkLoss()
        self._gcs_heard_wall: float | None = None  # the GCS link's last HEARTBEAT (wall time) ...
        self._gcs_heard_at: float | None = None  # ... and the vehicle time this loop first saw it

    # -- lifecycle ---------------------------------------------------------------

    def start(self) -> SimulatedPx4:
        if self._thread is not None:
            raise RuntimeError("SimulatedPx4 already started")
        self._thread = threading.Thread(target=self._run, name="px4-sim", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._sock.close()
        if self.gcs is not None:
            self.gcs.close()

    def __enter__(self) -> SimulatedPx4:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- fault injection and inspection -----------------------------------------

    def set_command_fault(self, command: int, result: int | None) -> None:
        """From now on answer ``command`` (a MAV_CMD) with ``result`` (a MAV_RESULT) without
        acting on it, or, with None, leave it unanswered (as PX4 does with gimbal commands)."""
        if command not in M.enums["MAV_CMD"]:
            raise ValueError(f"command must be a MAV_CMD, got {command!r}")
        if result is not None and result not in M.enums["MAV_RESULT"]:
            raise ValueError(f"result must be a MAV_RESULT or None, got {result!r}")
        with self._lock:
            self._command_faults[command] = result

    def pilot_mode_change(self, mode: FlightMode | str = FlightMode.POSCTL) -> None:
        """The pilot flips the RC mode switch (no MAVLink involved)."""
        with self._lock:
            self.vehicle.set_mode(mode)

    def gps_glitch(self, offset_enu: object) -> None:
        with self._lock:
            self.vehicle.inject_gps_glitch(offset_enu)

    def position_loss(self, lost: bool = True) -> None:
        with self._lock:
            self.vehicle.inject_position_loss(lost)

    def true_pose(self) -> tuple[np.ndarray, float, float]:
        """(position in W m, yaw rad, vehicle time s) of the simulated airframe, without
        odometry noise or GPS glitch: where simulated sensors must render from."""
        with self._lock:
            model = self.vehicle.model
            return model.position.copy(), float(model.yaw), float(self.vehicle.clock.now)

    def with_vehicle(self, func: Callable[[KinematicVehicle], Any]) -> Any:
        """Run ``func(vehicle)`` under the sim lock (consistent reads of the true state)."""
        with self._lock:
            return func(self.vehicle)

    # -- the loop ----------------------------------------------------------------

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.is_set():
            try:
                readable, _, _ = select.select([self._sock] + ([self.gcs.sock] if self.gcs else []), [], [],
                                               LOOP_PERIOD_S)
            except (OSError, ValueError):
                return
            now = time.monotonic()
            with self._lock:
                if readable:
                    self._receive(now)
                    if self.gcs is not None:  # a GCS's frames for the companion's components
                        for frame in self.gcs.receive(self.system_id, self.component_id):
                            self._sendto_peers(frame, gcs=False)
                self._deliver_due(now)
                # Lockstep-like: if this thread fell behind (a loaded machine), the
                # vehicle clock slows down rather than jumping, so no PX4 timeout
                # (COM_OF_LOSS_T...) fires because of our own scheduling.
                elapsed = min((now - last) * self.time_scale, MAX_STEP_VEHICLE_S)
                if elapsed > 0.0:
                    last = now
                    try:
                        self.vehicle.advance(elapsed)
                    except VehicleFailsafe:
                        pass  # PX4 flies its failsafe; the fault shows in HEARTBEAT/state
                if self.gcs is not None:
                    self._check_data_link()
                self._send_telemetry()

    def _check_data_link(self) -> None:
        """PX4's GCS connection loss: the age of the ground station's last HEARTBEAT in vehicle
        time (the loop's clock, so a slow loop does not fire it) against NAV_DLL_ACT's rule."""
        heard = self.gcs.last_heartbeat if self.gcs is not None else None
        if heard is not None and heard != self._gcs_heard_wall:
            self._gcs_heard_wall, self._gcs_heard_at = heard, self.vehicle.clock.now
        age = None if self._gcs_heard_at is None else self.vehicle.clock.now - self._gcs_heard_at
        values = self.parameters.values
        self.datalink.step(self.vehicle, age, action=int(values["NAV_DLL_ACT"][1]),
                           timeout=float(values["COM_DL_LOSS_T"][1]), exceptions=int(values["COM_DLL_EXCEPT"][1]),
                           delay=float(values["COM_FAIL_ACT_T"][1]))

    def _targets_us(self, msg: Any) -> bool:
        system = getattr(msg, "target_system", 0)
        component = getattr(msg, "target_component", 0)
        return system in (0, self.system_id) and component in (0, self.component_id)

    def _handle_message(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "SET_POSITION_TARGET_LOCAL_NED":
            if self._targets_us(msg) and msg.coordinate_frame == M.MAV_FRAME_LOCAL_NED:
                self.stats.setpoints += 1
                self.vehicle.command_setpoint(setpoint_from_target_local_ned(msg))
        elif kind == "TIMESYNC":
            self._answer_timesync(msg)
        elif kind in ("PARAM_REQUEST_READ", "PARAM_REQUEST_LIST", "PARAM_SET"):
            if self._targets_us(msg):
                self.parameters.handle(msg)
        elif kind == "COMMAND_LONG":
            if self._targets_us(msg):
                params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
                self._handle_command(msg, msg.command, params)
        elif kind == "COMMAND_INT":
            if self._targets_us(msg):
                params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.x * 1e-7, msg.y * 1e-7, msg.z]
                self._handle_command(msg, msg.command, params)

    def _handle_command(self, msg: Any, command: int, p: list[float]) -> None:
        name = M.enums["MAV_CMD"][command].name if command in M.enums["MAV_CMD"] else str(command)
        self.stats.commands[name] = self.stats.commands.get(name, 0) + 1
        vehicle = self.vehicle
        result = M.MAV_RESULT_ACCEPTED
        try:
            if command in self._command_faults:
                faulty = self._command_faults[command]
                if faulty is None:
                    return
                result = faulty
            elif command == M.MAV_CMD_COMPONENT_ARM_DISARM:
                action = round(p[0])
                if action == 1:
                    refusal = None if vehicle.armed else self.parameters.arming_refusal(self._ground_station_age())
                    if refusal is not None:
                        raise CommandRejected("arm", refusal)
                    vehicle.arm()
                elif action == 0:
                    vehicle.disarm(force=round(p[1]) == 21196)  # PX4's magic number
                else:
                    result = M.MAV_RESULT_UNSUPPORTED
            elif command == M.MAV_CMD_DO_SET_MODE:
                result = self._set_mode(int(p[0]), int(p[1]), int(p[2]))
            elif command == M.MAV_CMD_NAV_TAKEOFF:
                # param7 is the AMSL altitude; NaN means PX4's MIS_TAKEOFF_ALT.
                home_amsl = self.origin[2] + float(vehicle.home[2])
                altitude = p[6] - home_amsl if math.isfinite(p[6]) else vehicle.params.takeoff_altitude
                if altitude <= 0.0:
                    raise CommandRejected("takeoff", f"altitude {p[6]!r} m AMSL is not above home")
                vehicle.request_takeoff(altitude)
            elif command == M.MAV_CMD_NAV_LAND:
                vehicle.land()
            elif command == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                vehicle.return_to_launch()
            elif command == M.MAV_CMD_SET_MESSAGE_INTERVAL:
                result = self._set_interval(int(p[0]), p[1])
            elif command == M.MAV_CMD_REQUEST_MESSAGE:
                result = self._send_requested(int(p[0]))
            elif command == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
                self._send_autopilot_version()
            elif command in UNANSWERED_COMMANDS:
                return  # PX4 routes these to a gimbal module SITL does not run: no COMMAND_ACK at all
            else:  # MAV_CMD_IMAGE_START_CAPTURE included: PX4 answers UNSUPPORTED
                result = M.MAV_RESULT_UNSUPPORTED
        except CommandRejected as refusal:
            result = M.MAV_RESULT_TEMPORARILY_REJECTED if refusal.temporary else M.MAV_RESULT_DENIED
        self.stats.last_ack[command] = result
        self._send(M.MAVLink_command_ack_message(
            command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _ground_station_age(self) -> float | None:
        """Vehicle s since a ground station's last HEARTBEAT on the GCS link (None: never)."""
        heard = None if self.gcs is None else self.gcs.last_heartbeat
        return None if heard is None else (time.monotonic() - heard) * self.time_scale

    def _set_mode(self, base_mode: int, main: int, sub: int) -> int:
        """PX4 1.16's answers (measured on the SITL): an unknown main mode or a request
        without the custom-mode flag is ACCEPTED and nothing changes (only the HEARTBEAT
        tells). A mode it cannot enter now (POSCTL/MANUAL without RC, OFFBOARD without a
        setpoint stream) is TEMPORARILY_REJECTED when armed, ACCEPTED without switching
        when disarmed (PX4 also answered OFFBOARD-without-stream in the air ACCEPTED,
        without switching, in one of three runs: the client trusts the HEARTBEAT)."""
        mode = px4_modes.mode_from_set_mode(main, sub)
        if mode is None or not base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return M.MAV_RESULT_ACCEPTED
        try:
            if mode in (FlightMode.POSCTL, FlightMode.MANUAL) and not self.rc_connected:
                raise CommandRejected(f"set mode {mode.value}", "no RC")
            self.vehicle.set_mode(mode)
        except CommandRejected:
            if self.vehicle.armed:
                raise
        return M.MAV_RESULT_ACCEPTED
