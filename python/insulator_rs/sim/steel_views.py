"""Views of tower steel as the flight sees it, and the network's false boxes on them (hard negatives).

The live flights' false finds were tower steel, seen from the inspection path: the
earth-wire peak above tower B's body (confirmed as an insulator in sessions 15-17), a
body leg. The rendered training set (:mod:`insulator_rs.sim.dataset`) looks at the
insulators from 7-30 m at 1280 x 960, and the network sees it shrunk to 320 px; the
flight renders its detection frames at 320 x 240 directly, where thin members alias
into broken, string-like streaks. So this module renders the flight's kind of frame:

* :func:`write_steel_views` renders views aimed at the tower's non-insulator steel (the
  peak and its apex, the top of the body, the cross-arms' tips and roots, the legs, the
  body faces' horizontal struts)
  from where the inspection path flies (5-16 m from the aimed steel, level with it to
  6 m below), at the flight's detection size, and writes them in the YOLO layout with
  every insulator that shows labelled (so a view is a negative for the steel and a
  positive for any string in it). ``truth.json`` keeps every visible insulator's box,
  down to one pixel, for matching: a box on a sliver of string is not a false box.
* :func:`count_false_boxes` runs a detector over such a folder and counts, per view,
  the boxes that match no insulator (:func:`is_false_box`); the views with one are the
  hard negatives a training run adds (:func:`write_image_list`), and on views rendered
  with another seed the count per view is the false-positive rate a model card reports.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from insulator_rs.ports.detector import DETECT_CONF
from insulator_rs.sim.dataset import (
    SPLITS,
    DatasetSummary,
    jitter_view,
    look_at,
    render_outside_geometry,
    scaled_camera_model,
    split_indices,
    write_data_yaml,
    yolo_lines,
)

if TYPE_CHECKING:
    from insulator_rs.sim.towers import Tower

#: The flight's detection frame (the sensor head renders 320 x 240; see sensor_head.py).
FLIGHT_DETECTION_SIZE = (320, 240)
#: An insulator needs this many visible pixels at 320 x 240 to be labelled: the rendered
#: set's 30 pixels at 1280 x 960, scaled by the area (30 / 16 = 1.9), rounded up.
MIN_LABEL_PIXELS = 2
#: A box is a true box when it overlaps an insulator's visible box this much (IoU), or lies
#: mostly (this share of its own area) on one: a box on part of a string is not a false box.
MATCH_IOU = 0.1
MATCH_INSIDE = 0.5


@dataclass(frozen=True)
class SteelViewSampling:
    """Where the camera goes, relative to the aimed steel point (m, degrees).

    distance: horizontal distance from the aimed point (the inspection path: 6 m from a
    string, passes 8 m beyond the widest arm). below: how far under the aimed point the
    camera may sit (negative: above it). aim_jitter_deg: random offset of the view axis.
    """

    distance: tuple[float, float] = (5.0, 16.0)
    below: tuple[float, float] = (-2.0, 6.0)
    aim_jitter_deg: float = 10.0
    min_height: float = 2.0


def steel_aim_points(tower: Tower) -> np.ndarray:
    """(K, 3) points on the tower's steel that are no insulator: the peak (apex, and halfway
    down its members), the body's top corners, each cross-arm's tips and roots, the legs at
    a few heights."""
    body = tower.spec.body

    def half_width(z: float) -> float:  # the body's half-width at height z (it tapers linearly)
        return 0.5 * (body.base_width + (body.top_width - body.base_width) * z / body.height)

    points: list[np.ndarray] = []
    top_half = 0.5 * body.top_width
    corners_top = [np.array([sx * top_half, sy * top_half, body.height]) for sx in (1, -1) for sy in (1, -1)]
    if body.peak_height > 0.0:
        apex = np.array([0.0, 0.0, body.height + body.peak_height])
        points.append(apex)
        points.extend(0.5 * (apex + c) for c in corners_top)
    points.extend(corners_top)
    for arm in tower.spec.cross_arms:
        for sx in (1.0, -1.0):
            points.append(np.array([sx * arm.reach, 0.0, arm.height]))
            points.append(np.array([sx * 0.5 * (arm.reach + top_half), 0.0, arm.height + 0.5 * arm.depth]))
    for z in np.linspace(0.35, 0.95, 4) * body.height:
        half = half_width(z)
        points.extend(np.array([sx * half, sy * half, z]) for sx, sy in ((1, 1), (-1, -1)))
    # The middle of each face's horizontal strut in the upper half of the body: the member a
    # model fine-tuned without them confirmed as a string on tower A (x = 1.65 m, 20.2 m up,
    # along the line; session 18), parallel to the strain strings and as long.
    levels = np.linspace(0.0, body.height, body.panels + 1)
    for z in levels[levels >= 0.5 * body.height]:
        half = half_width(z)
        points.extend(np.array(p) for p in ((half, 0.0, z), (-half, 0.0, z), (0.0, half, z), (0.0, -half, z)))
    return np.array(points)


def sample_steel_view(rng: np.random.Generator, aim_points: np.ndarray, sampling: SteelViewSampling) -> np.ndarray:
    """A random T_w_c looking at (near) one of ``aim_points`` from where the inspection path flies."""
    target = aim_points[int(rng.integers(len(aim_points)))]
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    dist = rng.uniform(*sampling.distance)
    height = max(sampling.min_height, float(target[2] - rng.uniform(*sampling.below)))
    eye = np.array([target[0] + dist * math.cos(azimuth), target[1] + dist * math.sin(azimuth), height])
    return jitter_view(look_at(eye, target), rng, sampling.aim_jitter_deg)


def write_steel_views(*, scenes: Sequence[str | Path], out: Path, n_images: int,
                      split: Sequence[float] = (1.0, 0.0, 0.0),
                      image_size: tuple[int, int] = FLIGHT_DETECTION_SIZE,
                      sampling: SteelViewSampling = SteelViewSampling(), seed: int = 0,
                      progress: Callable[[int, int], None] | None = None) -> DatasetSummary:
    """Render ``n_images`` steel views (scenes in turn) into ``out`` in the YOLO layout, with
    ``truth.json`` (per image: every visible insulator's box and pixel count) and ``views.csv``.

    Raises ValueError when ``out`` already holds a dataset (nothing is overwritten).
    """
    import csv

    import cv2

    from insulator_rs.sim.camera_render import Camera
    from insulator_rs.sim.towers import load_tower

    if n_images < 1:
        raise ValueError(f"n_images: must be >= 1, got {n_images}")
    if not scenes:
        raise ValueError("scenes: give at least one scene")
    out = Path(out)
    if (out / "data.yaml").exists() or (out / "images").exists():
        raise ValueError(f"out: {out} already holds a dataset (images/ or data.yaml); choose an empty folder")
    rng = np.random.default_rng(seed)
    splits = split_indices(n_images, split, rng)
    towers = [load_tower(s) for s in scenes]
    camera = Camera(scaled_camera_model(*image_size))
    size = (int(camera.model.width), int(camera.model.height))
    for sp in SPLITS:
        (out / "images" / sp).mkdir(parents=True, exist_ok=True)
        (out / "labels" / sp).mkdir(parents=True, exist_ok=True)
    counts = {sp: 0 for sp in SPLITS}
    truth: dict[str, dict[str, object]] = {}
    n_boxes = n_empty = 0
    with (out / "views.csv").open("w", newline="") as f:
        views = csv.writer(f)
        views.writerow(["image", "split", "scene", "boxes"] + [f"T_w_c_{r}{c}" for r in range(4) for c in range(4)])
        for i, sp in enumerate(splits):
            tower = towers[i % len(towers)]
            aim = steel_aim_points(tower)
            frame = render_outside_geometry(camera, tower.mesh, lambda: sample_steel_view(rng, aim, sampling), rng,
                                            seed=i, min_box_pixels=1)  # every visible insulator, for matching
            name = f"{i:06d}"
            rel = f"images/{sp}/{name}.png"
            cv2.imwrite(str(out / rel), frame.rgb[:, :, ::-1])
            keys = sorted(frame.boxes)
            labelled = [frame.boxes[k] for k in keys if frame.visible_pixels[k] >= MIN_LABEL_PIXELS]
            lines = yolo_lines(np.array(labelled).reshape(-1, 4), *size)
            (out / "labels" / sp / f"{name}.txt").write_text("".join(line + "\n" for line in lines))
            truth[rel] = {"boxes": [list(map(float, frame.boxes[k])) for k in keys],
                          "pixels": [int(frame.visible_pixels[k]) for k in keys]}
            views.writerow([name, sp, tower.spec.name, len(lines)] + frame.T_w_c.reshape(-1).tolist())
            counts[sp] += 1
            n_boxes += len(lines)
            n_empty += int(len(lines) == 0)
            if progress is not None:
                progress(i + 1, n_images)
    (out / "truth.json").write_text(json.dumps(truth))
    return DatasetSummary(images=counts, boxes=n_boxes, empty_images=n_empty, data_yaml=write_data_yaml(out))


def is_false_box(box: np.ndarray, truth_boxes: np.ndarray) -> bool:
    """True when ``box`` (x1, y1, x2, y2) matches none of ``truth_boxes`` (M, 4): IoU under
    MATCH_IOU with each, and less than MATCH_INSIDE of its own area on any of them."""
    truth_boxes = np.asarray(truth_boxes, dtype=np.float64).reshape(-1, 4)
    if len(truth_boxes) == 0:
        return True
    ix = np.clip(np.minimum(box[2], truth_boxes[:, 2]) - np.maximum(box[0], truth_boxes[:, 0]), 0.0, None)
    iy = np.clip(np.minimum(box[3], truth_boxes[:, 3]) - np.maximum(box[1], truth_boxes[:, 1]), 0.0, None)
    inter = ix * iy
    area = max((box[2] - box[0]) * (box[3] - box[1]), 1e-12)
    areas = (truth_boxes[:, 2] - truth_boxes[:, 0]) * (truth_boxes[:, 3] - truth_boxes[:, 1])
    iou = inter / (area + areas - inter)
    return bool(np.all(iou < MATCH_IOU) and np.all(inter / area < MATCH_INSIDE))


#: the scores false boxes are counted at: the flight's detection threshold and a stricter one
FALSE_BOX_THRESHOLDS = (DETECT_CONF, 0.5)


@dataclass(frozen=True)
class FalseBoxCount:
    """A detector's false boxes over a folder of steel views, at two score thresholds."""

    views: int
    thresholds: tuple[float, ...]
    false_boxes: dict[float, int]  # threshold -> false boxes over all views
    views_with_false_box: dict[float, int]
    per_image: dict[str, list[float]]  # image (relative path) -> the scores of its false boxes

    def to_dict(self) -> dict[str, object]:
        """The model card's entry: per threshold, false boxes per view and the share of views with one."""
        return {"views": self.views, **{
            f"score>={t:g}": {"false_boxes": self.false_boxes[t],
                              "false_boxes_per_view": round(self.false_boxes[t] / max(self.views, 1), 4),
                              "views_with_a_false_box": self.views_with_false_box[t],
                              "share_of_views": round(self.views_with_false_box[t] / max(self.views, 1), 4)}
            for t in self.thresholds}}


def count_false_boxes(detect: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], folder: Path, *,
                      thresholds: Sequence[float] = FALSE_BOX_THRESHOLDS, splits: Sequence[str] = SPLITS) -> FalseBoxCount:
    """Run ``detect`` (BGR image -> boxes (M, 4), scores (M,)) over the steel views of ``folder``
    (written by :func:`write_steel_views`) and count the boxes that match no visible insulator.

    Raises ValueError naming the folder when it has no ``truth.json``.
    """
    import cv2

    folder = Path(folder)
    truth_path = folder / "truth.json"
    if not truth_path.is_file():
        raise ValueError(f"folder: {folder} has no truth.json (not written by write_steel_views)")
    truth = json.loads(truth_path.read_text())
    per_image: dict[str, list[float]] = {}
    for rel, entry in sorted(truth.items()):
        if rel.split("/")[1] not in splits:
            continue
        image = cv2.imread(str(folder / rel), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"folder: {folder / rel} is missing or not an image")
        boxes, scores = detect(image)
        gt = np.array(entry["boxes"], dtype=np.float64).reshape(-1, 4)
        per_image[rel] = [float(s) for b, s in zip(np.asarray(boxes).reshape(-1, 4), scores) if is_false_box(b, gt)]
    thresholds = tuple(sorted(thresholds))
    return FalseBoxCount(
        views=len(per_image), thresholds=thresholds,
        false_boxes={t: sum(sum(s >= t for s in v) for v in per_image.values()) for t in thresholds},
        views_with_false_box={t: sum(any(s >= t for s in v) for v in per_image.values()) for t in thresholds},
        per_image=per_image)


