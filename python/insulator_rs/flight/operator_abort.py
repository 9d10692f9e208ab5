"""The operator's abort of a flight in the air: what Ctrl-C, SIGTERM and the ground station's
abort command do.

* In the air, the first Ctrl-C (SIGINT) or SIGTERM asks the flight loop for the abort
  (:meth:`~insulator_rs.flight.loop.FlightLoop.request_abort`, reason
  ``"operator: Ctrl-C"``): at the next control tick the mission stops, flies the safe route out
  (:mod:`insulator_rs.flight.safe_exit`) and lands, and the report says ``aborted: operator``.
  The vehicle is never left to PX4's offboard-loss failsafe by a key press.
* A second one while the vehicle is still in the air raises :class:`ReturnHandover` in the main
  thread: the caller hands the vehicle to the autopilot's own Return (:func:`hand_to_return`,
  PX4's RTL) and exits at once. The pilot who presses twice wants the program out of the way.
* On the ground (before arming, after the landing) a signal stops the program as it always did:
  KeyboardInterrupt, and the report says ``interrupted``.
* The ground station's abort command (``mavlink/gcs.py``) comes through :meth:`OperatorAbort.request`:
  accepted in the air only.

The signal handlers are installed by the command line (:meth:`OperatorAbort.installed`, the
main thread only) and the old ones put back after the flight; a library caller keeps its own.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import TYPE_CHECKING, Any, Protocol

from insulator_rs.exceptions import VehicleError
from insulator_rs.flight.abort_policy import operator_reason
from insulator_rs.ports.vehicle import Vehicle
from insulator_rs.report.run_status import RunOutcome, RunStatus

if TYPE_CHECKING:
    from insulator_rs.flight.loop import FlightLoop

SIGNALS = (signal.SIGINT, signal.SIGTERM)  # what a person (or a supervisor stopping the service) sends
GROUND_STATION = "ground station"  # how the ground station's abort is named in the reason


class AbortablePilot(Protocol):
    """What the operator's abort needs of the flight: whether it flies, and the request."""

    airborne: bool
    vehicle: Vehicle

    def request_abort(self, reason: str = ...) -> None: ...


class ReturnHandover(KeyboardInterrupt):
    """The operator's second signal in the air: stop, hand the vehicle to the autopilot's Return.
    A KeyboardInterrupt, so that it unwinds the flight from wherever the main thread is."""

    def __init__(self, how: str) -> None:
        super().__init__(how)
        self.how = how


def signal_name(signum: int) -> str:
    """What the operator pressed or sent, as the report names it."""
    return "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name


class OperatorAbort:
    """The operator's abort of one flight (see the module docstring); ``signals`` counts the
    signals taken in the air."""

    def __init__(self, pilot: AbortablePilot) -> None:
        self.pilot = pilot
        self.signals = 0

    def in_flight(self) -> bool:
        """Whether the vehicle is in the air under this flight: armed for it and not landed."""
        return bool(self.pilot.airborne) and not self.pilot.vehicle.state().landed

    def request(self, how: str = GROUND_STATION) -> bool:
        """Ask for the abort (``how``: who asked, named in the reason); False, and nothing asked,
        when the vehicle is not in the air (there is nothing to fly out of)."""
        if not self.in_flight():
            return False
        self.pilot.request_abort(operator_reason(how))
        return True

    def on_signal(self, signum: int, frame: FrameType | None = None) -> None:
        """The signal handler (main thread): see the module docstring."""
        how = signal_name(signum)
        if not self.in_flight():
            raise KeyboardInterrupt(how)
        self.signals += 1
        if self.signals > 1:
            raise ReturnHandover(how)
        self.pilot.request_abort(operator_reason(how))
        # os.write: a print from a handler can land inside the main thread's own print (a
        # reentrant write of the same buffered stream raises)
        os.write(2, (f"\ninsulator-rs: operator abort ({how}): flying the safe route out and landing; "
                     f"{how} again hands the vehicle to PX4's Return and exits\n").encode())

    @contextmanager
    def installed(self) -> Iterator[OperatorAbort]:
        """The handler on SIGINT and SIGTERM for the ``with`` block, the old handlers back after
        it. Outside the main thread (where Python cannot set handlers) nothing is installed."""
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        old = {s: signal.getsignal(s) for s in SIGNALS}
        try:
            for s in SIGNALS:
                signal.signal(s, self.on_signal)
            yield self
        finally:
            for s, handler in old.items():
                signal.signal(s, handler)


def hand_to_return(vehicle: Any) -> str:
    """Hand the vehicle to the autopilot's own Return (PX4's RTL: climb to RTL_RETURN_ALT, fly
    home, land) and stop commanding it; the line that says what happened."""
    # the Return is no call of the Vehicle port: the adapter's own, under any decorator round it
    while getattr(vehicle, "return_to_launch", None) is None and getattr(vehicle, "inner", None) is not None:
        vehicle = vehicle.inner
    rtl = getattr(vehicle, "return_to_launch", None)
    if rtl is None:
        return (f"the vehicle ({type(vehicle).__name__}) has no Return: it is left as it is, and an autopilot's "
                f"offboard-loss failsafe takes it")
    try:
        rtl()
    except VehicleError as exc:
        return (f"PX4's Return was refused ({exc}): the setpoints stop, and PX4's offboard-loss failsafe "
                f"takes the vehicle")
    return "handed over to PX4's Return (RTL): the autopilot flies the vehicle home and lands it"


def return_handover(loop: FlightLoop, vehicle: Any, how: str) -> str:
    """After :class:`ReturnHandover`: the vehicle handed to the autopilot's Return, the summary
    written with the status ``aborted: operator: ...; <how> again: <what happened>`` (no plot,
    no score: the program exits at once); the line for the operator."""
    line = hand_to_return(vehicle)
    reason = loop.abort_reason or operator_reason(how)
    loop.outcome = RunOutcome(RunStatus.ABORTED, f"{reason}; {how} again: {line}")
    loop.write_summary()
    setup = loop.autopilot.setup
    kept = ("; the tower's autopilot parameters stay set (RTL altitude, geofence)"
            if setup is not None and setup.pending else "")
    return f"insulator-rs: {how} again: {line}. The mission stopped{kept}; the summary is in {loop.out}"
