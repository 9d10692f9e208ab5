"""GPS to the world frame W and the tower's line frame.

W is local ENU (x east, y north, z up) with its origin at the inspected tower's
base; the conversion is pymap3d's (WGS-84), never hand-written. The *line
frame* of the tower is W rotated about z so that its first axis runs along the
power line (from the neighbour towers) and its second axis points to the
tower's "+" side; the two sides of the tower are the half-spaces on either side
of the vertical plane that contains the line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pymap3d

# Below this horizontal distance (m) a neighbour gives no usable line direction.
MIN_NEIGHBOUR_DISTANCE = 1.0


@dataclass(frozen=True)
class GeoPoint:
    """A WGS-84 position: latitude and longitude in degrees, altitude in metres (ellipsoidal)."""

    lat: float
    lon: float
    alt: float = 0.0


def gps_to_enu(points: GeoPoint | list[GeoPoint], origin: GeoPoint) -> np.ndarray:
    """ENU coordinates (m) of ``points`` relative to ``origin``: (3,) for one point, (N, 3) for a list."""
    single = isinstance(points, GeoPoint)
    pts: list[GeoPoint] = [points] if isinstance(points, GeoPoint) else list(points)
    out = np.array(
        [pymap3d.geodetic2enu(p.lat, p.lon, p.alt, origin.lat, origin.lon, origin.alt) for p in pts],
        dtype=np.float64,
    ).reshape(len(pts), 3)
    return out[0] if single else out


def enu_to_gps(enu: np.ndarray, origin: GeoPoint) -> GeoPoint:
    """The WGS-84 position of an ENU point (m) relative to ``origin`` (the inverse of :func:`gps_to_enu`)."""
    e, n, u = (float(c) for c in np.asarray(enu, dtype=np.float64).reshape(3))
    lat, lon, alt = pymap3d.enu2geodetic(e, n, u, origin.lat, origin.lon, origin.alt)
    return GeoPoint(float(lat), float(lon), float(alt))


def enu_to_geodetic(enu: np.ndarray, origin: GeoPoint) -> np.ndarray:
    """WGS-84 (lat deg, lon deg, alt m) of ENU points (N, 3) relative to ``origin``: (N, 3), vectorised
    (the array form of :func:`enu_to_gps`, for flown paths of thousands of samples)."""
    p = np.asarray(enu, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros((0, 3))
    lat, lon, alt = pymap3d.enu2geodetic(p[:, 0], p[:, 1], p[:, 2], origin.lat, origin.lon, origin.alt)
    return np.stack([np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64),
                     np.asarray(alt, dtype=np.float64)], axis=-1).reshape(-1, 3)


@dataclass(frozen=True)
class LineFrame:
    """The tower's line frame in W.

    ``along`` is the horizontal unit vector of the power line, ``lateral`` the
    horizontal unit vector perpendicular to it (``lateral = along x z``, to the
    right looking along the line, as in the simulator's scenes), which points to
    the tower's "+" side. ``neighbours`` holds the neighbour towers'
    base positions in W (m).
    """

    along: np.ndarray
    lateral: np.ndarray
    neighbours: np.ndarray

    def to_line(self, points_w: np.ndarray) -> np.ndarray:
        """Coordinates (a, l, z) in the line frame of W points (..., 3)."""
        p = np.asarray(points_w, dtype=np.float64)
        return np.stack([p @ self.along, p @ self.lateral, p[..., 2]], axis=-1)

    def to_world(self, points_line: np.ndarray) -> np.ndarray:
        """W coordinates of line-frame points (..., 3) given as (along, lateral, z)."""
        q = np.asarray(points_line, dtype=np.float64)
        return (q[..., :1] * self.along + q[..., 1:2] * self.lateral
                + q[..., 2:3] * np.array([0.0, 0.0, 1.0]))

    def side(self, point_w: np.ndarray) -> int:
        """The side (+1 or -1) of a W point (3,); a point on the line plane counts as +1."""
        lat = float(np.asarray(point_w, dtype=np.float64).reshape(3)[:2] @ self.lateral[:2])
        return 1 if lat >= 0.0 else -1


def line_frame(neighbours_enu: np.ndarray) -> LineFrame:
    """The line frame from the neighbour towers' ENU positions (m), tower at the origin.

    With two neighbours the line runs from the first to the second (the chord
    through both, which is the conductors' mean direction at the tower); with
    one it runs from the tower towards it.
    """
    nb = np.asarray(neighbours_enu, dtype=np.float64).reshape(-1, 3)
    if nb.shape[0] not in (1, 2):
        raise ValueError(f"neighbours_enu: expected 1 or 2 neighbour towers, got {nb.shape[0]}")
    if not np.all(np.isfinite(nb)):
        raise ValueError("neighbours_enu: positions must be finite")
    for i, p in enumerate(nb):
        if np.hypot(p[0], p[1]) < MIN_NEIGHBOUR_DISTANCE:
            raise ValueError(f"neighbours_enu[{i}]: neighbour tower is within "
                             f"{MIN_NEIGHBOUR_DISTANCE} m of the inspected tower")
    d = nb[1, :2] - nb[0, :2] if nb.shape[0] == 2 else nb[0, :2]
    if np.hypot(*d) < MIN_NEIGHBOUR_DISTANCE:
        raise ValueError("neighbours_enu: the two neighbour towers coincide")
    along = np.array([d[0], d[1], 0.0]) / np.hypot(*d)
    lateral = np.array([along[1], -along[0], 0.0])
    return LineFrame(along=along, lateral=lateral, neighbours=nb)
