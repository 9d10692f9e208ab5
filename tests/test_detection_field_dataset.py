"""The field-geometry dataset: split by photo, export copies matched on their pixels and kept on their photo's side.

Reference: a small field set and an "export" made here the way Roboflow made
the real one (each photo stretched to a square and rotated by a multiple of 90
degrees, brightness changed), so which copy belongs to which photo is known
independently of the file names; one copy is deliberately misnamed and must be
reported as a mismatch. The shared 480-photo set is too large for a unit test.
"""

from __future__ import annotations

import json
import platform
from pathlib import Path

import cv2
import numpy as np
import pytest

from insulator_rs.detection.field_dataset import build_field_dataset, split_photos, verify_export_matches

CARD_TOL_X86 = 1e-9  # the card's mAP, reproduced where it was measured (x86-64)
CARD_TOL_OTHER_CPU = 1e-6  # elsewhere: another CPU's float rounding (see the card test)

VOC = """<annotation><size><width>{w}</width><height>{h}</height><depth>3</depth></size>
<object><name>insulator</name><bndbox><xmin>{x1}</xmin><ymin>{y1}</ymin><xmax>{x2}</xmax><ymax>{y2}</ymax></bndbox></object>
</annotation>"""


def _make_sets(root: Path, n: int = 12) -> tuple[Path, Path]:
    rng = np.random.default_rng(3)
    field, export = root / "field", root / "export"
    (field / "images").mkdir(parents=True)
    (field / "labels").mkdir()
    (export / "train").mkdir(parents=True)
    for i in range(n):
        name = f"{i:04d}"
        # Distinct low-frequency scenes, like different photos.
        img = cv2.resize(rng.integers(0, 255, (6, 8, 3), dtype=np.uint8), (160, 120), interpolation=cv2.INTER_CUBIC)
        cv2.imwrite(str(field / "images" / f"{name}.jpg"), img)
        (field / "labels" / f"{name}.xml").write_text(VOC.format(w=160, h=120, x1=10, y1=20, x2=60, y2=90))
        for k in range(3):
            copy = np.rot90(cv2.resize(img, (104, 104)), (i + k) % 4)
            copy = np.clip(copy.astype(np.int16) + 15 * (k - 1), 0, 255).astype(np.uint8)
            stem = f"{name}_jpg.rf.{k:032x}"
            cv2.imwrite(str(export / "train" / f"{stem}.jpg"), np.ascontiguousarray(copy))
            (export / "train" / f"{stem}.xml").write_text(VOC.format(w=104, h=104, x1=5, y1=5, x2=50, y2=60))
    return field, export


def test_split_is_by_photo_and_stable() -> None:
    names = [f"{i:04d}" for i in range(100)]
    a = split_photos(names, seed=0)
    assert [sum(v == s for v in a.values()) for s in ("train", "valid", "test")] == [75, 10, 15]
    b = split_photos(names + ["extra"], seed=0)
    assert sum(a[n] != b[n] for n in names) <= 2  # hash rank: adding a photo barely moves the others


def test_build_keeps_copies_on_their_photos_side(tmp_path: Path) -> None:
    field, export = _make_sets(tmp_path)
    summary = build_field_dataset(field, tmp_path / "out", export_root=export, with_export=True)
    assert summary.export_match["checked"] == 36 and summary.export_match["best_match_is_named_photo"] == 36
    record = json.loads((tmp_path / "out" / "split.json").read_text())["photos"]
    held = set(record["valid"]) | set(record["test"])
    train_images = [p.name for p in (tmp_path / "out" / "images" / "train").iterdir()]
    copies = [n for n in train_images if n.startswith("export_")]
    assert copies and all(n.removeprefix("export_").split("_jpg")[0] in record["train"] for n in copies)
    assert not any(n.split("_jpg")[0].removeprefix("export_") in held for n in train_images)
    assert summary.export_copies_in_train == 3 * len(record["train"])
    assert summary.export_copies_held_out == 3 * len(held)
    # The held-back photos are also a VOC folder at full frame geometry, for `detect eval`.
    voc = sorted(p.stem for p in (tmp_path / "out" / "field-test").glob("*.jpg"))
    assert voc == record["test"] and cv2.imread(str(next((tmp_path / "out" / "field-test").glob("*.jpg")))).shape == (120, 160, 3)


