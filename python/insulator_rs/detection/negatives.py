"""Hard negatives from labelled photos: tiles of a photo that hold no insulator, and the boxes a
detector still draws on them (issue 22: "a false-positive rate per negative frame is reported
beside the mAP").

The simulation model has rendered views of tower steel for this (``sim/steel_views.py``). A
real-photo model's negatives are the rest of its own photos: the tower body, cross-arms,
conductors, fittings, sky and ground round the strings. :func:`negative_tiles` cuts each photo
into square tiles (side ``TILE_FRACTION`` of its shorter side, overlapping by half) and keeps the
tiles that no labelled box comes within ``MARGIN_PX`` of; each kept tile is one negative frame,
letterboxed by the detector as any image. Every box on it at or above a threshold is a false box.

Caveat: an insulator the annotators left unlabelled counts as a false box here, so the rate is an
upper bound; :func:`count_negative_false_boxes` keeps each false box's tile and place so that a
reader can look.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from insulator_rs.detection.evaluate import LabelledImage

# a tile's side, as a share of the photo's shorter side (432 px of a 1152x864 field photo)
TILE_FRACTION = 0.5
# px: a tile this close to a labelled box is not a negative (a box's edge is not exact)
MARGIN_PX = 16


@dataclass(frozen=True)
class NegativeTile:
    """A tile of ``image`` (x0, y0, side px) that no labelled box comes near."""

    image: Path
    x0: int
    y0: int
    side: int


def negative_tiles(samples: Iterable[LabelledImage], tile_fraction: float = TILE_FRACTION,
                   margin: int = MARGIN_PX) -> list[NegativeTile]:
    """The tiles of each labelled image (a grid at half a tile's stride, the last row and column
    flush with the edges) that keep ``margin`` px away from every labelled box."""
    if not 0.05 <= tile_fraction <= 1.0:
        raise ValueError(f"tile_fraction: must be in [0.05, 1], got {tile_fraction!r}")
    out = []
    for s in samples:
        img = cv2.imread(str(s.image), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"image: cannot decode {s.image}")
        h, w = img.shape[:2]
        side = max(1, int(round(tile_fraction * min(h, w))))
        stride = max(1, side // 2)
        xs = sorted(set(list(range(0, w - side + 1, stride)) + [w - side]))
        ys = sorted(set(list(range(0, h - side + 1, stride)) + [h - side]))
        boxes = np.asarray(s.boxes, dtype=np.float64).reshape(-1, 4)
        for y0 in ys:
            for x0 in xs:
                near = ((boxes[:, 0] < x0 + side + margin) & (boxes[:, 2] > x0 - margin)
                        & (boxes[:, 1] < y0 + side + margin) & (boxes[:, 3] > y0 - margin))
                if not np.any(near):
                    out.append(NegativeTile(s.image, x0, y0, side))
    return out


@dataclass
class NegativeCount:
    """False boxes on negative tiles, per score threshold, and where they were."""

    tiles: int
    photos: int
    thresholds: tuple[float, ...]
    false_boxes: dict[float, int] = field(default_factory=dict)
    tiles_with_false_box: dict[float, int] = field(default_factory=dict)
    # (image name, x0, y0, side, score, box in the tile) of each false box at the lowest threshold
    where: list[tuple[str, int, int, int, float, list[float]]] = field(default_factory=list)

    def to_dict(self) -> dict[str, object]:
        rates = {}
        for t in self.thresholds:
            rates[f"score>={t:g}"] = {
                "false_boxes": self.false_boxes[t],
                "false_boxes_per_tile": self.false_boxes[t] / max(self.tiles, 1),
                "tiles_with_a_false_box": self.tiles_with_false_box[t],
                "share_of_tiles": self.tiles_with_false_box[t] / max(self.tiles, 1),
            }
        return {"negative_tiles": self.tiles, "photos": self.photos, **rates,
                "false_boxes_at_lowest_threshold": [
                    {"image": n, "tile_xy": [x, y], "tile_side": side, "score": sc, "box_in_tile": b}
                    for n, x, y, side, sc, b in self.where]}


def count_negative_false_boxes(detect: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                               tiles: Sequence[NegativeTile], thresholds: Sequence[float] = (0.25, 0.5),
                               progress: Callable[[int, int], None] | None = None) -> NegativeCount:
    """``detect(image) -> (boxes, scores)`` on each tile: every box is a false one."""
    ths = tuple(sorted(set(float(t) for t in thresholds)))
    if not ths:
        raise ValueError("thresholds: give at least one score threshold")
    count = NegativeCount(tiles=len(tiles), photos=len({t.image for t in tiles}), thresholds=ths,
                          false_boxes={t: 0 for t in ths}, tiles_with_false_box={t: 0 for t in ths})
    cache: dict[Path, np.ndarray] = {}
    for i, tile in enumerate(tiles, 1):
        img = cache.get(tile.image)
        if img is None:
            cache.clear()  # tiles come photo by photo: keep one decoded photo
            img = cv2.imread(str(tile.image), cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"image: cannot decode {tile.image}")
            cache[tile.image] = img
        crop = np.ascontiguousarray(img[tile.y0:tile.y0 + tile.side, tile.x0:tile.x0 + tile.side])
        boxes, scores = detect(crop)
        scores = np.asarray(scores, dtype=np.float64).ravel()
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        for t in ths:
            n = int(np.sum(scores >= t))
            count.false_boxes[t] += n
            count.tiles_with_false_box[t] += int(n > 0)
        for b, sc in zip(boxes, scores):
            if sc >= ths[0]:
                count.where.append((tile.image.name, tile.x0, tile.y0, tile.side, float(sc),
                                    [round(float(v), 1) for v in b]))
        if progress is not None:
            progress(i, len(tiles))
    return count
