"""The detector's edge: boxes and scores a model returns are checked before anyone uses them.

A network (or a corrupted/hostile model file) can return NaN or infinite
coordinates, inverted boxes (x2 < x1), boxes hanging off the image or outside
it, and scores that are NaN, infinite or outside [0, 1]. Downstream code
(``ir.points_in_boxes``, the registry) assumes finite boxes with positive area
inside the image. :func:`sanitize` enforces that, in pixels of the original
image, and counts every dropped box by reason.

Rules, in order (a box is counted under the first rule it breaks):
1. ``non_finite_box``: a coordinate is NaN or +-Inf.
2. ``bad_score``: the score is NaN, +-Inf or outside [0, 1].
3. ``inverted``: x2 < x1 or y2 < y1 (a decoder never emits these: a model bug).
4. clip to the image ([0, width] x [0, height]);
5. ``degenerate``: after clipping, width or height below ``MIN_SIDE_PX``
   (zero-area, a sliver at the edge, or wholly outside the image).
A box that breaks no rule and lies inside the image is returned unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_SIDE_PX = 1.0  # narrower than one pixel: no LiDAR point can be attributed to it


@dataclass(frozen=True)
class DroppedDetections:
    """How many detections the sanitiser dropped, by reason."""

    non_finite_box: int = 0
    bad_score: int = 0
    inverted: int = 0
    degenerate: int = 0

    @property
    def total(self) -> int:
        return self.non_finite_box + self.bad_score + self.inverted + self.degenerate

    def __add__(self, other: DroppedDetections) -> DroppedDetections:
        return DroppedDetections(self.non_finite_box + other.non_finite_box, self.bad_score + other.bad_score,
                                 self.inverted + other.inverted, self.degenerate + other.degenerate)

    def to_dict(self) -> dict[str, int]:
        return {"non_finite_box": self.non_finite_box, "bad_score": self.bad_score, "inverted": self.inverted,
                "degenerate": self.degenerate, "total": self.total}


def drop_invalid(boxes: np.ndarray, scores: np.ndarray) -> tuple[np.ndarray, DroppedDetections]:
    """Rules 1-3 (non-finite box, bad score, inverted): indices of the survivors and the counts.

    Independent of the image, so the detector applies it in network pixels,
    before NMS, where a NaN or +Inf could otherwise win or survive suppression.
    """
    boxes = np.asarray(boxes).reshape(-1, 4)
    scores = np.asarray(scores).reshape(-1)
    if scores.shape[0] != boxes.shape[0]:
        raise ValueError(f"scores: {scores.shape[0]} scores for {boxes.shape[0]} boxes")
    alive = np.ones(boxes.shape[0], dtype=bool)

    def drop(mask: np.ndarray) -> int:
        hit = alive & mask
        alive[hit] = False
        return int(hit.sum())

    with np.errstate(invalid="ignore"):
        non_finite = drop(~np.isfinite(boxes).all(axis=1))
        bad_score = drop(~(np.isfinite(scores) & (scores >= 0.0) & (scores <= 1.0)))
        inverted = drop((boxes[:, 2] < boxes[:, 0]) | (boxes[:, 3] < boxes[:, 1]))
    return np.flatnonzero(alive), DroppedDetections(non_finite, bad_score, inverted, 0)


def clip_to_image(boxes: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray, DroppedDetections]:
    """Rules 4-5 on finite, non-inverted boxes: (clipped float64 boxes kept, their indices, counts)."""
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    clipped = np.array(boxes, dtype=np.float64).reshape(-1, 4)
    clipped[:, [0, 2]] = np.clip(clipped[:, [0, 2]], 0.0, float(width))
    clipped[:, [1, 3]] = np.clip(clipped[:, [1, 3]], 0.0, float(height))
    too_small = ((clipped[:, 2] - clipped[:, 0]) < MIN_SIDE_PX) | ((clipped[:, 3] - clipped[:, 1]) < MIN_SIDE_PX)
    keep = np.flatnonzero(~too_small)
    return clipped[keep], keep, DroppedDetections(degenerate=int(too_small.sum()))


def sanitize(boxes: np.ndarray, scores: np.ndarray, width: int, height: int
             ) -> tuple[np.ndarray, np.ndarray, DroppedDetections]:
    """All five rules on one image's detections; returns (clipped boxes, kept indices, counts).

    ``boxes`` (N, 4) x1, y1, x2, y2 in pixels of a ``width`` x ``height`` image,
    ``scores`` (N,). The indices say which inputs survived, in input order, so
    callers can keep scores/classes aligned.
    """
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    valid, dropped = drop_invalid(boxes, scores)
    clipped, inside, small = clip_to_image(boxes[valid], width, height)
    return clipped, valid[inside], dropped + small
