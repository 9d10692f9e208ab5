"""Where an aborted mission lands, and the safe route there (W, metres).

An abort never descends where the vehicle happens to be: over the tower that descent goes into
the steel, next to an arm through the conductors. It first stops (:func:`plan_stop`: a smooth
straight stop that must not enter a safety volume), then flies straight legs, each from rest to
rest (a min-snap between two points is the straight line), to a landing point on the ground at
least :data:`LANDING_CLEARANCE` m (horizontally) from every safety volume's footprint, on the
vehicle's side of the tower (:func:`plan_abort_route`):

* over the tower (above a footprint): up to the crossing height if lower, then level on across
  to the side the mission was heading for, then straight down; never a metre lower while over
  a footprint;
* beside an arm (in a detour to an inspection waypoint, or too close to a footprint to descend):
  back the way it came, to where the detour left the exploration path, then straight down; with
  nowhere known to go back to, straight out from the line plane;
* anywhere else on a side (an exploration pass, the climb): straight down.

Every leg is checked exactly against the safety volumes, then, where the LiDAR's obstacle map is
kept, against what it saw outside them by the rule the mission's legs follow
(:func:`~insulator_rs.planning.obstacle_map.bend_polyline`): a leg that comes within the safety
margin of an obstacle seen is bent round it (across, up, or both; never down), the bends named in
:attr:`AbortRoute.bends`. PlanningError when no route can be found (inside a volume, unable to
stop before one, no clear way out, a leg no bend clears, the landing column or a corner of the
route within the margin of an obstacle seen): the caller then holds and hands over to the pilot,
never descends blind.

Why a hold, and not another way round, when the map refuses the route: the obstacle was seen on
the very way out the rules above chose as the safest from here (the way the vehicle came, on
across over the tower, straight down clear of the footprints). Every other way (PX4's Return
straight home at its altitude, a landing in place) knows nothing of the obstacle or goes through
what the route was chosen to avoid; the vehicle holding where it is, clear of everything (it flew
there on checked legs), with the pilot told where the obstacle is, is what a pilot expects from an
automatic that cannot see its way.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import Enum
from typing import Any

import numpy as np

from insulator_rs.exceptions import ObstacleBlocked, PlanningError
from insulator_rs.geodesy import LineFrame
from insulator_rs.planning.minsnap import MinSnapTrajectory, plan_min_snap_safe, stop_trajectory
from insulator_rs.planning.obstacle_map import Bend, SeenVolumes, bend_polyline
from insulator_rs.planning.safety import SafetyVolumes

# m: horizontal distance from every safety volume's footprint that a landing column keeps (the
# descent and the touchdown: GPS drift, the wind, the last metres in PX4's LAND)
LANDING_CLEARANCE = 2.0
EXIT_STEP = 0.25  # m: steps of the search for the way off a footprint
MAX_EXIT = 100.0  # m: no way off within this distance (a footprint that wide): no route
MIN_MOVING_SPEED = 0.05  # m/s: slower than this the vehicle is at rest already
CLIMB_TOLERANCE = 0.1  # m: this close below the crossing height, no climb first


class AbortCase(str, Enum):
    """Which way an abort leaves (see the module docstring)."""

    DESCEND = "descend"  # clear of every footprint: straight down
    BACK_OUT = "back out"  # beside an arm: back the way it came, then down
    STEP_OUT = "step out"  # close to a footprint, nowhere known to go back to: out, then down
    CROSS_ON = "cross on"  # over the tower: climb if needed, on across, then down

    def __str__(self) -> str:
        return str(self.value)


@dataclass(frozen=True)
class RouteBend:
    """A leg of the way out bent round an obstacle the LiDAR saw: ``leg`` its index in the route
    (0: the first), ``bend`` which of its segments, round what, with how many points."""

    leg: int
    bend: Bend

    def describe(self) -> str:
        return f"leg {self.leg + 1}: {self.bend.describe()}"

    def as_record(self) -> dict[str, Any]:
        return {"leg": self.leg, **self.bend.as_record()}


@dataclass(frozen=True)
class AbortRoute:
    """``legs``: legs (each (K, 3), W: straight, K = 2, or bent round what the LiDAR saw) flown
    one after the other from rest to rest, the last ending ``land_height`` above ``landing`` (W,
    on the ground) where the vehicle's own landing takes over; empty when it is there already.
    ``side``: the landing's side. ``bends``: the legs bent round the obstacle map, in order."""

    case: AbortCase
    legs: tuple[np.ndarray, ...]
    landing: np.ndarray
    side: int
    bends: tuple[RouteBend, ...] = ()


