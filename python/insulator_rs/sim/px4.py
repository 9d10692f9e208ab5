"""A simulated PX4 multirotor on loopback UDP, speaking MAVLink 2 as PX4 does.

It runs in a thread of its own: a UDP socket bound on 127.0.0.1, the PX4-like
autopilot of ``insulator_rs.sim.kinematics.KinematicVehicle`` for the motion
and the rules, and the MAVLink surface of PX4:

* HEARTBEAT with MAV_AUTOPILOT_PX4, MAV_TYPE_QUADROTOR and PX4's custom_mode;
* COMMAND_ACK for arm/disarm, DO_SET_MODE, NAV_TAKEOFF, NAV_LAND,
  NAV_RETURN_TO_LAUNCH, SET_MESSAGE_INTERVAL, REQUEST_MESSAGE with the results
  PX4 v1.16.0 SITL gives (measured against it, see tests/test_px4_sitl.py):
  TEMPORARILY_REJECTED for a refused arming or disarming in the air, ACCEPTED
  for arming an armed vehicle, ACCEPTED for an unknown mode (the HEARTBEAT shows
  it did not switch), TEMPORARILY_REJECTED, when armed, for OFFBOARD without a
  setpoint stream and for POSCTL/MANUAL (no RC) (ACCEPTED without switching
  when disarmed), FAILED for
  SET_MESSAGE_INTERVAL of a message it does not stream, UNSUPPORTED for what it
  does not handle (MAV_CMD_IMAGE_START_CAPTURE included: no camera on the
  autopilot), and no answer at all to gimbal/mount commands;
* SET_POSITION_TARGET_LOCAL_NED with PX4's type_mask semantics (ignored fields
  become NaN = not controlled on that axis; yaw or yaw rate or hold);
* telemetry at configurable rates (SET_MESSAGE_INTERVAL changes them):
  LOCAL_POSITION_NED, ATTITUDE, GLOBAL_POSITION_INT (pymap3d from a geodetic
  origin), HOME_POSITION, EXTENDED_SYS_STATE, SYS_STATUS, BATTERY_STATUS,
  SYSTEM_TIME;
* MAVLink 2 signing: with a key, anything not correctly signed is dropped
  (RADIO_STATUS excepted, as PX4 does);
* fault injection: packet loss, delay, a lost link, a pilot's mode change, a
  GPS glitch, loss of the position estimate, a command refused or unanswered.

Time: the vehicle's clock (``time_boot_ms``) runs ``time_scale`` times faster
than the wall clock; telemetry rates and PX4's timeouts (COM_OF_LOSS_T...) are
in vehicle time, as in PX4 SITL with a speed factor.

Peers: telemetry goes to ``remote`` if given (as PX4 SITL streams to the
offboard port) and to every address a valid message came from.

Limitations (kinematic stand-in): roll and pitch are reported as level,
acceleration setpoints are ignored, GLOBAL_POSITION_INT's alt is the WGS84
ellipsoid height of the origin plus the local height.
"""

from __future__ import annotations

import argparse
import heapq
import math
import os
import random
import select
import socket
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pymap3d  # type: ignore[import-untyped]

from insulator_rs.mavlink import px4_modes
from insulator_rs.mavlink.client import MavlinkVehicle
from insulator_rs.mavlink.frames import enu_to_ned, ned_to_enu, yaw_enu_to_ned, yaw_ned_to_enu
from insulator_rs.mavlink.signing import configure_signing, load_signing_key
from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.exceptions import CommandRejected, VehicleFailsafe
from insulator_rs.sim.kinematics import KinematicVehicle, Setpoint
from insulator_rs.sim.px4_gcs import GcsLink, forwarded
from insulator_rs.ports.vehicle import FlightMode

M = mavlink2
# Wall-clock period of the simulation loop (s): physics, inbound, telemetry.
LOOP_PERIOD_S = 0.005
MAX_DATAGRAM = 65535
# Most vehicle time one loop iteration may simulate (s).
MAX_STEP_VEHICLE_S = 0.05
UNSIGNED_ALLOWED = frozenset({M.MAVLINK_MSG_ID_RADIO_STATUS})
# Commands PX4 SITL (SIH) leaves without any COMMAND_ACK: its gimbal/mount modules do not run.
UNANSWERED_COMMANDS = frozenset({M.MAV_CMD_DO_MOUNT_CONTROL, M.MAV_CMD_DO_MOUNT_CONFIGURE,
                                 M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE})

# Telemetry PX4 streams on an onboard link, in Hz of vehicle time.
DEFAULT_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 2.0,
    "LOCAL_POSITION_NED": 50.0,
    "ATTITUDE": 20.0,
    "GLOBAL_POSITION_INT": 10.0,
    "HOME_POSITION": 0.5,
    "BATTERY_STATUS": 1.0,
    "SYSTEM_TIME": 1.0,
}

