"""A detector stand-in: ground-truth boxes with configurable jitter, misses and false positives.

Studies that must not depend on a trained network (the localization study of the
paper's Tables I and II) take the camera's ground-truth boxes and degrade them
the way a real detector would: each edge moves by Gaussian noise proportional to
the box size, a box is dropped with a miss probability, and a Poisson number of
false boxes appears per image. Everything is drawn from one seeded generator, so
a run is reproducible.

Boxes are pixel coordinates ``(x1, y1, x2, y2)`` with ``x1 < x2``, ``y1 < y2``
(x to the right, y down), the convention of ``ir.points_in_boxes``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from insulator_rs.ports.detector import DETECT_CONF

#: Id reported for a false-positive box (it matches no instance).
FALSE_POSITIVE_ID = -1
#: Smallest box side (px) the stand-in returns; a jittered box is widened to it.
MIN_BOX_SIDE_PX = 2.0


@dataclass(frozen=True)
class Detections:
    """The boxes of one image: ``boxes`` (K, 5) float64 ``x1, y1, x2, y2, score`` in pixels,
    ``instance_ids`` (K,) int64, the ground-truth instance each box came from
    (:data:`FALSE_POSITIVE_ID` for a false positive)."""

    boxes: np.ndarray
    instance_ids: np.ndarray

    def __len__(self) -> int:
        return int(self.boxes.shape[0])


class DetectorStandin:
    """Ground-truth boxes degraded like a detector's output.

    jitter: standard deviation of each box edge's displacement, as a fraction of
    the box width (x edges) or height (y edges). miss_rate: probability in [0, 1]
    that a true box is dropped. false_positives: mean number of false boxes per
    image (Poisson). fp_size: (min, max) side of a false box as a fraction of the
    image's smaller side. seed: seed of the generator (numpy PCG64).
    """

    def __init__(self, *, jitter: float = 0.05, miss_rate: float = 0.0,
                 false_positives: float = 0.0, fp_size: tuple[float, float] = (0.02, 0.15),
                 seed: int = 0) -> None:
        if not (isinstance(jitter, (int, float)) and math.isfinite(jitter) and jitter >= 0.0):
            raise ValueError(f"jitter: must be a finite number >= 0, got {jitter!r}")
        if not (isinstance(miss_rate, (int, float)) and 0.0 <= miss_rate <= 1.0):
            raise ValueError(f"miss_rate: must be within [0, 1], got {miss_rate!r}")
        if not (isinstance(false_positives, (int, float)) and math.isfinite(false_positives)
                and false_positives >= 0.0):
            raise ValueError(f"false_positives: must be a finite number >= 0, got {false_positives!r}")
        lo, hi = (float(v) for v in fp_size)
        if not (0.0 < lo <= hi <= 1.0):
            raise ValueError(f"fp_size: must satisfy 0 < min <= max <= 1, got {fp_size!r}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed: must be a non-negative integer, got {seed!r}")
        self.jitter = float(jitter)
        self.miss_rate = float(miss_rate)
        self.false_positives = float(false_positives)
        self.fp_size = (lo, hi)
        self.rng = np.random.default_rng(int(seed))

    def detect(self, gt_boxes: ArrayLike, image_size: tuple[int, int],
               instance_ids: ArrayLike | None = None) -> Detections:
        """Degrade the ground-truth boxes of one image.

        gt_boxes: (M, 4) pixel boxes ``x1, y1, x2, y2``. image_size: (width,
        height) in pixels; boxes are clipped to it. instance_ids: (M,) the
        instance of each box (default 0..M-1). Returns :class:`Detections`,
        true boxes first (in input order), then false positives.
        """
        boxes = np.asarray(gt_boxes, dtype=np.float64)
        if boxes.size == 0:
            boxes = boxes.reshape(0, 4)
        if boxes.ndim != 2 or boxes.shape[1] != 4:
            raise ValueError(f"gt_boxes: expected shape (M, 4), got {boxes.shape}")
        if not np.all(np.isfinite(boxes)):
            raise ValueError("gt_boxes: contains NaN or Inf")
        if np.any(boxes[:, 2] <= boxes[:, 0]) or np.any(boxes[:, 3] <= boxes[:, 1]):
            raise ValueError("gt_boxes: every box needs x2 > x1 and y2 > y1")
        try:
            width, height = (int(v) for v in image_size)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"image_size: expected (width, height), got {image_size!r}") from exc
        if width < 1 or height < 1:
            raise ValueError(f"image_size: width and height must be >= 1, got {image_size!r}")
        if instance_ids is None:
            ids = np.arange(len(boxes), dtype=np.int64)
        else:
            ids = np.asarray(instance_ids).astype(np.int64).reshape(-1)
            if ids.shape != (len(boxes),):
                raise ValueError(f"instance_ids: expected {len(boxes)} ids, got {ids.shape[0]}")

        keep = self.rng.random(len(boxes)) >= self.miss_rate
        kept, kept_ids = boxes[keep], ids[keep]
        size = np.column_stack([kept[:, 2] - kept[:, 0], kept[:, 3] - kept[:, 1]])
        noise = self.rng.normal(0.0, self.jitter, size=kept.shape) * np.tile(size, 2)
        jittered = self._clip(kept + noise, width, height)
        scores = self.rng.uniform(0.5, 0.95, size=len(jittered))

        n_fp = int(self.rng.poisson(self.false_positives))
        side = min(width, height) * self.rng.uniform(*self.fp_size, size=(n_fp, 2))
        x1 = self.rng.uniform(0.0, 1.0, n_fp) * np.maximum(width - side[:, 0], 0.0)
        y1 = self.rng.uniform(0.0, 1.0, n_fp) * np.maximum(height - side[:, 1], 0.0)
        fp = self._clip(np.column_stack([x1, y1, x1 + side[:, 0], y1 + side[:, 1]]), width, height)
        fp_scores = self.rng.uniform(DETECT_CONF, 0.6, size=n_fp)  # boxes the flight keeps

        out = np.vstack([np.column_stack([jittered, scores]), np.column_stack([fp, fp_scores])])
        out_ids = np.concatenate([kept_ids, np.full(n_fp, FALSE_POSITIVE_ID, np.int64)])
        return Detections(boxes=out.reshape(-1, 5), instance_ids=out_ids)

    @staticmethod
    def _clip(boxes: np.ndarray, width: int, height: int) -> np.ndarray:
        """Order the edges, clip to the image and keep every side >= MIN_BOX_SIDE_PX."""
        if len(boxes) == 0:
            return boxes.reshape(0, 4)
        x = np.sort(boxes[:, [0, 2]], axis=1)
        y = np.sort(boxes[:, [1, 3]], axis=1)
        side_x = min(MIN_BOX_SIDE_PX, float(width))
        side_y = min(MIN_BOX_SIDE_PX, float(height))
        x = np.clip(x, 0.0, float(width))
        y = np.clip(y, 0.0, float(height))
        # Widen a collapsed box around its centre, staying inside the image.
        for arr, side, limit in ((x, side_x, float(width)), (y, side_y, float(height))):
            short = arr[:, 1] - arr[:, 0] < side
            if np.any(short):
                c = np.clip(arr[short].mean(axis=1), side / 2, limit - side / 2)
                arr[short, 0] = c - side / 2
                arr[short, 1] = c + side / 2
        return np.column_stack([x[:, 0], y[:, 0], x[:, 1], y[:, 1]])
