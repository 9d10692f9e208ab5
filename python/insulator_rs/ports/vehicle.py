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

from insulator_rs.ports.capabilities import GPS_3D_FIX as GPS_3D_FIX  # re-exported: the navigation capability's data
from insulator_rs.ports.capabilities import NavigationStatus as NavigationStatus
from insulator_rs.ports.capabilities import ParameterStore as ParameterStore
from insulator_rs.ports.capabilities import HasParameters, MapsClock, ReportsNavigation, ReportsSetpointStream
from insulator_rs.poses import pose_from_quaternion, pose_from_yaw


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

    ``position``/``velocity`` are (3,) float64 in W (ENU, m and m/s). ``attitude`` is the unit
    quaternion (w, x, y, z) of R_w_b, the rotation from the body (FLU: x forward, y left, z up)
    to W, as the autopilot estimates it (PX4's NED/FRD is converted at the MAVLink boundary);
    ``angular_velocity`` (3,) the body rates in B (rad/s). ``yaw`` is the heading of that
    attitude (the Z-Y-X Euler yaw: from W's x (east), counter-clockwise, rad), kept for the
    mission's setpoints. ``time`` is the vehicle clock in seconds (simulated time in the
    simulator); the attitude and the rates are of that time.

    ``attitude`` None: an adapter that knows no attitude (a vehicle that reports a heading
    only); :attr:`T_w_b` is then level at ``yaw`` and :attr:`has_attitude` is False. Every
    adapter of this package reports the attitude.

    ``battery_fraction``: the charge left in the pack as the autopilot estimates it (0..1;
    MAVLink's BATTERY_STATUS / SYS_STATUS ``battery_remaining`` / 100), None when the vehicle
    does not know it (no battery message yet, or PX4's -1: no estimate). Nobody may read a
    missing charge as a full one: the battery reserve then makes no decision and says so.
    """

    time: float
    position: np.ndarray
    velocity: np.ndarray
    yaw: float
    armed: bool
    mode: str
    landed: bool
    battery_fraction: float | None = None
    healthy: bool = True
    fault: str | None = field(default=None)
    attitude: np.ndarray | None = None
    angular_velocity: np.ndarray | None = None

    @property
    def has_attitude(self) -> bool:
        return self.attitude is not None

    @property
    def T_w_b(self) -> np.ndarray:
        """The body pose in W (4x4): the full attitude (roll, pitch, yaw) at ``position``."""
        if self.attitude is None:
            return pose_from_yaw(self.position, self.yaw)
        return pose_from_quaternion(self.position, self.attitude)


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

    def hold(self) -> None:
        """Hold position in the autopilot's own mode (PX4 HOLD: AUTO_LOITER) and stop taking
        setpoints: the hand-over to the pilot when the mission has no safe way to go on."""
        ...

    def close(self) -> None: ...


def vehicle_navigation(vehicle: object) -> NavigationStatus | None:
    """The vehicle's global navigation status (:class:`~insulator_rs.ports.capabilities.ReportsNavigation`:
    an autopilot's), None for a vehicle without one (the in-process simulator)."""
    if not isinstance(vehicle, ReportsNavigation):
        return None
    status = vehicle.navigation()
    return status if isinstance(status, NavigationStatus) else None


def vehicle_parameters(vehicle: object) -> ParameterStore | None:
    """The vehicle's parameter store (:class:`~insulator_rs.ports.capabilities.HasParameters`), or
    None when it has none (or not that interface)."""
    store = vehicle.parameters if isinstance(vehicle, HasParameters) else None
    return store if isinstance(store, ParameterStore) else None


class VehicleDecorator:
    """A :class:`Vehicle` adapter round ``inner`` that passes every call of the port on as it is: a
    decorator (the recording's, the fault matrix's) subclasses it and overrides what it watches or
    changes. Of the optional capabilities (:mod:`insulator_rs.ports.capabilities`) it offers those
    ``inner`` has, and only those, so the flight finds the same through it; anything else of the
    adapter (its link's counters, its telemetry) is ``inner``'s, reached there."""

    def __init__(self, inner: Vehicle) -> None:
        self.inner = inner
        if isinstance(inner, HasParameters):
            self.parameters = inner.parameters
        if isinstance(inner, ReportsNavigation):
            self.navigation = inner.navigation
        if isinstance(inner, MapsClock):
            self.timesync_record = inner.timesync_record
        if isinstance(inner, ReportsSetpointStream):
            self.setpoint_gaps = inner.setpoint_gaps

    def state(self) -> VehicleState:
        return self.inner.state()

    def advance(self, dt: float) -> VehicleState:
        return self.inner.advance(dt)

    def arm(self) -> None:
        self.inner.arm()

    def start_offboard(self) -> None:
        self.inner.start_offboard()

    def takeoff(self, altitude: float) -> None:
        self.inner.takeoff(altitude)

    def send_setpoint(self, position: np.ndarray, velocity: np.ndarray | None = None,
                      yaw: float | None = None) -> None:
        self.inner.send_setpoint(position, velocity, yaw)

    def land(self) -> None:
        self.inner.land()

    def hold(self) -> None:
        self.inner.hold()

    def close(self) -> None:
        self.inner.close()
