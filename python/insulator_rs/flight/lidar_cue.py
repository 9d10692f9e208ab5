"""The LiDAR cue: insulator strings found in the LiDAR's returns by geometry alone, beside the
camera, in flight (issue 47).

Every insulator the flight finds starts as a camera box; a string the network never boxes (fog,
back light, a dirty lens) was never localized, inspected nor reported. The LiDAR sees the whole
tower: every SURVEY_PERIOD s the loop takes the newest scan's returns (W, deskewed), and this
cue keeps those near the tower (:class:`TowerCloud`) and, every :data:`CUE_PERIOD` s of flight
time, runs :func:`insulator_rs.find_insulator_strings` on them. Two rules use its strings:

* **A string no camera track covers** (no registry record, confirmed or not, and no perception
  track the second look will look at anyway, within
  :data:`~insulator_rs.flight.second_look.KNOWN_STRING_REACH` of it: :func:`uncovered_strings`;
  the loop says which tracks those are) becomes a look target: the second look
  (:mod:`insulator_rs.flight.second_look`, after the registry's candidates and the refused
  tracks, within its MAX_LOOKS) flies there where a side's search ends, if the
  battery spares it, and the camera's localizations confirm it in the registry, or nothing does.
  The LiDAR never creates an insulator by itself.
* **A record the geometry contradicts** (:func:`contradicts`): no string within
  :data:`SUPPORT_REACH` of where the camera localized it, although the cloud holds
  :data:`COVER_MIN_POINTS` returns within :data:`COVER_RADIUS` of that place (the map covers it):
  the registry holds it for more evidence (``tracking/confirmation.py`` HELD_FACTOR). Where the
  cloud is thin the cue says nothing: a place the LiDAR has barely seen is no evidence against
  a string.

The cue's strings, what each rule said and each record's evidence of both cues go into
summary.json (``flight.lidar_cue``, :meth:`LidarCue.record`).
"""

from __future__ import annotations

import math
import time as wallclock
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

import insulator_rs as ir
from insulator_rs.flight.second_look import near_a_known_string, string_distance
from insulator_rs.geodesy import LineFrame
from insulator_rs.planning.obstacle_map import GROUND_BAND
from insulator_rs.tracking.registry import Insulator

#: s of flight between runs of the string finder: one exploration side's pass is 20-60 s, and the
#: finder costs 0.05-0.2 s on one core for a tower's cloud (docs/results.md), a few per cent of a core
CUE_PERIOD = 5.0
#: m kept horizontally beyond the tower's half width round its axis: the strings hang within the
#: arms' reach (``max_width / 2``); farther returns are conductors, ground clutter and neighbours
CLOUD_REACH = 2.0
#: returns the cloud keeps at most; past that it is thinned to one return per CLOUD_VOXEL. The
#: finder's budget (issue 47: 500k points in at most 0.5 s on one core); one exploration of tower A
#: leaves 163k near the tower
MAX_CLOUD_POINTS = 500_000
#: m: the thinning voxel once the cloud is full, half the finder's own (4 cm), so thinning here
#: loses nothing it would keep
CLOUD_VOXEL = 0.02
#: m from a record's centre to a LiDAR string's segment within which the geometry supports it. The
#: finder's centre error on towers A and B is at most 0.15 m (docs/results.md); a record's centre is
#: a running mean of localizations, within the registry's gate of the string
SUPPORT_REACH = 1.0
#: m, and returns within it round a record's centre: the cloud covers that place. One exploration of
#: tower B leaves 344-401 returns within 0.5 m of each string's centre (the simulator's Mid-360, a
#: frame every 0.5 s); 150 is well under half of that, so a string seen by one side's passes
#: counts as covered, one glimpsed at the edge of a scan does not
COVER_RADIUS = 0.5
COVER_MIN_POINTS = 150
#: m: a string found again within this of a look target's centre is that target (the finder's
#: centres move by a few cm from run to run as the cloud grows)
SAME_STRING = 0.5
#: the geometry's word on a camera find it contradicts (:meth:`LidarCue.verdict`)
CONTRADICTED = "no string-like structure"


def _string_record(s: ir.InsulatorString) -> Insulator:
    """A LiDAR string as a registry-shaped record (id 0, never seen by the camera) for the
    segment distance rule of :func:`~insulator_rs.flight.second_look.near_a_known_string`."""
    return Insulator(id=0, center=np.asarray(s.center, dtype=np.float64).copy(),
                     axis=np.asarray(s.axis, dtype=np.float64).copy(), observations=0, side=0)


