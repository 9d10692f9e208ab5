"""Safe routes between two points of W (direct, or over the top of the tower) and their PMM
times: the edge costs of the inspection tour and of cheapest insertion, and the legs the flight
flies."""

from __future__ import annotations

import numpy as np

from insulator_rs.geodesy import LineFrame
from insulator_rs.planning.exploration import crossing_route
from insulator_rs.planning.pmm import plan_pmm, rest_to_rest_times
from insulator_rs.planning.safety import SafetyVolumes


def route(line: LineFrame, volumes: SafetyVolumes, a: np.ndarray, b: np.ndarray,
          clearance: float) -> np.ndarray:
    """The safe polyline (K, 3) from ``a`` to ``b`` in W (direct, or over the top)."""
    return np.array([a, *crossing_route(line, volumes, a, b, clearance), b])


def route_time(points: np.ndarray, v_max: np.ndarray, a_max: np.ndarray) -> float:
    """PMM time (s) of a route, at rest at both ends."""
    if len(points) == 2:
        return float(rest_to_rest_times(points[0], points[1], v_max, a_max))
    return plan_pmm(points, v_max, a_max).total_time


def cost_matrix(points: np.ndarray, line: LineFrame, volumes: SafetyVolumes, clearance: float,
                v_max: np.ndarray, a_max: np.ndarray) -> np.ndarray:
    """PMM route times (s) between every pair of ``points`` (n, 3); symmetric, zero diagonal."""
    n = len(points)
    c = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            c[i, j] = c[j, i] = route_time(route(line, volumes, points[i], points[j], clearance),
                                           v_max, a_max)
    return c