def write_image_list(folder: Path, count: FalseBoxCount, out_txt: Path, *, min_score: float) -> int:
    """Write the absolute paths of the views with a false box scoring ``min_score`` or more to
    ``out_txt`` (an Ultralytics image list: labels are found beside, under ``labels/``);
    returns how many."""
    chosen = [str((Path(folder) / rel).resolve()) for rel, s in sorted(count.per_image.items())
              if any(v >= min_score for v in s)]
    Path(out_txt).write_text("".join(p + "\n" for p in chosen))
    return len(chosen)


def data_yaml_with_steel(base_yaml: Path, steel_folder: Path, mined_list: Path | None, out_yaml: Path, *,
                         mined_repeats: int = 2) -> Path:
    """A data.yaml whose training set is ``base_yaml``'s plus every steel view of ``steel_folder``
    (train split) plus the mined views (``mined_list``) ``mined_repeats`` more times: the views the
    start model got wrong weigh more, as in hard-example mining. Validation and test stay the base's.

    Raises ValueError naming the file when the base yaml has no ``train`` entry.
    """
    import yaml

    base_yaml, steel_folder = Path(base_yaml).resolve(), Path(steel_folder).resolve()
    doc = yaml.safe_load(base_yaml.read_text())
    if not isinstance(doc, dict) or "train" not in doc:
        raise ValueError(f"base_yaml: {base_yaml} has no 'train' entry")
    root = Path(doc.get("path") or base_yaml.parent)

    def absolute(entry: str) -> str:
        return str(entry if Path(entry).is_absolute() else root / entry)

    train = doc["train"] if isinstance(doc["train"], list) else [doc["train"]]
    train = [absolute(t) for t in train] + [str(steel_folder / "images" / "train")]
    if mined_list is not None and mined_repeats > 0:
        train += [str(Path(mined_list).resolve())] * mined_repeats
    doc = {**doc, "path": str(root), "train": train,
           **{k: absolute(doc[k]) for k in ("val", "test") if isinstance(doc.get(k), str)}}
    out_yaml = Path(out_yaml)
    out_yaml.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out_yaml
