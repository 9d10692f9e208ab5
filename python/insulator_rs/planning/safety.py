"""Safety volumes round the tower and exact checks of paths against them.

The volumes are oriented boxes in W: the tower's *safety box* (its maximum
width and height plus the safety margin) and one *conductor corridor* from the
tower to each neighbour tower, as wide and as high as the safety box, where the
conductors run. They reach down to :data:`GROUND_DEPTH` below the base so that
no path can pass under the conductors. Together they split space into the two
sides of the tower; the only way from one side to the other is over the top.

Checks are exact geometry: a straight segment is tested against each box with
the slab (Liang-Barsky) method in the box's own frame; a sampled trajectory is
checked with each box grown by half the longest distance the vehicle can fly
between two samples, which bounds the continuous curve between them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from insulator_rs.geodesy import LineFrame

# The boxes reach this far below the tower base (m): nothing may pass under the conductors.
GROUND_DEPTH = 1000.0


@dataclass(frozen=True)
class OrientedBox:
    """A box in W: ``center`` (3,) m, ``axes`` (3, 3) with the box's unit axes as rows,
    ``half_extents`` (3,) m along those axes, and a ``name`` for messages."""

    center: np.ndarray
    axes: np.ndarray
    half_extents: np.ndarray
    name: str

    def to_local(self, points_w: np.ndarray) -> np.ndarray:
        """Coordinates of W points (..., 3) in the box frame."""
        return (np.asarray(points_w, dtype=np.float64) - self.center) @ self.axes.T

    def contains(self, points_w: np.ndarray, inflate: float = 0.0) -> np.ndarray:
        """Whether each W point (..., 3) lies inside (or on) the box grown by ``inflate`` m."""
        q = np.abs(self.to_local(points_w))
        return np.all(q <= self.half_extents + inflate, axis=-1)

    def footprint_distance(self, points_w: np.ndarray) -> np.ndarray:
        """Horizontal distance (m) of each W point (..., 3) from the box's footprint (its
        outline seen from above; 0 over it). The box's third axis is vertical, so a point
        this far from the footprint is as far from the box at every height."""
        q = np.abs(self.to_local(points_w)[..., :2]) - self.half_extents[:2]
        return np.hypot(np.maximum(q[..., 0], 0.0), np.maximum(q[..., 1], 0.0))

    def segments_intersect(self, p0: np.ndarray, p1: np.ndarray, inflate: float = 0.0) -> np.ndarray:
        """Whether each segment p0[i] -> p1[i] ((..., 3) each, W) touches the box grown by ``inflate``.

        Liang-Barsky clipping of the parametric segment against the three slabs:
        exact, and vectorised over segments.
        """
        a = self.to_local(p0)
        d = self.to_local(p1) - a
        h = self.half_extents + inflate
        t_lo = np.zeros(a.shape[:-1])
        t_hi = np.ones(a.shape[:-1])
        for k in range(3):
            dk, ak = d[..., k], a[..., k]
            parallel = np.abs(dk) < 1e-15
            with np.errstate(divide="ignore", invalid="ignore"):
                t1 = (-h[k] - ak) / dk
                t2 = (h[k] - ak) / dk
            lo = np.where(parallel, np.where(np.abs(ak) <= h[k], -np.inf, np.inf), np.minimum(t1, t2))
            hi = np.where(parallel, np.where(np.abs(ak) <= h[k], np.inf, -np.inf), np.maximum(t1, t2))
            t_lo = np.maximum(t_lo, lo)
            t_hi = np.minimum(t_hi, hi)
        return t_lo <= t_hi


def _box_between(start: np.ndarray, end: np.ndarray, half_width: float, top: float,
                 name: str) -> OrientedBox:
    """A box whose horizontal axis runs from ``start`` to ``end`` (W, only x/y used), of
    half-width ``half_width`` either side, from GROUND_DEPTH below the base up to ``top``."""
    d = np.array([end[0] - start[0], end[1] - start[1], 0.0])
    length = float(np.hypot(d[0], d[1]))
    along = d / length
    lateral = np.array([-along[1], along[0], 0.0])
    up = np.array([0.0, 0.0, 1.0])
    z_lo = -GROUND_DEPTH
    centre = np.array([(start[0] + end[0]) / 2, (start[1] + end[1]) / 2, (z_lo + top) / 2])
    return OrientedBox(centre, np.stack([along, lateral, up]),
                       np.array([length / 2, half_width, (top - z_lo) / 2]), name)


@dataclass(frozen=True)
class SafetyVolumes:
    """The tower's safety box and conductor corridors (all in W)."""

    boxes: tuple[OrientedBox, ...]
    top: float  # m: height of the boxes' top faces in W

    def points_clear(self, points_w: np.ndarray, inflate: float = 0.0) -> np.ndarray:
        """True for each W point (..., 3) outside every box grown by ``inflate`` m."""
        inside = np.zeros(np.asarray(points_w).shape[:-1], dtype=bool)
        for box in self.boxes:
            inside |= box.contains(points_w, inflate)
        return ~inside

    def footprint_distance(self, points_w: np.ndarray) -> np.ndarray:
        """Horizontal distance (m) of each W point (..., 3) from the nearest box's footprint
        (0 over one): a point at a positive distance can descend to the ground without
        touching a box."""
        return np.min([box.footprint_distance(points_w) for box in self.boxes], axis=0)

    def segments_clear(self, p0: np.ndarray, p1: np.ndarray, inflate: float = 0.0) -> np.ndarray:
        """True for each straight segment p0[i] -> p1[i] (W) that touches no box (exact)."""
        hit = np.zeros(np.asarray(p0).shape[:-1], dtype=bool)
        for box in self.boxes:
            hit |= box.segments_intersect(p0, p1, inflate)
        return ~hit

    def polyline_clear(self, points_w: np.ndarray, inflate: float = 0.0) -> bool:
        """Whether the polyline through the W points (N, 3) touches no box (exact)."""
        p = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
        if len(p) == 1:
            return bool(self.points_clear(p, inflate)[0])
        return bool(np.all(self.segments_clear(p[:-1], p[1:], inflate)))

    def samples_clear(self, positions: np.ndarray, max_step: float) -> bool:
        """Whether a continuous trajectory sampled at ``positions`` (N, 3) stays out of every box.

        ``max_step`` (m) bounds the length of the trajectory between two
        consecutive samples (e.g. v_max * dt). Every point of the curve between
        two samples is within max_step / 2 of one of them, so checking the
        samples against the boxes grown by max_step / 2 is conservative and exact
        for the continuous curve.
        """
        if max_step < 0 or not np.isfinite(max_step):
            raise ValueError(f"max_step: must be finite and >= 0, got {max_step}")
        return bool(np.all(self.points_clear(positions, inflate=max_step / 2)))


def safety_volumes(line: LineFrame, *, max_width: float, max_height: float,
                   margin: float) -> SafetyVolumes:
    """The safety box (tower at the W origin) and one corridor to each neighbour.

    The box is ``max_width`` + 2 ``margin`` wide along and across the line and
    ``max_height`` + ``margin`` high; each corridor runs from the tower to the
    neighbour's base with the same width and height.
    """
    half = max_width / 2 + margin
    top = max_height + margin
    o = np.zeros(3)
    tower = _box_between(o - half * line.along, o + half * line.along, half, top, "tower safety box")
    boxes = [tower]
    for i, nb in enumerate(line.neighbours):
        boxes.append(_box_between(o, nb, half, top, f"conductor corridor {i}"))
    return SafetyVolumes(tuple(boxes), top)
