"""Rendered training data for the insulator detector, in the YOLO (Ultralytics) layout.

:func:`write_dataset` renders images of a tower scene from varied viewpoints
(around both sides of the tower, at varied distance and height, looking at a
random part of it) under varied lighting (time of day, haze, sensor noise), and
writes::

    out/images/{train,val,test}/NNNNNN.png
    out/labels/{train,val,test}/NNNNNN.txt   one "0 cx cy w h" line per insulator (normalised)
    out/data.yaml                            path, splits, names {0: insulator}
    out/views.csv                            per image: split, scene, box count, camera pose T_w_c

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
from typing import TYPE_CHECKING

import numpy as np

from insulator_rs.sim.camera_render import Lighting

if TYPE_CHECKING:
    from insulator_rs._core import CameraModel
    from insulator_rs.sim.camera_render import Camera, CameraFrame
    from insulator_rs.sim.mesh import Mesh
    from insulator_rs.sim.towers import Tower

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


def sample_lighting(rng: np.random.Generator) -> Lighting:
    """Time of day (7:00 to 18:00, sun azimuth varied), clear to hazy or foggy air, sunny to
    overcast sky, sensor noise: the variations the paper's simulation dataset used."""
    weather = rng.choice(["sunny", "cloudy", "rainy"])
    overcast = {"sunny": 0.0, "cloudy": rng.uniform(0.4, 0.8), "rainy": rng.uniform(0.8, 1.0)}[weather]
    haze = {"sunny": rng.uniform(0.0, 0.004), "cloudy": rng.uniform(0.002, 0.01),
            "rainy": rng.uniform(0.01, 0.03)}[weather]
    return Lighting.at_time_of_day(
        float(rng.uniform(7.0, 18.0)), haze_density=float(haze),
        noise_sigma=float(rng.uniform(0.5, 4.0)), overcast=float(overcast),
        sun_azimuth_offset=float(rng.uniform(-0.5, 0.5)))


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
    return jitter_view(look_at(eye, target), rng, sampling.aim_jitter_deg)


def jitter_view(T_w_c: np.ndarray, rng: np.random.Generator, jitter_deg: float) -> np.ndarray:
    """``T_w_c`` with its viewing direction jittered: rotations of up to ``jitter_deg`` about the
    camera's x and y axes (drawn in that order), in place; returns it."""
    ax, ay = np.radians(rng.uniform(-jitter_deg, jitter_deg, 2))
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    T_w_c[:3, :3] = T_w_c[:3, :3] @ rx @ ry
    return T_w_c


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


def scaled_camera_model(width: int | None, height: int | None) -> CameraModel:
    """The default simulated camera's lens at another image size (same field of view across,
    square pixels, principal point at the centre of the new image); both None: the default."""
    from insulator_rs._core import CameraModel
    from insulator_rs.sim.camera_render import default_camera_model

    base = default_camera_model()
    if width is None and height is None:
        return base
    if width is None or height is None or width < 1 or height < 1:
        raise ValueError(f"image_size: width and height must be >= 1, got {width}x{height}")
    f = base.fx * width / base.width
    return CameraModel(f, f, (width - 1) / 2, (height - 1) / 2, width, height, dist=list(base.dist))


def _aim_points(tower: Tower) -> np.ndarray:
    """What the dataset camera looks at: every insulator's centre and points up the tower axis."""
    heights = np.linspace(0.3, 1.0, 6) * tower.max_height
    axis_points = np.column_stack([np.zeros_like(heights), np.zeros_like(heights), heights])
    return np.vstack([np.array([i.center for i in tower.insulators]), axis_points])


def render_outside_geometry(camera: Camera, mesh: Mesh, draw_view: Callable[[], np.ndarray],
                            rng: np.random.Generator, *, seed: int, min_box_pixels: int,
                            attempts: int = 20) -> CameraFrame:
    """Render the first view ``draw_view`` gives (a T_w_c) whose camera is not inside geometry,
    under a lighting drawn from ``rng`` after each view; RuntimeError after ``attempts`` draws."""
    for _attempt in range(attempts):
        T_w_c = draw_view()
        try:
            return camera.render(mesh, T_w_c @ np.linalg.inv(camera.T_b_c), lighting=sample_lighting(rng),
                                 seed=seed, min_box_pixels=min_box_pixels)
        except ValueError as exc:  # camera inside geometry: draw another view
            if "inside geometry" not in str(exc):
                raise
    raise RuntimeError(f"image {seed}: no view outside the geometry in {attempts} draws")


