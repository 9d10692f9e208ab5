"""COCO-style accuracy of a detector on a labelled split (pycocotools' COCOeval).

A split is either a VOC folder (images with same-stem ``.xml``) or a YOLO split
(``.../images/<split>`` with labels in ``.../labels/<split>``). Ground-truth and
predicted boxes are in pixels of the original image; the detector should run
with a low confidence threshold (Ultralytics validates at 0.001) so the
precision-recall curve is complete.
"""

from __future__ import annotations

import contextlib
import io
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from insulator_rs.detection.voc import IMAGE_SUFFIXES, parse_voc

EVAL_CONF = 0.001  # Ultralytics' validation threshold


@dataclass(frozen=True)
class LabelledImage:
    """An image file and its ground-truth boxes (pixels, x1 y1 x2 y2) and class names."""

    image: Path
    boxes: np.ndarray  # (K, 4) float64
    labels: tuple[str, ...]


@dataclass(frozen=True)
class CocoMetrics:
    """The COCOeval summary figures on one split."""

    map50_95: float
    map50: float
    map75: float
    recall100: float  # AR@100 over IoU 0.5:0.95
    images: int
    instances: int
    detections: int
    ms_per_image: float  # detector wall time, pre+inference+post

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


def load_split(path: Path, names: dict[int, str] | None = None) -> list[LabelledImage]:
    """Read a VOC folder or a YOLO ``images/<split>`` folder into labelled images.

    YOLO labels are denormalised with the image size read from the pixels and
    need ``names`` (class id -> name). Boxes are clipped to the image.
    """
    path = Path(path)
    if not path.is_dir():
        raise ValueError(f"path: {path} is not a directory")
    images = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise ValueError(f"path: no image in {path}")
    return load_images(images, names, yolo_labels=path.parent.parent / "labels" / path.name)


def load_images(images: list[Path], names: dict[int, str] | None = None, *,
                yolo_labels: Path | None = None, voc_dir: Path | None = None) -> list[LabelledImage]:
    """Labelled images from image paths: a same-stem VOC ``.xml`` (beside each image, or in ``voc_dir``),
    else a YOLO label in ``yolo_labels``."""
    out = []
    for img_path in images:
        xml = voc_dir / f"{img_path.stem}.xml" if voc_dir is not None else img_path.with_suffix(".xml")
        shape = cv2.imread(str(img_path), cv2.IMREAD_UNCHANGED)
        if shape is None:
            raise ValueError(f"path: cannot decode {img_path}")
        h, w = shape.shape[:2]
        if xml.is_file():
            voc = parse_voc(xml)
            boxes = np.array([[b.xmin, b.ymin, b.xmax, b.ymax] for b in voc], dtype=np.float64).reshape(-1, 4)
            labels = tuple(b.name for b in voc)
        elif yolo_labels is not None and (yolo_labels / f"{img_path.stem}.txt").is_file():
            if names is None:
                raise ValueError("names: needed to read YOLO labels (class id -> name)")
            rows = np.loadtxt(yolo_labels / f"{img_path.stem}.txt", ndmin=2).reshape(-1, 5)
            cx, cy, bw, bh = rows[:, 1] * w, rows[:, 2] * h, rows[:, 3] * w, rows[:, 4] * h
            boxes = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], axis=1)
            labels = tuple(names[int(c)] for c in rows[:, 0])
        else:
            raise ValueError(f"path: {img_path.name} has neither a VOC .xml beside it nor a YOLO label in {yolo_labels}")
        boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(0, w)
        boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0, h)
        out.append(LabelledImage(img_path, boxes, labels))
    return out


def coco_evaluate(
    samples: list[LabelledImage],
    detect: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, list[str]]],
    *,
    progress: Callable[[int, int], None] | None = None,
) -> CocoMetrics:
    """Run ``detect(bgr) -> (boxes xyxy, scores, labels)`` on every sample and score it with COCOeval.

    Classes are matched by name; a ground-truth class the detector never emits
    still counts (as missed).
    """
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    if not samples:
        raise ValueError("samples: empty split")
    categories = sorted({lbl for s in samples for lbl in s.labels})
    cat_id = {name: i + 1 for i, name in enumerate(categories)}
    gt = {"images": [], "annotations": [], "categories": [{"id": i, "name": n} for n, i in cat_id.items()]}
    dets = []
    seconds = 0.0
    for img_id, s in enumerate(samples, start=1):
        image = cv2.imread(str(s.image), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"samples: cannot decode {s.image}")
        h, w = image.shape[:2]
        gt["images"].append({"id": img_id, "width": w, "height": h, "file_name": s.image.name})
        for box, lbl in zip(s.boxes, s.labels):
            bw, bh = float(box[2] - box[0]), float(box[3] - box[1])
            gt["annotations"].append({"id": len(gt["annotations"]) + 1, "image_id": img_id, "category_id": cat_id[lbl],
                                      "bbox": [float(box[0]), float(box[1]), bw, bh], "area": bw * bh, "iscrowd": 0})
        t0 = time.perf_counter()
        boxes, scores, labels = detect(image)
        seconds += time.perf_counter() - t0
        for box, score, lbl in zip(boxes, scores, labels):
            if lbl not in cat_id:
                cat_id[lbl] = len(cat_id) + 1  # a class absent from the ground truth: only false positives
                gt["categories"].append({"id": cat_id[lbl], "name": lbl})
            dets.append({"image_id": img_id, "category_id": cat_id[lbl], "score": float(score),
                         "bbox": [float(box[0]), float(box[1]), float(box[2] - box[0]), float(box[3] - box[1])]})
        if progress is not None:
            progress(img_id, len(samples))
    with contextlib.redirect_stdout(io.StringIO()):  # COCOeval prints its tables
        coco_gt = COCO()
        coco_gt.dataset = gt
        coco_gt.createIndex()
        coco_dt = coco_gt.loadRes(dets) if dets else None
        if coco_dt is None:
            stats = np.zeros(12)
        else:
            ev = COCOeval(coco_gt, coco_dt, iouType="bbox")
            ev.evaluate()
            ev.accumulate()
            ev.summarize()
            stats = np.maximum(ev.stats, 0.0)  # -1 means "no such objects": report 0
    return CocoMetrics(map50_95=float(stats[0]), map50=float(stats[1]), map75=float(stats[2]),
                       recall100=float(stats[8]), images=len(samples), instances=len(gt["annotations"]),
                       detections=len(dets), ms_per_image=1000 * seconds / len(samples))


def evaluate_field_test(detector: object, field_photos: Path,
                        progress: Callable[[int, int], None] | None = None) -> CocoMetrics:
    """COCO figures of ``detector`` (a :class:`Detector`) on the held-back field photos, full frames letterboxed.

    The split is :func:`field_dataset.field_test_images` (the one training held back, by photo).
    """
    from insulator_rs.detection.field_dataset import field_test_images

    samples = load_images(field_test_images(field_photos), voc_dir=Path(field_photos) / "labels")

    def detect(image: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
        det = detector(image)  # type: ignore[operator]
        return det.boxes, det.scores, det.labels

    return coco_evaluate(samples, detect, progress=progress)