def test_verify_reports_a_misnamed_copy(tmp_path: Path) -> None:
    field, export = _make_sets(tmp_path, n=6)
    wrong = export / "train" / f"0001_jpg.rf.{0:032x}.jpg"
    (export / "train" / f"0004_jpg.rf.{9:032x}.jpg").write_bytes(wrong.read_bytes())  # photo 1 named as photo 4
    photos = {p.stem: p for p in (field / "images").glob("*.jpg")}
    result = verify_export_matches(photos, sorted((export / "train").glob("*.jpg")))
    assert result["mismatches"] == [f"0004_jpg.rf.{9:032x}.jpg"]
    assert result["best_match_is_named_photo"] == result["checked"] - 1


def test_detect_eval_field_test_scores_the_held_back_photos(tmp_path: Path) -> None:
    """`detect eval --split field-test` scores exactly the photos the dataset builder held back."""
    from insulator_rs.app.cli import main
    from insulator_rs.detection.field_dataset import field_test_images

    field, _ = _make_sets(tmp_path, n=40)
    build_field_dataset(field, tmp_path / "out")
    held = sorted(p.stem for p in (tmp_path / "out" / "field-test").glob("*.jpg"))
    assert [p.stem for p in field_test_images(field)] == held and len(held) == 6
    out = tmp_path / "m.json"
    assert main(["detect", "eval", "--split", "field-test", "--field-photos", str(field), "--json", str(out),
                 "--threads", "1", "--imgsz", "320"]) == 0
    m = json.loads(out.read_text())
    assert m["images"] == 6 and m["instances"] == 6 and m["imgsz"] == [320, 320]
    assert main(["detect", "eval", "--split", "field-test", "--field-photos", str(tmp_path / "none")]) == 2
    assert main(["detect", "eval"]) == 2


def test_field_comparison_before_and_after(tmp_path: Path) -> None:
    """Same model before and after: identical figures; a different input size is scored separately."""
    from insulator_rs.app.train_command import PAPER_MAP, field_comparison
    from insulator_rs.models import model_path

    field, _ = _make_sets(tmp_path, n=40)
    out = field_comparison(model_path("insulator-real"), field, "insulator-real", threads=1)
    assert out["paper_map"] == PAPER_MAP and out["after"]["images"] == 6
    assert out["before"]["map50_95"] == out["after"]["map50_95"] and "before_at_new_imgsz" not in out
    assert "detect eval --split field-test --model insulator-real" in out["command"]


def _field_photos() -> Path | None:
    """``../shared/data/insulator_field_photos`` beside the repository or its main checkout (worktrees)."""
    from helpers.px4_sitl import REPO, _main_checkout

    for root in (REPO, _main_checkout(REPO)):
        folder = root.parent / "shared" / "data" / "insulator_field_photos"
        if (folder / "images").is_dir():
            return folder
    return None


@pytest.mark.slow
def test_shipped_field_model_reproduces_its_card(tmp_path: Path) -> None:
    """`detect eval --split field-test --model insulator-field` gives the card's figures (pycocotools, exact
    to 1e-9 on x86-64, where the card was measured: same photos, same model, deterministic onnxruntime
    CPU), and they meet issue 22's goal (mAP50-95 >= 0.45; issue 12's was 0.35 / 0.75).

    On another CPU (the Jetson's aarch64, under qemu in CI) onnxruntime's kernels round differently
    (NEON against AVX2 FMA): scores move in the 7th digit (the cross-arch test holds the boxes to
    x86-64's) and pycocotools' interpolated precision with them; with the session-21 weights the
    aarch64 mAP50-95 was 0.5671826722 against 0.5671826771 (4.9e-9). There the card is reproduced
    to 1e-6, three orders of magnitude above that and far below any difference between models."""
    from insulator_rs.app.cli import main
    from insulator_rs.models import model_card

    field = _field_photos()
    if field is None:
        pytest.skip("the field photos (../shared/data/insulator_field_photos) are not beside the repository")
    card = model_card("insulator-field")["field_geometry_metrics"]
    out = tmp_path / "m.json"
    assert main(["detect", "eval", "--split", "field-test", "--model", "insulator-field", "--field-photos",
                 str(field), "--json", str(out), "--threads", "2"]) == 0
    m = json.loads(out.read_text())
    after = card["after_insulator_field_640"]
    assert m["images"] == after["images"] == 72 and m["instances"] == after["instances"]
    tol = CARD_TOL_X86 if platform.machine() in ("x86_64", "AMD64") else CARD_TOL_OTHER_CPU
    assert m["map50_95"] == pytest.approx(after["map50_95"], abs=tol)
    assert m["map50"] == pytest.approx(after["map50"], abs=tol)
    assert m["map50_95"] >= 0.45 and m["map50"] >= 0.75 > card["before_insulator_real_320"]["map50"]
