"""The optional capabilities of the ports: what the flight loop uses where an adapter has it.

The three ports (:class:`~insulator_rs.ports.vehicle.Vehicle`,
:class:`~insulator_rs.ports.sensors.Sensors`, the detector) say what every adapter must do. Some
adapters can do more, and the flight uses it where they can: an autopilot's parameters and its
navigation status (the pre-flight gate, PX4's failsafes set for the tower), the clock map of a
companion to an autopilot (TIMESYNC), the setpoint stream's gaps, the sensors' stream status, a
network detector's name and what its sanitiser dropped. Each is one small Protocol here, so a new
adapter reads what the loop expects of it, and mypy checks an adapter that claims one.

Found with ``isinstance`` against ``@runtime_checkable`` Protocols, not with ``getattr`` probes
nor with optional attributes on the ports themselves: the adapters are written apart (the
in-process simulator, the MAVLink client, live drivers, a replay) and none inherits from the
ports, so a structural check is the one that fits them all; an optional attribute on every port
would make each adapter say None for what it lacks, for capabilities most adapters never have.
``isinstance`` sees only the names, not their signatures: mypy checks those where an adapter is
used as the Protocol. A decorator of a port (recording, fault injection) therefore offers a
capability only when what it wraps has it, by explicit delegation
(:class:`~insulator_rs.ports.vehicle.VehicleDecorator`), never by passing every attribute on.
The capabilities' data (:class:`NavigationStatus`, :class:`StreamStatus`) live here with them;
the port modules import this one (and re-export those names), never the other way round.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from insulator_rs.timesync import TimesyncRecord


@runtime_checkable
class ParameterStore(Protocol):
    """An autopilot's own parameters (PX4's names), as a vehicle that has them exposes them on
    its ``parameters`` attribute (a vehicle without, the in-process simulator, has None there).

    ``read`` returns the value the autopilot reports (an int for an integer parameter, a float
    otherwise); ``set`` returns the value the autopilot reports after the set, verified equal.
    Both raise ``insulator_rs.exceptions.ParameterError`` naming the parameter when it is missing,
    unanswered or refused. ``ground_station`` is whether a ground station's HEARTBEAT has reached
    the vehicle's link within ``wait`` s (PX4 refuses to arm with a data-link-loss action and no
    ground station)."""

    def read(self, name: str) -> int | float: ...

    def set(self, name: str, value: int | float) -> int | float: ...

    def ground_station(self, wait: float) -> bool: ...


GPS_3D_FIX = 3  # MAVLink GPS_FIX_TYPE_3D_FIX: the least fix a flight may start on (DGPS, RTK above it)


@dataclass(frozen=True)
class NavigationStatus:
    """What an autopilot says of its global position, as the pre-flight gate reads it.

    ``gps_fix_type``: MAVLink's GPS_FIX_TYPE of the newest GPS_RAW_INT (0 no GPS, 1 no fix,
    2 2D, 3 3D, 4 DGPS, 5/6 RTK), None when none came. ``satellites``: its satellites visible.
    ``global_position``: (lat deg, lon deg, alt m AMSL) of the newest GLOBAL_POSITION_INT (PX4
    publishes it only while its estimator has a global position), None before one. ``home``:
    (lat, lon, alt AMSL) of HOME_POSITION, None while the autopilot has set no home."""

    gps_fix_type: int | None
    satellites: int | None
    global_position: tuple[float, float, float] | None
    home: tuple[float, float, float] | None



@dataclass(frozen=True)
class StreamStatus:
    """One sensor stream as the pre-flight gate sees it (:mod:`insulator_rs.flight.preflight`).

    ``name``: the sensor ("camera", "lidar"). ``delivered``: data it has delivered so far (frames,
    scans). ``newest``: the vehicle-clock stamp (s) of its newest datum at or before the time
    asked, None when there is none. ``unstamped``: data dropped for want of a vehicle-clock stamp.
    ``error``: why the sensor could not deliver, if it could not (a render that failed).
    """

    name: str
    delivered: int
    newest: float | None
    unstamped: int = 0
    error: str | None = None


@runtime_checkable
class HasParameters(Protocol):
    """A vehicle with an autopilot's parameters (PX4's names) on ``parameters``: the tower's
    failsafes are set there before take-off and put back after the landing."""

    parameters: ParameterStore


@runtime_checkable
class ReportsNavigation(Protocol):
    """A vehicle whose autopilot reports its GPS fix, global position and home (the pre-flight
    gate's ``gps_home`` check)."""

    def navigation(self) -> NavigationStatus: ...


@runtime_checkable
class MapsClock(Protocol):
    """A vehicle or sensors whose stamps come through a clock map to the vehicle clock (TIMESYNC,
    or its telemetry fallback): the pre-flight gate waits for it, summary.json reports it."""

    def timesync_record(self) -> TimesyncRecord: ...


class GapRecord(Protocol):
    def record(self) -> dict[str, Any]: ...


@runtime_checkable
class ReportsSetpointStream(Protocol):
    """A vehicle that streams setpoints from a thread of its own (the MAVLink client): the longest
    gaps of that stream, for summary.json's ``setpoint_stream``."""

    setpoint_gaps: GapRecord


@runtime_checkable
class ReportsStreams(Protocol):
    """Sensors that can say, without consuming anything, what each stream has delivered by vehicle
    time ``now`` (the pre-flight gate's ``sensors`` check)."""

    def streams(self, now: float) -> list[StreamStatus]: ...


@runtime_checkable
class ExplainsMissingPhoto(Protocol):
    """Sensors whose photo can fail for a reason of their own (a payload's faults: a capture never
    answered, a download cut): why the newest ``photo`` gave no frame, in words for the report, or
    None when it gave one (or cannot say)."""

    def photo_failure(self) -> str | None: ...


@runtime_checkable
class Named(Protocol):
    """A detector with a name for the report (else its type's name is used)."""

    name: str


@runtime_checkable
class CountsDrops(Protocol):
    """A detector whose sanitiser drops detections and counts them (a network)."""

    dropped: Any  # DroppedDetections (detection/), checked where it is read
