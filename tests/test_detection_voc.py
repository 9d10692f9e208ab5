"""VOC -> YOLO conversion and the split by source photo.

References: hand-computed YOLO lines; the property that no source-photo prefix
ever lands in two splits (hypothesis over random folder assignments).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from helpers.photos import PHOTOS

from insulator_rs.detection.voc import (
    SPLITS,
    VocBox,
    VocSample,
    convert_voc_dataset,
    parse_voc,
    plan_split,
    source_prefix,
    yolo_label_lines,
)


def test_source_prefix() -> None:
    assert source_prefix("0058_jpg.rf.51ff3cb15ac967b4298716c209c4f366.jpg") == "0058"
    assert source_prefix("/a/b/0058_jpg.rf.x.xml") == "0058"
    assert source_prefix("frame_0001.png") == "frame_0001"


def test_yolo_lines_hand_computed_and_clipped() -> None:
    boxes = [VocBox("insulator", 100, 50, 200, 250), VocBox("insulator", 381, 171, 413, 296),
             VocBox("insulator", 500, 10, 600, 20)]
    lines, dropped = yolo_label_lines(boxes, 412, 412, {"insulator": 0})
    assert dropped == 1  # entirely outside the image
    assert lines[0] == f"0 {150 / 412:.6f} {150 / 412:.6f} {100 / 412:.6f} {200 / 412:.6f}"
    cx, w = (381 + 412) / 2 / 412, (412 - 381) / 412  # xmax 413 clipped to the width
    assert lines[1] == f"0 {cx:.6f} {(171 + 296) / 2 / 412:.6f} {w:.6f} {125 / 412:.6f}"


def test_parse_voc_errors(tmp_path: Path) -> None:
    bad = tmp_path / "a.xml"
    bad.write_text("<annotation><object><name>x</name></object></annotation>")
    with pytest.raises(ValueError, match="a.xml.*bndbox"):
        parse_voc(bad)
    bad.write_text("<foo/>")
    with pytest.raises(ValueError, match="expected <annotation>"):
        parse_voc(bad)
    bad.write_text("<annotation>")
    with pytest.raises(ValueError, match="not valid XML"):
        parse_voc(bad)
    assert len(parse_voc(next(PHOTOS.glob("*.xml")))) >= 1


def _samples(names: list[str]) -> list[VocSample]:
    return [VocSample(Path(n + ".jpg"), Path(n + ".xml"), ()) for n in names]


def test_clean_split_is_kept_and_leaky_split_is_redone() -> None:
    clean = {"train": _samples(["1_jpg.rf.a", "1_jpg.rf.b"]), "valid": _samples(["2_jpg.rf.a"]),
             "test": _samples(["3_jpg.rf.a"])}
    out, resplit, leaked = plan_split(clean)
    assert not resplit and leaked == 0 and [len(out[k]) for k in SPLITS] == [2, 1, 1]
    leaky = {"train": _samples(["1_jpg.rf.a", "2_jpg.rf.b"]), "valid": _samples(["1_jpg.rf.c"]),
             "test": _samples(["3_jpg.rf.a"])}
    out, resplit, leaked = plan_split(leaky)
    assert resplit and leaked == 1
    owners = {k: {source_prefix(s.image.name) for s in v} for k, v in out.items()}
    assert not (owners["train"] & owners["valid"] or owners["train"] & owners["test"]
                or owners["valid"] & owners["test"])


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 40), st.sampled_from(SPLITS), st.integers(0, 9)), min_size=1, max_size=120),
       st.integers(0, 5))
def test_no_source_photo_spans_two_splits(items, seed: int) -> None:
    folders: dict[str, list[VocSample]] = {k: [] for k in SPLITS}
    for prefix, folder, copy in items:
        folders[folder] += _samples([f"{prefix:04d}_jpg.rf.{copy}{len(folders[folder])}"])
    out, _, _ = plan_split(folders, seed=seed)
    where: dict[str, set[str]] = {}
    for split, samples in out.items():
        for s in samples:
            where.setdefault(source_prefix(s.image.name), set()).add(split)
    assert all(len(v) == 1 for v in where.values())
    assert sum(len(v) for v in out.values()) == len(items)


def test_plan_split_rejects_bad_fractions() -> None:
    with pytest.raises(ValueError, match="fractions"):
        plan_split({"x": []}, fractions=(0.5, 0.5, 0.5))


def test_convert_flat_folder(tmp_path: Path) -> None:
    summary = convert_voc_dataset(PHOTOS, tmp_path / "yolo")
    assert summary.resplit and summary.names == ["insulator"]
    assert sum(summary.images.values()) == len(list(PHOTOS.glob("*.jpg")))
    total_boxes = sum(len(parse_voc(x)) for x in PHOTOS.glob("*.xml"))
    assert sum(summary.boxes.values()) + summary.dropped_boxes == total_boxes
    yaml = (tmp_path / "yolo" / "data.yaml").read_text()
    assert "train: images/train" in yaml and "0: insulator" in yaml
    for split in SPLITS:
        for label in (tmp_path / "yolo" / "labels" / split).glob("*.txt"):
            rows = np.loadtxt(label, ndmin=2)
            assert rows.shape[1] == 5 and ((rows[:, 1:] >= 0) & (rows[:, 1:] <= 1)).all()
    record = json.loads((tmp_path / "yolo" / "split.json").read_text())
    assert set(record["source_photos"]) == set(SPLITS)


def test_convert_rejects_missing_or_empty_source(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="not a directory"):
        convert_voc_dataset(tmp_path / "nope", tmp_path / "out")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no image with a VOC"):
        convert_voc_dataset(tmp_path / "empty", tmp_path / "out")
