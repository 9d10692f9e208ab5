"""The offboard client: the ``Vehicle`` interface over MAVLink 2 to PX4 (pymavlink).

What it does, as PX4's offboard documentation asks, one job per module:

* ``link``: connects over UDP (``udpin:HOST:PORT``, ``udpout:HOST:PORT``) or
  serial (``/dev/ttyTHS1:921600``), accepts only the autopilot it connected to
  (system, component, address), parses each datagram on its own and counts
  what it drops;
* ``telemetry``: requests telemetry with SET_MESSAGE_INTERVAL and keeps one
  consistent state: mode, armed, landed state, local position/velocity (NED
  converted to ENU there and only there), attitude, global position, home,
  battery;
* ``commands``: arms with MAV_CMD_COMPONENT_ARM_DISARM, switches with
  MAV_CMD_DO_SET_MODE (custom main mode 6 = OFFBOARD), takes off, lands,
  returns; every COMMAND_ACK is read (with retransmission) and a refusal raises
  ``CommandRejected`` naming the command and result; a mode is only believed
  once the HEARTBEAT shows it (PX4 may ACCEPT a mode and not enter it);
* ``failsafes``: heartbeat lost, a mode change we did not command, stale
  position, low battery; ``advance`` raises ``VehicleFailsafe`` once with the
  reason and the action taken; ``state().fault`` keeps the reason;
* this module: the two threads (receiving; sending our HEARTBEAT at 1 Hz as an
  onboard computer and streaming SET_POSITION_TARGET_LOCAL_NED at
  ``setpoint_rate_hz``, 20 Hz of vehicle time, before and during offboard) and
  the ``Vehicle`` methods;
* ``parameters``: PARAM_REQUEST_READ / PARAM_SET verified by PARAM_VALUE (bytewise-encoded
  integers, the parameter's own type, retried on loss): :attr:`MavlinkVehicle.parameters`;
* ``timesync``: TIMESYNC both ways (our requests, 10 Hz then 1 Hz, fitted into the host ->
  vehicle clock map; PX4's requests answered with our time): :attr:`MavlinkVehicle.timesync`
  is the companion computer's vehicle clock;
* MAVLink 2 signing with a 32-byte key (``signing``: signature checked before
  any stream state changes).

The inspection photo is not the autopilot's business: the camera is the
companion computer's own (the ``Sensors`` port); PX4 answers
MAV_CMD_IMAGE_START_CAPTURE with UNSUPPORTED, so the client never sends it.

W is PX4's local frame converted to ENU, shifted by ``local_origin_w`` (the
position of PX4's local origin in W; zero when they coincide, as in the sim).
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from insulator_rs.exceptions import CommandRejected, VehicleError, VehicleFailsafe
from insulator_rs.mavlink import px4_modes
from insulator_rs.mavlink.commands import CommandProtocol
from insulator_rs.mavlink.failsafes import FailsafeMonitor, FailsafeSettings
from insulator_rs.mavlink.setpoint_gaps import SetpointGaps
from insulator_rs.mavlink.frames import enu_to_ned, local_origin_in_w, yaw_enu_to_ned
from insulator_rs.mavlink.link import AutopilotLink, LinkStats, open_connection
from insulator_rs.mavlink.parameters import ParameterProtocol
from insulator_rs.mavlink.signing import configure_signing, load_signing_key
from insulator_rs.mavlink.telemetry import REQUESTED_RATES_HZ, Telemetry, TelemetryStore
from insulator_rs.mavlink.timesync import MavlinkTimesync
from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.validation import as_finite, as_vector3, require_positive
from insulator_rs.ports.vehicle import FlightMode, NavigationStatus, VehicleState
from insulator_rs.timesync import TimesyncRecord

__all__ = ["CommandRejected", "FailsafeSettings", "LinkStats", "MavlinkVehicle", "Telemetry", "VehicleFailsafe",
           "connect_vehicle", "open_connection"]

M = mavlink2
# MAV_COMP_ID_ONBOARD_COMPUTER: we are the companion computer of the vehicle.
ONBOARD_COMPONENT_ID = 191
# type_mask for position + velocity + yaw: acceleration/force and yaw rate ignored.
TYPE_MASK_IGNORE_ACCEL = (M.POSITION_TARGET_TYPEMASK_AX_IGNORE | M.POSITION_TARGET_TYPEMASK_AY_IGNORE
                          | M.POSITION_TARGET_TYPEMASK_AZ_IGNORE)
TYPE_MASK_POS_VEL_YAW = TYPE_MASK_IGNORE_ACCEL | M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
TYPE_MASK_IGNORE_VEL = (M.POSITION_TARGET_TYPEMASK_VX_IGNORE | M.POSITION_TARGET_TYPEMASK_VY_IGNORE
                        | M.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
UNSIGNED_ALLOWED = frozenset({M.MAVLINK_MSG_ID_RADIO_STATUS})
# Wall seconds one receive poll may wait: the failsafe checks run at least this often.
RECEIVE_POLL_S = 0.05

Setpoint = tuple[np.ndarray, "np.ndarray | None", "float | None"]


class MavlinkVehicle:
    """The ``Vehicle`` interface on a PX4 autopilot over MAVLink 2.

    ``target_system`` pins the autopilot's system id (default: the first autopilot
    heartbeat's; PX4 SITL instance N is system N + 1).
    """

    def __init__(
        self,
        connection: str,
        *,
        heartbeat_timeout: float = 10.0,
        command_timeout: float = 1.0,
        command_retries: int = 3,
        parameter_timeout: float = 1.0,
        parameter_retries: int = 5,
        setpoint_rate_hz: float = 20.0,
        time_scale: float = 1.0,
        failsafes: FailsafeSettings | None = None,
        signing_key: bytes | None = None,
        source_system: int = 1,
        source_component: int = ONBOARD_COMPONENT_ID,
        local_origin_w: object = (0.0, 0.0, 0.0),
        target_system: int | None = None,
    ) -> None:
        heartbeat_timeout = require_positive(heartbeat_timeout, "heartbeat_timeout")
        command_timeout = require_positive(command_timeout, "command_timeout")
        parameter_timeout = require_positive(parameter_timeout, "parameter_timeout")
        self.setpoint_rate_hz = as_finite(setpoint_rate_hz, "setpoint_rate_hz")
        if self.setpoint_rate_hz < 20.0:
            raise ValueError(f"setpoint_rate_hz must be >= 20 (PX4 offboard), got {setpoint_rate_hz!r}")
        self.time_scale = require_positive(time_scale, "time_scale")
        # our stream's own gaps: PX4's brief offboard-loss failsafes, which the 1 Hz heartbeat misses
        self.setpoint_gaps = SetpointGaps(time_scale=self.time_scale)
        self.failsafes = failsafes or FailsafeSettings()
        self.local_origin_w = as_vector3(local_origin_w, "local_origin_w")
        self.connection = connection
        self._close_also: list[Callable[[], None]] = []  # what close() stops too (close_with)

        self._lock = threading.Condition()
        self._stop = threading.Event()
        self._telemetry = TelemetryStore()
        self._monitor = FailsafeMonitor(self.failsafes)
        self._setpoint: Setpoint | None = None
        self.timesync = MavlinkTimesync()  # host -> vehicle clock (TIMESYNC, both ways)
        self._link = AutopilotLink(connection, source_system=source_system, source_component=source_component,
                                   target_system=target_system)
        self._commands = CommandProtocol(self._link, self._lock, self._stop, timeout=command_timeout,
                                         retries=command_retries)
        # the autopilot's parameters (PARAM_SET verified by PARAM_VALUE): the ParameterStore port
        self.parameters = ParameterProtocol(self._link, self._lock, self._stop, timeout=parameter_timeout,
                                            retries=parameter_retries)
        self._link.add_listener(self._foreign_message)
        if signing_key is not None:
            configure_signing(self._link.mav, signing_key, link_id=1, allow_unsigned=UNSIGNED_ALLOWED)
        self._receiver = threading.Thread(target=self._receive_loop, name="mavlink-rx", daemon=True)
        self._sender = threading.Thread(target=self._send_loop, name="mavlink-tx", daemon=True)
        self._receiver.start()
        self._sender.start()
        try:
            self._wait_for(lambda: self._telemetry.heartbeat is not None, heartbeat_timeout,
                           f"no autopilot heartbeat on {connection} within {heartbeat_timeout:g} s")
            for message_id, rate in REQUESTED_RATES_HZ.items():
                try:
                    self._command(M.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 1e6 / rate,
                                  detail=M.mavlink_map[message_id].msgname)
                except CommandRejected:
                    if message_id != M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
                        raise  # an autopilot without ATTITUDE_QUATERNION: the attitude from ATTITUDE
            self._wait_for(lambda: self._telemetry.local is not None and self._telemetry.home is not None,
                           heartbeat_timeout, "no LOCAL_POSITION_NED/HOME_POSITION from the autopilot")
        except BaseException:
            self.close()
            raise

    # -- Vehicle protocol ------------------------------------------------------

    def state(self) -> VehicleState:
        """The latest telemetry as one snapshot in W (ENU)."""
        with self._lock:
            return self._telemetry.vehicle_state(self.local_origin_w, self._monitor.fault)

    def telemetry(self) -> Telemetry:
        """State plus attitude, global position, home and the link's counts, as one snapshot."""
        with self._lock:
            return self._telemetry.snapshot(self.local_origin_w, self._monitor.fault, self._link.stats.as_dict())

    def navigation(self) -> NavigationStatus:
        """The GPS fix (GPS_RAW_INT), global position and home the autopilot last sent."""
        with self._lock:
            return self._telemetry.navigation()

    @property
    def link_stats(self) -> LinkStats:
        """What the link received and dropped, by reason (a live object: read, do not keep)."""
        return self._link.stats

    @property
    def link(self) -> AutopilotLink:
        """The link to the autopilot (other components of the companion send through it)."""
        return self._link

    def timesync_record(self) -> TimesyncRecord:
        """The TIMESYNC map's figures for the summary (source ``none`` if PX4 never answered)."""
        return self.timesync.record()

    @property
    def autopilot(self) -> tuple[int, int] | None:
        """(system id, component id) of the autopilot this client accepts."""
        return self._link.autopilot

    def set_world_origin(self, latitude: float, longitude: float, altitude: float) -> np.ndarray:
        """Place W's origin at a geodetic point (deg, deg, m AMSL), e.g. the tower base.

        PX4's local frame starts where its estimator started, not at the tower, so
        the shift comes from HOME_POSITION, which carries home both in geodetic and
        in local coordinates: local_origin_w = ENU(home wrt origin, pymap3d) -
        ENU(home local). Returns the new ``local_origin_w`` (m, W).
        """
        lat = as_finite(latitude, "latitude")
        lon = as_finite(longitude, "longitude")
        alt = as_finite(altitude, "altitude")
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise ValueError(f"latitude/longitude out of range: {lat!r}, {lon!r}")
        with self._lock:
            home = self._telemetry.home
            if home is None:
                raise VehicleError("no HOME_POSITION from the autopilot yet")
            self.local_origin_w = local_origin_in_w((home.latitude * 1e-7, home.longitude * 1e-7, home.altitude * 1e-3),
                                                    [home.x, home.y, home.z], (lat, lon, alt))
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
            self._monitor.offboard_engaged = True
            self._monitor.commanding_stopped = None

    def hold(self) -> None:
        """Switch to HOLD (AUTO_LOITER) and stop streaming setpoints."""
        self._leave_offboard(FlightMode.HOLD, lambda: self._set_mode(FlightMode.HOLD))

    def takeoff(self, altitude: float) -> None:
        """MAV_CMD_NAV_TAKEOFF to ``altitude`` m above home; the climb runs while ``advance`` waits."""
        altitude = require_positive(altitude, "altitude")
        if not self.state().armed:
            raise VehicleError("takeoff refused: vehicle is disarmed")
        with self._lock:
            home_amsl = self._telemetry.home.altitude / 1000.0
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
            if self._monitor.commanding_stopped is not None:
                raise VehicleFailsafe(self._monitor.commanding_stopped, "offboard commanding stopped")
            first = self._setpoint is None
            self._setpoint = sp
        if first:
            self.setpoint_gaps.paused()  # a new run of the stream, not a gap in it
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
            while (self._telemetry.local.time_boot_ms / 1000.0 < start + dt - 1e-6
                   and self._monitor.pending is None and time.monotonic() < deadline):
                self._lock.wait(timeout=0.05)
        self._check_failsafes()
        return self.state()

    def land(self) -> None:
        self._leave_offboard(FlightMode.LAND, lambda: self._command(
            M.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan, math.nan, math.nan))

    def return_to_launch(self) -> None:
        self._leave_offboard(FlightMode.RTL, lambda: self._command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH))

    def close(self) -> None:
        """Stop the threads, close the link, stop the simulator if we started it."""
        self._stop.set()
        for thread in (getattr(self, "_receiver", None), getattr(self, "_sender", None)):
            if thread is not None and thread.is_alive() and thread is not threading.current_thread():
                thread.join(timeout=2.0)
        link = getattr(self, "_link", None)
        if link is not None:
            link.close()
        also = getattr(self, "_close_also", [])
        while also:
            also.pop()()

    def close_with(self, stop: Callable[[], None]) -> None:
        """Have ``close()`` call ``stop`` too, once, after the link is closed (what a caller
        started for this client, e.g. the simulated PX4 it talks to)."""
        self._close_also.append(stop)

    def __enter__(self) -> MavlinkVehicle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- commands ----------------------------------------------------------------

    def _command(self, command: int, *params: float, detail: str = "") -> None:
        self._commands.send(command, *params, detail=detail)

    def _set_mode(self, mode: FlightMode) -> None:
        main, sub = px4_modes.main_sub_modes(mode)
        with self._lock:
            self._monitor.expected_mode = mode.value
        self._command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub, detail=mode.value)
        self._wait_mode(mode)

    def _wait_mode(self, mode: FlightMode) -> None:
        # PX4 may ACCEPT a mode it then does not enter: the heartbeat (1 Hz of
        # vehicle time) is what confirms the switch.
        self._wait_for(lambda: self.state().mode == mode.value, 2.0 / self.time_scale + 1.0,
                       f"vehicle accepted mode {mode.value} but its heartbeat never showed it")

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

    def _leave_offboard(self, mode: FlightMode, switch: Callable[[], None]) -> None:
        """Leave OFFBOARD for ``mode`` by ``switch()`` (a command), holding the last setpoint's
        position in the stream until the heartbeat shows ``mode``, then stop streaming.

        Why not stop first: PX4 fails safe COM_OF_LOSS_T (1 s) after the last setpoint, and a
        command whose ACK is late or lost is sent again only after 1 s. Against PX4 SITL on a
        loaded box, a landing that stopped the stream first logged ``Failsafe activated`` and
        started PX4's Return before the LAND arrived (flights 4 and 5 of session 9's soak)."""
        with self._lock:
            self._monitor.offboard_engaged = False  # the mode change that follows is ours
            if self._setpoint is not None:
                position, _velocity, yaw = self._setpoint
                self._setpoint = (position, None, yaw)  # hold there: no feed-forward carried on
        try:
            switch()
            self._wait_mode(mode)
        finally:
            self._stop_streaming()

    def _stop_streaming(self) -> None:
        with self._lock:
            self._setpoint = None
            self._monitor.offboard_engaged = False

    def _send_setpoint(self, sp: Setpoint) -> None:
        self.setpoint_gaps.sent_at(time.monotonic())
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
        system, component = self._link.autopilot or (1, 1)
        self._link.send("set_position_target_local_ned", self._boot_ms(), system, component,
                        M.MAV_FRAME_LOCAL_NED, mask, *position_ned, *velocity_ned, 0.0, 0.0, 0.0,
                        0.0 if yaw is None else yaw_enu_to_ned(yaw), 0.0)

    def _boot_ms(self) -> int:
        with self._lock:
            local = self._telemetry.local
            return 0 if local is None else int(local.time_boot_ms)

    def _send_loop(self) -> None:
        period = 1.0 / (self.setpoint_rate_hz * self.time_scale)
        next_heartbeat = 0.0
        next_setpoint = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_heartbeat:
                self._link.send("heartbeat", M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0,
                                M.MAV_STATE_ACTIVE)
                next_heartbeat = now + 1.0
            request = self.timesync.request_due()
            if request is not None:
                self._link.send("timesync", *request)
            with self._lock:
                sp = self._setpoint if self._monitor.commanding_stopped is None else None
            if sp is None:
                self.setpoint_gaps.paused()
            elif now >= next_setpoint:
                self._send_setpoint(sp)
                next_setpoint = max(next_setpoint + period, now)
            self._stop.wait(min(period, 0.05) / 2)

    # -- receiving and failsafes --------------------------------------------------

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            messages = self._link.receive(RECEIVE_POLL_S)
            now = time.monotonic()
            with self._lock:
                for msg in messages:
                    self._update(msg, now)
                if self._monitor.check(self._telemetry, now):
                    self._setpoint = None  # heartbeat lost: the autopilot flies its own failsafe
                self._lock.notify_all()

    def _update(self, msg: Any, now: float) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.autopilot == M.MAV_AUTOPILOT_INVALID:
                return
            previous = self._telemetry.mode
            self._telemetry.set_heartbeat(msg, now)
            if self._monitor.on_mode(previous, px4_modes.decode_custom_mode(msg.custom_mode)):
                self._setpoint = None  # the pilot (or PX4's own failsafe) took the vehicle: stop at once
        elif kind == "COMMAND_ACK":
            self._commands.on_ack(msg)
        elif kind == "PARAM_VALUE":
            self.parameters.on_value(msg)
        elif kind == "TIMESYNC":
            answer = self.timesync.on_timesync(msg.tc1, msg.ts1)
            if answer is not None:  # the autopilot's request: our time back, with its ts1
                self._link.send("timesync", *answer)
        else:
            self._telemetry.update(msg, now)

    def _foreign_message(self, msg: Any) -> None:
        """Another system's message the autopilot forwarded (the receiver's thread, before it takes
        the lock: one float is stored): a ground station's HEARTBEAT says one is on the autopilot's
        data link."""
        if msg.get_type() == "HEARTBEAT" and msg.type == M.MAV_TYPE_GCS:
            self.parameters.on_ground_station_heartbeat()

    def _check_failsafes(self) -> None:
        """Run a pending failsafe's action (commands need this thread) and raise it."""
        with self._lock:
            pending = self._monitor.take_pending()
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
    connection: str,
    *,
    time_scale: float = 1.0,
    signing_key: bytes | str | os.PathLike[str] | None = None,
    **client_options: Any,
) -> MavlinkVehicle:
    """The MAVLink vehicle the mission flies through: a real PX4 or its SITL.

    ``connection`` is a pymavlink connection string, e.g. ``udpin:0.0.0.0:14540``
    (PX4 SITL's offboard port) or ``/dev/ttyTHS1:921600``. ``signing_key`` is the
    32-byte key or the path of a key file (``signing.load_signing_key``); with it
    every message is signed and unsigned ones are ignored, on both ends.
    ``time_scale`` is the SITL's speed factor (keep 1.0 for a real vehicle). The
    simulated PX4 is an adapter of the simulator: ``insulator_rs.sim.px4.connect_simulated_px4``.
    """
    if connection is None:
        raise TypeError("connection must be a MAVLink connection string; the simulated PX4 is started "
                        "by insulator_rs.sim.px4.connect_simulated_px4")
    if signing_key is not None and not isinstance(signing_key, bytes):
        signing_key = load_signing_key(signing_key)
    return MavlinkVehicle(connection, time_scale=time_scale, signing_key=signing_key, **client_options)
