"""The offboard client: the ``Vehicle`` interface over MAVLink 2 to PX4 (pymavlink).

What it does, as PX4's offboard documentation asks:

* connects over UDP (``udpin:HOST:PORT``, ``udpout:HOST:PORT``) or serial
  (``/dev/ttyTHS1:921600``), sends its own HEARTBEAT at 1 Hz (as an onboard
  computer), waits for the autopilot's heartbeat, requests its telemetry with
  SET_MESSAGE_INTERVAL and keeps one consistent state: mode, armed, landed
  state, local position/velocity (NED converted to ENU here and only here),
  attitude, global position, home, battery;
* streams SET_POSITION_TARGET_LOCAL_NED (position + velocity feed-forward +
  yaw; type_mask ignores acceleration and yaw rate) from a background thread
  at ``setpoint_rate_hz`` (20 Hz) before and during offboard;
* arms with MAV_CMD_COMPONENT_ARM_DISARM, switches with MAV_CMD_DO_SET_MODE
  (custom main mode 6 = OFFBOARD), takes off, lands, returns; every
  COMMAND_ACK is read (with retransmission per the MAVLink command protocol)
  and a refusal raises ``CommandRejected`` naming the command and result;
* never asks the autopilot for photos: the inspection camera is the companion
  computer's own (the ``Sensors`` port); PX4 answers MAV_CMD_IMAGE_START_CAPTURE
  with UNSUPPORTED;
* failsafes on our side: autopilot heartbeat lost, a mode change we did not
  command (the pilot took over: setpoint streaming stops at once, in the
  receiving thread), stale local position (-> HOLD), low battery (-> RTL or
  HOLD). ``advance`` raises ``VehicleFailsafe`` once with the reason and the
  action taken; ``state().fault`` keeps the reason;
* MAVLink 2 signing with a 32-byte key (see ``signing.load_signing_key``).

W is PX4's local frame converted to ENU, shifted by ``local_origin_w`` (the
position of PX4's local origin in W; zero when they coincide, as in the sim).
"""

from __future__ import annotations

import math
import os
import re
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from insulator_rs.exceptions import VehicleError
from insulator_rs.mavlink import px4_modes
from insulator_rs.mavlink.frames import (
    attitude_ned_frd_to_enu_flu,
    enu_to_ned,
    ned_to_enu,
    yaw_enu_to_ned,
    yaw_ned_to_enu,
)
from insulator_rs.mavlink.signing import configure_signing, load_signing_key
from insulator_rs.mavlink.wire import command_name, mavlink2, mavutil, result_name
from insulator_rs.sim.kinematics import (
    FlightMode,
    VehicleFailsafe,
    as_finite,
    as_vector3,
    require_positive,
)
from insulator_rs.vehicle import VehicleState

M = mavlink2
# MAV_COMP_ID_ONBOARD_COMPUTER: we are the companion computer of the vehicle.
ONBOARD_COMPONENT_ID = 191
# type_mask for position + velocity + yaw: acceleration/force and yaw rate ignored.
TYPE_MASK_IGNORE_ACCEL = (M.POSITION_TARGET_TYPEMASK_AX_IGNORE | M.POSITION_TARGET_TYPEMASK_AY_IGNORE
                          | M.POSITION_TARGET_TYPEMASK_AZ_IGNORE)
