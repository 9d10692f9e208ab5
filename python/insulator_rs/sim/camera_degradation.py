"""A degraded detection camera, as decorators round the flight loop's detector port.

The degraded-camera study (:mod:`insulator_rs.evaluation.degraded_camera_study`) flies the shipped
network on frames a real crew meets in fog, in back light or through a dirty lens, and a network
that misses most of what it should box. Each degradation wraps the real detector (the loop flies
as it would against a camera or a network that failed that way), never a hook inside the loop:

* :class:`HazedFrames`: every detection frame goes through the atmospheric scattering model
  (Koschmieder: ``I' = t I + (1 - t) A``, transmission ``t = 1 - haze``, air light ``A``) and then
  a contrast stretch about the frame's mean (``I'' = m + contrast (I' - m)``) before the network
  sees it. The frame's RMS contrast (the pixel standard deviation) falls by ``(1 - haze) *
  contrast``, before rounding and clipping to 8 bits.
* :class:`DroppedTrueBoxes`: each box the inner detector gives that lies on a true insulator (its
  centre inside the simulator's true box of the frame, grown by :data:`TRUE_BOX_SLACK_PX`) is dropped with
  probability ``fraction``, independently per box and frame, from a seeded generator. Boxes on
  anything else pass: the network's false positives stay what they were.

Only the detection frames are degraded: the inspection photos come from the gimballed zoom camera
and are checked by a detector of their own.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from insulator_rs.ports.detector import BoxDetector, detector_name

#: px: a box whose centre lies inside a true insulator's box grown by this much is a box on that
#: insulator (a "true box"). Not an IoU: on the detection frame a string is a few pixels wide, and
#: the network's boxes on it, one or two pixels off sideways, fall under mAP50's IoU of 0.5
TRUE_BOX_SLACK_PX = 2.0
#: the air light of the haze (8-bit grey level): fog's bright, nearly white veil
AIR_LIGHT = 220.0

#: (frame) -> the true insulator boxes of that frame {instance id: (x1, y1, x2, y2) px}
TruthOf = Callable[[np.ndarray], dict[int, tuple[float, float, float, float]]]


def _fraction(value: float, name: str, *, upper_open: bool = False) -> float:
    if not (math.isfinite(value) and 0.0 <= value and (value < 1.0 if upper_open else value <= 1.0)):
        interval = "[0, 1)" if upper_open else "[0, 1]"
        raise ValueError(f"{name}: a fraction in {interval} is needed, got {value}")
    return float(value)


def haze_frame(image: np.ndarray, *, haze: float, contrast: float, air_light: float = AIR_LIGHT) -> np.ndarray:
    """``image`` (H, W, 3) uint8 seen through haze ``haze`` (the share of the scene's light lost to
    scattering, in [0, 1)) and with its contrast scaled by ``contrast`` (in (0, 1]) about its mean:
    a new uint8 frame (module docstring)."""
    haze = _fraction(haze, "haze", upper_open=True)
    if not (math.isfinite(contrast) and 0.0 < contrast <= 1.0):
        raise ValueError(f"contrast: a factor in (0, 1] is needed, got {contrast}")
    if not (math.isfinite(air_light) and 0.0 <= air_light <= 255.0):
        raise ValueError(f"air_light: an 8-bit grey level in [0, 255] is needed, got {air_light}")
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3:
        raise ValueError(f"image: an (H, W, C) uint8 frame is needed, got {img.dtype} of shape {img.shape}")
    hazed = (1.0 - haze) * img.astype(np.float32) + haze * np.float32(air_light)
    mean = hazed.mean(dtype=np.float64)
    flat = np.float32(mean) + np.float32(contrast) * (hazed - np.float32(mean))
    return np.clip(np.rint(flat), 0, 255).astype(np.uint8)


class HazedFrames:
    """The ``BoxDetector`` port whose frames are hazed and flattened (:func:`haze_frame`) before
    ``inner`` (the network) sees them."""

    def __init__(self, inner: BoxDetector, *, haze: float, contrast: float, air_light: float = AIR_LIGHT) -> None:
        haze_frame(np.zeros((1, 1, 3), np.uint8), haze=haze, contrast=contrast, air_light=air_light)  # refuse now
        self.inner = inner
        self.haze, self.contrast, self.air_light = float(haze), float(contrast), float(air_light)
        self.name = f"{detector_name(inner)} on hazed frames (haze {haze:g}, contrast x{contrast:g})"

    def __call__(self, image: np.ndarray) -> np.ndarray:
        return self.inner(haze_frame(image, haze=self.haze, contrast=self.contrast, air_light=self.air_light))

    def __getattr__(self, name: str) -> Any:  # the sanitiser's counts of a network
        return getattr(self.inner, name)


def on_true_boxes(boxes: np.ndarray, truth: list[tuple[float, float, float, float]]) -> np.ndarray:
    """(M,) bool: which of ``boxes`` (M, 4+) px lie on one of the ``truth`` boxes (their centre
    inside one, grown by TRUE_BOX_SLACK_PX)."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, np.asarray(boxes).shape[-1] if len(boxes) else 4)
    if not len(b) or not truth:
        return np.zeros(len(b), dtype=bool)
    t = np.asarray(truth, dtype=np.float64).reshape(-1, 4)
    cx, cy = (b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2
    s = TRUE_BOX_SLACK_PX
    inside = ((cx[:, None] >= t[None, :, 0] - s) & (cx[:, None] <= t[None, :, 2] + s)
              & (cy[:, None] >= t[None, :, 1] - s) & (cy[:, None] <= t[None, :, 3] + s))
    return np.asarray(inside.any(axis=1))


class DroppedTrueBoxes:
    """The ``BoxDetector`` port dropping each of ``inner``'s boxes on a true insulator (``truth`` of
    the frame: :func:`on_true_boxes`) with probability ``fraction``, seeded by ``seed``. ``counts``:
    the true boxes seen and dropped, and the other boxes passed."""

    def __init__(self, inner: BoxDetector, truth: TruthOf, *, fraction: float, seed: int) -> None:
        self.inner = inner
        self.truth = truth
        self.fraction = _fraction(fraction, "fraction")
        self.rng = np.random.default_rng(seed)
        self.name = f"{detector_name(inner)}, {100 * self.fraction:g} % of true boxes dropped (seed {seed})"
        self.counts = {"true_boxes": 0, "dropped": 0, "other_boxes": 0}

    def __call__(self, image: np.ndarray) -> np.ndarray:
        truth = list(self.truth(image).values())  # this very frame's truth: ask before the inner sees it
        boxes = np.asarray(self.inner(image))
        if not len(boxes):
            return boxes
        on_truth = on_true_boxes(boxes, truth)
        # one draw per box, true or not, so the drops of a frame do not hang on the other boxes' kinds
        drop = (self.rng.random(len(boxes)) < self.fraction) & on_truth
        self.counts["true_boxes"] += int(on_truth.sum())
        self.counts["dropped"] += int(drop.sum())
        self.counts["other_boxes"] += int((~on_truth).sum())
        return boxes[~drop]

    def __getattr__(self, name: str) -> Any:  # the sanitiser's counts of a network
        return getattr(self.inner, name)
