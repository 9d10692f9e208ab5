"""How the flight loop flies (:class:`FlightSettings`), as the composition root sets it."""

from __future__ import annotations

from dataclasses import dataclass

from insulator_rs.mission.state_machine import Policy
from insulator_rs.perception.localization_method import DEFAULT_METHOD, LocalizationMethod


@dataclass(frozen=True)
class FlightSettings:
    """How the loop flies: localization ``method``, buffering ``policy``, s between detection
    events, the flight-time limit (s), the min-snap ``time_allocation``, progress output."""

    method: LocalizationMethod = DEFAULT_METHOD  # the product's default (inspect --method): tests fly what users fly
    policy: Policy = Policy.IMMEDIATE
    detect_period: float = 1.0
    max_flight_time: float = 1800.0
    time_allocation: str = "pmm"
    quiet: bool = False
    # check every leg against the LiDAR's obstacle map as well as the GPS-derived safety
    # volumes (planning/obstacle_map.py); False flies the volumes only (inspect --no-obstacle-map:
    # what the map buys, measured)
    obstacle_map: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "policy", Policy(self.policy))  # a bad policy is refused, named