#: m: distances compared to a clearance tolerate this much rounding.
DISTANCE_EPS = 1e-9


def plan_stop(volumes: SafetyVolumes, position: np.ndarray, velocity: np.ndarray,
              a_max: np.ndarray | float) -> MinSnapTrajectory | None:
    """The smooth straight stop from ``velocity`` at ``position`` (None when at rest already).
    Over a footprint a sinking vehicle is stopped level (the stop's line keeps only the
    horizontal and rising parts of the velocity): no commanded descent over the tower.
    PlanningError when stopping within ``a_max`` enters a safety volume."""
    v = np.asarray(velocity, dtype=np.float64).reshape(3).copy()
    p = np.asarray(position, dtype=np.float64).reshape(3)
    if float(volumes.footprint_distance(p[None])[0]) <= 0.0:
        v[2] = max(v[2], 0.0)
    if float(np.linalg.norm(v)) < MIN_MOVING_SPEED:
        return None
    traj = stop_trajectory(p, v, a_max)
    end = traj.waypoints[-1]
    if not volumes.segments_clear(traj.waypoints[:1], end[None])[0]:
        raise PlanningError(f"stop: braking from {np.round(v, 2).tolist()} m/s takes "
                            f"{np.linalg.norm(end - traj.waypoints[0]):.2f} m and enters a safety volume")
    return traj


def _way_off(volumes: SafetyVolumes, start: np.ndarray, direction: np.ndarray, clearance: float) -> np.ndarray | None:
    """The first point level with ``start`` along ``direction`` (horizontal unit) at least
    ``clearance`` from every footprint, the level line to it clear of the volumes; None within
    MAX_EXIT."""
    steps = np.arange(1, int(MAX_EXIT / EXIT_STEP) + 1) * EXIT_STEP
    q = start + steps[:, None] * direction
    ok = np.flatnonzero(volumes.footprint_distance(q) >= clearance)
    if len(ok) == 0:
        return None
    end = q[ok[0]]
    return end if volumes.segments_clear(start[None], end[None])[0] else None


