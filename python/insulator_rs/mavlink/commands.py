"""The MAVLink command protocol: COMMAND_LONG, its COMMAND_ACK, retransmission.

As the MAVLink command protocol asks: send, wait ``timeout`` for the ACK, resend
with ``confirmation`` counting up, ``retries`` tries in all; IN_PROGRESS keeps
waiting. ACCEPTED returns; any other result raises ``CommandRejected`` naming the
command, what was asked and the MAV_RESULT; no ACK at all raises ``VehicleError``
saying so. Either way the caller decides (the mission reports it and goes on or
aborts): a refused or unanswered command never ends a flight by itself.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from insulator_rs.exceptions import CommandRejected, VehicleError
from insulator_rs.mavlink.link import AutopilotLink
from insulator_rs.mavlink.wire import command_name, mavlink2, result_name

M = mavlink2


class CommandProtocol:
    """Sends commands over ``link`` and waits for their ACKs on ``condition`` (the client's
    lock, notified by the receiver after each ``on_ack``)."""

    def __init__(self, link: AutopilotLink, condition: threading.Condition, stop: threading.Event, *,
                 timeout: float, retries: int) -> None:
        if not isinstance(retries, int) or retries < 1:
            raise ValueError(f"command_retries must be an int >= 1, got {retries!r}")
        self.link = link
        self.timeout = timeout
        self.retries = retries
        self._condition = condition
        self._stop = stop
        self._acks: dict[int, Any] = {}

    def on_ack(self, msg: Any) -> None:
        """Called by the receiver, under the condition's lock."""
        self._acks[msg.command] = msg

    def send(self, command: int, *params: float, detail: str = "", component: int | None = None) -> None:
        """COMMAND_LONG to the autopilot (or ``component`` of its system); raise unless ACCEPTED."""
        padded = [float(p) for p in params] + [0.0] * (7 - len(params))
        name = command_name(command)
        system, autopilot_component = self.link.autopilot or (self.link.target_system or 1, 1)
        for confirmation in range(self.retries):
            with self._condition:
                self._acks.pop(command, None)
            self.link.send("command_long", system, autopilot_component if component is None else component,
                           command, confirmation, *padded)
            deadline = time.monotonic() + self.timeout
            with self._condition:
                while True:
                    ack = self._acks.get(command)
                    if ack is not None and ack.result != M.MAV_RESULT_IN_PROGRESS:
                        break
                    remaining = deadline - time.monotonic()
                    if remaining <= 0 or self._stop.is_set():
                        break
                    self._condition.wait(timeout=remaining)
            if ack is not None and ack.result != M.MAV_RESULT_IN_PROGRESS:
                if ack.result != M.MAV_RESULT_ACCEPTED:
                    raise CommandRejected(name, result_name(ack.result), detail)
                return
        raise VehicleError(f"{name}{f' ({detail})' if detail else ''}: no COMMAND_ACK after "
                           f"{self.retries} tries of {self.timeout:g} s")
