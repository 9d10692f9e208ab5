"""The two-flight baseline: a scan flight along the exploration path, then the time-optimal
tour of all inspection waypoints.

Edge costs are point-mass-model (PMM) times, rest to rest at the inspection
waypoints; an edge between the two sides goes up, over the top of the safety
volumes and down (:func:`~.exploration.crossing_route`) and costs the PMM time
of that route with optimised velocities at its corners. The tour (closed, from
the take-off point) is exact (:func:`~.tsp.solve_tour`); it is then flown as one
PMM trajectory whose velocities at the waypoints are optimised as well, the same
way the single flight is timed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from insulator_rs.geodesy import LineFrame
from insulator_rs.planning.pmm import plan_pmm
from insulator_rs.planning.routes import cost_matrix, route
from insulator_rs.planning.safety import SafetyVolumes
from insulator_rs.planning.tsp import Tour, solve_tour


@dataclass(frozen=True)
class TwoFlightResult:
    """Times (s) of the two-flight strategy and the tour it flies."""

    t_scan: float
    t_tsp: float
    tour: Tour
    tour_route: np.ndarray  # (K, 3) W, the flown polyline of the inspection flight

    @property
    def t_total(self) -> float:
        return self.t_scan + self.t_tsp


def two_flight(path_points: np.ndarray, waypoints: np.ndarray, *, line: LineFrame,
               volumes: SafetyVolumes, clearance: float, v_max: np.ndarray,
               a_max: np.ndarray) -> TwoFlightResult:
    """Scan flight along ``path_points`` (from and back to the take-off point, its first point),
    then the optimal closed tour from the take-off point through ``waypoints`` (N, 3)."""
    t_scan = plan_pmm(path_points, v_max, a_max).total_time
    takeoff = path_points[0]
    nodes = np.vstack([takeoff[None], np.asarray(waypoints, dtype=np.float64).reshape(-1, 3)])
    costs = cost_matrix(nodes, line, volumes, clearance, v_max, a_max)
    tour = solve_tour(costs)
    seq = list(tour.order) + [0]
    pts = [nodes[0]]
    for a, b in zip(seq[:-1], seq[1:]):
        pts.extend(route(line, volumes, nodes[a], nodes[b], clearance)[1:])
    flown = np.array(pts)
    t_tsp = plan_pmm(flown, v_max, a_max).total_time if len(flown) > 1 else 0.0
    return TwoFlightResult(t_scan, t_tsp, tour, flown)
