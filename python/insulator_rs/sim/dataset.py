"""Rendered training data for the insulator detector, in the YOLO (Ultralytics) layout.

:func:`write_dataset` renders images of a tower scene from varied viewpoints
(around both sides of the tower, at varied distance and height, looking at a
random part of it) under varied lighting (time of day, haze, sensor noise), and
writes::

    out/images/{train,val,test}/NNNNNN.png
    out/labels/{train,val,test}/NNNNNN.txt   one "0 cx cy w h" line per insulator (normalised)
    out/data.yaml                            path, splits, names {0: insulator}

Ground-truth boxes come from the visible pixels of each insulator in the
rendered instance-id image, so occluded parts do not count; boxes with fewer
than ``min_visible_pixels`` pixels are left out. Everything is drawn from one
seeded generator.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SPLITS: tuple[str, ...] = ("train", "val", "test")
CLASS_NAMES: dict[int, str] = {0: "insulator"}


@dataclass(frozen=True)
class ViewSampling:
    """Where the dataset's camera goes (m, degrees), relative to the tower at the origin of W.

    distance: (min, max) horizontal distance of the camera from the tower axis.
    height: (min, max) camera height above ground. aim_jitter_deg: random
    offset of the viewing direction from the aimed tower point.
    """

    distance: tuple[float, float] = (7.0, 30.0)
    height: tuple[float, float] = (5.0, 32.0)
    aim_jitter_deg: float = 12.0


@dataclass(frozen=True)
class LightingSample:
    """One draw of the lighting and weather: sun elevation/azimuth (deg), haze (1/m), noise (8-bit
    counts), overcast (0 sunny .. 1 overcast: dimmer sun, brighter grey sky)."""

    sun_elevation_deg: float
    sun_azimuth_deg: float
    haze_density: float
    noise_sigma: float
    overcast: float


def sample_lighting(rng: np.random.Generator) -> LightingSample:
    """Time of day (sun from 8 to 70 degrees up, any azimuth), clear to hazy, sunny to overcast."""
    return LightingSample(
        sun_elevation_deg=float(rng.uniform(8.0, 70.0)),
        sun_azimuth_deg=float(rng.uniform(0.0, 360.0)),
        haze_density=float(rng.choice([0.0, rng.uniform(0.0, 0.004), rng.uniform(0.004, 0.02)])),
        noise_sigma=float(rng.uniform(0.5, 4.0)),
        overcast=float(rng.choice([0.0, rng.uniform(0.0, 1.0)])),
    )


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """4x4 T_w_c of a camera at ``eye`` (W) whose optical axis (C: z forward, x right, y down)
    points at ``target``, with the image's 'up' toward W's +z."""
    z = np.asarray(target, dtype=np.float64) - np.asarray(eye, dtype=np.float64)
    n = np.linalg.norm(z)
    if n == 0.0:
        raise ValueError("target: must differ from eye")
    z /= n
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight up or down
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = eye
    return T


def sample_view(rng: np.random.Generator, aim_points: np.ndarray, sampling: ViewSampling) -> np.ndarray:
    """A random T_w_c looking at (near) one of ``aim_points`` (K, 3) from around the tower."""
    target = aim_points[int(rng.integers(len(aim_points)))]
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    dist = rng.uniform(*sampling.distance)
    eye = np.array([dist * math.cos(azimuth), dist * math.sin(azimuth), rng.uniform(*sampling.height)])
    T = look_at(eye, target)
    # Jitter the viewing direction: small rotations about the camera's x and y axes.
    ax, ay = np.radians(rng.uniform(-sampling.aim_jitter_deg, sampling.aim_jitter_deg, 2))
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    T[:3, :3] = T[:3, :3] @ rx @ ry
    return T


def yolo_lines(boxes: np.ndarray, width: int, height: int, class_id: int = 0) -> list[str]:
    """YOLO label lines ``class cx cy w h`` (normalised to [0, 1]) for pixel boxes (M, 4) x1 y1 x2 y2."""
    if width < 1 or height < 1:
        raise ValueError(f"width/height: must be >= 1, got {width}x{height}")
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    b = boxes.copy()
    b[:, [0, 2]] = np.clip(b[:, [0, 2]], 0.0, width)
    b[:, [1, 3]] = np.clip(b[:, [1, 3]], 0.0, height)
    if np.any(b[:, 2] <= b[:, 0]) or np.any(b[:, 3] <= b[:, 1]):
        raise ValueError("boxes: every box needs x2 > x1 and y2 > y1 inside the image")
    cx = (b[:, 0] + b[:, 2]) / 2.0 / width
    cy = (b[:, 1] + b[:, 3]) / 2.0 / height
    w = (b[:, 2] - b[:, 0]) / width
    h = (b[:, 3] - b[:, 1]) / height
    return [f"{class_id} {a:.6f} {c:.6f} {d:.6f} {e:.6f}" for a, c, d, e in zip(cx, cy, w, h)]


def split_indices(n: int, fractions: Sequence[float], rng: np.random.Generator) -> list[str]:
    """Assign each of ``n`` images to a split (train/val/test) by ``fractions`` (sum 1), shuffled.

    Counts are rounded so they add up to ``n``; every split with a positive
    fraction gets at least one image when n allows it.
    """
    f = np.asarray(fractions, dtype=np.float64)
    if f.shape != (len(SPLITS),) or np.any(f < 0) or not math.isclose(float(f.sum()), 1.0, abs_tol=1e-6):
        raise ValueError(f"split: expected {len(SPLITS)} non-negative fractions summing to 1, "
                         f"got {list(fractions)}")
    counts = np.floor(f * n).astype(int)
    for i in np.argsort(-(f * n - counts))[: n - int(counts.sum())]:
        counts[i] += 1
    for i in range(len(f)):
        if f[i] > 0 and counts[i] == 0 and n >= int(np.count_nonzero(f)):
            donor = int(np.argmax(counts))
            counts[donor] -= 1
            counts[i] += 1
    labels = np.repeat(np.arange(len(SPLITS)), counts)
    rng.shuffle(labels)
    return [SPLITS[i] for i in labels]


def write_data_yaml(out: Path) -> Path:
    """Write the Ultralytics ``data.yaml`` for a dataset folder; returns its path."""
    import yaml

    doc = {"path": str(out.resolve()), "train": "images/train", "val": "images/val",
           "test": "images/test", "nc": len(CLASS_NAMES), "names": dict(CLASS_NAMES)}
    path = out / "data.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@dataclass(frozen=True)
class DatasetSummary:
    """What :func:`write_dataset` wrote: images per split, boxes in total, the data.yaml path."""

    images: dict[str, int]
    boxes: int
    empty_images: int
    data_yaml: Path


RenderFn = Callable[[np.ndarray, LightingSample, int], tuple[np.ndarray, np.ndarray]]