def write_dataset(*, scenes: Sequence[str | Path], out: Path, n_images: int,
                  split: Sequence[float] = (0.8, 0.1, 0.1),
                  image_size: tuple[int, int] | None = None, min_visible_pixels: int = 30,
                  sampling: ViewSampling = ViewSampling(), seed: int = 0,
                  progress: bool = False) -> DatasetSummary:
    """Render ``n_images`` images (scenes taken in turn) into ``out`` in the YOLO layout.

    Also writes ``out/views.csv``: per image its split, scene, lighting hour and the
    camera pose T_w_c (16 values, row-major), so every label can be checked and reproduced.
    Raises ValueError when ``out`` already holds a dataset (nothing is overwritten).
    """
    import csv
    import sys
    import time

    import cv2

    from insulator_rs.sim.camera_render import Camera
    from insulator_rs.sim.towers import load_tower

    if n_images < 1:
        raise ValueError(f"n_images: must be >= 1, got {n_images}")
    if not scenes:
        raise ValueError("scenes: give at least one scene")
    if min_visible_pixels < 1:
        raise ValueError(f"min_visible_pixels: must be >= 1, got {min_visible_pixels}")
    out = Path(out)
    if (out / "data.yaml").exists() or (out / "images").exists() or (out / "labels").exists():
        raise ValueError(f"out: {out} already holds a dataset (images/, labels/ or data.yaml); "
                         "choose an empty folder")
    rng = np.random.default_rng(seed)
    labels_split = split_indices(n_images, split, rng)
    towers = [load_tower(s) for s in scenes]
    width, height = image_size if image_size is not None else (None, None)
    camera = Camera(scaled_camera_model(width, height))
    size = (int(camera.model.width), int(camera.model.height))
    for sp in SPLITS:
        (out / "images" / sp).mkdir(parents=True, exist_ok=True)
        (out / "labels" / sp).mkdir(parents=True, exist_ok=True)
    counts = {sp: 0 for sp in SPLITS}
    n_boxes = n_empty = 0
    start = time.monotonic()
    with (out / "views.csv").open("w", newline="") as f:
        views = csv.writer(f)
        views.writerow(["image", "split", "scene", "boxes"] + [f"T_w_c_{r}{c}" for r in range(4)
                                                                for c in range(4)])
        for i, sp in enumerate(labels_split):
            tower = towers[i % len(towers)]
            aim = _aim_points(tower)
            frame = render_outside_geometry(camera, tower.mesh, lambda: sample_view(rng, aim, sampling), rng,
                                            seed=i, min_box_pixels=min_visible_pixels)
            name = f"{i:06d}"
            cv2.imwrite(str(out / "images" / sp / f"{name}.png"), frame.rgb[:, :, ::-1])
            boxes = np.array([frame.boxes[k] for k in sorted(frame.boxes)]).reshape(-1, 4)
            lines = yolo_lines(boxes, *size)
            (out / "labels" / sp / f"{name}.txt").write_text("".join(line + "\n" for line in lines))
            views.writerow([name, sp, tower.spec.name, len(lines)] + frame.T_w_c.reshape(-1).tolist())
            counts[sp] += 1
            n_boxes += len(lines)
            n_empty += int(len(lines) == 0)
            if progress and ((i + 1) % max(1, n_images // 20) == 0 or i + 1 == n_images):
                elapsed = time.monotonic() - start
                print(f"  {i + 1}/{n_images} images, {elapsed:.0f} s elapsed, "
                      f"ETA {elapsed / (i + 1) * (n_images - i - 1):.0f} s", file=sys.stderr, flush=True)
    return DatasetSummary(images=counts, boxes=n_boxes, empty_images=n_empty,
                          data_yaml=write_data_yaml(out))
