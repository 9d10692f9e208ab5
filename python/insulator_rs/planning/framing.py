"""Inspection shots framed from what was measured: how much of a localized string one photo of
the inspection camera holds, the tiles a long string needs, and the zoom at a distance.

Issue 20's rule: the string fills 60-85 % of the frame's long side at <= 2 mm/px. The camera
is held level by its gimbal and the viewpoints look at the string square-on (they lie in the
plane perpendicular to its axis), so the string's horizontal part runs along the image's x axis
and its vertical part along y: a hanging (vertical) string can use only the frame's height
(75 % of the long side on a 4:3 sensor). The planned pixel span is :data:`TARGET_FILL` of the
long side, capped at :data:`EDGE_FILL` of the frame's extent along the string, which leaves
room for the localization's error (a 5 cm error in the centre moves the string 90 px at 0.56
mm/px). The GSD of a frame that holds a piece ``l`` m long over ``s`` px is ``l / s`` whatever
the distance, so the fill fixes the GSD and a string whose GSD would exceed the limit is cut
into overlapping tiles; the distance is the closest safe one (least zoom: a pointing error
moves the image least), and the zoom (focal length) follows from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from insulator_rs.inspection_camera import InspectionCamera
from insulator_rs.perception.photo_quality import MAX_GSD_MM

#: The band of the frame's long side the string must fill (issue 20).
MIN_FILL = 0.60
MAX_FILL = 0.85
#: The planned fill of the long side: inside the band with room either way for the error of
#: the localized centre and length.
TARGET_FILL = 0.72
#: At most this share of the frame's extent along the string: the rest is margin at the ends.
EDGE_FILL = 0.90
#: The planned GSD stays this far under the limit (a safety volume may push a viewpoint out).
GSD_MARGIN = 0.9
#: Share of a tile's piece of the string that the next tile sees too.
TILE_OVERLAP = 0.15
#: More tiles than this for one string: the camera cannot inspect it (a planning error).
MAX_TILES = 12


@dataclass(frozen=True)
class Tile:
    """One shot's piece of a string: ``target`` (W, its middle, where the gimbal aims),
    ``offset`` (m along the axis from the string's centre), ``length`` (m of string framed)."""

    target: np.ndarray
    offset: float
    length: float


@dataclass(frozen=True)
class StringFraming:
    """How a string is shot: ``tiles`` (one, or overlapping pieces end to end), ``span_px`` (the
    planned pixel length of each tile's piece), ``gsd_mm`` (planned, mm/px: piece / span)."""

    tiles: tuple[Tile, ...]
    span_px: float
    gsd_mm: float

    def focal_px(self, camera: InspectionCamera, distance: float) -> float:
        """The focal length (px) that makes a tile's piece span ``span_px`` from ``distance`` m,
        within the zoom range (at the ends of the range the fill is what the lens gives)."""
        return camera.clamp_focal(self.span_px * distance / self.tiles[0].length)

    def distance(self, camera: InspectionCamera, min_distance: float) -> float:
        """The viewing distance (m): ``min_distance`` (the mission's safe inspection distance),
        farther only when even the widest zoom would frame the piece too tightly there."""
        return max(min_distance, camera.focal_px[0] * self.tiles[0].length / self.span_px)


def extent_along(axis: np.ndarray, width: int, height: int) -> float:
    """Pixels the frame spans through its centre along the image direction of a string with unit
    ``axis`` (W) seen square-on by a level camera (horizontal part along x, vertical along y)."""
    u = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    a, b = math.sqrt(max(0.0, 1.0 - float(u[2]) ** 2)), abs(float(u[2]))
    return min(width / a if a > 1e-12 else math.inf, height / b if b > 1e-12 else math.inf)


def frame_string(center: np.ndarray, axis: np.ndarray, length: float, camera: InspectionCamera, *,
                 max_gsd_mm: float = MAX_GSD_MM) -> StringFraming:
    """The shots of the string ``length`` m at ``center`` along ``axis`` (W) for ``camera`` (module
    docstring): the fewest overlapping tiles whose GSD is within ``GSD_MARGIN * max_gsd_mm``.
    Raises ValueError on a bad argument, or when even :data:`MAX_TILES` tiles would not do."""
    c = np.asarray(center, dtype=np.float64).reshape(3)
    u = np.asarray(axis, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(u))) or np.linalg.norm(u) < 1e-9:
        raise ValueError("center/axis: must be finite and the axis non-zero")
    if not (math.isfinite(length) and length > 0):
        raise ValueError(f"length: must be finite and > 0, got {length}")
    if not (math.isfinite(max_gsd_mm) and max_gsd_mm > 0):
        raise ValueError(f"max_gsd_mm: must be finite and > 0, got {max_gsd_mm}")
    u = u / np.linalg.norm(u)
    cam = camera.camera
    span = min(TARGET_FILL * max(cam.width, cam.height), EDGE_FILL * extent_along(u, cam.width, cam.height))
    limit_m = GSD_MARGIN * max_gsd_mm * 1e-3
    for n in range(1, MAX_TILES + 1):
        # n pieces of l m, each overlapping the next by TILE_OVERLAP * l: l (1 + (n - 1)(1 - ov)) = L
        piece = length / (1.0 + (n - 1) * (1.0 - TILE_OVERLAP))
        if piece / span <= limit_m:
            break
    else:
        raise ValueError(f"length: a {length:.2f} m string needs more than {MAX_TILES} tiles at "
                         f"{max_gsd_mm:g} mm/px with this camera")
    step = piece * (1.0 - TILE_OVERLAP)
    offsets = [(k - (n - 1) / 2) * step for k in range(n)]
    tiles = tuple(Tile(c + o * u, float(o), float(piece)) for o in offsets)
    return StringFraming(tiles, float(span), 1000.0 * piece / span)
