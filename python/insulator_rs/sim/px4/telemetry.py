"""The simulated PX4's telemetry: PX4's onboard-link streams at rates in vehicle time
(SET_MESSAGE_INTERVAL and REQUEST_MESSAGE change or ask for them), each message built from
the simulated vehicle's state: HEARTBEAT with PX4's custom_mode, LOCAL_POSITION_NED,
ATTITUDE and ATTITUDE_QUATERNION (the airframe's attitude and body rates, FRD/NED),
GLOBAL_POSITION_INT (pymap3d from a geodetic origin), HOME_POSITION,
EXTENDED_SYS_STATE, SYS_STATUS, BATTERY_STATUS, SYSTEM_TIME, AUTOPILOT_VERSION; TIMESYNC both ways (PX4's requests at
10 Hz, and its answers to the companion's).

A mixin of :class:`insulator_rs.sim.px4.autopilot.SimulatedPx4` (which owns the state).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import pymap3d

from insulator_rs.mavlink import px4_modes
from insulator_rs.mavlink.frames import (attitude_enu_flu_to_ned_frd, enu_to_ned, flu_to_frd,
                                         quaternion_ned_frd_from_enu_flu, yaw_enu_to_ned)
from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.ports.vehicle import FlightMode
from insulator_rs.sim.kinematics import KinematicVehicle

M = mavlink2

# Telemetry PX4 streams on an onboard link, in Hz of vehicle time.
DEFAULT_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 2.0,
    "LOCAL_POSITION_NED": 50.0,
    "ATTITUDE": 20.0,
    "ATTITUDE_QUATERNION": 50.0,
    "GLOBAL_POSITION_INT": 10.0,
    "GPS_RAW_INT": 1.0,
    "HOME_POSITION": 0.5,
    "BATTERY_STATUS": 1.0,
    "SYSTEM_TIME": 1.0,
    "TIMESYNC": 10.0,  # PX4's own requests (tc1 = 0, ts1 = its boot time in ns), as v1.16 sends them
}


class Px4Telemetry:
    """The telemetry half of the simulated PX4 (see the module docstring)."""

    vehicle: KinematicVehicle
    rates_hz: dict[str, float]
    origin: tuple[float, float, float]
    system_id: int
    _next_send: dict[str, float]
    _peers: list[tuple[str, int]]
    _lock: Any
    stats: Any
    answer_timesync: bool  # False: an autopilot that never answers TIMESYNC (a fault for the fallback)

    def set_rate(self, message: str, rate_hz: float) -> None:
        """Change a telemetry rate (Hz of vehicle time; 0 stops it), as a fault or a test needs."""
        if message not in self.rates_hz or not (math.isfinite(rate_hz) and rate_hz >= 0.0):
            raise ValueError(f"message must be one of {sorted(self.rates_hz)} and rate_hz >= 0, "
                             f"got {message!r}, {rate_hz!r}")
        with self._lock:
            self.rates_hz[message] = float(rate_hz)
            self._next_send[message] = 0.0

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
        if name in ("ATTITUDE", "ATTITUDE_QUATERNION"):
            R_w_b = state.T_w_b[:3, :3]
            rates = flu_to_frd(np.zeros(3) if state.angular_velocity is None else state.angular_velocity)
            if name == "ATTITUDE":
                return M.MAVLink_attitude_message(boot_ms, *attitude_enu_flu_to_ned_frd(R_w_b), *rates)
            return M.MAVLink_attitude_quaternion_message(boot_ms, *quaternion_ned_frd_from_enu_flu(R_w_b), *rates,
                                                         [0.0, 0.0, 0.0, 0.0])
        if name == "GLOBAL_POSITION_INT":
            lat, lon, alt = self._geodetic(state.position)
            return M.MAVLink_global_position_int_message(
                boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
                int(round((state.position[2] - v.home[2]) * 1000)),
                *(int(round(c * 100)) for c in vel_ned), int(round(math.degrees(yaw_ned) % 360 * 100)))
        if name == "GPS_RAW_INT":  # a 3D fix of 12 satellites, none while the position is lost
            lat, lon, alt = self._geodetic(state.position)
            fix, satellites = (M.GPS_FIX_TYPE_3D_FIX, 12) if v.position_valid else (M.GPS_FIX_TYPE_NO_FIX, 0)
            return M.MAVLink_gps_raw_int_message(
                int(time.time() * 1e6), fix, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
                80, 120, int(round(float(np.linalg.norm(state.velocity[:2])) * 100)), 65535, satellites)
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
                sensors, sensors, health, 200, self._voltage_mv(), -1, _remaining(state.battery_fraction),
                0, 0, 0, 0, 0, 0)
        if name == "BATTERY_STATUS":
            return M.MAVLink_battery_status_message(
                0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 2500,
                [self._voltage_mv()] + [65535] * 9, -1, -1, -1, _remaining(state.battery_fraction))
        if name == "SYSTEM_TIME":
            return M.MAVLink_system_time_message(int(time.time() * 1e6), boot_ms)
        if name == "TIMESYNC":
            return M.MAVLink_timesync_message(0, self._boot_ns())
        raise ValueError(f"unknown telemetry message {name!r}")

    def _boot_ns(self) -> int:
        """PX4's ``hrt_absolute_time() * 1000``: the vehicle clock (that of ``time_boot_ms``) in ns."""
        return int(round(self.vehicle.clock.now * 1e9))

    def _answer_timesync(self, msg: Any) -> None:
        """PX4 v1.16's ``MavlinkTimesync``: a request (``tc1 == 0``) is answered with ``tc1`` =
        its time in ns and the request's ``ts1``; an answer to one of its own requests updates
        its estimate of the companion's clock (counted here, not modelled)."""
        if msg.tc1 == 0:
            if self.answer_timesync:
                self._send(M.MAVLink_timesync_message(self._boot_ns(), msg.ts1))
        elif msg.tc1 > 0:
            self.stats.timesync_answers += 1

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
        # 4S LiPo: 3.5 V (empty) to 4.2 V (full) per cell, linear in charge; UINT16_MAX (MAVLink's
        # "unknown") without a battery monitor
        fraction = self.vehicle.battery_fraction
        return 65535 if fraction is None else int(round(4 * (3500 + 700 * fraction)))

    def _geodetic(self, position_enu: np.ndarray) -> tuple[float, float, float]:
        lat, lon, alt = pymap3d.enu2geodetic(*position_enu, *self.origin)
        return float(lat), float(lon), float(alt)

    def _send_autopilot_version(self) -> None:
        capabilities = (M.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                        | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                        | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT)
        self._send(M.MAVLink_autopilot_version_message(
            capabilities, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, self.system_id))

    def _send(self, msg: Any) -> None:  # provided by Px4Transport
        raise NotImplementedError


def _remaining(fraction: float | None) -> int:
    """``battery_remaining`` as PX4 fills it: whole percents (PX4's mavlink streams round the
    battery's ``remaining``), -1 when there is no estimate."""
    return -1 if fraction is None else int(round(min(max(fraction, 0.0), 1.0) * 100))
