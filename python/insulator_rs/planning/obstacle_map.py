"""What the LiDAR has seen, kept for the planner: a hashed voxel grid of returns in W.

The safety volumes (:mod:`insulator_rs.planning.safety`) are built from the tower's GPS, height
and width only; a second circuit, a guy wire, a neighbouring structure or a tree is invisible
to them, although the LiDAR sees it every scan. This map keeps those returns so that every
planned path is also checked against what was seen.

* Voxels of :data:`VOXEL_SIZE` m, keyed by their integer index (a dict: only occupied voxels
  cost memory), each with a count of returns. A voxel counts as occupied from
  :data:`MIN_HITS` returns on: a single noise return (dust, a bird, a multipath echo) must
  not block a route.
* Returns inside the safety volumes are not kept (the boxes already keep the planner out of
  there, and the tower and its conductors would otherwise fill the map), nor returns less than
  :data:`GROUND_BAND` m above the take-off ground, nor returns farther than
  :data:`SURVEY_RANGE` m from the sensor or :data:`MAP_RADIUS` m horizontally from the tower (the flight never goes there). At most
  :data:`MAX_VOXELS` voxels are kept; past that new voxels are counted as dropped and the
  record says so.
* Distances are conservative: the clearance of a point is its distance to the nearest
  occupied voxel's centre less half the voxel's diagonal, so it never exceeds the distance to
  any return in that voxel, and is at most one voxel diagonal below the true distance.

:class:`SeenVolumes` is the safety volumes with the map added: the same checks
(``points_clear``, ``segments_clear``, ``polyline_clear``, ``samples_clear``), so every planner
that takes the volumes (min-snap refinement, the routes) checks the map too, with the
mission's safety margin kept from every occupied voxel. :func:`bend_polyline` bends a polyline
round what the map holds, or refuses it, and says which segment was bent round which obstacle
(for the log): the one rule for every path flown, the legs of the mission
(:mod:`insulator_rs.planning.segments`) and the abort's way out (:mod:`insulator_rs.planning.abort`)
alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from insulator_rs.exceptions import ObstacleBlocked, ObstacleMapError
from insulator_rs.planning.safety import SafetyVolumes

VOXEL_SIZE = 0.4  # m: a pole or a guy wire fills a voxel; a 2 m margin is 5 voxels
MIN_HITS = 2  # returns before a voxel counts as occupied (one noise return must not block)
# m above the take-off ground: returns below are the ground. Deskewed with the estimated pose,
# ground returns land up to 1.2 m high, 1-4 m from the take-off point too (measured on the
# simulated flight: they blocked the landing approach 2 m above it). Legs fly no lower than 3 m
# (the landing approach 2 m): what stands lower than this is not seen by the map (README)
GROUND_BAND = 1.5
# m from the sensor: farther returns are left out (the least accurate, and seen again nearer
# when the flight goes there)
SURVEY_RANGE = 25.0
MAP_RADIUS = 150.0  # m from the tower, horizontally: beyond it the flight never goes
MAX_VOXELS = 2_000_000  # about 200 MB of dict at worst; a tower flight fills a few thousand
# detour offsets tried, in multiples of (margin + one voxel diagonal) from the closest approach
DETOUR_STEPS = (1.0, 1.5, 2.0, 3.0, 4.0)
DETOUR_DEPTH = 2  # a detour's halves may themselves be bent once more
# m kept beyond the margin by a detour: the min-snap curve through it is checked with the margin
# grown by half a sampling step, and must be able to hug the polyline closely enough to pass
DETOUR_SLACK = 0.25


class ObstacleMap:
    """A hashed voxel grid of LiDAR returns in W (see the module docstring).

    ``known``: the safety volumes whose inside is not mapped (None: map everything);
    ``ground_z``: height (W) of the take-off ground."""

    def __init__(self, *, known: SafetyVolumes | None, ground_z: float, voxel: float = VOXEL_SIZE,
                 min_hits: int = MIN_HITS, max_voxels: int = MAX_VOXELS) -> None:
        for name, value in (("voxel", voxel), ("ground_z", ground_z)):
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise ObstacleMapError(f"{name}: must be a finite number, got {value!r}")
        if not 0.05 <= voxel <= 5.0:
            raise ObstacleMapError(f"voxel: must lie in [0.05, 5] m (finer only costs memory, coarser "
                                   f"blocks what is clear), got {voxel}")
        if isinstance(min_hits, bool) or not isinstance(min_hits, int) or min_hits < 1:
            raise ObstacleMapError(f"min_hits: must be an integer >= 1, got {min_hits!r}")
        if isinstance(max_voxels, bool) or not isinstance(max_voxels, int) or max_voxels < 1:
            raise ObstacleMapError(f"max_voxels: must be an integer >= 1, got {max_voxels!r}")
        self.voxel = float(voxel)
        self.min_hits = min_hits
        self.max_voxels = max_voxels
        self.known = known
        self.ground_z = float(ground_z)
        self.half_diagonal = math.sqrt(3.0) * self.voxel / 2
        self.hits: dict[tuple[int, int, int], int] = {}
        self.returns = 0  # returns inserted and kept
        self.dropped_voxels = 0  # new voxels refused because the map was full
        self.version = 0  # grows whenever the set of occupied voxels changes
        self._tree: cKDTree | None = None
        self._centres = np.zeros((0, 3))
        self._tree_version = -1

    # -- building ------------------------------------------------------------------------
    def insert(self, points_w: np.ndarray, sensor_w: np.ndarray | None = None) -> int:
        """Add LiDAR returns (N, 3) in W seen from ``sensor_w`` (3,) W (None: from anywhere; else
        returns beyond SURVEY_RANGE are left out); the number of voxels that became occupied.
        Non-finite returns are ignored (a driver's NaN padding)."""
        p = np.asarray(points_w, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ObstacleMapError(f"points_w: expected an (N, 3) array, got shape {p.shape}")
        p = p[np.all(np.isfinite(p), axis=1)]
        if sensor_w is not None:
            p = p[np.linalg.norm(p - np.asarray(sensor_w, dtype=np.float64), axis=1) <= SURVEY_RANGE]
        p = p[(p[:, 2] >= self.ground_z + GROUND_BAND) & (np.hypot(p[:, 0], p[:, 1]) <= MAP_RADIUS)]
        if self.known is not None and len(p):
            p = p[self.known.points_clear(p)]
        if not len(p):
            return 0
        keys, counts = np.unique(np.floor(p / self.voxel).astype(np.int64), axis=0, return_counts=True)
        became = 0
        for key, n in zip(map(tuple, keys.tolist()), counts.tolist()):
            old = self.hits.get(key)
            if old is None and len(self.hits) >= self.max_voxels:
                self.dropped_voxels += 1
                continue
            new = (old or 0) + n
            self.hits[key] = new
            became += (old or 0) < self.min_hits <= new
        self.returns += len(p)
        if became:
            self.version += 1
        return became

    # -- queries -------------------------------------------------------------------------
    def occupied_centres(self) -> np.ndarray:
        """Centres (M, 3) in W of the occupied voxels."""
        self._refresh()
        return self._centres

    def _refresh(self) -> None:
        if self._tree_version == self.version:
            return
        keys = [k for k, n in self.hits.items() if n >= self.min_hits]
        self._centres = (np.array(keys, dtype=np.float64).reshape(-1, 3) + 0.5) * self.voxel
        self._tree = cKDTree(self._centres) if len(keys) else None
        self._tree_version = self.version

    def clearance(self, points_w: np.ndarray) -> np.ndarray:
        """Conservative distance (m) of each W point (..., 3) from the returns in occupied voxels
        (inf where the map is empty; 0 inside a voxel)."""
        p = np.asarray(points_w, dtype=np.float64)
        self._refresh()
        if self._tree is None:
            return np.full(p.shape[:-1], np.inf)
        d, _ = self._tree.query(p.reshape(-1, 3))
        return np.maximum(np.asarray(d).reshape(p.shape[:-1]) - self.half_diagonal, 0.0)

    def nearest(self, points_w: np.ndarray) -> np.ndarray:
        """The centre (3,) W of the occupied voxel nearest to any of ``points_w`` (N, 3): where
        the obstacle that a path came closest to was seen (named in the log). ObstacleMapError
        when the map holds no occupied voxel."""
        p = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
        self._refresh()
        if self._tree is None:
            raise ObstacleMapError("nearest: the map holds no occupied voxel")
        d, k = self._tree.query(p)
        return np.array(self._centres[int(np.asarray(k).reshape(-1)[int(np.argmin(d))])])

    def points_clear(self, points_w: np.ndarray, margin: float) -> np.ndarray:
        """True for each W point (..., 3) at least ``margin`` m from every occupied voxel."""
        return self.clearance(points_w) >= margin

    def segments_clear(self, p0: np.ndarray, p1: np.ndarray, margin: float) -> np.ndarray:
        """True for each straight segment p0[i] -> p1[i] ((..., 3), W) that stays ``margin`` m
        from every occupied voxel: sampled at most half a voxel apart, each sample checked with
        the margin grown by half the step (every point of the segment is that close to one)."""
        a = np.asarray(p0, dtype=np.float64)
        b = np.asarray(p1, dtype=np.float64)
        shape = np.broadcast_shapes(a.shape, b.shape)[:-1]
        a, b = np.broadcast_to(a, shape + (3,)).reshape(-1, 3), np.broadcast_to(b, shape + (3,)).reshape(-1, 3)
        if not len(self.occupied_centres()):
            return np.ones(shape, dtype=bool)
        lengths = np.linalg.norm(b - a, axis=1)
        n = np.maximum(np.ceil(lengths / (self.voxel / 2)).astype(int), 1)
        out = np.empty(len(a), dtype=bool)
        for i in range(len(a)):
            t = np.linspace(0.0, 1.0, n[i] + 1)[:, None]
            step = lengths[i] / n[i]
            out[i] = bool(np.all(self.points_clear(a[i] + t * (b[i] - a[i]), margin + step / 2)))
        return out.reshape(shape)

    def record(self) -> dict[str, Any]:
        """What the map holds (summary.json)."""
        return {"voxel_m": self.voxel, "min_hits": self.min_hits, "returns": self.returns,
                "voxels": len(self.hits), "occupied_voxels": len(self.occupied_centres()),
                "dropped_voxels": self.dropped_voxels, "full": len(self.hits) >= self.max_voxels}


@dataclass(frozen=True)
class SeenVolumes(SafetyVolumes):
    """The safety volumes and the obstacle map together: a point or a path is clear when it is
    out of every box and ``margin`` m from every occupied voxel (inflated alike). The
    footprint and the top stay the boxes' (the abort's landing and crossing heights)."""

    obstacles: ObstacleMap | None = None
    margin: float = 0.0

    @classmethod
    def of(cls, volumes: SafetyVolumes, obstacles: ObstacleMap, margin: float) -> SeenVolumes:
        return cls(volumes.boxes, volumes.top, obstacles, float(margin))

    def points_clear(self, points_w: np.ndarray, inflate: float = 0.0) -> np.ndarray:
        clear = super().points_clear(points_w, inflate)
        if self.obstacles is not None:
            clear &= self.obstacles.points_clear(points_w, self.margin + inflate)
        return clear

    def segments_clear(self, p0: np.ndarray, p1: np.ndarray, inflate: float = 0.0) -> np.ndarray:
        clear = super().segments_clear(p0, p1, inflate)
        if self.obstacles is not None:
            clear &= self.obstacles.segments_clear(p0, p1, self.margin + inflate)
        return clear


def _detour_directions(a: np.ndarray, b: np.ndarray) -> list[np.ndarray]:
    """Unit directions to push a segment's closest approach: both ways across it horizontally,
    up, and the two diagonals up and across (never down: the ground is there)."""
    d = b - a
    across = np.array([-d[1], d[0], 0.0])
    if np.linalg.norm(across) < 1e-9:  # a vertical segment: across is any horizontal direction
        across = np.array([1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    up = np.array([0.0, 0.0, 1.0])
    diag = (across + up) / math.sqrt(2.0)
    diag2 = (-across + up) / math.sqrt(2.0)
    return [across, -across, up, diag, diag2]


def _bend(a: np.ndarray, b: np.ndarray, space: SeenVolumes, depth: int) -> list[np.ndarray] | None:
    """Points between ``a`` and ``b`` (exclusive) making a clear polyline: [] when the straight
    segment is clear, else the shortest bend found with the fewest points (one via point, else
    one whose halves bend once more, down to ``depth``); None when none is clear."""
    if space.segments_clear(a[None], b[None])[0]:
        return []
    if depth == 0 or space.obstacles is None:
        return None
    # push the point of the segment closest to what was seen away from it; a via point keeps
    # DETOUR_SLACK from the boxes too (the curve through it swings out a little either way)
    near = _closest_approach(a, b, space.obstacles)
    reach = space.margin + 2 * space.obstacles.half_diagonal
    vias = [near + s * reach * u for s in DETOUR_STEPS for u in _detour_directions(a, b)]
    vias = [v for v in vias if space.points_clear(v[None], inflate=DETOUR_SLACK)[0]]
    vias.sort(key=lambda v: float(np.linalg.norm(v - a) + np.linalg.norm(b - v)))
    for level in range(1, depth + 1):  # the fewest bends first, the shortest of those
        best: list[np.ndarray] | None = None
        for via in vias:
            first = _bend(a, via, space, level - 1)
            second = None if first is None else _bend(via, b, space, level - 1)
            if first is None or second is None:
                continue
            route = [*first, via, *second]
            if best is None or _length([a, *route, b]) < _length([a, *best, b]):
                best = route
            if level == 1:
                break  # sorted by length: the first single bend is the shortest
        if best is not None:
            return best
    return None


def _closest_approach(a: np.ndarray, b: np.ndarray, obstacles: ObstacleMap) -> np.ndarray:
    """The point of the segment ``a`` -> ``b`` (sampled half a voxel apart) nearest to what the
    map holds."""
    n = max(int(np.ceil(np.linalg.norm(b - a) / (obstacles.voxel / 2))), 1)
    samples = a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)
    return samples[int(np.argmin(obstacles.clearance(samples)))]


def _seen_near(a: np.ndarray, b: np.ndarray, obstacles: ObstacleMap | None) -> np.ndarray | None:
    """Where the map saw what the segment ``a`` -> ``b`` comes nearest to: the centre (W) of that
    occupied voxel; None without a map or with an empty one (only the boxes then)."""
    if obstacles is None or not len(obstacles.occupied_centres()):
        return None
    return obstacles.nearest(_closest_approach(a, b, obstacles))


def _where(point: np.ndarray) -> str:
    return str(np.round(point, 1).tolist())


def _at(point: np.ndarray | None) -> str:
    return "" if point is None else f" at {_where(point)}"


def _length(points: list[np.ndarray]) -> float:
    return float(np.sum(np.linalg.norm(np.diff(np.array(points), axis=0), axis=1)))


@dataclass(frozen=True)
class Bend:
    """One segment of a polyline bent round what the map holds: ``segment`` its index in the
    polyline given (0: the first), ``start``/``end`` its ends, ``obstacle`` the centre (W) of the
    occupied voxel the straight segment came nearest to (None: the map holds none; the boxes
    alone bent it), ``points`` the via points added."""

    segment: int
    start: np.ndarray
    end: np.ndarray
    obstacle: np.ndarray | None
    points: int

    def describe(self) -> str:
        """One line for the log and the summary."""
        return (f"segment {_where(self.start)} -> {_where(self.end)} bent round the obstacle the LiDAR "
                f"saw{_at(self.obstacle)} ({self.points} point{'s' if self.points != 1 else ''} added)")

    def as_record(self) -> dict[str, Any]:
        return {"segment": self.segment, "start": self.start.tolist(), "end": self.end.tolist(),
                "obstacle": None if self.obstacle is None else self.obstacle.tolist(), "points_added": self.points}


def bend_polyline(points: np.ndarray, space: SeenVolumes,
                  slack: float = DETOUR_SLACK) -> tuple[np.ndarray, tuple[Bend, ...]]:
    """``points`` (K, 3) with detour points inserted wherever a segment comes closer than the
    margin to what the map holds: for each such segment, its point closest to the map pushed
    across, up or both, the shortest clear bend first; the bends keep ``slack`` m beyond the
    margin (the boxes are kept as they are). With the segments bent (:class:`Bend`, in order).
    ObstacleBlocked (a PlanningError), naming the segment or the waypoint and where the obstacle
    was seen, when no bend clears a segment (the path is refused) or a point itself is within the
    margin."""
    p = np.asarray(points, dtype=np.float64)
    blocked = ~space.points_clear(p)
    if np.any(blocked):
        i = int(np.flatnonzero(blocked)[0])
        raise ObstacleBlocked(f"waypoint {_where(p[i])} lies within the safety margin of "
                              f"an obstacle the LiDAR saw{_at(_seen_near(p[i], p[i], space.obstacles))}")
    wide = SeenVolumes(space.boxes, space.top, space.obstacles, space.margin + slack)
    out = [p[0]]
    bends: list[Bend] = []
    for k, (a, b) in enumerate(zip(p[:-1], p[1:])):
        bend = [] if space.segments_clear(a[None], b[None])[0] else _bend(a, b, wide, DETOUR_DEPTH)
        if bend is None:
            raise ObstacleBlocked(f"segment {_where(a)} -> {_where(b)}: no detour round the obstacle the LiDAR "
                                  f"saw{_at(_seen_near(a, b, space.obstacles))}")
        if bend:
            bends.append(Bend(k, a.copy(), b.copy(), _seen_near(a, b, space.obstacles), len(bend)))
        out.extend(bend)
        out.append(b)
    return np.array(out), tuple(bends)
