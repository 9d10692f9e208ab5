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
from insulator_rs.mavlink.frames import attitude_ned_frd_to_enu_flu, ned_to_enu, yaw_ned_to_enu
from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.ports.vehicle import VehicleState

M = mavlink2
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
        self.global_position: Any = None
        self.home: Any = None
        self.landed_state = M.MAV_LANDED_STATE_UNDEFINED
        self.battery = 1.0

    def update(self, msg: Any, now: float) -> None:
        """Keep ``msg`` if it is telemetry (HEARTBEAT is kept by the caller, who compares modes)."""
        kind = msg.get_type()
        if kind == "LOCAL_POSITION_NED":
            self.local, self.local_wall = msg, now
        elif kind == "ATTITUDE":
            self.attitude = msg
        elif kind == "GLOBAL_POSITION_INT":
            self.global_position = msg
        elif kind == "HOME_POSITION":
            self.home = msg
        elif kind == "EXTENDED_SYS_STATE":
            self.landed_state = msg.landed_state
        elif kind in ("SYS_STATUS", "BATTERY_STATUS"):
            if msg.battery_remaining >= 0:
                self.battery = msg.battery_remaining / 100.0

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

    def vehicle_state(self, local_origin_w: np.ndarray, fault: str | None) -> VehicleState:
        local, heartbeat, attitude = self.local, self.heartbeat, self.attitude
        if local is None or heartbeat is None:
            raise VehicleError("no telemetry from the autopilot yet")
        return VehicleState(
            time=local.time_boot_ms / 1000.0,
            position=ned_to_enu([local.x, local.y, local.z]) + local_origin_w,
            velocity=ned_to_enu([local.vx, local.vy, local.vz]),
            yaw=yaw_ned_to_enu(attitude.yaw) if attitude is not None else 0.0,
            armed=self.armed,
            mode=px4_modes.decode_custom_mode(heartbeat.custom_mode),
            landed=self.on_ground,
            battery_fraction=self.battery,
            healthy=fault is None,
            fault=fault,
        )

    def snapshot(self, local_origin_w: np.ndarray, fault: str | None, link: dict[str, int]) -> Telemetry:
        att, gpos, home = self.attitude, self.global_position, self.home
        return Telemetry(
            state=self.vehicle_state(local_origin_w, fault),
            attitude=None if att is None else attitude_ned_frd_to_enu_flu(att.roll, att.pitch, att.yaw),
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
