"""The one vehicle interface the mission flies through.

Two implementations share it: the in-process kinematic simulator
(`insulator_rs.sim.kinematics`) and the MAVLink offboard client that commands
PX4 or the simulated PX4 (`insulator_rs.mavlink`). Everything here is in the
world frame W (local ENU at the tower base, metres, radians, seconds); NED
appears only inside the MAVLink package.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


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
