"""The flight observer port: what the flight tells the people watching it, as it happens.

The flight loop calls an observer at each mission event; adapters turn the events into what a
watcher needs (the console's progress lines, MAVLink STATUSTEXT and camera messages for the
pilot's ground station). An observer must not raise: the flight does not wait for watchers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class PhaseChange:
    """The mission went from phase ``source`` to ``target`` at flight time ``time_s``, because ``reason``."""

    time_s: float
    source: str
    target: str
    reason: str


@dataclass(frozen=True)
class InsulatorFound:
    """Insulator ``insulator_id`` localized at ``center`` (W, m) and ``wgs84`` (lat, lon, alt),
    ``outcome`` of the state machine ("new", "deferred", ...), at flight time ``time_s``."""

    time_s: float
    insulator_id: int
    center: np.ndarray
    wgs84: tuple[float, float, float]
    outcome: str


@dataclass(frozen=True)
class PhotoTaken:
    """Photo ``file`` of insulator ``insulator_id``, the ``index``-th of the flight (1-based),
    taken at flight time ``time_s`` and UTC ``time_utc`` (POSIX s) from ``position`` (W) /
    ``wgs84`` (lat, lon, alt) with the camera looking along ``yaw`` (W, rad) and
    ``gimbal_pitch`` (rad)."""

    time_s: float
    time_utc: float
    insulator_id: int
    index: int
    file: str
    position: np.ndarray
    wgs84: tuple[float, float, float]
    yaw: float
    gimbal_pitch: float


class FlightObserver(Protocol):
    def phase(self, event: PhaseChange) -> None: ...

    def insulator_found(self, event: InsulatorFound) -> None: ...

    def photo_taken(self, event: PhotoTaken) -> None: ...

    def aborted(self, time_s: float, reason: str) -> None: ...

    def handed_over(self, time_s: float, reason: str) -> None:
        """The mission found no safe way on: the vehicle holds in the autopilot's mode and the
        pilot must take over (``reason``: why)."""
        ...

    def preflight_failed(self, time_s: float, failed: list[tuple[str, str]]) -> None:
        """The pre-flight gate refused to arm: ``failed`` holds (check name, reason) of every
        check that failed."""
        ...

    def message(self, time_s: float, text: str) -> None: ...
