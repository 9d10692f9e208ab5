"""Pascal VOC annotations -> an Ultralytics YOLO dataset, split by source photo.

Roboflow exports several augmented copies of one photo (``0058_jpg.rf.<hash>.jpg``);
copies of one photo must stay in one split or validation scores are optimistic.
:func:`source_prefix` gives the grouping key, :func:`plan_split` keeps the
dataset's own train/valid/test folders when they do not share a prefix and
re-splits by prefix (deterministically) when they do.

Label format written: one ``class cx cy w h`` line per box, normalised to [0, 1]
by the image size read from the pixels (not trusted from the XML).
"""

from __future__ import annotations

import hashlib
import json
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp")
ROBOFLOW_COPY_MARKER = "_jpg.rf."
SPLITS = ("train", "valid", "test")
DEFAULT_FRACTIONS = (0.8, 0.13, 0.07)


@dataclass(frozen=True)
class VocBox:
    """One annotated box in pixels of the original image (VOC corners)."""

    name: str
    xmin: float
    ymin: float
    xmax: float
    ymax: float


@dataclass(frozen=True)
class VocSample:
    """An image file and the boxes of its VOC annotation."""

    image: Path
    annotation: Path
    boxes: tuple[VocBox, ...]


@dataclass
class DatasetSummary:
    """What :func:`convert_voc_dataset` wrote; serialised into the model card."""

    root: Path
    yaml_path: Path
    names: list[str]
    images: dict[str, int] = field(default_factory=dict)
    boxes: dict[str, int] = field(default_factory=dict)
    source_photos: dict[str, int] = field(default_factory=dict)
    resplit: bool = False
    leaked_prefixes: int = 0
    dropped_boxes: int = 0

    def to_dict(self) -> dict[str, object]:
        return {
            "root": str(self.root),
            "yaml": str(self.yaml_path),
            "names": self.names,
            "images": self.images,
            "boxes": self.boxes,
            "source_photos": self.source_photos,
            "resplit_by_source_photo": self.resplit,
            "prefixes_leaking_across_original_split": self.leaked_prefixes,
            "dropped_degenerate_boxes": self.dropped_boxes,
        }


def source_prefix(image_name: str) -> str:
    """Key of the source photo an (augmented) image comes from.

    ``"0058_jpg.rf.51ff...jpg"`` -> ``"0058"``; names without the Roboflow marker
    are their own source (stem without suffix).
    """
    base = os.path.basename(image_name)
    if ROBOFLOW_COPY_MARKER in base:
        return base.split(ROBOFLOW_COPY_MARKER, 1)[0]
    return os.path.splitext(base)[0]


def parse_voc(annotation: Path) -> tuple[VocBox, ...]:
    """Read the boxes of one VOC XML file.

    Raises ValueError naming the file when it is not VOC (no ``annotation``
    root, or an object without a complete ``bndbox``).
    """
    try:
        root = ET.parse(annotation).getroot()
    except ET.ParseError as exc:
        raise ValueError(f"annotation {annotation}: not valid XML ({exc})") from exc
    if root.tag != "annotation":
        raise ValueError(f"annotation {annotation}: root element is <{root.tag}>, expected <annotation>")
    boxes = []
    for obj in root.iter("object"):
        name = (obj.findtext("name") or "").strip()
        bb = obj.find("bndbox")
        if not name or bb is None:
            raise ValueError(f"annotation {annotation}: <object> without <name> or <bndbox>")
        try:
            coords = [float(bb.findtext(k) or "nan") for k in ("xmin", "ymin", "xmax", "ymax")]
        except ValueError as exc:
            raise ValueError(f"annotation {annotation}: non-numeric bndbox ({exc})") from exc
        if not all(np.isfinite(coords)):
            raise ValueError(f"annotation {annotation}: bndbox of {name!r} is missing a coordinate")
        boxes.append(VocBox(name, *coords))
    return tuple(boxes)


def find_samples(folder: Path) -> list[VocSample]:
    """Every image in ``folder`` that has a same-stem ``.xml`` beside it, sorted by name."""
    samples = []
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        xml = path.with_suffix(".xml")
        if not xml.is_file():
            continue
        samples.append(VocSample(path, xml, parse_voc(xml)))
    return samples


def _stable_rank(key: str, seed: int) -> str:
    # Hash rank: a deterministic shuffle that does not move when other prefixes are added.
    return hashlib.sha256(f"{seed}:{key}".encode()).hexdigest()


