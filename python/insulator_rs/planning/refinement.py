"""Re-planning with extra waypoints until a trajectory stays out of the safety volumes.

Richter et al.'s remedy for a polynomial (or any smooth) trajectory that leaves
a safe straight-line path: insert a waypoint at the middle of each offending
segment and plan again; with enough waypoints the curve hugs the polyline,
which is clear. Shared by the minimum-snap and the point-mass planners.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, TypeVar

import numpy as np

from insulator_rs.exceptions import PlanningError
from insulator_rs.planning.safety import SafetyVolumes


class _Timed(Protocol):
    @property
    def durations(self) -> np.ndarray: ...


T = TypeVar("T", bound=_Timed)


def segment_deviation(pos: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (m) of each point pos[i] from the straight segment a[i] -> b[i]."""
    d = b - a
    den = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
    t = np.clip(np.einsum("ij,ij->i", pos - a, d) / den, 0.0, 1.0)
    return np.linalg.norm(pos - (a + t[:, None] * d), axis=1)


def refine_until_clear(waypoints: np.ndarray, plan: Callable[[np.ndarray], T],
                       positions: Callable[[T, float], tuple[np.ndarray, np.ndarray]],
                       volumes: SafetyVolumes, *, max_speed: float, dt: float,
                       max_refinements: int, max_deviation: float | None = None) -> T:
    """Plan through ``waypoints`` (M, 3) with ``plan``, sample with ``positions(traj, dt)`` ->
    (times, positions), and insert a midpoint into every segment that comes within
    ``max_speed * dt / 2`` of a safety volume (the conservative continuous-curve check of
    :meth:`SafetyVolumes.samples_clear`) or strays more than ``max_deviation`` m from its
    straight segment; repeat until clear. The straight polyline must be clear (PlanningError
    otherwise). If only the deviation bound still fails after ``max_refinements``, the safe
    trajectory is returned; if safety still fails, PlanningError."""
    p = np.asarray(waypoints, dtype=np.float64)
    if not volumes.polyline_clear(p):
        raise PlanningError("waypoints: the straight path through them enters a safety volume")
    max_step = max_speed * dt
    for refinement in range(max_refinements + 1):
        traj = plan(p)
        times, pos = positions(traj, dt)
        starts = np.concatenate([[0.0], np.cumsum(traj.durations)])
        seg = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(traj.durations) - 1)
        unsafe = ~volumes.points_clear(pos, inflate=max_step / 2)
        bad = unsafe.copy()
        if max_deviation is not None:
            bad |= segment_deviation(pos, p[seg], p[seg + 1]) > max_deviation
        if not np.any(bad) or (not np.any(unsafe) and refinement == max_refinements):
            return traj
        bad_segments = set(np.unique(seg[bad]).tolist())
        new = [p[0]]
        for i in range(len(p) - 1):
            if i in bad_segments:
                new.append((p[i] + p[i + 1]) / 2)
            new.append(p[i + 1])
        p = np.array(new)
    raise PlanningError(f"waypoints: no safe trajectory after {max_refinements} refinements")
