"""What a flight behaviour may ask of the loop that schedules it: the :class:`Pilot`.

The flight loop (:mod:`insulator_rs.flight.loop`) is a scheduler: it owns the control tick (one
setpoint, one control period, the pose logged and handed to perception, the abort policy
checked) and the state machine, and hands the behaviours (the second look, the photo session,
the autopilot session, the energy budget, the safe exit, the summary) this narrow view of
itself. A behaviour flies only through :meth:`Pilot.tick`, so every tick it causes is a tick of
the one loop, and a test drives a behaviour with a small fake pilot instead of a mission.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from insulator_rs.exceptions import VehicleFailsafe
from insulator_rs.mission.state_machine import InspectionStateMachine
from insulator_rs.ports.vehicle import Vehicle, VehicleState
from insulator_rs.report import FlightClock

CONTROL_PERIOD = 0.05  # s: 20 Hz setpoint stream, as PX4 offboard wants
LAND_HEIGHT = 2.0  # m above the take-off point where the landing starts


class Pilot(Protocol):
    """The loop as its behaviours see it (see the module docstring)."""

    vehicle: Vehicle
    sm: InspectionStateMachine
    t_start: float  # vehicle time of the take-off
    clock: FlightClock  # the UTC of vehicle stamps (anchored at the take-off)
    failsafe: VehicleFailsafe | None  # the vehicle's failsafe that stopped the mission: the autopilot flies
    airborne: bool  # whether the vehicle was armed and told to take off
    abort_reason: str | None  # why the mission aborted (None: it did not)

    def land(self) -> None:
        """Land where the vehicle is (nothing when a failsafe has it or it never flew)."""
        ...

    def abort(self, reason: str, time: float | None = None) -> None:
        """Abort the mission (at vehicle ``time``; None: now)."""
        ...

    def on_failsafe(self, exc: VehicleFailsafe) -> None:
        """The vehicle's failsafe fired: the mission aborts and stops commanding."""
        ...

    def tick(self, position: np.ndarray, velocity: np.ndarray | None, yaw: float) -> VehicleState:
        """Stream one setpoint, let one control period pass; the state after it."""
        ...

    def healthy(self) -> bool:
        """Whether the vehicle is healthy in offboard (else the state machine is told the fault)."""
        ...

    def say(self, text: str) -> None: ...

    def now(self) -> float:
        """Seconds of flight (vehicle time since take-off)."""
        ...

    def write_summary(self) -> None: ...
