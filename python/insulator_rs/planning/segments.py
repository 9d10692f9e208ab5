"""One leg of the flight: the safe route through the plan's next items and its min-snap
trajectory, with the time at which the trajectory passes each item."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from insulator_rs.geodesy import LineFrame
from insulator_rs.planning.minsnap import MinSnapTrajectory, plan_min_snap_safe
from insulator_rs.planning.obstacle_map import Bend, SeenVolumes, bend_polyline
from insulator_rs.planning.routes import route
from insulator_rs.planning.safety import SafetyVolumes

SAFETY_CHECK_DT = 0.05  # s: sampling of planned trajectories for the safety check
# m: a min-snap curve straying further than this from its straight path gets extra waypoints
# (keeps the flight near the planned path, away from the conductors beyond it).
MAX_PATH_DEVIATION = 2.0


class Target(Protocol):
    """Anything the plan flies to: a position in W (the mission's plan items)."""

    @property
    def position(self) -> np.ndarray: ...


@dataclass(frozen=True)
class Segment:
    """``trajectory`` from the vehicle's position through ``items``; ``item_times`` (s from
    the trajectory's start) at which it passes each item. None trajectory: nothing to fly."""

    trajectory: MinSnapTrajectory | None
    item_times: list[float]
    detours: int = 0  # points added to bend the route round obstacles of the map
    bends: tuple[Bend, ...] = ()  # the route's segments bent round the map, and round what


def polyline(line: LineFrame, volumes: SafetyVolumes, start: np.ndarray, items: Sequence[Target],
             clearance: float) -> np.ndarray:
    """The safe route (crossing above the tower, out of the conductor corridor) from ``start``
    through every item, repeated points removed."""
    pts = [start]
    for it in items:
        r = route(line, volumes, pts[-1], it.position, clearance)
        pts.extend(r[1:])
    keep = [pts[0]]
    for p in pts[1:]:
        if np.linalg.norm(p - keep[-1]) > 1e-3:
            keep.append(p)
    return np.array(keep)


def plan_segment(line: LineFrame, volumes: SafetyVolumes, start: np.ndarray, velocity: np.ndarray,
                 items: Sequence[Target], *,
                 v_max: np.ndarray, a_max: np.ndarray, clearance: float, time_allocation: str,
                 seen: SeenVolumes | None = None) -> Segment:
    """Plan the min-snap, safety-checked trajectory through ``items`` from ``start`` (W) moving
    at ``velocity`` (m/s, as measured: over the limits it starts by slowing down to them).
    ``seen``: the volumes with the LiDAR's obstacle map (:mod:`~insulator_rs.planning.obstacle_map`):
    the route is bent round what it holds and the trajectory checked against it too; None: the
    safety volumes only. PlanningError when none is safe (the vehicle cannot stop before a
    safety volume, or no detour clears an obstacle seen)."""
    pts = polyline(line, volumes, start, items, clearance)
    if len(pts) < 2:
        return Segment(None, [])
    planned = len(pts)
    bends: tuple[Bend, ...] = ()
    if seen is not None:
        pts, bends = bend_polyline(pts, seen)
    traj = plan_min_snap_safe(pts, v_max, a_max, volumes if seen is None else seen, dt=SAFETY_CHECK_DT,
                              v_start=velocity,
                              max_deviation=MAX_PATH_DEVIATION, time_allocation=time_allocation)
    # items are among the trajectory's waypoints: the knot time of each
    knots = np.concatenate([[0.0], np.cumsum(traj.durations)])
    item_times = []
    j = 0
    for it in items:
        while j < len(traj.waypoints) and np.linalg.norm(traj.waypoints[j] - it.position) > 1e-6:
            j += 1
        item_times.append(float(knots[min(j, len(knots) - 1)]))
    return Segment(traj, item_times, len(pts) - planned, bends)
