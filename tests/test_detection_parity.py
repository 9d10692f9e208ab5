"""The onnxruntime detector against Ultralytics' own predict on the same ONNX model.

Reference: tests/fixtures/detection/ultralytics_predict.json, written by
scripts/make_ultralytics_fixture.py with ``YOLO(model).predict`` (Ultralytics'
letterbox, torch pre-processing, torchvision NMS, scale_boxes) on the committed
photos and exact crops/concatenations of them, at conf 0.25 and 0.01, iou 0.7.
Tolerance: 1e-3 px on boxes, 1e-5 on scores, identical class ids and counts.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from insulator_rs.detection.detector import Detector
from insulator_rs.models import model_path

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "fixtures" / "detection" / "ultralytics_predict.json"
_spec = importlib.util.spec_from_file_location("make_fixture", ROOT / "scripts" / "make_ultralytics_fixture.py")
assert _spec is not None and _spec.loader is not None
make_fixture = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_fixture)

BOX_TOL_PX = 1e-3
SCORE_TOL = 1e-5


@pytest.fixture(scope="module")
def fixture() -> dict:
    return json.loads(FIXTURE.read_text())


def test_fixture_was_made_from_the_shipped_model(fixture: dict) -> None:
    """The fixture is only a reference for the model it was generated from."""
    path = model_path(fixture["model"].removesuffix(".onnx"))
    assert hashlib.sha256(path.read_bytes()).hexdigest() == fixture["model_sha256"], (
        "shipped model changed: rerun scripts/make_ultralytics_fixture.py")
    assert sum(len(c["boxes"]) for c in fixture["cases"]) >= 50  # enough boxes to exercise NMS and mapping


def _sorted(boxes: np.ndarray, scores: np.ndarray, classes: np.ndarray) -> tuple[np.ndarray, ...]:
    order = np.lexsort((boxes[:, 1], boxes[:, 0], -scores))
    return boxes[order], scores[order], classes[order]


def test_detector_matches_ultralytics_predict(fixture: dict) -> None:
    detectors: dict[float, Detector] = {}
    checked = 0
    for case in fixture["cases"]:
        conf = case["conf"]
        if conf not in detectors:
            detectors[conf] = Detector.from_name(fixture["model"].removesuffix(".onnx"), conf=conf, iou=case["iou"],
                                                 warmup=False)
        image = make_fixture.build_image(case)
        assert list(image.shape) == case["shape"]
        det = detectors[conf](image)
        ref_boxes = np.array(case["boxes"], dtype=np.float64).reshape(-1, 4)
        ref_scores = np.array(case["scores"], dtype=np.float64)
        ref_cls = np.array(case["class_ids"], dtype=np.int64)
        where = f"{case['photos']} crop={case['crop']} conf={conf}"
        assert len(det) == len(ref_scores), where
        assert det.boxes.dtype == np.float64 and det.class_ids.dtype == np.int64
        ours = _sorted(det.boxes, det.scores, det.class_ids)
        ref = _sorted(ref_boxes, ref_scores, ref_cls)
        np.testing.assert_allclose(ours[0], ref[0], atol=BOX_TOL_PX, rtol=0, err_msg=where)
        np.testing.assert_allclose(ours[1], ref[1], atol=SCORE_TOL, rtol=0, err_msg=where)
        np.testing.assert_array_equal(ours[2], ref[2], err_msg=where)
        checked += len(det)
    assert checked == sum(len(c["boxes"]) for c in fixture["cases"])