TYPE_MASK_POS_VEL_YAW = TYPE_MASK_IGNORE_ACCEL | M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
TYPE_MASK_IGNORE_VEL = (M.POSITION_TARGET_TYPEMASK_VX_IGNORE | M.POSITION_TARGET_TYPEMASK_VY_IGNORE
                        | M.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
# Telemetry the client asks for (Hz).
REQUESTED_RATES_HZ: dict[int, float] = {
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 50.0,
    M.MAVLINK_MSG_ID_ATTITUDE: 20.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 2.0,
    M.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
}
UNSIGNED_ALLOWED = frozenset({M.MAVLINK_MSG_ID_RADIO_STATUS})
_SERIAL = re.compile(r"^(?P<device>(/|COM|com)[^:]*):(?P<baud>\d+)$")


class CommandRejected(VehicleError):
    """The autopilot answered a command with something other than ACCEPTED."""

    def __init__(self, command: str, result: str, detail: str = "") -> None:
        what = f"{command} ({detail})" if detail else command
        super().__init__(f"{what} refused by the vehicle: {result}")
        self.command = command
        self.result = result


@dataclass(frozen=True)
class Telemetry:
    """Everything the client knows about the vehicle, read under one lock.

    ``attitude`` is R_w_b (3x3, body FLU -> W ENU); ``global_position`` and
    ``home_global`` are (latitude deg, longitude deg, altitude m AMSL); ``home``
    is the home position in W (m). None where the autopilot has not sent it.
    """

    state: VehicleState
    attitude: np.ndarray | None
    global_position: tuple[float, float, float] | None
    home_global: tuple[float, float, float] | None
    home: np.ndarray | None
    landed_state: str


@dataclass(frozen=True)
class FailsafeSettings:
    """Client-side failsafe thresholds (wall seconds; battery as a fraction)."""

    link_loss_timeout: float = 3.0
    position_stale_timeout: float = 1.0
    low_battery_fraction: float = 0.2
    low_battery_action: str = "return"  # "return" (RTL) or "hold"

    def __post_init__(self) -> None:
        for name in ("link_loss_timeout", "position_stale_timeout"):
            require_positive(getattr(self, name), name)
        if not 0.0 <= self.low_battery_fraction < 1.0:
            raise ValueError(f"low_battery_fraction must be in [0, 1), got {self.low_battery_fraction!r}")
        if self.low_battery_action not in ("return", "hold"):
            raise ValueError(f"low_battery_action must be 'return' or 'hold', got {self.low_battery_action!r}")


def open_connection(connection: str, *, source_system: int, source_component: int) -> Any:
    """A pymavlink connection for ``udpin:``/``udpout:``/``udp:``/``tcp:`` strings or ``DEVICE:BAUD``."""
    if not isinstance(connection, str) or not connection:
        raise TypeError(f"connection must be a non-empty string, got {connection!r}")
    serial = _SERIAL.match(connection)
    if serial:
        return mavutil.mavlink_connection(serial["device"], baud=int(serial["baud"]),
                                          source_system=source_system, source_component=source_component)
    if not connection.startswith(("udpin:", "udpout:", "udp:", "tcp:", "tcpin:")):
        raise ValueError("connection must be udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT "
                         f"or DEVICE:BAUD, got {connection!r}")
    return mavutil.mavlink_connection(connection, source_system=source_system,
                                      source_component=source_component)


class MavlinkVehicle:
    """The ``Vehicle`` interface on a PX4 autopilot over MAVLink 2."""

    def __init__(
        self,
        connection: str,
        *,
        heartbeat_timeout: float = 10.0,
        command_timeout: float = 1.0,
        command_retries: int = 3,
        setpoint_rate_hz: float = 20.0,
        time_scale: float = 1.0,
        failsafes: FailsafeSettings | None = None,
        signing_key: bytes | None = None,
        source_system: int = 1,
        source_component: int = ONBOARD_COMPONENT_ID,
        local_origin_w: object = (0.0, 0.0, 0.0),
    ) -> None:
        heartbeat_timeout = require_positive(heartbeat_timeout, "heartbeat_timeout")
        self.command_timeout = require_positive(command_timeout, "command_timeout")
        if not isinstance(command_retries, int) or command_retries < 1:
            raise ValueError(f"command_retries must be an int >= 1, got {command_retries!r}")
        self.command_retries = command_retries
        self.setpoint_rate_hz = as_finite(setpoint_rate_hz, "setpoint_rate_hz")
        if self.setpoint_rate_hz < 20.0:
            raise ValueError(f"setpoint_rate_hz must be >= 20 (PX4 offboard), got {setpoint_rate_hz!r}")
        self.time_scale = require_positive(time_scale, "time_scale")
        self.failsafes = failsafes or FailsafeSettings()
        self.local_origin_w = as_vector3(local_origin_w, "local_origin_w")
        self.connection = connection
        self.simulator: Any = None  # set by connect_vehicle when it started the sim

        self._lock = threading.Condition()
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._acks: dict[int, Any] = {}
        self._target = (1, 1)
        self._heartbeat: Any = None
        self._heartbeat_wall = -math.inf
        self._local: Any = None
        self._local_wall = -math.inf
        self._attitude: Any = None
        self._global: Any = None
        self._home: Any = None
        self._landed_state = M.MAV_LANDED_STATE_UNDEFINED
        self._battery = 1.0
        self._setpoint: tuple[np.ndarray, np.ndarray | None, float | None] | None = None
        self._offboard_engaged = False
        self._commanding_stopped: str | None = None
        self._expected_mode: str | None = None
        self._fault: str | None = None
        self._pending_failsafe: tuple[str, str] | None = None
        self._raised_failsafes: set[str] = set()

        self._conn = open_connection(connection, source_system=source_system, source_component=source_component)
        if signing_key is not None:
            configure_signing(self._conn.mav, signing_key, link_id=1, allow_unsigned=UNSIGNED_ALLOWED)
        self._receiver = threading.Thread(target=self._receive_loop, name="mavlink-rx", daemon=True)
        self._sender = threading.Thread(target=self._send_loop, name="mavlink-tx", daemon=True)
        self._receiver.start()
        self._sender.start()
        try:
            self._wait_for(lambda: self._heartbeat is not None, heartbeat_timeout,
                           f"no autopilot heartbeat on {connection} within {heartbeat_timeout:g} s")
            for message_id, rate in REQUESTED_RATES_HZ.items():
                self._command(M.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 1e6 / rate,
                              detail=M.mavlink_map[message_id].msgname)
            self._wait_for(lambda: self._local is not None and self._home is not None, heartbeat_timeout,
                           "no LOCAL_POSITION_NED/HOME_POSITION from the autopilot")
        except BaseException:
            self.close()
            raise

    # -- Vehicle protocol ------------------------------------------------------

    def state(self) -> VehicleState:
        """The latest telemetry as one snapshot in W (ENU)."""
        with self._lock:
            local, heartbeat, attitude = self._local, self._heartbeat, self._attitude
            if local is None or heartbeat is None:
                raise VehicleError("no telemetry from the autopilot yet")
            position = ned_to_enu([local.x, local.y, local.z]) + self.local_origin_w
            velocity = ned_to_enu([local.vx, local.vy, local.vz])
            yaw = yaw_ned_to_enu(attitude.yaw) if attitude is not None else 0.0
            return VehicleState(
                time=local.time_boot_ms / 1000.0,
                position=position,
                velocity=velocity,
                yaw=yaw,
                armed=bool(heartbeat.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED),
                mode=px4_modes.decode_custom_mode(heartbeat.custom_mode),
                landed=self._landed_state == M.MAV_LANDED_STATE_ON_GROUND,
                battery_fraction=self._battery,
                healthy=self._fault is None,
                fault=self._fault,
            )

    def telemetry(self) -> Telemetry:
        """State plus attitude, global position and home, as one consistent snapshot."""
        with self._lock:
            state = self.state()
            att, gpos, home = self._attitude, self._global, self._home
            landed = M.enums["MAV_LANDED_STATE"][self._landed_state].name
            return Telemetry(
                state=state,
                attitude=None if att is None else attitude_ned_frd_to_enu_flu(att.roll, att.pitch, att.yaw),
                global_position=None if gpos is None else (gpos.lat * 1e-7, gpos.lon * 1e-7, gpos.alt * 1e-3),
                home_global=None if home is None else (home.latitude * 1e-7, home.longitude * 1e-7,
                                                       home.altitude * 1e-3),
                home=None if home is None else ned_to_enu([home.x, home.y, home.z]) + self.local_origin_w,
                landed_state=landed,
            )

    def set_world_origin(self, latitude: float, longitude: float, altitude: float) -> np.ndarray:
        """Place W's origin at a geodetic point (deg, deg, m AMSL), e.g. the tower base.

        PX4's local frame starts where its estimator started, not at the tower, so
        the shift comes from HOME_POSITION, which carries home both in geodetic and
        in local coordinates: local_origin_w = ENU(home wrt origin, pymap3d) -
        ENU(home local). Returns the new ``local_origin_w`` (m, W).
        """
        import pymap3d  # type: ignore[import-untyped]

        lat = as_finite(latitude, "latitude")
        lon = as_finite(longitude, "longitude")
        alt = as_finite(altitude, "altitude")
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise ValueError(f"latitude/longitude out of range: {lat!r}, {lon!r}")
        with self._lock:
            home = self._home
            if home is None:
                raise VehicleError("no HOME_POSITION from the autopilot yet")
            home_w = np.array(pymap3d.geodetic2enu(home.latitude * 1e-7, home.longitude * 1e-7,
                                                   home.altitude * 1e-3, lat, lon, alt), dtype=np.float64)
            self.local_origin_w = home_w - ned_to_enu([home.x, home.y, home.z])
            return self.local_origin_w.copy()

    def arm(self) -> None:
        """MAV_CMD_COMPONENT_ARM_DISARM(1); returns once the heartbeat shows armed."""
        self._command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, detail="arm")
        self._wait_for(lambda: self.state().armed, 2.0 / self.time_scale + 1.0,
                       "vehicle accepted arming but its heartbeat never showed armed")

    def disarm(self) -> None:
        self._command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, detail="disarm")

    def start_offboard(self) -> None:
        """DO_SET_MODE custom main mode 6; the setpoint stream must already be running."""
        self._set_mode(FlightMode.OFFBOARD)
        with self._lock:
            self._offboard_engaged = True
            self._commanding_stopped = None

    def hold(self) -> None:
        """Switch to HOLD (AUTO_LOITER) and stop streaming setpoints."""
        self._stop_streaming()
        self._set_mode(FlightMode.HOLD)

    def takeoff(self, altitude: float) -> None:
        """MAV_CMD_NAV_TAKEOFF to ``altitude`` m above home; the climb runs while ``advance`` waits."""
        altitude = require_positive(altitude, "altitude")
        if not self.state().armed:
            raise VehicleError("takeoff refused: vehicle is disarmed")
        with self._lock:
            home_amsl = self._home.altitude / 1000.0
        self._stop_streaming()
        self._command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, home_amsl + altitude,
                      detail=f"{altitude:g} m")

    def send_setpoint(
        self, position: np.ndarray, velocity: np.ndarray | None = None, yaw: float | None = None
    ) -> None:
        """Set the position (+ velocity feed-forward, + yaw) setpoint the background thread streams."""
        sp = (as_vector3(position, "position"),
              None if velocity is None else as_vector3(velocity, "velocity"),
              None if yaw is None else as_finite(yaw, "yaw"))
        with self._lock:
            if self._commanding_stopped is not None:
                raise VehicleFailsafe(self._commanding_stopped, "offboard commanding stopped")
            first = self._setpoint is None
            self._setpoint = sp
        if first:
            self._send_setpoint(sp)

    def advance(self, dt: float) -> VehicleState:
        """Wait until the vehicle clock has moved ``dt`` s; raise ``VehicleFailsafe`` if one fired."""
        dt = require_positive(dt, "dt")
        self._check_failsafes()
        start = self.state().time
        # Vehicle time is known at the LOCAL_POSITION_NED rate: stop within half a
        # sample of the target instead of overshooting by a whole one.
        dt -= 0.5 / REQUESTED_RATES_HZ[M.MAVLINK_MSG_ID_LOCAL_POSITION_NED]
        wall_limit = dt / self.time_scale + self.failsafes.link_loss_timeout + 1.0
        deadline = time.monotonic() + wall_limit
        with self._lock:
            while (self._local.time_boot_ms / 1000.0 < start + dt - 1e-6 and self._pending_failsafe is None
                   and time.monotonic() < deadline):
                self._lock.wait(timeout=0.05)
        self._check_failsafes()
        return self.state()

    def land(self) -> None:
        self._stop_streaming()
        self._command(M.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)
        self._wait_mode(FlightMode.LAND)

    def return_to_launch(self) -> None:
        self._stop_streaming()
        self._command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH)
        self._wait_mode(FlightMode.RTL)

    def close(self) -> None:
        """Stop the threads, close the link, stop the simulator if we started it."""
        self._stop.set()
        for thread in (getattr(self, "_receiver", None), getattr(self, "_sender", None)):
            if thread is not None and thread.is_alive() and thread is not threading.current_thread():
                thread.join(timeout=2.0)
        try:
            self._conn.close()
        except (OSError, AttributeError):
            pass
        if self.simulator is not None:
            self.simulator.stop()
            self.simulator = None

    def __enter__(self) -> MavlinkVehicle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- commands ----------------------------------------------------------------

    def _set_mode(self, mode: FlightMode) -> None:
        main, sub = px4_modes.main_sub_modes(mode)
        with self._lock:
            self._expected_mode = mode.value
        self._command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub, detail=mode.value)
        self._wait_mode(mode)

    def _wait_mode(self, mode: FlightMode) -> None:
        # The heartbeat (1 Hz of vehicle time) confirms the switch.
        self._wait_for(lambda: self.state().mode == mode.value, 2.0 / self.time_scale + 1.0,
                       f"vehicle accepted mode {mode.value} but its heartbeat never showed it")

    def _command(self, command: int, *params: float, detail: str = "", component: int | None = None) -> None:
        """COMMAND_LONG with retransmission; raise unless the ACK says ACCEPTED."""
        padded = [float(p) for p in params] + [0.0] * (7 - len(params))
        name = command_name(command)
        for confirmation in range(self.command_retries):
            with self._lock:
                self._acks.pop(command, None)
            with self._send_lock:
                target_component = self._target[1] if component is None else component
                self._conn.mav.command_long_send(self._target[0], target_component, command, confirmation,
                                                 *padded)
            deadline = time.monotonic() + self.command_timeout
            with self._lock:
                while True:
                    ack = self._acks.get(command)
                    if ack is not None and ack.result != M.MAV_RESULT_IN_PROGRESS:
                        break
                    remaining = deadline - time.monotonic()
                    if remaining <= 0 or self._stop.is_set():
                        break
                    self._lock.wait(timeout=remaining)
            if ack is not None and ack.result != M.MAV_RESULT_IN_PROGRESS:
                if ack.result != M.MAV_RESULT_ACCEPTED:
                    raise CommandRejected(name, result_name(ack.result), detail)
                return
        raise VehicleError(f"{name}{f' ({detail})' if detail else ''}: no COMMAND_ACK after "
                           f"{self.command_retries} tries of {self.command_timeout:g} s")

    def _wait_for(self, predicate: Any, timeout: float, message: str) -> None:
        deadline = time.monotonic() + timeout
        with self._lock:
            while True:
                try:
                    if predicate():
                        return
                except VehicleError:
                    pass
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise VehicleError(message)
                self._lock.wait(timeout=min(remaining, 0.05))

    # -- setpoint streaming and heartbeat ---------------------------------------

    def _stop_streaming(self) -> None:
        with self._lock:
            self._setpoint = None
            self._offboard_engaged = False

    def _send_setpoint(self, sp: tuple[np.ndarray, np.ndarray | None, float | None]) -> None:
        position, velocity, yaw = sp
        mask = TYPE_MASK_POS_VEL_YAW
        if velocity is None:
            mask |= TYPE_MASK_IGNORE_VEL
            velocity_ned = np.zeros(3)
        else:
            velocity_ned = enu_to_ned(velocity)
        if yaw is None:
            mask |= M.POSITION_TARGET_TYPEMASK_YAW_IGNORE
        position_ned = enu_to_ned(position - self.local_origin_w)
        with self._send_lock:
            self._conn.mav.set_position_target_local_ned_send(
                self._boot_ms(), self._target[0], self._target[1], M.MAV_FRAME_LOCAL_NED, mask,
                *position_ned, *velocity_ned, 0.0, 0.0, 0.0,
                0.0 if yaw is None else yaw_enu_to_ned(yaw), 0.0)

    def _boot_ms(self) -> int:
        with self._lock:
            return 0 if self._local is None else int(self._local.time_boot_ms)

    def _send_loop(self) -> None:
        period = 1.0 / (self.setpoint_rate_hz * self.time_scale)
        next_heartbeat = 0.0
        next_setpoint = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                if now >= next_heartbeat:
                    with self._send_lock:
                        self._conn.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID,
                                                      0, 0, M.MAV_STATE_ACTIVE)
                    next_heartbeat = now + 1.0
                with self._lock:
                    sp = self._setpoint if self._commanding_stopped is None else None
                if sp is not None and now >= next_setpoint:
                    self._send_setpoint(sp)
                    next_setpoint = max(next_setpoint + period, now)
            except OSError:
                pass  # no route yet (udpin before the first packet): keep trying
            self._stop.wait(min(period, 0.05) / 2)

    # -- receiving and failsafes --------------------------------------------------

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self._conn.recv_match(blocking=True, timeout=0.05)
            except (OSError, ValueError):
                if self._stop.is_set():
                    return
                continue
            now = time.monotonic()
            with self._lock:
                if msg is not None:
                    self._update(msg, now)
                self._detect_failsafes(now)
                self._lock.notify_all()

    def _update(self, msg: Any, now: float) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.autopilot == M.MAV_AUTOPILOT_INVALID or msg.get_srcComponent() != 1:
                return  # another GCS or companion, not the autopilot
            previous = self._heartbeat
            self._target = (msg.get_srcSystem(), msg.get_srcComponent())
            self._heartbeat, self._heartbeat_wall = msg, now
            mode = px4_modes.decode_custom_mode(msg.custom_mode)
            was = None if previous is None else px4_modes.decode_custom_mode(previous.custom_mode)
            if self._offboard_engaged and was == FlightMode.OFFBOARD.value and mode != was \
                    and self._expected_mode != mode:
                # The pilot (or PX4's own failsafe) took the vehicle: stop at once.
                reason = f"mode changed from OFFBOARD to {mode} outside our control"
                self._commanding_stopped = reason
                self._setpoint = None
                self._offboard_engaged = False
                self._raise_failsafe(reason, "offboard commanding stopped")
        elif kind == "LOCAL_POSITION_NED":
            self._local, self._local_wall = msg, now
        elif kind == "ATTITUDE":
            self._attitude = msg
        elif kind == "GLOBAL_POSITION_INT":
            self._global = msg
        elif kind == "HOME_POSITION":
            self._home = msg
        elif kind == "EXTENDED_SYS_STATE":
            self._landed_state = msg.landed_state
        elif kind in ("SYS_STATUS", "BATTERY_STATUS"):
            if msg.battery_remaining >= 0:
                self._battery = msg.battery_remaining / 100.0
        elif kind == "COMMAND_ACK":
            self._acks[msg.command] = msg

    def _raise_failsafe(self, reason: str, action: str) -> None:
        if reason in self._raised_failsafes:
            return
        self._raised_failsafes.add(reason)
        self._fault = reason
        self._pending_failsafe = (reason, action)

    def _detect_failsafes(self, now: float) -> None:
        if self._heartbeat is None:
            return
        fs = self.failsafes
        silent = now - self._heartbeat_wall
        if silent > fs.link_loss_timeout:
            self._setpoint = None
            self._raise_failsafe(f"autopilot heartbeat lost for more than {fs.link_loss_timeout:g} s",
                                 "setpoints stopped; the autopilot flies its own failsafe")
            return
        armed = bool(self._heartbeat.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
        # Stale position only while the link is provably alive: a heartbeat came
        # more than the stale timeout after the last position. A heartbeat that
        # merely happened to be the link's last message must not turn a silent
        # link into a stale-position hold (the heartbeat failsafe above owns that).
        if armed and now - self._local_wall > fs.position_stale_timeout \
                and self._heartbeat_wall - self._local_wall > fs.position_stale_timeout:
            self._raise_failsafe(f"local position stale for more than {fs.position_stale_timeout:g} s", "hold")
        elif armed and self._battery < fs.low_battery_fraction \
                and self._landed_state != M.MAV_LANDED_STATE_ON_GROUND:
            self._raise_failsafe(f"battery low ({self._battery:.0%} < {fs.low_battery_fraction:.0%})",
                                 fs.low_battery_action)

    def _check_failsafes(self) -> None:
        """Run a pending failsafe's action (commands need this thread) and raise it."""
        with self._lock:
            pending, self._pending_failsafe = self._pending_failsafe, None
        if pending is None:
            return
        reason, action = pending
        try:
            if action == "hold":
                self.hold()
            elif action == "return":
                self.return_to_launch()
        except VehicleError as exc:
            action = f"{action} failed ({exc})"
        raise VehicleFailsafe(reason, action)


def connect_vehicle(
    connection: str | None = None,
    *,
    time_scale: float = 1.0,
    signing_key: bytes | str | os.PathLike[str] | None = None,
    sim_options: dict[str, Any] | None = None,
    **client_options: Any,
) -> MavlinkVehicle:
    """The MAVLink vehicle the mission flies through.

    ``connection=None`` starts the simulated PX4 (``px4_sim.SimulatedPx4``) on a
    free loopback port and connects to it (``udpout``); the returned client owns
    it (``client.simulator``) and stops it on ``close()``. Otherwise
    ``connection`` is a pymavlink connection string for a real PX4 or its SITL,
    e.g. ``udpin:0.0.0.0:14540`` or ``/dev/ttyTHS1:921600``. ``signing_key`` is
    the 32-byte key or the path of a key file (``signing.load_signing_key``);
    with it every message is signed and unsigned ones are ignored, on both ends.
    ``time_scale`` is the simulator's speed-up (keep 1.0 for a real vehicle).
    """
    if signing_key is not None and not isinstance(signing_key, bytes):
        signing_key = load_signing_key(signing_key)
    if connection is not None:
        if sim_options:
            raise ValueError("sim_options only apply when connection is None (the built-in simulated PX4)")
        return MavlinkVehicle(connection, time_scale=time_scale, signing_key=signing_key, **client_options)
    from insulator_rs.mavlink.px4_sim import SimulatedPx4

    sim = SimulatedPx4(time_scale=time_scale, signing_key=signing_key, **(sim_options or {})).start()
    try:
        host, port = sim.address
        client = MavlinkVehicle(f"udpout:{host}:{port}", time_scale=time_scale, signing_key=signing_key,
                                **client_options)
    except BaseException:
        sim.stop()
        raise
    client.simulator = sim
    return client