def plan_abort_route(line: LineFrame, volumes: SafetyVolumes, position: np.ndarray, *, toward_side: int,
                     back_to: np.ndarray | None, ground_z: float, land_height: float,
                     crossing_clearance: float, clearance: float = LANDING_CLEARANCE,
                     seen: SeenVolumes | None = None) -> AbortRoute:
    """The safe route from ``position`` (W, at rest) to the nearest landing point on the
    vehicle's side (see the module docstring). ``toward_side`` (+1/-1): where an interrupted
    crossing was going; ``back_to`` (W): where the detour the vehicle is in left the exploration
    path (None outside a detour); ``ground_z``: the ground's height in W (the take-off point's);
    ``land_height``: m above the ground where the vehicle's own landing starts;
    ``crossing_clearance``: m above the volumes' top at which sides are crossed; ``seen``: the
    volumes with the LiDAR's obstacle map, the legs bent round what it holds (None: the safety
    volumes only). ObstacleBlocked (a PlanningError) when the map refuses the route."""
    p = np.asarray(position, dtype=np.float64).reshape(3)
    if not volumes.points_clear(p[None])[0]:
        raise PlanningError(f"abort: the vehicle at {np.round(p, 2).tolist()} is inside a safety volume")
    low = ground_z + land_height
    here = float(volumes.footprint_distance(p[None])[0])
    side = line.side(p)
    legs: list[np.ndarray] = []
    case = AbortCase.DESCEND
    if here <= 0.0:  # over the tower or a corridor: level or up, never down
        case = AbortCase.CROSS_ON
        top = p.copy()
        if volumes.top + crossing_clearance > p[2] + CLIMB_TOLERANCE:
            top[2] = volumes.top + crossing_clearance
            legs.append(np.stack([p, top]))
        sides = [toward_side] if toward_side in (1, -1) else []
        sides += [s for s in (side, -side) if s not in sides]
        for s in sides:
            off = _way_off(volumes, top, s * line.lateral, clearance)
            if off is not None:
                legs.append(np.stack([top, off]))
                side = s
                break
        else:
            raise PlanningError(f"abort: no level way off the footprint within {MAX_EXIT:.0f} m")
    elif here < clearance or back_to is not None:  # beside an arm: back out the way it came
        back = None if back_to is None else np.asarray(back_to, dtype=np.float64).reshape(3)
        if (back is not None and line.side(back) == side
                and float(volumes.footprint_distance(back[None])[0]) >= clearance
                and volumes.segments_clear(p[None], back[None])[0]):
            case = AbortCase.BACK_OUT
            legs.append(np.stack([p, back]))
        elif here < clearance:
            case = AbortCase.STEP_OUT
            off = _way_off(volumes, p, side * line.lateral, clearance)
            if off is None:
                raise PlanningError("abort: no clear way out from beside the tower")
            legs.append(np.stack([p, off]))
    column = legs[-1][1] if legs else p
    landing = np.array([column[0], column[1], ground_z])
    if column[2] > low + 1e-6:
        legs.append(np.stack([column, np.array([column[0], column[1], low])]))
    for leg in legs:
        if not volumes.segments_clear(leg[:1], leg[1:])[0]:
            raise PlanningError("abort: a leg of the route enters a safety volume")
    # the way off was found at >= clearance in a batch; one point's distance may round the
    # other way (1.9999999999999982 for 2.0: the derandomized CI profile found it over the axis)
    if float(volumes.footprint_distance(landing[None])[0]) < clearance - DISTANCE_EPS:
        raise PlanningError("abort: no landing point clear of the safety volumes")
    if seen is None:
        return AbortRoute(case, tuple(legs), landing, side)
    return bent_round_the_map(AbortRoute(case, tuple(legs), landing, side), seen)


def bent_round_the_map(route: AbortRoute, seen: SeenVolumes, *, only: int | None = None) -> AbortRoute:
    """``route`` with each leg (``only``: that leg alone) checked against the obstacle map in
    ``seen`` and bent round what it holds, by the mission's legs' rule
    (:func:`~insulator_rs.planning.obstacle_map.bend_polyline`; a bend never goes down, so over
    the tower a leg stays at its height or above); the new bends appended to the route's.
    ObstacleBlocked naming the leg, the segment or waypoint and where the obstacle was seen, when
    no bend clears a leg or a point of it (the vehicle's position, a corner, the landing column's
    foot) lies within the margin: the route is refused (the caller holds, see the module
    docstring)."""
    legs = list(route.legs)
    bends: list[RouteBend] = []
    for i in range(len(legs)) if only is None else (only,):
        try:
            legs[i], leg_bends = bend_polyline(legs[i], seen)
        except ObstacleBlocked as exc:
            raise ObstacleBlocked(f"abort: leg {i + 1} of the way out ({route.case}): {exc}") from exc
        bends.extend(RouteBend(i, b) for b in leg_bends)
    return replace(route, legs=tuple(legs), bends=route.bends + tuple(bends))


def leg_trajectory(leg: np.ndarray, volumes: SafetyVolumes, *, v_max: np.ndarray, a_max: np.ndarray,
                   dt: float) -> MinSnapTrajectory:
    """The min-snap, safety-checked trajectory of one leg (straight, or bent round the obstacle
    map: pass the :class:`~insulator_rs.planning.obstacle_map.SeenVolumes` then, so the curve is
    checked against the map too), from rest to rest."""
    return plan_min_snap_safe(leg, v_max, a_max, volumes, dt=dt)
