"""Adapters of the flight observer port that live with the flight: the console's progress
lines, and a group that hands each event to several observers (the console and the GCS).

An observer that fails is reported once on stderr and dropped: the flight does not depend on
who watches it.
"""

from __future__ import annotations

import sys

from insulator_rs.ports.observer import FlightObserver, InsulatorFound, PhaseChange, PhotoTaken


class ConsoleObserver:
    """Prints the flight's progress lines and phase changes (``[   t s] ...``) to stdout."""

    def phase(self, event: PhaseChange) -> None:
        print(f"[{event.time_s:7.1f} s] {event.source} -> {event.target}: {event.reason}", flush=True)

    def insulator_found(self, event: InsulatorFound) -> None:
        pass  # its line comes as a message, with the points it rests on

    def photo_taken(self, event: PhotoTaken) -> None:
        pass  # its line comes as a message, with the photo's figures

    def aborted(self, time_s: float, reason: str) -> None:
        pass  # the loop says why, as a message

    def handed_over(self, time_s: float, reason: str) -> None:
        print(f"[{time_s:7.1f} s] HOLDING, pilot take over: {reason}", flush=True)

    def preflight_failed(self, time_s: float, failed: list[tuple[str, str]]) -> None:
        for name, reason in failed:
            print(f"PRE-FLIGHT FAILED, not armed: {name}: {reason}", flush=True)

    def message(self, time_s: float, text: str) -> None:
        print(text, flush=True)


class ObserverGroup:
    """Each event to every observer in turn; one that raises is reported and dropped."""

    def __init__(self, observers: list[FlightObserver]) -> None:
        self.observers = list(observers)

    def _each(self, method: str, *args: object) -> None:
        for obs in list(self.observers):
            try:
                getattr(obs, method)(*args)
            except Exception as exc:  # a watcher's failure must not become the flight's
                self.observers.remove(obs)
                print(f"note: flight observer {type(obs).__name__} failed and is dropped: "
                      f"{type(exc).__name__}: {exc}", file=sys.stderr)

    def phase(self, event: PhaseChange) -> None:
        self._each("phase", event)

    def insulator_found(self, event: InsulatorFound) -> None:
        self._each("insulator_found", event)

    def photo_taken(self, event: PhotoTaken) -> None:
        self._each("photo_taken", event)

    def aborted(self, time_s: float, reason: str) -> None:
        self._each("aborted", time_s, reason)

    def handed_over(self, time_s: float, reason: str) -> None:
        self._each("handed_over", time_s, reason)

    def preflight_failed(self, time_s: float, failed: list[tuple[str, str]]) -> None:
        self._each("preflight_failed", time_s, failed)

    def message(self, time_s: float, text: str) -> None:
        self._each("message", time_s, text)
