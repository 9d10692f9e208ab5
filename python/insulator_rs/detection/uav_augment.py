"""Photometric augmentations of UAV imagery that Ultralytics lacks without albumentations.

Ultralytics already varies scale (``scale``, mosaic), HSV and flips. An
inspection drone's camera also sees motion/defocus blur (vibration, wind,
capture while moving), haze (distance, humidity) and sun flare (the sun near
the frame while circling a tower). :class:`UavPhotometric` adds the three with
a few numpy/OpenCV operations per image; boxes are untouched (no geometry
changes). :func:`attach` splices it into an Ultralytics dataset's pipeline just
before ``Format``, also after mosaic is closed (the pipeline is rebuilt then).

The random draws use :mod:`random`, which Ultralytics seeds per run.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np


@dataclass(frozen=True)
class UavPhotometric:
    """Blur, haze and sun flare, each applied with its own probability."""

    p_blur: float = 0.2
    p_haze: float = 0.15
    p_flare: float = 0.1

    def __call__(self, labels: dict[str, Any]) -> dict[str, Any]:
        img = labels["img"]
        if random.random() < self.p_blur:
            img = motion_or_defocus_blur(img)
        if random.random() < self.p_haze:
            img = haze(img, airlight=random.uniform(170, 245), density=random.uniform(0.1, 0.45))
        if random.random() < self.p_flare:
            h, w = img.shape[:2]
            img = sun_flare(img, centre=(random.uniform(0, w), random.uniform(0, h)),
                            radius=random.uniform(0.08, 0.35) * max(h, w), strength=random.uniform(80, 220))
        labels["img"] = img
        return labels


def motion_or_defocus_blur(img: np.ndarray) -> np.ndarray:
    """A straight motion streak (3-9 px, any direction) or a Gaussian defocus (sigma 0.6-2 px)."""
    if random.random() < 0.5:
        length = random.randrange(3, 10, 2)
        kernel: np.ndarray = np.zeros((length, length), np.float32)
        kernel[length // 2, :] = 1.0
        rot = cv2.getRotationMatrix2D(((length - 1) / 2, (length - 1) / 2), random.uniform(0, 180), 1.0)
        kernel = cv2.warpAffine(kernel, rot, (length, length))
        total = kernel.sum()
        if total <= 0:
            return img
        return cv2.filter2D(img, -1, kernel / total)
    return cv2.GaussianBlur(img, (0, 0), random.uniform(0.6, 2.0))


def haze(img: np.ndarray, *, airlight: float, density: float) -> np.ndarray:
    """Koschmieder's model with one transmission: I = J (1 - d) + A d."""
    out = img.astype(np.float32) * (1.0 - density) + airlight * density
    return np.clip(out, 0, 255).astype(np.uint8)


def sun_flare(img: np.ndarray, *, centre: tuple[float, float], radius: float, strength: float) -> np.ndarray:
    """A warm Gaussian glow added around ``centre`` (pixels), saturating at white."""
    h, w = img.shape[:2]
    ys, xs = np.ogrid[:h, :w]
    glow = np.exp(-((xs - centre[0]) ** 2 + (ys - centre[1]) ** 2) / (2.0 * radius**2)).astype(np.float32)
    tint = np.array([0.85, 0.95, 1.0], np.float32)  # BGR: slightly warm
    out = img.astype(np.float32) + strength * glow[..., None] * tint
    return np.clip(out, 0, 255).astype(np.uint8)


def attach(dataset: Any, augment: UavPhotometric) -> None:
    """Insert ``augment`` before the last transform (``Format``) of an Ultralytics dataset, now and on rebuilds."""
    original = dataset.build_transforms

    def build_transforms(hyp: Any = None) -> Any:
        transforms = original(hyp)
        transforms.insert(len(transforms.transforms) - 1, augment)
        return transforms

    dataset.build_transforms = build_transforms
    dataset.transforms.insert(len(dataset.transforms.transforms) - 1, augment)


def uav_trainer_class() -> type:
    """Ultralytics' DetectionTrainer with :class:`UavPhotometric` on the training set."""
    from ultralytics.models.yolo.detect import DetectionTrainer

    class UavDetectionTrainer(DetectionTrainer):  # type: ignore[misc]  # ultralytics is untyped
        def build_dataset(self, img_path: str, mode: str = "train", batch: int | None = None) -> Any:
            dataset = super().build_dataset(img_path, mode, batch)
            if mode == "train" and getattr(dataset, "augment", False):
                attach(dataset, UavPhotometric())
            return dataset

    return UavDetectionTrainer
