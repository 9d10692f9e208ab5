"""``insulator-rs detect run`` / ``detect eval`` and the COCO evaluation plumbing.

Reference for the evaluator plumbing: pycocotools itself must give mAP 1.0
when the detections are the labels and 0 when there are none.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.photos import PHOTOS

from insulator_rs.app.cli import main
from insulator_rs.detection.evaluate import coco_evaluate, load_split


def test_coco_evaluate_perfect_and_empty() -> None:
    samples = load_split(PHOTOS)
    by_name = {s.image.name: s for s in samples}
    order = iter(samples)

    def perfect(image: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
        s = next(order)
        return s.boxes, np.ones(len(s.boxes)), list(s.labels)

    m = coco_evaluate(samples, perfect)
    assert m.map50_95 == pytest.approx(1.0) and m.map50 == pytest.approx(1.0)
    assert m.images == len(by_name) and m.instances == sum(len(s.boxes) for s in samples)
    empty = coco_evaluate(samples, lambda im: (np.zeros((0, 4)), np.zeros(0), []))
    assert empty.map50_95 == 0.0 and empty.map50 == 0.0 and empty.detections == 0


def test_coco_evaluate_rejects_empty_split() -> None:
    with pytest.raises(ValueError, match="samples"):
        coco_evaluate([], lambda im: (np.zeros((0, 4)), np.zeros(0), []))


def test_load_split_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="not a directory"):
        load_split(tmp_path / "none")
    (tmp_path / "a.jpg").write_bytes((PHOTOS / next(PHOTOS.glob("*.jpg")).name).read_bytes())
    with pytest.raises(ValueError, match="neither a VOC"):
        load_split(tmp_path)


def test_detect_run_writes_json_and_drawings(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    images = sorted(PHOTOS.glob("*.jpg"))[:2]
    out = tmp_path / "det.json"
    code = main(["detect", "run", *map(str, images), "--json", str(out), "--draw", str(tmp_path / "draw"),
                 "--threads", "2"])
    assert code == 0
    result = json.loads(out.read_text())
    assert [r["image"] for r in result] == [str(p) for p in images]
    for r in result:
        assert len(r["boxes"]) == len(r["scores"]) == len(r["labels"])
    assert len(list((tmp_path / "draw").glob("*_det.jpg"))) == 2
    assert "detection(s)" in capsys.readouterr().out


def test_detect_eval_on_committed_photos(tmp_path: Path) -> None:
    out = tmp_path / "m.json"
    assert main(["detect", "eval", str(PHOTOS), "--json", str(out), "--threads", "2"]) == 0
    m = json.loads(out.read_text())
    assert m["images"] == len(list(PHOTOS.glob("*.jpg")))
    assert 0.0 <= m["map50_95"] <= m["map50"] <= 1.0
    assert m["conf"] == 0.001


def test_detect_run_unreadable_image(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"not an image")
    assert main(["detect", "run", str(bad)]) == 2
    assert "cannot read image" in capsys.readouterr().err


def _bad_images(tmp_path: Path) -> tuple[Path, Path, Path]:
    """A good photo, a 16-bit PNG and the same photo's JPEG cut in half."""
    import cv2

    good = sorted(PHOTOS.glob("*.jpg"))[0]
    png16 = tmp_path / "deep.png"
    cv2.imwrite(str(png16), (cv2.imread(str(good)).astype(np.uint16) * 257))
    truncated = tmp_path / "cut.jpg"
    data = good.read_bytes()
    truncated.write_bytes(data[: len(data) // 2])
    return good, png16, truncated


def test_read_image_refuses_16bit_and_truncated(tmp_path: Path) -> None:
    """OpenCV alone decodes the cut JPEG (grey fill) and returns uint16 for the PNG: both refused, file named."""
    import cv2

    from insulator_rs.detection.image_file import read_image
    from insulator_rs.exceptions import ImageError

    good, png16, truncated = _bad_images(tmp_path)
    assert cv2.imread(str(truncated)) is not None  # the silent-wrong-answer this guards against
    assert read_image(good).dtype == np.uint8
    with pytest.raises(ImageError, match=r"deep\.png: 16-bit"):
        read_image(png16)
    with pytest.raises(ImageError, match=r"cut\.jpg: truncated JPEG"):
        read_image(truncated)
    with pytest.raises(ImageError, match="directory"):
        read_image(tmp_path)
    with pytest.raises(ImageError, match="no such file"):
        read_image(tmp_path / "missing.jpg")


def test_detect_run_keeps_results_when_an_image_fails(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good, png16, truncated = _bad_images(tmp_path)
    out = tmp_path / "det.json"
    code = main(["detect", "run", str(good), str(png16), str(truncated), str(good), "--json", str(out),
                 "--threads", "1"])
    assert code == 2
    err = capsys.readouterr().err
    assert "deep.png: 16-bit" in err and "cut.jpg: truncated JPEG" in err and "Traceback" not in err
    result = json.loads(out.read_text())
    assert [r["image"] for r in result] == [str(good), str(png16), str(truncated), str(good)]
    assert "boxes" in result[0] and "boxes" in result[3] and result[0]["boxes"] == result[3]["boxes"]
    assert "16-bit" in result[1]["error"] and "truncated" in result[2]["error"]
    assert result[0]["dropped_by_sanitiser"]["total"] == 0


@pytest.mark.parametrize("threads", ["100000", "0", "-3", "two"])
def test_detect_run_threads_bounded(threads: str, capsys: pytest.CaptureFixture[str]) -> None:
    """The bound itself is bounds.py's (robust's validation layer); here: detect run refuses cleanly."""
    photo = str(sorted(PHOTOS.glob("*.jpg"))[0])
    with pytest.raises(SystemExit) as exc:
        main(["detect", "run", photo, "--threads", threads])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--threads" in err and "Traceback" not in err