def plan_split(
    samples_by_folder: Mapping[str, Sequence[VocSample]],
    *,
    fractions: tuple[float, float, float] = DEFAULT_FRACTIONS,
    seed: int = 0,
) -> tuple[dict[str, list[VocSample]], bool, int]:
    """Assign samples to train/valid/test so that no source photo spans two splits.

    ``samples_by_folder`` maps a folder name (``train``/``valid``/``test`` or
    anything else) to its samples. When the folders are exactly the three
    splits and share no prefix, they are kept. Otherwise every sample is pooled
    and re-split by prefix with ``fractions`` (train, valid, test) of the
    source photos. Returns (split -> samples, resplit?, number of leaking prefixes).
    """
    if len(fractions) != 3 or any(f < 0 for f in fractions) or not np.isclose(sum(fractions), 1.0):
        raise ValueError(f"fractions must be three non-negative numbers summing to 1, got {fractions}")
    owners: dict[str, set[str]] = {}
    for folder, samples in samples_by_folder.items():
        for s in samples:
            owners.setdefault(source_prefix(s.image.name), set()).add(folder)
    leaked = sum(1 for f in owners.values() if len(f) > 1)
    if leaked == 0 and set(samples_by_folder) == set(SPLITS):
        return {k: list(samples_by_folder[k]) for k in SPLITS}, False, 0

    prefixes = sorted(owners, key=lambda p: _stable_rank(p, seed))
    n = len(prefixes)
    n_train = int(round(fractions[0] * n))
    n_valid = int(round(fractions[1] * n))
    assign = {}
    for i, p in enumerate(prefixes):
        assign[p] = "train" if i < n_train else "valid" if i < n_train + n_valid else "test"
    out: dict[str, list[VocSample]] = {k: [] for k in SPLITS}
    for samples in samples_by_folder.values():
        for s in samples:
            out[assign[source_prefix(s.image.name)]].append(s)
    for k in SPLITS:
        out[k].sort(key=lambda s: s.image.name)
    return out, True, leaked


def yolo_label_lines(
    boxes: Iterable[VocBox], width: int, height: int, class_ids: Mapping[str, int]
) -> tuple[list[str], int]:
    """YOLO label lines for ``boxes`` in an image of ``width`` x ``height`` pixels.

    Boxes are clipped to the image (Roboflow writes xmax = width + 1); boxes
    with no area left are dropped and counted. Returns (lines, dropped).
    """
    lines, dropped = [], 0
    for b in boxes:
        x1, x2 = np.clip([b.xmin, b.xmax], 0, width)
        y1, y2 = np.clip([b.ymin, b.ymax], 0, height)
        if x2 - x1 < 1 or y2 - y1 < 1:
            dropped += 1
            continue
        cx, cy = (x1 + x2) / 2 / width, (y1 + y2) / 2 / height
        w, h = (x2 - x1) / width, (y2 - y1) / height
        lines.append(f"{class_ids[b.name]} {cx:.6f} {cy:.6f} {w:.6f} {h:.6f}")
    return lines, dropped


def convert_voc_dataset(
    source: Path,
    out: Path,
    *,
    fractions: tuple[float, float, float] = DEFAULT_FRACTIONS,
    seed: int = 0,
    limit_per_split: int | None = None,
) -> DatasetSummary:
    """Convert a VOC dataset into an Ultralytics YOLO dataset under ``out``.

    ``source`` holds images with same-stem XML files, either directly or in
    sub-folders (e.g. ``train/``, ``valid/``, ``test/``). Images are linked
    (hard link, copy as fallback) into ``out/images/<split>`` with labels in
    ``out/labels/<split>``; ``out/data.yaml`` is written for Ultralytics and
    ``out/split.json`` records which source photo went where.
    ``limit_per_split`` keeps only the first N images of each split (tests).
    """
    source, out = Path(source), Path(out)
    if not source.is_dir():
        raise ValueError(f"source: {source} is not a directory")
    folders = {p.name: find_samples(p) for p in sorted(source.iterdir()) if p.is_dir()}
    folders = {k: v for k, v in folders.items() if v}
    top = find_samples(source)
    if top:
        folders[source.name or "."] = top
    if not folders:
        raise ValueError(f"source: no image with a VOC .xml beside it under {source}")

    splits, resplit, leaked = plan_split(folders, fractions=fractions, seed=seed)
    names = sorted({b.name for ss in splits.values() for s in ss for b in s.boxes})
    if not names:
        raise ValueError(f"source: the annotations under {source} contain no object")
    class_ids = {n: i for i, n in enumerate(names)}
    summary = DatasetSummary(root=out, yaml_path=out / "data.yaml", names=names, resplit=resplit, leaked_prefixes=leaked)
    record: dict[str, list[str]] = {}
    for split, samples in splits.items():
        if limit_per_split is not None:
            samples = samples[:limit_per_split]
        img_dir, lbl_dir = out / "images" / split, out / "labels" / split
        img_dir.mkdir(parents=True, exist_ok=True)
        lbl_dir.mkdir(parents=True, exist_ok=True)
        n_boxes = 0
        for s in samples:
            image = cv2.imread(str(s.image), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise ValueError(f"source: cannot decode image {s.image}")
            h, w = image.shape[:2]
            lines, dropped = yolo_label_lines(s.boxes, w, h, class_ids)
            summary.dropped_boxes += dropped
            n_boxes += len(lines)
            dst = img_dir / s.image.name
            if not dst.exists():
                try:
                    os.link(s.image, dst)
                except OSError:
                    dst.write_bytes(s.image.read_bytes())
            (lbl_dir / (s.image.stem + ".txt")).write_text("".join(line + "\n" for line in lines))
        summary.images[split] = len(samples)
        summary.boxes[split] = n_boxes
        prefixes = sorted({source_prefix(s.image.name) for s in samples})
        summary.source_photos[split] = len(prefixes)
        record[split] = prefixes
    yaml_lines = [f"path: {out.resolve()}", "train: images/train", "val: images/valid", "test: images/test", "names:"]
    yaml_lines += [f"  {i}: {n}" for i, n in enumerate(names)]
    summary.yaml_path.write_text("\n".join(yaml_lines) + "\n")
    (out / "split.json").write_text(json.dumps({"summary": summary.to_dict(), "source_photos": record}, indent=1))
    return summary
