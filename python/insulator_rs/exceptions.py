"""Every exception the package raises, under one base class (one name per meaning).

Every class is declared here, those the compiled core raises included: its bindings
look ``LocalizationError``, ``AmbiguousLocalizationError`` and ``PacketError`` up in this module when ``_core`` is
imported (besides ``ValueError``/``TypeError`` for bad arguments); the Python layers
raise the others.
"""

from __future__ import annotations

from enum import Enum


class InsulatorError(Exception):
    """Base class of every insulator_rs-specific error."""


class ConfigError(InsulatorError, ValueError):
    """A mission, scene or calibration file is missing a field or holds a bad value.

    The message names the file and the field.
    """


class VehicleError(InsulatorError):
    """The vehicle refused a command or reported a fault (the message says which)."""


class ModelError(InsulatorError, ValueError):
    """A detection model file is missing, truncated/not ONNX, or not a YOLO detection export.

    The message names the file and which of those it is.
    """


class BagError(InsulatorError, ValueError):
    """A recorded flight (MCAP file, rosbag2 folder, ROS 1 bag) cannot be read or replayed:
    missing or truncated file, a missing topic, a wrong message type, stamps out of order or
    jumping. The message names the file or topic and the time."""


class CommandRejected(VehicleError):
    """The vehicle (autopilot) refused a command.

    ``command`` names it (e.g. ``"arm"``, ``"MAV_CMD_DO_SET_MODE"``), ``reason`` says why
    (the autopilot's words, or its MAV_RESULT name), ``detail`` adds what was asked (e.g. the
    mode). ``temporary`` is True where the command may succeed later (PX4's
    TEMPORARILY_REJECTED: arming before a position estimate exists) and False where it is
    denied outright. The simulator and the MAVLink client raise this same class.
    """

    def __init__(self, command: str, reason: str, detail: str = "", *, temporary: bool = True) -> None:
        what = f"{command} ({detail})" if detail else command
        super().__init__(f"{what} refused by the vehicle: {reason}")
        self.command = command
        self.reason = reason
        self.detail = detail
        self.temporary = temporary


class VehicleFailsafe(VehicleError):
    """A failsafe fired; ``reason`` says why, ``action`` what the vehicle (or the client on its
    behalf) did. A vehicle's ``advance`` raises it once per failsafe; the mission then stops
    commanding (the autopilot, or the pilot, flies)."""

    def __init__(self, reason: str, action: str) -> None:
        super().__init__(f"failsafe: {reason}; action: {action}")
        self.reason = reason
        self.action = action


class ImageError(InsulatorError, ValueError):
    """An image file cannot be used: missing, not decodable, truncated, or of an unsupported pixel depth.

    The message names the file and which of those it is.
    """


class SensorError(InsulatorError):
    """A live sensor could not be opened, configured or read (the message names the sensor
    and the address, device or pipeline)."""


class DetectorError(InsulatorError):
    """The box detector failed on a frame (its runtime raised): that detection event is lost and
    counted; a detector failing for longer than the sensor-lost timeout aborts the mission. The
    message names the detector and what it raised."""


class PacketError(SensorError):
    """A Livox datagram or control frame is malformed (raised by the compiled core's Livox
    bindings): truncated, a length, version, data type or sample count that does not fit, a
    bad CRC, an unexpected command. The message starts with the packet or frame field at
    fault (``packet.crc32: ...``, ``command.sof: ...``)."""


class PayloadError(SensorError):
    """One attempt at an inspection shot through the payload (a MAVLink gimbal and camera) failed.

    ``fault``: which way (a :class:`insulator_rs.ports.payload.PayloadFault`); the message names
    it and what was seen (the command and its MAV_RESULT, the seconds waited, the bytes fetched).
    The payload adapter catches it per attempt, retries a bounded number of times and reports every
    attempt: it never reaches the flight loop."""

    def __init__(self, fault: Enum, detail: str) -> None:
        super().__init__(f"payload {fault.value}: {detail}")
        self.fault = fault
        self.detail = detail


class LocalizationError(InsulatorError):
    """The cloud holds no usable insulator.

    Raised by ``localize`` (the compiled core) when no cluster is found, fewer than two
    usable points remain, or the line fit fails. The message says which.
    """


class AmbiguousLocalizationError(LocalizationError):
    """The bounded method refused a box it cannot tell apart (raised by ``localize`` with method
    ``"bounded"`` and a known ``insulator_length``): another line in the box, on more points and
    more than 0.3 m from the one fitted, fits the insulator's known length at the box's scale
    better, but by less than the box's own noise (about 10 %), so which of the two is the
    insulator cannot be told. (A rival that fits clearly better is returned instead: typically
    the string behind a conductor fitted in front of it.) The message gives both lines' points
    and scales.
    """


class TimeSyncError(InsulatorError):
    """A clock map was asked for before any time pair arrived."""


class PlanningError(InsulatorError):
    """No trajectory could be planned through valid waypoints: the straight path through them
    enters a safety volume, the vehicle cannot stop before one, or inserting waypoints did not
    keep the curve out of them. The message names the argument and which of those it is.

    The flight loop aborts the mission on it (lands, status ``aborted: planning failed: ...``).
    Not a ``ValueError``: a planning failure in flight is not a bad argument.
    """


class ObstacleMapError(InsulatorError, ValueError):
    """The obstacle map (``insulator_rs.planning.obstacle_map``) was given a bad setting (voxel
    size, hit count, capacity) or points that are not an (N, 3) array. The message names the
    argument and the allowed range."""


class ObstacleBlocked(PlanningError):
    """A leg comes within the safety margin of an obstacle the LiDAR saw (the obstacle map) and
    no detour round it is clear: the leg is refused. The message names the segment or waypoint."""


class ReportError(InsulatorError, ValueError):
    """A report folder cannot be read back (``insulator-rs report``, ``report.html``): a missing
    or malformed ``summary.json`` or ``inspection.geojson``. The message names the file and what
    is wrong with it."""


class ParameterError(VehicleError):
    """An autopilot parameter could not be read, set or verified: the autopilot has no parameter
    of that name, never answered (no PARAM_VALUE after every retry), reported another value than
    the one set, or the value does not fit the parameter's type or range.

    ``parameter`` names the parameter (PX4's name, e.g. ``"RTL_RETURN_ALT"``); the message says
    which of those it is. A ``VehicleError``: before take-off the mission refuses to arm on it."""

    def __init__(self, parameter: str, reason: str) -> None:
        super().__init__(f"parameter {parameter}: {reason}")
        self.parameter = parameter
        self.reason = reason


class PreflightRefused(InsulatorError):
    """The pre-flight gate refused to arm (``insulator_rs.flight.preflight``): a check failed.

    ``failed`` holds (check name, reason) for every check that failed; the message names each.
    Nothing was armed or flown."""

    def __init__(self, failed: list[tuple[str, str]]) -> None:
        super().__init__("pre-flight checks failed: " + "; ".join(f"{name}: {reason}" for name, reason in failed))
        self.failed = list(failed)


class ClientKilled(BaseException):
    """The simulator's stand-in for ``kill -9`` of the companion process (``sim/faults.py``): raised
    at the moment of the kill, through every handler (a ``BaseException``, as the process's end is
    not an error anything in it may handle); nothing more is sent to the vehicle, nothing more is
    written. Never raised outside the fault matrix."""