# type_mask bits of SET_POSITION_TARGET_*: ignore flags.
_POS_IGNORE = (M.POSITION_TARGET_TYPEMASK_X_IGNORE, M.POSITION_TARGET_TYPEMASK_Y_IGNORE,
               M.POSITION_TARGET_TYPEMASK_Z_IGNORE)
_VEL_IGNORE = (M.POSITION_TARGET_TYPEMASK_VX_IGNORE, M.POSITION_TARGET_TYPEMASK_VY_IGNORE,
               M.POSITION_TARGET_TYPEMASK_VZ_IGNORE)


@dataclass
class LinkFaults:
    """Injected link faults, applied to every datagram in both directions."""

    drop_probability: float = 0.0  # each datagram is lost with this probability
    delay_s: float = 0.0  # extra one-way latency, wall seconds
    link_lost: bool = False  # nothing gets through


@dataclass
class SimStats:
    """Counters the tests and the CLI read (updated by the sim thread)."""

    received: int = 0
    dropped: int = 0
    rejected_signature: int = 0
    bad_data: int = 0
    setpoints: int = 0
    commands: dict[str, int] = field(default_factory=dict)
    last_ack: dict[int, int] = field(default_factory=dict)


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


class SimulatedPx4:
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
        self._command_faults: dict[int, int | None] = {}
        # PX4's GCS link and its forwarding between links (sim/px4_gcs.py), when a port is given
        self.gcs = GcsLink(gcs_port) if gcs_port is not None else None

    # -- lifecycle ---------------------------------------------------------------

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the vehicle listens on."""
        host, port = self._sock.getsockname()[:2]
        return host, port

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

    def set_link_lost(self, lost: bool = True) -> None:
        with self._lock:
            self.faults.link_lost = lost

    def set_packet_loss(self, probability: float) -> None:
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability!r}")
        with self._lock:
            self.faults.drop_probability = probability

    def set_delay(self, seconds: float) -> None:
        if not (math.isfinite(seconds) and seconds >= 0.0):
            raise ValueError(f"seconds must be finite and >= 0, got {seconds!r}")
        with self._lock:
            self.faults.delay_s = seconds

    def set_rate(self, message: str, rate_hz: float) -> None:
        """Change a telemetry rate (Hz of vehicle time; 0 stops it), as a fault or a test needs."""
        if message not in self.rates_hz or not (math.isfinite(rate_hz) and rate_hz >= 0.0):
            raise ValueError(f"message must be one of {sorted(self.rates_hz)} and rate_hz >= 0, "
                             f"got {message!r}, {rate_hz!r}")
        with self._lock:
            self.rates_hz[message] = float(rate_hz)
            self._next_send[message] = 0.0

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
                self._send_telemetry()

    def _receive(self, now: float) -> None:
        while True:
            try:
                data, addr = self._sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            if self._lost():
                continue
            if self.faults.delay_s > 0.0:
                self._queue(now + self.faults.delay_s, "in", data, addr)
            else:
                self._handle_datagram(data, addr)

    def _lost(self) -> bool:
        if self.faults.link_lost or (self.faults.drop_probability > 0.0
                                     and self._rng.random() < self.faults.drop_probability):
            self.stats.dropped += 1
            return True
        return False

    def _queue(self, due: float, kind: str, data: bytes, addr: tuple[str, int] | None) -> None:
        self._sequence += 1
        heapq.heappush(self._delayed, (due, self._sequence, kind, data, addr))

    def _deliver_due(self, now: float) -> None:
        while self._delayed and self._delayed[0][0] <= now:
            _due, _seq, kind, data, addr = heapq.heappop(self._delayed)
            if kind == "in" and addr is not None:
                self._handle_datagram(data, addr)
            else:
                self._sendto_peers(data)

    def _handle_datagram(self, data: bytes, addr: tuple[str, int]) -> None:
        try:
            messages = self._mav.parse_buffer(data) or []
        except M.MAVError:
            self.stats.bad_data += 1
            messages = []
        if self._mav.buf_len() > 0:
            # A UDP datagram carries whole frames: a leftover is a truncated or
            # garbage frame, and must not swallow the start of the next datagram.
            self.stats.bad_data += 1
            self._mav.buf = bytearray()
            self._mav.buf_index = 0
            self._mav.expected_length = M.HEADER_LEN_V1 + 2
        for msg in messages:
            if msg.get_type() == "BAD_DATA":
                if "signature" in str(getattr(msg, "reason", "")).lower():
                    self.stats.rejected_signature += 1
                else:
                    self.stats.bad_data += 1
                continue
            self.stats.received += 1
            if addr not in self._peers:
                self._peers.append(addr)
            if self.gcs is not None and forwarded(msg, self.system_id, self.component_id):
                self.gcs.forward_to_gcs(msg)  # as PX4 forwards the companion's messages
            self._handle_message(msg)

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

    def _set_interval(self, message_id: int, interval_us: float) -> int:
        name = next((n for n in self.rates_hz if getattr(M, f"MAVLINK_MSG_ID_{n}") == message_id), None)
        if name is None:
            return M.MAV_RESULT_FAILED  # PX4: FAILED for a message it cannot stream
        if interval_us == -1:
            self.rates_hz[name] = 0.0
        elif interval_us == 0:
            self.rates_hz[name] = DEFAULT_RATES_HZ[name]
        elif interval_us > 0:
            self.rates_hz[name] = 1e6 / interval_us
        else:
            return M.MAV_RESULT_DENIED
        self._next_send[name] = 0.0
        return M.MAV_RESULT_ACCEPTED

    def _send_requested(self, message_id: int) -> int:
        if message_id == M.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            self._send_autopilot_version()
            return M.MAV_RESULT_ACCEPTED
        name = next((n for n in self.rates_hz if getattr(M, f"MAVLINK_MSG_ID_{n}") == message_id), None)
        if name is None:
            return M.MAV_RESULT_UNSUPPORTED
        self._send(self._telemetry(name))
        return M.MAV_RESULT_ACCEPTED

    # -- outbound ----------------------------------------------------------------

    def _send(self, msg: Any) -> None:
        data = msg.pack(self._mav)
        now = time.monotonic()
        if self._lost():
            return
        if self.faults.delay_s > 0.0:
            self._queue(now + self.faults.delay_s, "out", data, None)
        else:
            self._sendto_peers(data)

    def _sendto_peers(self, data: bytes, *, gcs: bool = True) -> None:
        if gcs and self.gcs is not None:
            self.gcs.send(data)
        for peer in self._peers:
            try:
                self._sock.sendto(data, peer)
            except OSError:
                pass  # a peer that went away: UDP has nobody to tell

    def _send_telemetry(self) -> None:
        if not self._peers:
            return
        now = self.vehicle.clock.now
        for name, rate in self.rates_hz.items():
            if rate <= 0.0 or now < self._next_send[name]:
                continue
            self._next_send[name] = max(self._next_send[name] + 1.0 / rate, now)
            self._send(self._telemetry(name))

    def _telemetry(self, name: str) -> Any:
        v = self.vehicle
        state = v.state()
        boot_ms = int(state.time * 1000) & 0xFFFFFFFF
        pos_ned = enu_to_ned(state.position)
        vel_ned = enu_to_ned(state.velocity)
        yaw_ned = yaw_enu_to_ned(state.yaw)
        if name == "HEARTBEAT":
            return self._heartbeat()
        if name == "LOCAL_POSITION_NED":
            return M.MAVLink_local_position_ned_message(boot_ms, *pos_ned, *vel_ned)
        if name == "ATTITUDE":
            return M.MAVLink_attitude_message(boot_ms, 0.0, 0.0, yaw_ned, 0.0, 0.0, 0.0)
        if name == "GLOBAL_POSITION_INT":
            lat, lon, alt = self._geodetic(state.position)
            return M.MAVLink_global_position_int_message(
                boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
                int(round((state.position[2] - v.home[2]) * 1000)),
                *(int(round(c * 100)) for c in vel_ned), int(round(math.degrees(yaw_ned) % 360 * 100)))
        if name == "HOME_POSITION":
            lat, lon, alt = self._geodetic(v.home)
            home_ned = enu_to_ned(v.home)
            return M.MAVLink_home_position_message(
                int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
                *home_ned, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(time.time() * 1e6))
        if name == "EXTENDED_SYS_STATE":
            return M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED, self._landed_state())
        if name == "SYS_STATUS":
            sensors = (M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                       | M.MAV_SYS_STATUS_SENSOR_3D_MAG | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
                       | M.MAV_SYS_STATUS_SENSOR_GPS)
            health = sensors if v.position_valid else sensors & ~M.MAV_SYS_STATUS_SENSOR_GPS
            return M.MAVLink_sys_status_message(
                sensors, sensors, health, 200, self._voltage_mv(), -1,
                int(round(state.battery_fraction * 100)), 0, 0, 0, 0, 0, 0)
        if name == "BATTERY_STATUS":
            return M.MAVLink_battery_status_message(
                0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 2500,
                [self._voltage_mv()] + [65535] * 9, -1, -1, -1, int(round(state.battery_fraction * 100)))
        if name == "SYSTEM_TIME":
            return M.MAVLink_system_time_message(int(time.time() * 1e6), boot_ms)
        raise ValueError(f"unknown telemetry message {name!r}")

    def _heartbeat(self) -> Any:
        v = self.vehicle
        base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if v.armed:
            base |= M.MAV_MODE_FLAG_SAFETY_ARMED
        if v.mode != FlightMode.MANUAL:
            base |= M.MAV_MODE_FLAG_STABILIZE_ENABLED | M.MAV_MODE_FLAG_GUIDED_ENABLED
        if v.mode in (FlightMode.HOLD, FlightMode.TAKEOFF, FlightMode.LAND, FlightMode.RTL, FlightMode.MISSION):
            base |= M.MAV_MODE_FLAG_AUTO_ENABLED
        status = M.MAV_STATE_ACTIVE if v.armed else M.MAV_STATE_STANDBY
        if v.fault is not None and v.armed:
            status = M.MAV_STATE_CRITICAL
        return M.MAVLink_heartbeat_message(
            M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, base, px4_modes.encode_custom_mode(v.mode), status, 3)

    def _landed_state(self) -> int:
        v = self.vehicle
        if v.landed:
            return M.MAV_LANDED_STATE_ON_GROUND
        if v.mode == FlightMode.TAKEOFF:
            return M.MAV_LANDED_STATE_TAKEOFF
        if v.mode == FlightMode.LAND:
            return M.MAV_LANDED_STATE_LANDING
        return M.MAV_LANDED_STATE_IN_AIR

    def _voltage_mv(self) -> int:
        # 4S LiPo: 3.5 V (empty) to 4.2 V (full) per cell, linear in charge.
        return int(round(4 * (3500 + 700 * self.vehicle.battery_fraction)))

    def _geodetic(self, position_enu: np.ndarray) -> tuple[float, float, float]:
        lat, lon, alt = pymap3d.enu2geodetic(*position_enu, *self.origin)
        return float(lat), float(lon), float(alt)

    def _send_autopilot_version(self) -> None:
        capabilities = (M.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                        | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                        | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT)
        self._send(M.MAVLink_autopilot_version_message(
            capabilities, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, self.system_id))


def connect_simulated_px4(
    *,
    time_scale: float = 1.0,
    signing_key: bytes | str | os.PathLike[str] | None = None,
    sim_options: dict[str, Any] | None = None,
    **client_options: Any,
) -> MavlinkVehicle:
    """Start a ``SimulatedPx4`` on a free loopback port and connect the MAVLink client to it
    (``udpout``). The client owns the simulator (``client.simulator``) and stops it on
    ``close()``. ``sim_options`` go to ``SimulatedPx4``, ``client_options`` to ``MavlinkVehicle``;
    ``signing_key`` (bytes or a key file) is used by both ends."""
    if signing_key is not None and not isinstance(signing_key, bytes):
        signing_key = load_signing_key(signing_key)
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


def main(argv: list[str] | None = None) -> int:
    """Run the simulated PX4 standalone: ``python -m insulator_rs.sim.px4``."""
    parser = argparse.ArgumentParser(description="Simulated PX4 multirotor on loopback UDP (MAVLink 2).")
    parser.add_argument("--port", type=int, default=18570, help="UDP port to listen on (default 18570)")
    parser.add_argument("--remote", default="127.0.0.1:14540",
                        help="host:port to stream telemetry to (default 127.0.0.1:14540; '' for none)")
    parser.add_argument("--time-scale", type=float, default=1.0, help="vehicle seconds per wall second")
    parser.add_argument("--signing-key", help="file with the MAVLink 2 signing key (64 hex chars)")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: run until Ctrl-C)")
    args = parser.parse_args(argv)
    remote = None
    if args.remote:
        host, _, port = args.remote.rpartition(":")
        remote = (host or "127.0.0.1", int(port))
    key = load_signing_key(args.signing_key) if args.signing_key else None
    sim = SimulatedPx4(port=args.port, remote=remote, time_scale=args.time_scale, signing_key=key)
    with sim:
        print(f"simulated PX4 listening on udp {sim.address[0]}:{sim.address[1]}, streaming to {remote}",
              flush=True)
        deadline = time.monotonic() + args.duration if args.duration > 0 else math.inf
        try:
            while time.monotonic() < deadline:
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
        state = sim.with_vehicle(lambda v: v.state())
        print(f"stopped: mode {state.mode}, armed {state.armed}, position {np.round(state.position, 2)}, "
              f"stats {sim.stats}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
