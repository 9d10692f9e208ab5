"""Synthetic LiDAR clouds with known ground truth, for tests, benchmarks and trying the API.

* :func:`insulator_cloud` — what box culling hands to ``localize``: the visible
  side of one insulator (a rod with sheds) seen from the UAV, plus the clutter
  that shares its bounding box in practice (tower members behind its tower end,
  the conductor leaving its line end, stray returns) and range noise.
* :func:`line_clusters` — insulator-like rods on a grid plus uniform noise, at
  a density independent of the size (the DBSCAN benchmark workload).
* :func:`lidar_frame` — a full-frame cloud spread over a Livox Mid-360's field
  of view (the projection/culling benchmark workload).
* :func:`tower_cloud` — a whole lattice tower and its conductors over ~60 m, as
  accumulated scans see it (the sparse tower-scale DBSCAN workload).

Frames and units: metres; clouds for ``localize`` are in the body frame B (FLU,
the UAV at the origin); :func:`lidar_frame` is in the LiDAR frame L. Every
function is deterministic for its ``seed``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "CONDUCTOR",
    "INSULATOR",
    "STRAY",
    "TOWER",
    "SyntheticInsulator",
    "insulator_cloud",
    "lidar_frame",
    "line_clusters",
    "tower_cloud",
]

# Source labels of the points of an insulator cloud.
INSULATOR, TOWER, CONDUCTOR, STRAY = 0, 1, 2, 3

# Insulator shape: a glass/composite string is a core rod with sheds (discs)
# every ~0.12 m whose radius is about twice the core's.
_SHED_PITCH = 0.12  # m
_SHED_WIDTH = 0.03  # m, thickness of one shed along the axis
_CORE_RADIUS_FRACTION = 0.45  # core radius / shed radius
# Tower angle members and the conductor, as seen in a culled box.
_MEMBER_LENGTH = 2.0  # m
_MEMBER_HALF_WIDTH = 0.04  # m, half the flange of an L-section angle member
_CONDUCTOR_RADIUS = 0.015  # m
# Livox Mid-360 field of view (vertical band, degrees) and range for lidar_frame.
_MID360_ELEVATION = (-7.0, 52.0)


@dataclass(frozen=True)
class SyntheticInsulator:
    """A culled cloud around one insulator, with ground truth.

    ``points`` (N,3) float64 in B; ``source`` (N,) int8, one of ``INSULATOR``,
    ``TOWER``, ``CONDUCTOR``, ``STRAY`` per point; ``center`` (3,) the true
    centre of the insulator axis; ``axis`` (3,) its unit direction, largest
    |component| positive; ``length`` and ``radius`` (shed radius) in metres.
    """

    points: NDArray[np.float64]
    source: NDArray[np.int8]
    center: NDArray[np.float64]
    axis: NDArray[np.float64]
    length: float
    radius: float

    def errors(self, center: ArrayLike, direction: ArrayLike) -> tuple[float, float]:
        """(centre error in m, axis error in degrees) of an estimate against the truth.

        The axis error ignores the sign of ``direction``.
        """
        c_err = float(np.linalg.norm(np.asarray(center, dtype=np.float64) - self.center))
        d = np.asarray(direction, dtype=np.float64)
        cos = abs(float(d @ self.axis)) / float(np.linalg.norm(d))
        return c_err, float(np.degrees(np.arccos(min(1.0, cos))))


def insulator_cloud(
    *,
    seed: int = 0,
    distance: float = 9.0,
    azimuth: float = 0.0,
    elevation: float = 0.0,
    orientation: Literal["horizontal", "vertical"] | ArrayLike = "horizontal",
    length: float = 1.2,
    radius: float = 0.09,
    n_insulator: int = 300,
    tower: bool = True,
    tower_gap: float = 0.6,
    tower_depth: float = 0.4,
    n_tower: int = 250,
    conductor: bool = True,
    conductor_angle: float = 60.0,
    conductor_length: float = 0.8,
    n_conductor: int = 40,
    n_stray: int = 15,
    range_noise: float = 0.02,
) -> SyntheticInsulator:
    """One insulator as the fusion pipeline sees it after box culling (B frame).

    Geometry: the insulator's centre lies ``distance`` m from the UAV, at
    ``azimuth``/``elevation`` (radians, FLU: azimuth from +x towards +y).
    ``orientation`` is ``"horizontal"`` (axis horizontal and across the line of
    sight, tower A), ``"vertical"`` (tower B) or an explicit axis vector.
    Only the side facing the sensor returns points (``n_insulator`` of them,
    the 3-frame accumulation of the paper).

    Clutter: with ``tower``, two angle members (``n_tower`` points) start
    ``tower_gap`` m beyond the insulator's tower end (the end towards -axis)
    and ``tower_depth`` m further from the UAV; ``tower_gap`` below DBSCAN's
    eps makes them touch the insulator's cluster (a hard case). With
    ``conductor``, a conductor (``n_conductor`` points) leaves the line end at
    ``conductor_angle`` degrees from the axis for ``conductor_length`` m; it
    is attached, so DBSCAN keeps it in the insulator's cluster and only line
    fitting removes it. ``n_stray`` uniform returns fill the box region.
    ``range_noise`` is the std of Gaussian noise along each ray (m).
    """
    if distance <= 0 or length <= 0 or radius <= 0:
        raise ValueError("distance, length and radius must be positive")
    rng = np.random.default_rng(seed)
    line_of_sight = np.array(
        [
            np.cos(elevation) * np.cos(azimuth),
            np.cos(elevation) * np.sin(azimuth),
            np.sin(elevation),
        ]
    )
    center = distance * line_of_sight
    axis = _axis_for(orientation, line_of_sight)
    # Unit vectors across the axis: `toward` faces the sensor, `side` completes the frame.
    toward = _perpendicular_part(-line_of_sight, axis)
    side = np.cross(axis, toward)

    parts: list[tuple[NDArray[np.float64], int]] = []
    parts.append((_insulator_surface(rng, center, axis, toward, side, length, radius, n_insulator), INSULATOR))
    if tower and n_tower > 0:
        tower_end = center - 0.5 * length * axis
        anchor = tower_end - tower_gap * axis + tower_depth * (-toward)
        parts.append((_tower_members(rng, anchor, axis, toward, n_tower), TOWER))
    if conductor and n_conductor > 0:
        line_end = center + 0.5 * length * axis
        bend = np.radians(conductor_angle)
        across = _perpendicular_part(np.array([0.0, 0.0, -1.0]), axis)
        if not np.any(across):
            across = side
        direction = np.cos(bend) * axis + np.sin(bend) * across
        parts.append(
            (_rod(rng, line_end, direction, conductor_length, _CONDUCTOR_RADIUS, n_conductor), CONDUCTOR)
        )
    if n_stray > 0:
        half = 0.5 * length + 0.5
        stray = center + rng.uniform(-half, half, size=(n_stray, 3))
        parts.append((stray, STRAY))

    points = np.concatenate([p for p, _ in parts])
    source = np.concatenate([np.full(len(p), s, dtype=np.int8) for p, s in parts])
    points = _add_range_noise(rng, points, range_noise)
    return SyntheticInsulator(
        points=points,
        source=source,
        center=center,
        axis=_canonical(axis),
        length=float(length),
        radius=float(radius),
    )


def line_clusters(
    n_points: int,
    *,
    points_per_line: int = 500,
    noise_fraction: float = 0.2,
    spacing: float = 3.0,
    seed: int = 0,
) -> NDArray[np.float64]:
    """``n_points`` (N,3) float64: insulator-like clusters on a grid, plus uniform noise.

    Each cluster is the visible half of a 2 m long, 0.12 m radius rod (radius
    jittered by +-2 cm) with a random tilt, about ``points_per_line`` points;
    clusters sit ``spacing`` m apart on a square grid in the z = 0 plane; a
    ``noise_fraction`` of the points are uniform over the grid's box (z within
    +-2 m). The density stays the same as ``n_points`` grows (the DBSCAN scaling
    workload; fusion_core's criterion bench builds nearly the same cloud). With eps
    0.3 m and min_points 5 the rods come out as clusters.
    """
    if n_points < 0 or points_per_line < 1 or not 0.0 <= noise_fraction <= 1.0:
        raise ValueError("need n_points >= 0, points_per_line >= 1, 0 <= noise_fraction <= 1")
    rng = np.random.default_rng(seed)
    n_noise = int(noise_fraction * n_points)
    n_rod_points = n_points - n_noise
    n_lines = max(1, round(n_rod_points / points_per_line))
    # Split the rod points evenly so the noise share is exactly noise_fraction at every size.
    per_rod = np.full(n_lines, n_rod_points // n_lines)
    per_rod[: n_rod_points % n_lines] += 1
    side = int(np.ceil(np.sqrt(n_lines)))
    rods = []
    for k, count in enumerate(per_rod):
        centre = spacing * np.array([k % side, k // side, 0.0])
        axis = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), 1.0])
        axis /= np.linalg.norm(axis)
        u = np.cross(axis, [0.3, 0.2, 0.9])
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        t = rng.uniform(-1.0, 1.0, size=count)
        theta = rng.uniform(-np.pi / 2, np.pi / 2, size=count)
        r = 0.12 + rng.uniform(-0.02, 0.02, size=count)
        radial = np.outer(np.cos(theta), u) + np.outer(np.sin(theta), v)
        rods.append(centre + np.outer(t, axis) + r[:, None] * radial)
    points = np.concatenate(rods)
    extent = spacing * side
    noise = np.column_stack(
        [
            rng.uniform(-1.0, extent, size=n_noise),
            rng.uniform(-1.0, extent, size=n_noise),
            rng.uniform(-2.0, 2.0, size=n_noise),
        ]
    )
    return np.concatenate([points, noise])


def lidar_frame(
    n_points: int, *, seed: int = 0, min_range: float = 1.0, max_range: float = 40.0
) -> NDArray[np.float64]:
    """(N,3) float64 in L: one frame spread over a Mid-360's 360 x (-7..52 deg) field of view.

    Ranges are uniform in [min_range, max_range] m; about a quarter of the
    points fall in front of a forward-looking camera.
    """
    rng = np.random.default_rng(seed)
    azimuth = rng.uniform(-np.pi, np.pi, size=n_points)
    elevation = np.radians(rng.uniform(*_MID360_ELEVATION, size=n_points))
    rng_m = rng.uniform(min_range, max_range, size=n_points)
    return np.column_stack(
        [
            rng_m * np.cos(elevation) * np.cos(azimuth),
            rng_m * np.cos(elevation) * np.sin(azimuth),
            rng_m * np.sin(elevation),
        ]
    )


# A lattice tower (fusion_core's benches/tower.rs builds the same recipe): height, body
# half-widths at base and top, (height, reach) of the cross-arms, panel height, conductor
# half-span along y, sag, the conductor and stray shares, and the per-axis jitter (m).
_TOWER_HEIGHT = 48.0
_TOWER_BASE_HALF, _TOWER_TOP_HALF = 5.0, 1.0
_TOWER_ARMS = ((30.0, 9.0), (37.0, 7.5), (44.0, 6.0))
_TOWER_PANEL = 3.0
_SPAN_HALF, _SAG = 30.0, 2.0
_WIRE_SHARE, _STRAY_SHARE, _TOWER_JITTER = 0.25, 0.02, 0.02


def _tower_segments() -> NDArray[np.float64]:
    """(S,2,3): the lattice as straight members (legs, rings and X-bracing per panel,
    cross-arm chords and braces, an earth-wire peak)."""

    def half(z: float) -> float:
        return _TOWER_BASE_HALF + (_TOWER_TOP_HALF - _TOWER_BASE_HALF) * z / _TOWER_HEIGHT

    def corners(z: float) -> list[list[float]]:
        h = half(z)
        return [[h, h, z], [-h, h, z], [-h, -h, z], [h, -h, z]]

    segs: list[tuple[list[float], list[float]]] = []
    z = 0.0
    while z < _TOWER_HEIGHT:
        z1 = min(z + _TOWER_PANEL, _TOWER_HEIGHT)
        lo, hi = corners(z), corners(z1)
        for k in range(4):
            n = (k + 1) % 4
            segs += [(lo[k], hi[k]), (hi[k], hi[n]), (lo[k], hi[n]), (lo[n], hi[k])]
        z = z1
    for za, reach in _TOWER_ARMS:
        h = half(za)
        for side in (-1.0, 1.0):
            tip = [side * reach, 0.0, za]
            for y in (-h, h):
                segs += [([side * h, y, za], tip), ([side * h, y, za + 2.0], tip),
                         ([side * h, y, za], [side * (h + reach) / 2.0, 0.0, za + 1.0])]
    top = _TOWER_HEIGHT + 3.0
    segs += [([_TOWER_TOP_HALF, _TOWER_TOP_HALF, _TOWER_HEIGHT], [0.0, 0.0, top]),
             ([-_TOWER_TOP_HALF, -_TOWER_TOP_HALF, _TOWER_HEIGHT], [0.0, 0.0, top])]
    return np.asarray(segs, dtype=np.float64)


def tower_cloud(n_points: int, *, seed: int = 0) -> NDArray[np.float64]:
    """``n_points`` (N,3) float64: a lattice tower and its conductors, about 60 m long.

    A 48 m tower (body tapering from 10 m to 2 m square, X-braced panels of 3 m,
    three pairs of cross-arms) sampled uniformly along its members; 25 % of the
    points on six conductors hanging 3 m below the arm tips with a 2 m parabolic
    sag over +-30 m along y; 2 % uniform stray returns; +-2 cm jitter on each axis.
    Most grid cells of side eps/sqrt(3) at eps 0.3 m hold fewer than 5 points (median 1
    at 10k points, 3 at 65k): the sparse tower-scale
    DBSCAN workload (issue 23; fusion_core's ``benches/tower.rs`` is the same
    recipe, with a different random generator).
    """
    if n_points < 0:
        raise ValueError(f"need n_points >= 0, got {n_points}")
    rng = np.random.default_rng(seed)
    segs = _tower_segments()
    length = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1)
    n_stray = int(n_points * _STRAY_SHARE)
    n_wire = int(n_points * _WIRE_SHARE)
    n_lattice = n_points - n_stray - n_wire
    k = rng.choice(len(segs), size=n_lattice, p=length / length.sum())
    t = rng.uniform(0.0, 1.0, size=(n_lattice, 1))
    lattice = segs[k, 0] + t * (segs[k, 1] - segs[k, 0])
    arms = np.asarray(_TOWER_ARMS)[rng.integers(0, len(_TOWER_ARMS), size=n_wire)]
    side = rng.choice([-1.0, 1.0], size=n_wire)
    y = rng.uniform(-_SPAN_HALF, _SPAN_HALF, size=n_wire)
    wire = np.column_stack([side * arms[:, 1], y, arms[:, 0] - 3.0 - _SAG * (y / _SPAN_HALF) ** 2])
    body = np.concatenate([lattice, wire])
    body += rng.uniform(-_TOWER_JITTER, _TOWER_JITTER, size=body.shape)
    stray = np.column_stack([rng.uniform(-12.0, 12.0, n_stray), rng.uniform(-_SPAN_HALF, _SPAN_HALF, n_stray),
                             rng.uniform(0.0, _TOWER_HEIGHT, n_stray)])
    return np.concatenate([body, stray])


# --- geometry helpers ------------------------------------------------------------------


def _canonical(v: NDArray[np.float64]) -> NDArray[np.float64]:
    v = np.asarray(v, dtype=np.float64) / np.linalg.norm(v)
    return -v if v[np.argmax(np.abs(v))] < 0 else v


def _perpendicular_part(v: NDArray[np.float64], axis: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit component of ``v`` perpendicular to unit ``axis`` (zeros if parallel)."""
    p = v - (v @ axis) * axis
    norm = np.linalg.norm(p)
    return p / norm if norm > 1e-9 else np.zeros(3)


def _axis_for(
    orientation: Literal["horizontal", "vertical"] | ArrayLike, line_of_sight: NDArray[np.float64]
) -> NDArray[np.float64]:
    if isinstance(orientation, str):
        if orientation == "vertical":
            return np.array([0.0, 0.0, 1.0])
        if orientation == "horizontal":
            across = np.cross([0.0, 0.0, 1.0], line_of_sight)
            return across / np.linalg.norm(across)
        raise ValueError(f"orientation: expected 'horizontal', 'vertical' or a vector, got {orientation!r}")
    axis = np.asarray(orientation, dtype=np.float64).reshape(3)
    norm = np.linalg.norm(axis)
    if not np.isfinite(norm) or norm == 0.0:
        raise ValueError("orientation: axis vector must be finite and non-zero")
    axis = axis / norm
    if np.linalg.norm(np.cross(axis, line_of_sight)) < 1e-3:
        raise ValueError("orientation: axis along the line of sight shows no length")
    return axis


def _insulator_surface(
    rng: np.random.Generator,
    center: NDArray[np.float64],
    axis: NDArray[np.float64],
    toward: NDArray[np.float64],
    side: NDArray[np.float64],
    length: float,
    radius: float,
    n: int,
) -> NDArray[np.float64]:
    """``n`` points on the sensor-facing half of a shedded rod."""
    t = rng.uniform(-0.5 * length, 0.5 * length, size=n)
    on_shed = np.mod(t, _SHED_PITCH) < _SHED_WIDTH
    r = np.where(on_shed, radius, _CORE_RADIUS_FRACTION * radius)
    # Visible half: angle from `toward` within +-90 deg, denser where it faces the ray.
    phi = np.arcsin(rng.uniform(-1.0, 1.0, size=n))
    radial = np.outer(np.cos(phi), toward) + np.outer(np.sin(phi), side)
    return center + np.outer(t, axis) + r[:, None] * radial


def _tower_members(
    rng: np.random.Generator,
    anchor: NDArray[np.float64],
    axis: NDArray[np.float64],
    toward: NDArray[np.float64],
    n: int,
) -> NDArray[np.float64]:
    """Two angle members meeting at ``anchor``: one across the axis, one diagonal."""
    across = np.cross(axis, toward)
    away = (across - axis) / np.sqrt(2.0)  # leaves the anchor away from the insulator
    half = n // 2
    first = _rod(rng, anchor - 0.5 * _MEMBER_LENGTH * across, across, _MEMBER_LENGTH, _MEMBER_HALF_WIDTH, half)
    second = _rod(rng, anchor, away, _MEMBER_LENGTH, _MEMBER_HALF_WIDTH, n - half)
    return np.concatenate([first, second])


def _rod(
    rng: np.random.Generator,
    start: NDArray[np.float64],
    direction: NDArray[np.float64],
    length: float,
    radius: float,
    n: int,
) -> NDArray[np.float64]:
    """``n`` points scattered within ``radius`` of a segment from ``start`` along ``direction``."""
    direction = direction / np.linalg.norm(direction)
    t = rng.uniform(0.0, length, size=n)
    scatter = rng.normal(scale=radius, size=(n, 3))
    scatter -= np.outer(scatter @ direction, direction)
    return start + np.outer(t, direction) + scatter


def _add_range_noise(
    rng: np.random.Generator, points: NDArray[np.float64], sigma: float
) -> NDArray[np.float64]:
    """Gaussian noise of std ``sigma`` (m) along each point's ray from the sensor."""
    if sigma <= 0:
        return points
    ranges = np.linalg.norm(points, axis=1, keepdims=True)
    return points + rng.normal(scale=sigma, size=(len(points), 1)) * points / ranges
