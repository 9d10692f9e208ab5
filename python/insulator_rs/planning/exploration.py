"""The exploration path round both sides of the tower, and the over-the-top crossing.

In the line frame (along a, lateral l, up z; see :mod:`.geodesy`) the path
keeps a lateral distance ``max_width / 2 + standoff`` from the line plane, runs
horizontal passes along the tower's along-extent at heights spaced by
``pass_spacing`` to cover its height (a serpentine, upward on the take-off side,
downward on the other), crosses sides above the safety volumes, and comes back
over the top to land where it took off. All waypoints are in W.

``pass_spacing`` is an upper bound: given the elevations the camera and the LiDAR both see
(:meth:`~insulator_rs.rig.SensorRig.vertical_view`), the passes are no further apart than
the band of heights one pass sees on the line plane, so every height of the tower is in view
of both sensors on some pass. Mid-360's field of view starts 7 deg below its horizon: a small
tower's 10 m spacing at 9 m from the plane left the strings at 9-10 m 24-31 deg below the top
pass and on the bottom row of the camera's image from the lower one (13 localizations a flight
at 1 Hz, one of its two strings found; 32 and both with the passes the band allows).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from insulator_rs.geodesy import LineFrame
from insulator_rs.planning.safety import SafetyVolumes

# Lowest exploration pass above the base (m): keeps the vehicle clear of the ground.
MIN_PASS_HEIGHT = 3.0
# m: the take-off point and the whole path keep at least this distance from the safety
# volumes, so that smooth trajectories through the path can be made safe by refinement.
PATH_CLEARANCE = 1.0
# m: when a bent line turns a conductor corridor towards the passes, they move out in steps
# of this much, up to MAX_WIDENING.
WIDENING_STEP = 0.5
MAX_WIDENING = 30.0
#: rad kept off each edge of the sensors' shared view: a box cut by the image border is not
#: one the detector gives reliably, and the LiDAR's edge rings are sparse.
VIEW_EDGE_MARGIN = math.radians(3.0)


class PlanKind(str, Enum):
    """What a waypoint of the path or the plan is for (a ``str`` enum: compares equal to its value)."""

    TAKEOFF = "takeoff"
    SCAN = "scan"  # a pass corner of the exploration path
    CROSS = "cross"  # above the safety volumes, from one side to the other
    LAND = "land"
    INSPECT = "inspect"  # an inspection waypoint: a photo
    RETURN = "return"  # back to where a detour for inspection began

    def __str__(self) -> str:  # "scan", not "PlanKind.SCAN", in reasons and reports
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


@dataclass(frozen=True)
class PathWaypoint:
    """One exploration-path waypoint in W. ``kind``: "takeoff", "scan" (a pass corner),
    "cross" (above the safety volumes) or "land". ``side``: +1/-1 for the side of the
    tower it is on, 0 above the tower. ``yaw``: rad, heading that faces the tower."""

    position: np.ndarray
    kind: PlanKind
    side: int
    yaw: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", PlanKind(self.kind))  # a bad kind is refused here


def facing_yaw(line: LineFrame, side: int) -> float:
    """Yaw (rad, from W's x axis, counter-clockwise) that looks from ``side`` at the line plane."""
    look = -side * line.lateral
    return math.atan2(look[1], look[0])


def crossing_route(line: LineFrame, volumes: SafetyVolumes, a: np.ndarray, b: np.ndarray,
                   clearance: float) -> list[np.ndarray]:
    """Intermediate W waypoints for flying from ``a`` to ``b``: none if the straight segment is
    clear, else straight up from ``a`` to ``clearance`` above the safety volumes, across, and
    straight down to ``b`` (clear whenever ``a`` and ``b`` are)."""
    if volumes.segments_clear(a[None], b[None])[0]:
        return []
    z = volumes.top + clearance
    return [np.array([a[0], a[1], max(z, a[2])]), np.array([b[0], b[1], max(z, b[2])])]


def view_band(view: tuple[float, float], distance: float) -> float:
    """Height (m) of the band a pass sees at ``distance`` (m) ahead, between the elevations
    ``view`` (rad, down < up) less VIEW_EDGE_MARGIN at each edge."""
    down, up = view[0] + VIEW_EDGE_MARGIN, view[1] - VIEW_EDGE_MARGIN
    if not down < up:
        raise ValueError(f"view: the sensors' shared view {math.degrees(view[0]):.1f}..{math.degrees(view[1]):.1f} "
                         f"deg is narrower than its edge margins")
    return distance * (math.tan(up) - math.tan(down))


def pass_heights(max_height: float, pass_spacing: float, band: float | None = None) -> list[float]:
    """Heights (m, ascending) of the horizontal passes: from the tower top down in steps of
    ``pass_spacing``, or of ``band`` (m, :func:`view_band`) where that is less, the lowest no
    lower than MIN_PASS_HEIGHT."""
    step = pass_spacing if band is None else min(pass_spacing, band)
    heights = []
    z = max_height
    while z >= MIN_PASS_HEIGHT - 1e-9:
        heights.append(z)
        z -= step
    if not heights:
        heights = [max(max_height, MIN_PASS_HEIGHT)]
    return sorted(heights)


def exploration_path(line: LineFrame, volumes: SafetyVolumes, *, takeoff: np.ndarray,
                     max_width: float, max_height: float, standoff: float, pass_spacing: float,
                     crossing_clearance: float, along_extent: float | None = None,
                     view: tuple[float, float] | None = None) -> list[PathWaypoint]:
    """The exploration path from ``takeoff`` (W) round both sides and back.

    ``view`` (rad, down < up): the elevations the camera and LiDAR both see ahead of a level
    body; the passes are then spaced no wider than the band it covers on the line plane.

    ``along_extent`` (m) is the half-length of each pass along the line (default:
    half the maximum width plus the standoff's quarter, so the passes see the
    tower's ends obliquely). Where the line bends at the tower a corridor can
    turn towards the passes: they then move out until the whole path keeps
    PATH_CLEARANCE from the volumes. Raises ValueError if the take-off point is
    within PATH_CLEARANCE of a safety volume or no such path exists.
    """
    takeoff = np.asarray(takeoff, dtype=np.float64).reshape(3)
    if not volumes.points_clear(takeoff[None], inflate=PATH_CLEARANCE)[0]:
        raise ValueError(f"takeoff: the take-off point is inside or within {PATH_CLEARANCE} m "
                         f"of a safety volume")
    widening = 0.0
    while widening <= MAX_WIDENING:
        path = _path_at(line, volumes, takeoff, max_width / 2 + standoff + widening, max_width,
                        max_height, standoff, pass_spacing, crossing_clearance, along_extent, view)
        if volumes.polyline_clear(np.array([w.position for w in path]), inflate=PATH_CLEARANCE):
            return path
        widening += WIDENING_STEP
    raise ValueError("standoff: no exploration path keeps clear of the safety volumes "
                     "(raise the standoff or lower the safety margin)")


def _path_at(line: LineFrame, volumes: SafetyVolumes, takeoff: np.ndarray, lateral: float,
             max_width: float, max_height: float, standoff: float, pass_spacing: float,
             crossing_clearance: float, along_extent: float | None,
             view: tuple[float, float] | None) -> list[PathWaypoint]:
    """The exploration path with its passes ``lateral`` m from the line plane."""
    half_len = max_width / 2 + standoff / 4 if along_extent is None else along_extent
    heights = pass_heights(max_height, pass_spacing, None if view is None else view_band(view, lateral))
    first = line.side(takeoff)
    a_take = float(takeoff @ line.along)
    start_a = -half_len if a_take <= 0 else half_len  # start the passes at the nearer end
    path = [PathWaypoint(takeoff, PlanKind.TAKEOFF, first, facing_yaw(line, first))]

    def side_passes(side: int, zs: list[float], a0: float) -> float:
        a = a0
        for z in zs:
            for a_end in (a, -a):
                p = line.to_world(np.array([a_end, side * lateral, z]))
                path.append(PathWaypoint(p, PlanKind.SCAN, side, facing_yaw(line, side)))
            a = -a
        return a  # where the last pass ended

    z_cross = volumes.top + crossing_clearance
    a_last = side_passes(first, heights, start_a)  # the along position the passes ended at
    # up above the safety volumes, across, and down the other side
    path.append(PathWaypoint(line.to_world(np.array([a_last, first * lateral, z_cross])),
                             PlanKind.CROSS, 0, facing_yaw(line, first)))
    path.append(PathWaypoint(line.to_world(np.array([a_last, -first * lateral, z_cross])),
                             PlanKind.CROSS, 0, facing_yaw(line, -first)))
    a_last = side_passes(-first, heights[::-1], a_last)
    # home: up, over the top, down to the take-off point
    path.append(PathWaypoint(line.to_world(np.array([a_last, -first * lateral, z_cross])),
                             PlanKind.CROSS, 0, facing_yaw(line, -first)))
    path.append(PathWaypoint(line.to_world(np.array([a_take, first * lateral, z_cross])),
                             PlanKind.CROSS, 0, facing_yaw(line, first)))
    path.append(PathWaypoint(np.array([takeoff[0], takeoff[1], z_cross]), PlanKind.CROSS, 0,
                             facing_yaw(line, first)))
    path.append(PathWaypoint(takeoff, PlanKind.LAND, first, facing_yaw(line, first)))
    return [w for i, w in enumerate(path)
            if i == 0 or np.linalg.norm(w.position - path[i - 1].position) > 1e-6]
