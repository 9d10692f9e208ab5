"""The ``Payload`` port: the inspection camera on its gimbal, as a device apart from the sensors.

A gimbal-and-zoom payload (Siyi ZR10/ZR30/A8, a Gremsy with a Sony, the simulated one of
``insulator_rs.sim.payload``) is asked for one shot at a time: the gimbal aimed (pitch from the
horizon, yaw from the body heading: the gimbal stabilises roll and pitch itself), the lens zoomed
to a focal length, one image captured and fetched. A shot takes seconds (slew, zoom travel,
capture latency, a download) and may fail in named ways (:class:`PayloadFault`), each attempt
retried a bounded number of times, so :meth:`Payload.submit` returns at once with a
:class:`~concurrent.futures.Future`: the caller (the flight loop) polls it between its control
ticks, or waits on it with a timeout, and its setpoint stream never waits for the payload.

Why a port of its own rather than a capability of ``Sensors``: the sensors are streams polled
every tick, the payload a device commanded shot by shot; its faults are per attempt and per
insulator, not a stream's health; it lives on its own link (a MAVLink gimbal and camera, routed
by the autopilot or beside it) and a rig may fly one with any sensors (the simulator's, a
recording's, the live drivers'). A ``Sensors`` adapter that photographs through a payload
(``LiveSensors``) composes one; nothing of the sensors' streams changes for it.

Every time is the vehicle clock (s); every pose W (ENU) and the camera optical frame C.
"""

from __future__ import annotations

import enum
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from insulator_rs._core import CameraModel


class PayloadFault(enum.Enum):
    """Why one attempt at a shot failed (the value is what the report and the errors say)."""

    PAYLOAD_LOST = "payload_lost"  # no HEARTBEAT of the camera or the gimbal within the lost time
    GIMBAL_AT_LIMIT = "gimbal_at_limit"  # the aim is past the gimbal's range, or it stopped short
    GIMBAL_REFUSED = "gimbal_refused"  # the gimbal manager refused the aim or did not answer
    ZOOM_REFUSED = "zoom_refused"  # MAV_CMD_SET_CAMERA_ZOOM refused, unanswered, or never reached
    CAPTURE_REFUSED = "capture_refused"  # MAV_CMD_IMAGE_START_CAPTURE refused or unanswered
    NO_CAPTURE_ANSWER = "no_capture_answer"  # no CAMERA_IMAGE_CAPTURED, even when asked again
    CAPTURE_FAILED = "capture_failed"  # CAMERA_IMAGE_CAPTURED says the capture failed
    DOWNLOAD_FAILED = "download_failed"  # the file could not be fetched whole, or is no image


@dataclass(frozen=True)
class ShotRequest:
    """One shot: ``pitch`` (rad, from the horizon, negative looks down), ``yaw`` (rad, from the
    body heading, counter-clockwise seen from above), ``focal_px`` (the mean focal length the
    framing asks for, px at full resolution)."""

    pitch: float
    yaw: float
    focal_px: float


@dataclass(frozen=True)
class PayloadAttempt:
    """One attempt at a shot: ``fault`` None when it gave the photo; ``detail`` what was seen."""

    attempt: int
    fault: PayloadFault | None
    detail: str = ""


@dataclass(frozen=True)
class PayloadPhoto:
    """A photo as the payload took it, its pose from the capture message, not from the request.

    ``time``: the capture instant (vehicle clock, s). ``image``: (H, W, 3) uint8 BGR.
    ``camera``: its intrinsics (the rig's per-zoom table at ``focal_px``). ``R_w_c``: the camera
    optical frame's attitude in W at capture (from the message's quaternion). ``wgs84``: (lat deg,
    lon deg, alt m AMSL) of the camera at capture. ``file_url``: where it was fetched from.
    ``image_index``: the camera's index of the image."""

    time: float
    image: np.ndarray
    camera: CameraModel
    R_w_c: np.ndarray
    wgs84: tuple[float, float, float]
    focal_px: float
    file_url: str
    image_index: int


@dataclass(frozen=True)
class ShotResult:
    """What a shot ended with: the photo (None when every attempt failed) and every attempt."""

    photo: PayloadPhoto | None
    attempts: tuple[PayloadAttempt, ...] = field(default_factory=tuple)

    @property
    def faults(self) -> list[PayloadFault]:
        """The faults of the failed attempts, in order."""
        return [a.fault for a in self.attempts if a.fault is not None]


@runtime_checkable
class Payload(Protocol):
    """A gimbal-and-zoom camera taking one shot at a time (see the module docstring)."""

    def submit(self, request: ShotRequest) -> Future[ShotResult]:
        """Start the shot and return at once; the future never raises for a payload fault (they
        are in its :class:`ShotResult`), and ends within the adapter's bounded time."""
        ...

    def health(self) -> dict[str, object]:
        """Counters for the report: shots, photos, faults by name."""
        ...

    def alive(self) -> bool:
        """Whether the payload answers now (its components' heartbeats are fresh): the pre-flight
        gate flies a rig with a payload only when it does."""
        ...

    def close(self) -> None:
        ...
