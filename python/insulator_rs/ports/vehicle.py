"""The one vehicle interface the mission flies through.

Two adapters implement it: the in-process kinematic simulator
(`insulator_rs.sim.kinematics`) and the MAVLink offboard client that commands
PX4 or the simulated PX4 (`insulator_rs.mavlink`). Everything here is in the
world frame W (local ENU at the tower base, metres, radians, seconds); NED
appears only inside the MAVLink package. The inspection photo is not the
vehicle's business: the companion computer takes it through
:meth:`insulator_rs.ports.sensors.Sensors.photo`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Protocol, runtime_checkable

import numpy as np

from insulator_rs.poses import pose_from_yaw


class FlightMode(str, Enum):
    """PX4 navigation states a vehicle can be in (names as PX4 prints them; the ``mode`` of
    :class:`VehicleState` is one of these values)."""

    MANUAL = "MANUAL"
    POSCTL = "POSCTL"
    HOLD = "HOLD"  # AUTO_LOITER
    TAKEOFF = "TAKEOFF"  # AUTO_TAKEOFF
    LAND = "LAND"  # AUTO_LAND
    RTL = "RTL"  # AUTO_RTL
    MISSION = "MISSION"  # AUTO_MISSION (not flown here: treated as HOLD)
    OFFBOARD = "OFFBOARD"


def wrap_angle(angle: float) -> float:
    """Wrap an angle in rad to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class VehicleState:
    """A snapshot of the vehicle as the mission sees it.

    ``position``/``velocity`` are (3,) float64 in W (ENU, m and m/s); ``yaw`` is
    the heading of the body x axis from W's x (east) axis, counter-clockwise, rad.
    ``time`` is the vehicle clock in seconds (simulated time in the simulator).
    """

    time: float
    position: np.ndarray
    velocity: np.ndarray
    yaw: float
    armed: bool
    mode: str
    landed: bool
    battery_fraction: float = 1.0
    healthy: bool = True
    fault: str | None = field(default=None)

    @property
    def T_w_b(self) -> np.ndarray:
        """The body pose in W (4x4) as the port reports it: a level body at ``yaw`` (the
        airframe's roll and pitch are not in the port yet: the airframe issue)."""
        return pose_from_yaw(self.position, self.yaw)


@runtime_checkable
class Vehicle(Protocol):
    """What the mission needs from a multirotor.

    ``send_setpoint`` is streamed every control tick (>= 20 Hz, as PX4 offboard
    requires); ``advance`` lets time pass: the simulator integrates its model,
    the MAVLink client waits on the wire clock. Refusals and faults raise
    ``insulator_rs.exceptions.VehicleError`` (or a subclass) with the reason.
    """

    def state(self) -> VehicleState: ...

    def arm(self) -> None: ...

    def start_offboard(self) -> None: ...

    def takeoff(self, altitude: float) -> None: ...

    def send_setpoint(
        self, position: np.ndarray, velocity: np.ndarray | None = None, yaw: float | None = None
    ) -> None: ...

    def advance(self, dt: float) -> VehicleState: ...

    def land(self) -> None: ...

    def close(self) -> None: ...