def covered(s: ir.InsulatorString, places: list[np.ndarray], records: list[Insulator], length: float) -> bool:
    """Whether a camera track covers the LiDAR string ``s``: a perception track's anchor in
    ``places`` (W) within KNOWN_STRING_REACH of its segment, or a registry record whose centre is
    that near it or whose own segment (``length`` m) passes that near its centre."""
    own = [_string_record(s)]
    return (any(near_a_known_string(p, own, float(s.length)) for p in places)
            or any(near_a_known_string(r.center, own, float(s.length)) for r in records)
            or near_a_known_string(np.asarray(s.center, dtype=np.float64), records, length))


def uncovered_strings(strings: list[ir.InsulatorString], places: list[np.ndarray], records: list[Insulator],
                      length: float) -> list[ir.InsulatorString]:
    """The LiDAR's strings no camera track covers (:func:`covered`): the look candidates."""
    return [s for s in strings if not covered(s, places, records, length)]


def contradicts(center: np.ndarray, strings: list[ir.InsulatorString], cover: int) -> bool:
    """Whether the LiDAR's geometry contradicts a record at ``center`` (W): ``cover`` returns lie
    within COVER_RADIUS of it (COVER_MIN_POINTS or more: the map covers the place) and no string
    of ``strings`` passes within SUPPORT_REACH of it."""
    if cover < COVER_MIN_POINTS:
        return False
    return not any(string_distance(center, _string_record(s), float(s.length)) <= SUPPORT_REACH for s in strings)


class TowerCloud:
    """The LiDAR's returns (W) within ``reach`` m horizontally of the tower's axis (W origin,
    z up) and GROUND_BAND m or more above the take-off ground ``ground_z`` (the obstacle map's rule:
    lower is the ground, a dense plane the finder would only wade through), at most
    ``max_points`` (then thinned to one a CLOUD_VOXEL)."""

    def __init__(self, reach: float, *, ground_z: float = 0.0, max_points: int = MAX_CLOUD_POINTS) -> None:
        if not (math.isfinite(reach) and reach > 0):
            raise ValueError(f"reach: must be a finite number > 0 m, got {reach}")
        if not math.isfinite(ground_z):
            raise ValueError(f"ground_z: must be a finite number (m), got {ground_z}")
        self.floor = float(ground_z) + GROUND_BAND
        if isinstance(max_points, bool) or not isinstance(max_points, int) or max_points < 1:
            raise ValueError(f"max_points: must be an integer >= 1, got {max_points!r}")
        self.reach = float(reach)
        self.max_points = max_points
        self._parts: list[np.ndarray] = []
        self._n = 0
        self.thinned = 0  # times the cloud was thinned

    def __len__(self) -> int:
        return self._n

    def add(self, points_w: np.ndarray) -> None:
        p = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1)]
        p = p[(np.hypot(p[:, 0], p[:, 1]) <= self.reach) & (p[:, 2] >= self.floor)]
        if not len(p):
            return
        self._parts.append(p)
        self._n += len(p)
        if self._n > self.max_points:
            cloud = self.points()
            _, first = np.unique(np.floor(cloud / CLOUD_VOXEL).astype(np.int64), axis=0, return_index=True)
            cloud = cloud[np.sort(first)][-self.max_points:]  # still over: the oldest go
            self._parts, self._n = [cloud], len(cloud)
            self.thinned += 1

    def points(self) -> np.ndarray:
        if len(self._parts) > 1:
            self._parts = [np.concatenate(self._parts)]
        return self._parts[0] if self._parts else np.zeros((0, 3))


