"""The simulated PX4's GCS connection loss failsafe (NAV_DLL_ACT), as PX4 v1.16's commander and
failsafe framework take it (``src/modules/commander/failsafe/failsafe.cpp`` and
``framework.cpp``; not measured on the SITL):

* the GCS connection is lost once a ground station's HEARTBEAT has been heard on PX4's GCS link
  and none came for COM_DL_LOSS_T s (default 10); a vehicle that never heard one never loses it;
* while armed, NAV_DLL_ACT 1 (Hold), 2 (Return) or 3 (Land) is then taken in every mode (the
  take-off climb and Hold included) except Land (PX4 ignores the loss there) and the modes
  COM_DLL_EXCEPT excepts (bit 0 Mission, bit 1 Hold, bit 2 Offboard; default none);
* the action is delayed: PX4 holds for COM_FAIL_ACT_T s (default 5; none at 0.1 s or less) so a
  pilot can take over, then switches to the action (its "Failsafe activated: entering Hold for 5
  seconds");
* Hold clears with its condition: the ground station heard again, PX4 goes back to the mode it
  was in. Return and Land stay until another mode is chosen or the vehicle disarms;
* an action that would not change anything (the vehicle already in it, or in a failsafe as
  severe: Return, Land) is not taken, and no delay is held then (a simplification: PX4's
  framework may still hold for the delay first).

Not modelled: NAV_DLL_ACT 5 (Terminate) and 6 (Lockdown, a disarm in the air): stored and
answered, no effect on the kinematic airframe.
"""

from __future__ import annotations

from dataclasses import dataclass

from insulator_rs.exceptions import CommandRejected
from insulator_rs.ports.vehicle import FlightMode
from insulator_rs.sim.kinematics import KinematicVehicle

#: NAV_DLL_ACT values (PX4 v1.16's parameter reference) and the mode each one flies
DATALINK_LOSS_MODES = {1: FlightMode.HOLD, 2: FlightMode.RTL, 3: FlightMode.LAND}
#: COM_DLL_EXCEPT's bits: the modes where the data link's loss is ignored
EXCEPTION_BITS = {FlightMode.MISSION: 1, FlightMode.HOLD: 2, FlightMode.OFFBOARD: 4}
#: PX4's Action order (framework.h): a failsafe already taking a more severe action is kept
SEVERITY = {FlightMode.HOLD: 1, FlightMode.RTL: 2, FlightMode.LAND: 3}
MIN_DELAY_S = 0.1  # COM_FAIL_ACT_T at or below this: no delay (framework.cpp)
REASON = "GCS connection lost for more than {timeout:g} s (NAV_DLL_ACT {action})"


@dataclass
class DataLinkLoss:
    """The failsafe's state between two looks (see the module docstring). ``step`` is called by
    the simulator's loop, under its lock, with the vehicle-time age of the last ground station
    HEARTBEAT (None: never heard) and the parameters' current values."""

    lost: bool = False
    _action: FlightMode | None = None  # the mode being taken (after the delay)
    _delay_until: float | None = None  # vehicle time the delay's Hold ends
    _before: FlightMode | None = None  # the mode before the failsafe (Hold clears back to it)
    _reason: str = ""

    def step(self, vehicle: KinematicVehicle, age: float | None, *, action: int, timeout: float,
             exceptions: int, delay: float) -> None:
        lost = age is not None and age > timeout
        if not lost:
            if self.lost and self._action == FlightMode.HOLD and vehicle.armed \
                    and vehicle.mode == FlightMode.HOLD and self._before is not None:
                self._clear(vehicle)
            self.lost, self._action, self._delay_until = False, None, None
            return
        if not vehicle.armed:
            self.lost, self._action, self._delay_until = True, None, None
            return
        if not self.lost:
            self.lost = True
            self._start(vehicle, action, timeout, exceptions, delay)
        elif self._delay_until is not None and vehicle.clock.now >= self._delay_until:
            self._delay_until = None
            if vehicle.mode == FlightMode.HOLD and self._action is not None:  # nobody took over
                vehicle.autopilot_failsafe(self._action, self._reason)

    def _start(self, vehicle: KinematicVehicle, action: int, timeout: float, exceptions: int, delay: float) -> None:
        mode = DATALINK_LOSS_MODES.get(int(action))
        now = vehicle.mode
        if mode is None or now == FlightMode.LAND or exceptions & EXCEPTION_BITS.get(now, 0):
            return
        if SEVERITY.get(now, 0) >= SEVERITY[mode]:
            return  # already flying it, or a failsafe as severe
        self._action, self._before = mode, now
        self._reason = REASON.format(timeout=timeout, action=int(action))
        if delay > MIN_DELAY_S and mode != FlightMode.HOLD:
            self._delay_until = vehicle.clock.now + delay
            vehicle.autopilot_failsafe(FlightMode.HOLD, self._reason + f": Hold for {delay:g} s first")
        else:
            vehicle.autopilot_failsafe(mode, self._reason)

    def _clear(self, vehicle: KinematicVehicle) -> None:
        try:
            vehicle.clear_failsafe(self._before or FlightMode.HOLD)
        except CommandRejected:
            vehicle.fault = None  # a mode it cannot re-enter now (no position): it stays in Hold
