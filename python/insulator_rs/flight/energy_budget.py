"""The flight's energy sums: what the battery pays for the mission before it starts, and, while
it flies, for the rest of the plan and for the way out, weighed by the battery reserve
(:mod:`insulator_rs.flight.reserve`: the charge and its consumption fit) every check period.

Each route is a :class:`~insulator_rs.planning.energy.RouteDemand` (time and distance at the
vehicle's limits, point-mass model) to the touchdown; a photo stop is costed at its longest
(PHOTO_SETTLE_TIMEOUT): the budget errs on the side of turning back.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from insulator_rs.exceptions import PlanningError
from insulator_rs.flight.photo_session import PHOTO_SETTLE_TIMEOUT
from insulator_rs.flight.pilot import LAND_HEIGHT
from insulator_rs.flight.reserve import TOUCHDOWN_TIME, BatteryReserve
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import PlanItem
from insulator_rs.planning.abort import AbortRoute
from insulator_rs.planning.energy import RouteDemand, route_demand
from insulator_rs.planning.exploration import PlanKind
from insulator_rs.planning.waypoints import InspectionWaypoint
from insulator_rs.ports.vehicle import VehicleState

TOUCHDOWN = RouteDemand(TOUCHDOWN_TIME, LAND_HEIGHT)  # the descent from LAND_HEIGHT and the touchdown


class EnergyBudget:
    """The energy sums of one flight, and the reserve that weighs them (``battery``).

    ``way_out(position)``: the safe route out an abort from ``position`` would fly (PlanningError
    where none can be planned now); ``crossing_clearance``: m above the tower where a way home
    without such a route crosses."""

    def __init__(self, geom: MissionGeometry, *, v_max: np.ndarray, a_max: np.ndarray, reserve: float,
                 crossing_clearance: float, way_out: Callable[[np.ndarray], AbortRoute]) -> None:
        self.geom = geom
        self.limits = (v_max, a_max)
        self.crossing_clearance = crossing_clearance
        self.way_out = way_out
        self.battery = BatteryReserve(reserve)

    def mission_demand(self, start: np.ndarray) -> RouteDemand:
        """What the battery pays for the mission before anything is found: the exploration path
        from ``start`` (the take-off point) to above the landing point, and the touchdown."""
        points = np.vstack([start, self.geom.path_points()])
        return route_demand(points, *self.limits) + TOUCHDOWN

    def rest_of_plan(self, here: np.ndarray, plan: Sequence[PlanItem],
                     deferred: Mapping[int, Sequence[InspectionWaypoint]]) -> RouteDemand:
        """The plan's items in order from ``here`` (scan, inspect, return, cross, then above the
        landing point), each ``deferred`` far-side waypoint as a detour there and back from the
        nearest plan point on its side, a photo stop at every inspection waypoint; to the touchdown."""
        points = [np.asarray(here, dtype=np.float64)]
        stops = 0
        for it in plan:
            if it.kind == PlanKind.LAND:
                points.append(it.position + np.array([0.0, 0.0, LAND_HEIGHT]))
                break
            points.append(np.asarray(it.position, dtype=np.float64))
            stops += it.kind == PlanKind.INSPECT
        rest = route_demand(np.array(points), *self.limits, stops=stops, stop_time=PHOTO_SETTLE_TIMEOUT) + TOUCHDOWN
        for side, wps in deferred.items():
            on_side = [p for p, it in zip(points[1:], plan) if it.side == side] or [points[-1]]
            for w in wps:
                near = min(on_side, key=lambda p: float(np.linalg.norm(p - w.position)))
                rest = rest + route_demand(np.array([near, w.position, near]), *self.limits, stops=1,
                                           stop_time=PHOTO_SETTLE_TIMEOUT)
        return rest

    def way_out_demand(self, here: np.ndarray) -> RouteDemand:
        """The safe route an abort at ``here`` would fly, or, where none can be planned now, the
        way home over the crossing height; to the touchdown."""
        here = np.asarray(here, dtype=np.float64)
        try:
            route = self.way_out(here)
            way = [here] + [point for leg in route.legs for point in leg[1:]]  # bent legs: every corner
        except PlanningError:
            up = max(here[2], self.geom.volumes.top + self.crossing_clearance)
            home = np.asarray(self.geom.takeoff, dtype=np.float64)
            way = [here, np.array([here[0], here[1], up]), np.array([home[0], home[1], up]),
                   home + np.array([0.0, 0.0, LAND_HEIGHT])]
        return route_demand(np.array(way), *self.limits) + TOUCHDOWN

    def spare_after_detour(self, here: np.ndarray, via: Sequence[np.ndarray], stop_time: float) -> float | None:
        """What the latest weighing leaves above the reserve after the rest of the plan and a
        detour not in it: from ``here`` through ``via`` and back, standing ``stop_time`` s at
        each (fractions of the pack; negative: the detour would cost the plan its end). None
        before the first weighing."""
        points = np.vstack([np.asarray(here, dtype=np.float64), *via, np.asarray(here, dtype=np.float64)])
        return self.battery.spare_after(route_demand(points, *self.limits, stops=len(via), stop_time=stop_time))

    def observe(self, st: VehicleState) -> None:
        """One tick's state (the battery's time, distance and charge)."""
        self.battery.observe(st)

    def check(self, st: VehicleState, time_s: float, plan: Sequence[PlanItem],
              deferred: Mapping[int, Sequence[InspectionWaypoint]]) -> str | None:
        """Why the vehicle must turn back now (the reserve), or None."""
        return self.battery.check(st, time_s, lambda: (self.rest_of_plan(st.position, plan, deferred),
                                                       self.way_out_demand(st.position)))

    def record(self) -> dict[str, Any]:
        """summary.json's ``battery``."""
        return self.battery.record()
