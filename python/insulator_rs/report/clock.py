"""UTC for vehicle-clock stamps: what the photos' EXIF times and the report's times say.

Every sensor stamp is in the vehicle's clock (seconds, :attr:`VehicleState.time`), which
has no date. The flight loop anchors one :class:`FlightClock` (usually at take-off) to a
UTC instant: the companion computer's wall clock by default (kept on GPS/NTP time on the
vehicle), or any UTC the caller knows better (a GNSS time message). A simulated flight that
runs faster than real time gets the flight's own timeline starting at the anchor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone


@dataclass(frozen=True)
class FlightClock:
    """Vehicle time ``vehicle_time`` (s) is the UTC instant ``utc``."""

    vehicle_time: float
    utc: datetime = field(default_factory=lambda: datetime.now(timezone.utc))

    def __post_init__(self) -> None:
        if not math.isfinite(self.vehicle_time):
            raise ValueError(f"vehicle_time: must be finite, got {self.vehicle_time}")
        if not isinstance(self.utc, datetime) or self.utc.tzinfo is None:
            raise ValueError(f"utc: must be a timezone-aware datetime, got {self.utc!r}")

    def at(self, vehicle_time: float) -> datetime:
        """The UTC instant of a vehicle-clock stamp (s)."""
        if not math.isfinite(vehicle_time):
            raise ValueError(f"vehicle_time: must be finite, got {vehicle_time}")
        return (self.utc + timedelta(seconds=vehicle_time - self.vehicle_time)).astimezone(timezone.utc)
