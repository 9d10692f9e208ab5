"""The field-geometry dataset: whole 4:3 UAV frames, split by photo, export copies kept on their photo's side.

``../shared/data/insulator_field_photos`` holds the photos as the camera took
them (1152x864, ``images/NAME.jpg`` + ``labels/NAME.xml``); the Roboflow export
``../shared/data/insulator_photos`` holds the same photos stretched to 412x412,
rotated by multiples of 90 degrees, three copies per training photo. A photo and
its copies are one *source photo*: they go to one split only.

How a copy is matched to its photo: by the export's file-name stem, the prefix
before ``_jpg`` (``0058_jpg.rf.<hash>.jpg`` -> ``0058`` -> ``images/0058.jpg``),
as both datasets' ATTRIBUTION files state. :func:`verify_export_matches` checks
that claim on the pixels: the field photo, stretched to a square thumbnail, must
correlate with one of the copy's four 90-degree rotations better than with any
other field photo's thumbnail (normalised cross-correlation of 32x32 grey
thumbnails, brightness-normalised, which survives Roboflow's brightness change).

The field split is a hash rank of the photo name (deterministic, stable when
photos are added). Frames are linked unchanged: the trainer and the evaluator
letterbox them to the model's square input, so insulators keep their shape.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from insulator_rs.detection.voc import (VocSample, _stable_rank, find_samples, parse_voc, source_prefix,
                                        yolo_label_lines)

FIELD_FRACTIONS = (0.75, 0.10, 0.15)  # train, valid, test of the field photos
THUMB = 32
FIELD_TEST = "field-test"  # the named split of `insulator-rs detect eval --split`
DEFAULT_FIELD_PHOTOS = Path("../shared/data/insulator_field_photos")  # beside the repository, as in the README


@dataclass
class FieldDatasetSummary:
    """What :func:`build_field_dataset` wrote; goes into the model card."""

    root: Path
    yaml_path: Path
    photos: dict[str, int] = field(default_factory=dict)
    images: dict[str, int] = field(default_factory=dict)
    boxes: dict[str, int] = field(default_factory=dict)
    export_copies_in_train: int = 0
    export_copies_held_out: int = 0
    export_match: dict[str, object] = field(default_factory=dict)
    dropped_boxes: int = 0

    def to_dict(self) -> dict[str, object]:
        return {"root": str(self.root), "yaml": str(self.yaml_path), "photos": self.photos, "images": self.images,
                "boxes": self.boxes, "export_copies_in_train": self.export_copies_in_train,
                "export_copies_not_used_because_their_photo_is_in_valid_or_test": self.export_copies_held_out,
                "export_match": self.export_match, "dropped_degenerate_boxes": self.dropped_boxes}


def split_photos(names: list[str], fractions: tuple[float, float, float] = FIELD_FRACTIONS,
                 seed: int = 0) -> dict[str, str]:
    """Photo name -> ``train``/``valid``/``test``, by a seeded hash rank of the name."""
    if len(fractions) != 3 or min(fractions) < 0 or not np.isclose(sum(fractions), 1.0):
        raise ValueError(f"fractions must be three non-negative numbers summing to 1, got {fractions}")
    ranked = sorted(names, key=lambda n: _stable_rank(n, seed))
    n_train = int(round(fractions[0] * len(ranked)))
    n_valid = int(round(fractions[1] * len(ranked)))
    return {n: "train" if i < n_train else "valid" if i < n_train + n_valid else "test" for i, n in enumerate(ranked)}


def field_test_images(field_root: Path, *, seed: int = 0,
                      fractions: tuple[float, float, float] = FIELD_FRACTIONS) -> list[Path]:
    """The held-back field photos (full frames with their VOC labels): the same split the training used.

    The labels live in ``field_root/labels``; the images are returned in name
    order. Raises ValueError naming the folder when it is not a field-photo set.
    """
    field_root = Path(field_root)
    img_dir, lbl_dir = field_root / "images", field_root / "labels"
    if not img_dir.is_dir() or not lbl_dir.is_dir():
        raise ValueError(f"field photos: {field_root} has no images/ and labels/ folders "
                         "(pass --field-photos to name the field-photo set)")
    photos = sorted(p for p in img_dir.glob("*.jpg") if (lbl_dir / f"{p.stem}.xml").is_file())
    if not photos:
        raise ValueError(f"field photos: no .jpg with a VOC label under {field_root}")
    assign = split_photos([p.stem for p in photos], fractions, seed)
    return [p for p in photos if assign[p.stem] == "test"]


def _thumb(image: np.ndarray) -> np.ndarray:
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    t = cv2.resize(grey, (THUMB, THUMB), interpolation=cv2.INTER_AREA).astype(np.float64).ravel()
    t -= t.mean()
    norm = np.linalg.norm(t)
    return t / norm if norm > 0 else t


def verify_export_matches(field_images: dict[str, Path], export_images: list[Path]) -> dict[str, object]:
    """Check on the pixels that each export copy is the field photo its stem names.

    Returns counts: copies checked, copies whose best-matching field photo (over
    all photos and the copy's 4 rotations) is the named one, the smallest
    correlation with the named photo, and the names of mismatches (first 20).
    """
    names = sorted(field_images)
    thumbs = []
    for n in names:
        img = cv2.imread(str(field_images[n]), cv2.IMREAD_REDUCED_COLOR_4)
        if img is None:
            raise ValueError(f"field photo: cannot decode {field_images[n]}")
        thumbs.append(_thumb(img))
    bank = np.stack(thumbs)
    index = {n: i for i, n in enumerate(names)}
    agree, worst, mismatches = 0, 1.0, []
    for path in export_images:
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"export image: cannot decode {path}")
        # Undo the rotation: try all four; the stretch is undone by comparing square thumbnails.
        rots = np.stack([_thumb(np.ascontiguousarray(np.rot90(img, k))) for k in range(4)])
        corr = (bank @ rots.T).max(axis=1)  # best rotation per field photo
        named = source_prefix(path.name)
        if named not in index:
            mismatches.append(path.name)
            continue
        worst = min(worst, float(corr[index[named]]))
        if int(np.argmax(corr)) == index[named]:
            agree += 1
        else:
            mismatches.append(path.name)
    return {"method": f"filename stem, checked by {THUMB}x{THUMB} grey NCC over 4 rotations against all field photos",
            "checked": len(export_images), "best_match_is_named_photo": agree,
            "min_correlation_with_named_photo": round(worst, 3), "mismatches": mismatches[:20]}


def _link(src: Path, dst: Path) -> None:
    if dst.exists():
        return
    try:
        os.link(src, dst)
    except OSError:
        dst.write_bytes(src.read_bytes())


def build_field_dataset(field_root: Path, out: Path, *, export_root: Path | None = None, with_export: bool = False,
                        fractions: tuple[float, float, float] = FIELD_FRACTIONS, seed: int = 0,
                        verify: bool = True) -> FieldDatasetSummary:
    """Write an Ultralytics dataset under ``out`` from the field photos (and optionally export copies).

    ``out/images/{train,valid,test}`` + ``out/labels/...`` + ``data.yaml`` +
    ``split.json`` (which photo went where, the export check). Export copies are
    added to ``train`` only when ``with_export`` and only for photos in train.
    ``out/field-test`` is a VOC folder (frames + XML) of the held-back photos:
    what ``detect eval --split field-test`` scores.
    """
    field_root, out = Path(field_root), Path(out)
    img_dir, lbl_dir = field_root / "images", field_root / "labels"
    if not img_dir.is_dir() or not lbl_dir.is_dir():
        raise ValueError(f"field_root: {field_root} needs images/ and labels/ folders")
    samples = []
    for img in sorted(img_dir.iterdir()):
        xml = lbl_dir / f"{img.stem}.xml"
        if img.suffix.lower() == ".jpg" and xml.is_file():
            samples.append(VocSample(img, xml, parse_voc(xml)))
    if not samples:
        raise ValueError(f"field_root: no image with a VOC label under {field_root}")
    assign = split_photos([s.image.stem for s in samples], fractions, seed)
    summary = FieldDatasetSummary(root=out, yaml_path=out / "data.yaml")
    for split in ("train", "valid", "test"):
        (out / "images" / split).mkdir(parents=True, exist_ok=True)
        (out / "labels" / split).mkdir(parents=True, exist_ok=True)
        summary.images[split] = summary.boxes[split] = summary.photos[split] = 0
    voc_test = out / "field-test"
    voc_test.mkdir(parents=True, exist_ok=True)

    def add(split: str, image: Path, boxes: tuple[Any, ...], stem: str) -> None:
        h, w = _image_size(image)
        lines, dropped = yolo_label_lines(boxes, w, h, {"insulator": 0})
        summary.dropped_boxes += dropped
        _link(image, out / "images" / split / f"{stem}{image.suffix}")
        (out / "labels" / split / f"{stem}.txt").write_text("".join(line + "\n" for line in lines))
        summary.images[split] += 1
        summary.boxes[split] += len(lines)

    for s in samples:
        split = assign[s.image.stem]
        add(split, s.image, s.boxes, s.image.stem)
        summary.photos[split] += 1
        if split == "test":
            _link(s.image, voc_test / s.image.name)
            _link(s.annotation, voc_test / f"{s.image.stem}.xml")
    if export_root is not None:
        copies = [c for sub in ("train", "valid", "test") if (export_root / sub).is_dir()
                  for c in find_samples(export_root / sub)]
        if verify:
            summary.export_match = verify_export_matches({s.image.stem: s.image for s in samples},
                                                         [c.image for c in copies])
        for c in copies:
            photo = source_prefix(c.image.name)
            if assign.get(photo, "train") != "train":
                summary.export_copies_held_out += 1
            elif with_export:
                add("train", c.image, c.boxes, f"export_{c.image.stem}")
                summary.export_copies_in_train += 1
    summary.yaml_path.write_text(f"path: {out.resolve()}\ntrain: images/train\nval: images/valid\n"
                                 "test: images/test\nnames:\n  0: insulator\n")
    record = {split: sorted(n for n, sp in assign.items() if sp == split) for split in ("train", "valid", "test")}
    (out / "split.json").write_text(json.dumps({"summary": summary.to_dict(), "photos": record,
                                                "fractions": fractions, "seed": seed}, indent=1, default=str))
    return summary


def _image_size(path: Path) -> tuple[int, int]:
    """(height, width) from the decoded pixels, not trusted from the XML."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"image: cannot decode {path}")
    return img.shape[0], img.shape[1]