@dataclass(eq=False)
class LidarCue:
    """The cue in flight (see the module docstring): ``add`` the survey's returns, ``update`` at
    each tick (the finder every CUE_PERIOD s), ``doubt`` for the registry, ``look_targets`` for the
    second look, ``record`` for summary.json."""

    line: LineFrame
    max_width: float  # m, the tower's widest arms
    insulator_length: float  # m, the mission's
    ground_z: float = 0.0  # m, the take-off ground's height in W
    cloud: TowerCloud = field(init=False)
    strings: list[ir.InsulatorString] = field(default_factory=list, init=False)
    runs: int = field(default=0, init=False)
    run_time_s: float = field(default=0.0, init=False)  # wall time of the finder, summed
    _next_run: float | None = field(default=None, init=False)
    _tree: cKDTree | None = field(default=None, init=False)  # the cloud the finder last saw
    _targets: list[Insulator] = field(default_factory=list, init=False)  # look targets, kept by identity

    def __post_init__(self) -> None:
        self.cloud = TowerCloud(self.max_width / 2 + CLOUD_REACH, ground_z=self.ground_z)

    def add(self, points_w: np.ndarray) -> None:
        self.cloud.add(points_w)

    def update(self, now: float) -> bool:
        """At vehicle time ``now``: the finder on the cloud when CUE_PERIOD s have passed since its
        last run (the first a period after the first call); whether it ran."""
        if self._next_run is None:
            self._next_run = now + CUE_PERIOD
        if now < self._next_run:
            return False
        self._next_run = now + CUE_PERIOD
        self.run()
        return True

    def run(self) -> None:
        """The finder on the cloud as it is now."""
        cloud = self.cloud.points()
        t0 = wallclock.perf_counter()
        self.strings = ir.find_insulator_strings(cloud) if len(cloud) else []
        self._tree = cKDTree(cloud) if len(cloud) else None
        self.run_time_s += wallclock.perf_counter() - t0
        self.runs += 1

    def cover(self, center: np.ndarray) -> int:
        """Returns of the cloud the finder last saw within COVER_RADIUS of ``center`` (W)."""
        if self._tree is None:
            return 0
        return len(self._tree.query_ball_point(np.asarray(center, dtype=np.float64).reshape(3), COVER_RADIUS))

    def doubt(self, center: np.ndarray) -> bool:
        """The registry's question: does the geometry contradict a record at ``center`` now?"""
        return contradicts(center, self.strings, self.cover(center))

    def look_targets(self, places: list[np.ndarray], records: list[Insulator]) -> list[Insulator]:
        """Look targets (registry-shaped, id 0, seen 0 times) for the strings no camera track
        covers, the same record for a string from run to run (so the second look knows which it
        has looked at), the highest score first."""
        found = sorted(uncovered_strings(self.strings, places, records, self.insulator_length),
                       key=lambda s: -float(s.score))
        targets = []
        for s in found:
            c = np.asarray(s.center, dtype=np.float64)
            same = next((t for t in self._targets if float(np.linalg.norm(t.center - c)) <= SAME_STRING), None)
            if same is None:
                same = Insulator(id=0, center=c.copy(), axis=np.asarray(s.axis, dtype=np.float64).copy(),
                                 observations=0, side=int(self.line.side(c)))
                self._targets.append(same)
            targets.append(same)
        return targets

    def verdict(self, center: np.ndarray) -> dict[str, Any]:
        """What the geometry says of a camera find at ``center`` (W): ``lidar`` "string" (a string
        within SUPPORT_REACH), "no string-like structure" (none, in a covered place: what
        :func:`contradicts` holds) or "not covered"; the nearest string's distance from its segment
        and score (None without strings), the cover of the place."""
        near = [(string_distance(center, _string_record(s), float(s.length)), s) for s in self.strings]
        d, s = min(near, key=lambda x: x[0], default=(math.inf, None))
        cover = self.cover(center)
        lidar = ("string" if d <= SUPPORT_REACH else
                 CONTRADICTED if contradicts(center, self.strings, cover) else "not covered")
        return {"lidar": lidar, "lidar_distance_m": None if s is None else round(d, 3),
                "lidar_score": None if s is None else round(float(s.score), 3), "lidar_cover": cover}

    def evidence(self, records: list[Insulator], places: list[np.ndarray]) -> list[dict[str, Any]]:
        """Per registry record (confirmed or not) the evidence of both cues: the camera's
        localizations, whether confirmed, and the LiDAR's: the nearest string's distance from its
        segment and score, the cover of its place, whether the geometry contradicts it now and how
        many times the registry held it; then each LiDAR string no camera track covers."""
        rows: list[dict[str, Any]] = []
        for r in records:
            rows.append({"insulator_id": r.id, "center": np.round(r.center, 3).tolist(), "confirmed": r.confirmed,
                         "camera_localizations": r.observations, **self.verdict(r.center), "held": r.held})
        for s in uncovered_strings(self.strings, places, records, self.insulator_length):
            rows.append({"insulator_id": None, "center": np.round(np.asarray(s.center), 3).tolist(),
                         "confirmed": False, "camera_localizations": 0, "lidar": "string, no camera track",
                         "lidar_distance_m": 0.0, "lidar_score": round(float(s.score), 3),
                         "lidar_cover": self.cover(np.asarray(s.center)), "held": 0})
        return rows

    def record(self, records: list[Insulator], places: list[np.ndarray]) -> dict[str, Any]:
        """summary.json's ``flight.lidar_cue``: the cloud, the finder's runs, its strings now, and
        the per-record evidence of both cues (:meth:`evidence`)."""
        return {"enabled": True, "cloud_points": len(self.cloud), "cloud_thinned": self.cloud.thinned,
                "runs": self.runs, "finder_wall_s": round(self.run_time_s, 3),
                "strings": [{"center": np.round(np.asarray(s.center), 3).tolist(),
                             "axis": np.round(np.asarray(s.axis), 3).tolist(), "length": round(float(s.length), 3),
                             "score": round(float(s.score), 3), "n_points": int(s.n_points)} for s in self.strings],
                "evidence": self.evidence(records, places)}
