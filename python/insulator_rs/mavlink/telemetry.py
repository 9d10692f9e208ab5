"""Telemetry: the autopilot's latest messages, and the vehicle state the mission reads from them.

NED (PX4) is converted to ENU (W) here and only here; W is PX4's local frame
shifted by ``local_origin_w`` (the position of PX4's local origin in W). The
store has no lock of its own: the client updates and reads it under its lock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from insulator_rs.exceptions import VehicleError
from insulator_rs.mavlink import px4_modes
from insulator_rs.mavlink.frames import (attitude_ned_frd_to_enu_flu, attitude_quaternion_ned_frd_to_enu_flu,
                                         frd_to_flu, ned_to_enu)
from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.poses import quaternion_from_rotation, yaw_of
from insulator_rs.ports.vehicle import NavigationStatus, VehicleState

M = mavlink2
# Telemetry the client asks for (Hz). The attitude comes from ATTITUDE_QUATERNION (no Euler
# singularity; PX4 streams it on an onboard link) at the rate of the position, so the pose
# history interpolates over 20 ms; ATTITUDE is the fallback of an autopilot without it.
REQUESTED_RATES_HZ: dict[int, float] = {
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 50.0,
    M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    M.MAVLINK_MSG_ID_ATTITUDE: 20.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 2.0,
    M.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
}


@dataclass(frozen=True)
class Telemetry:
    """Everything the client knows about the vehicle, read under one lock.

    ``attitude`` is R_w_b (3x3, body FLU -> W ENU); ``global_position`` and
    ``home_global`` are (latitude deg, longitude deg, altitude m AMSL); ``home``
    is the home position in W (m). None where the autopilot has not sent it.
    ``link`` counts what the link received and dropped (``link.LinkStats.as_dict``).
    """

    state: VehicleState
    attitude: np.ndarray | None
    global_position: tuple[float, float, float] | None
    home_global: tuple[float, float, float] | None
    home: np.ndarray | None
    landed_state: str
    link: dict[str, int]


class TelemetryStore:
    """The latest message of each kind the mission uses, with the wall time of arrival."""

    def __init__(self) -> None:
        self.heartbeat: Any = None
        self.heartbeat_wall = -math.inf
        self.local: Any = None
        self.local_wall = -math.inf
        self.attitude: Any = None
        self.attitude_quaternion: Any = None
        self.global_position: Any = None
        self.home: Any = None
        self.gps_raw: Any = None  # GPS_RAW_INT as PX4 streams it (not requested: not every autopilot has it)
        self.landed_state = M.MAV_LANDED_STATE_UNDEFINED
        # the charge (fraction) of the newest BATTERY_STATUS / SYS_STATUS; None: unknown (none
        # came yet, or the autopilot said -1); out-of-range values are dropped and counted
        self.battery: float | None = None
        self.battery_rejected = 0

    def update(self, msg: Any, now: float) -> None:
        """Keep ``msg`` if it is telemetry (HEARTBEAT is kept by the caller, who compares modes)."""
        kind = msg.get_type()
        if kind == "LOCAL_POSITION_NED":
            self.local, self.local_wall = msg, now
        elif kind == "ATTITUDE":
            self.attitude = msg
        elif kind == "ATTITUDE_QUATERNION":
            if _unit_quaternion(msg) is not None:  # a zero or NaN quaternion is not an attitude
                self.attitude_quaternion = msg
        elif kind == "GLOBAL_POSITION_INT":
            self.global_position = msg
        elif kind == "HOME_POSITION":
            self.home = msg
        elif kind == "GPS_RAW_INT":
            self.gps_raw = msg
        elif kind == "EXTENDED_SYS_STATE":
            self.landed_state = msg.landed_state
        elif kind in ("SYS_STATUS", "BATTERY_STATUS"):
            self._battery(msg)

    def _battery(self, msg: Any) -> None:
        """``battery_remaining`` (int8 %): 0..100 the charge, -1 "unknown" (PX4 sends -1 while it
        has no estimate, and for a battery it does not monitor). Anything else cannot come from
        a battery monitor: dropped and counted, the last good value kept. BATTERY_STATUS of
        another battery than the first (``id`` != 0) is not the pack the mission flies on."""
        if msg.get_type() == "BATTERY_STATUS" and getattr(msg, "id", 0) != 0:
            return
        value = getattr(msg, "battery_remaining", None)
        if isinstance(value, bool) or not isinstance(value, int) or not -1 <= value <= 100:
            self.battery_rejected += 1
            return
        self.battery = None if value == -1 else value / 100.0

    def set_heartbeat(self, msg: Any, now: float) -> None:
        self.heartbeat, self.heartbeat_wall = msg, now

    @property
    def armed(self) -> bool:
        return self.heartbeat is not None and bool(self.heartbeat.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def mode(self) -> str | None:
        return None if self.heartbeat is None else px4_modes.decode_custom_mode(self.heartbeat.custom_mode)

    @property
    def on_ground(self) -> bool:
        return self.landed_state == M.MAV_LANDED_STATE_ON_GROUND

    def body_attitude(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(R_w_b 3x3 ENU<-FLU, body rates FLU rad/s) from the newest of ATTITUDE_QUATERNION and
        ATTITUDE (their ``time_boot_ms``), None before either."""
        quat, euler = self.attitude_quaternion, self.attitude
        if quat is not None and (euler is None or quat.time_boot_ms >= euler.time_boot_ms):
            q = _unit_quaternion(quat)
            if q is not None:
                return (attitude_quaternion_ned_frd_to_enu_flu(q),
                        frd_to_flu([quat.rollspeed, quat.pitchspeed, quat.yawspeed]))
        if euler is None:
            return None
        return (attitude_ned_frd_to_enu_flu(euler.roll, euler.pitch, euler.yaw),
                frd_to_flu([euler.rollspeed, euler.pitchspeed, euler.yawspeed]))

    def vehicle_state(self, local_origin_w: np.ndarray, fault: str | None) -> VehicleState:
        local, heartbeat = self.local, self.heartbeat
        if local is None or heartbeat is None:
            raise VehicleError("no telemetry from the autopilot yet")
        att = self.body_attitude()
        R = np.eye(3) if att is None else att[0]  # level, heading east, until the first attitude
        return VehicleState(
            time=local.time_boot_ms / 1000.0,
            position=ned_to_enu([local.x, local.y, local.z]) + local_origin_w,
            velocity=ned_to_enu([local.vx, local.vy, local.vz]),
            yaw=yaw_of(R),
            armed=self.armed,
            mode=px4_modes.decode_custom_mode(heartbeat.custom_mode),
            landed=self.on_ground,
            battery_fraction=self.battery,
            healthy=fault is None,
            fault=fault,
            attitude=quaternion_from_rotation(R),
            angular_velocity=np.zeros(3) if att is None else att[1],
        )

    def navigation(self) -> NavigationStatus:
        """The GPS fix, global position and home as the autopilot last sent them."""
        gps, gpos, home = self.gps_raw, self.global_position, self.home
        return NavigationStatus(
            gps_fix_type=None if gps is None else int(gps.fix_type),
            satellites=None if gps is None or gps.satellites_visible == 255 else int(gps.satellites_visible),
            global_position=None if gpos is None else (gpos.lat * 1e-7, gpos.lon * 1e-7, gpos.alt * 1e-3),
            home=None if home is None else (home.latitude * 1e-7, home.longitude * 1e-7, home.altitude * 1e-3))

    def snapshot(self, local_origin_w: np.ndarray, fault: str | None, link: dict[str, int]) -> Telemetry:
        att, gpos, home = self.body_attitude(), self.global_position, self.home
        return Telemetry(
            state=self.vehicle_state(local_origin_w, fault),
            attitude=None if att is None else att[0],
            global_position=None if gpos is None else (gpos.lat * 1e-7, gpos.lon * 1e-7, gpos.alt * 1e-3),
            home_global=None if home is None else (home.latitude * 1e-7, home.longitude * 1e-7,
                                                   home.altitude * 1e-3),
            home=None if home is None else ned_to_enu([home.x, home.y, home.z]) + local_origin_w,
            landed_state=landed_state_name(self.landed_state),
            link=link,
        )


def landed_state_name(value: int) -> str:
    """MAV_LANDED_STATE name (a value the dialect does not know reads MAV_LANDED_STATE_<n>)."""
    entry = M.enums["MAV_LANDED_STATE"].get(int(value))
    return entry.name if entry is not None else f"MAV_LANDED_STATE_{int(value)}"


def _unit_quaternion(msg: Any) -> np.ndarray | None:
    """ATTITUDE_QUATERNION's (q1..q4) = (w, x, y, z) of R_ned_frd, normalised; None when it is not
    finite or near zero. PX4 fills ``repr_offset_q`` only for VTOL tailsitters (zero for a
    multirotor): the attitude is q itself."""
    q = np.array([msg.q1, msg.q2, msg.q3, msg.q4], dtype=np.float64)
    n = float(np.linalg.norm(q))
    if not (math.isfinite(n) and n > 0.5):
        return None
    return q / n
