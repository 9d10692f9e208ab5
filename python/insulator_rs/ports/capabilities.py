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
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:  # the data types only (annotations): the port modules import this one
    from insulator_rs.ports.sensors import StreamStatus
    from insulator_rs.ports.vehicle import NavigationStatus, ParameterStore
    from insulator_rs.timesync import TimesyncRecord


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
class Named(Protocol):
    """A detector with a name for the report (else its type's name is used)."""

    name: str


@runtime_checkable
class CountsDrops(Protocol):
    """A detector whose sanitiser drops detections and counts them (a network)."""

    dropped: Any  # DroppedDetections (detection/), checked where it is read
