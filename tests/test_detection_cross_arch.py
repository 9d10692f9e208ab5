"""The detector on this CPU against its committed x86-64 output (the Jetson runs aarch64).

Reference: tests/fixtures/detection/x86_detections.json, written on x86-64 by
scripts/make_x86_detections.py (each shipped model, the committed photos and
crops/pairs of them, conf 0.25 and 0.01). scripts/test-aarch64.sh runs this file
on aarch64 under qemu; the main suites run it on x86-64.

* Pre-processing: the network input tensor is the same bytes on every CPU
  (SHA-256 equal): the letterbox resize is the integer kernel
  ``_core.resize_linear``, not OpenCV's CPU-dependent ``cv2.resize``.
* Detections: the same count and class ids; boxes within BOX_TOL_PX and scores
  within SCORE_TOL. What is left to differ is onnxruntime's float arithmetic
  (its x86 AVX2/AVX-512 and aarch64 NEON kernels sum in different orders; measured
  under qemu: see README, "The Jetson's CPU in CI"). On x86-64 the match is
  exact up to onnxruntime version changes.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import platform
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from insulator_rs.detection.detector import Detector
from insulator_rs.models import model_path

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "fixtures" / "detection" / "x86_detections.json"
_spec = importlib.util.spec_from_file_location("make_x86", ROOT / "scripts" / "make_x86_detections.py")
assert _spec is not None and _spec.loader is not None
make_x86 = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_x86)
make_fixture = make_x86._load_fixture_module()

BOX_TOL_PX = 1e-3
SCORE_TOL = 1e-5


@pytest.fixture(scope="module")
def reference() -> dict:
    return json.loads(FIXTURE.read_text())


def test_reference_is_x86_and_of_the_shipped_models(reference: dict) -> None:
    assert reference["machine"] in ("x86_64", "AMD64")
    for name, digest in reference["models"].items():
        assert hashlib.sha256(model_path(name).read_bytes()).hexdigest() == digest, (
            f"shipped model {name} changed: rerun scripts/make_x86_detections.py on x86-64")
    assert sum(len(r["scores"]) for r in reference["runs"]) >= 100


def _sorted(boxes: np.ndarray, scores: np.ndarray, classes: np.ndarray) -> tuple[np.ndarray, ...]:
    order = np.lexsort((boxes[:, 1], boxes[:, 0], -scores))
    return boxes[order], scores[order], classes[order]


@pytest.mark.parametrize("model", make_x86.MODELS)
def test_detections_match_the_x86_reference(reference: dict, model: str) -> None:
    detectors: dict[float, Detector] = {}
    runs = [r for r in reference["runs"] if r["model"] == model]
    assert runs
    # The network runs once per image; each reference conf decodes that one output (Detector.decode,
    # what detect does after the pass). Under qemu-aarch64 a pass costs ~16 s, and the runs at
    # conf 0.25 and 0.01 share their images: half the passes, the same comparisons.
    passes: dict[str, tuple[np.ndarray, Any]] = {}
    worst_box, worst_score = 0.0, 0.0
    for run in runs:
        conf = run["conf"]
        if conf not in detectors:
            detectors[conf] = Detector.from_name(model, conf=conf, warmup=False, threads=1)
        det = detectors[conf]
        image = make_fixture.build_image(run)
        where = f"{model} {run['photos']} crop={run['crop']} conf={conf} on {platform.machine()}"
        assert list(image.shape) == run["shape"], where
        assert make_x86.network_input_sha256(det, image) == run["input_sha256"], f"network input differs: {where}"
        key = hashlib.sha256(image.tobytes()).hexdigest() + str(image.shape)
        if key not in passes:
            passes[key] = det.raw(image)
        found = det.decode(*passes[key])
        ref_boxes = np.array(run["boxes"], dtype=np.float64).reshape(-1, 4)
        assert len(found) == len(run["scores"]), where
        ours = _sorted(found.boxes, found.scores, found.class_ids)
        ref = _sorted(ref_boxes, np.array(run["scores"]), np.array(run["class_ids"], dtype=np.int64))
        np.testing.assert_array_equal(ours[2], ref[2], err_msg=where)
        np.testing.assert_allclose(ours[0], ref[0], atol=BOX_TOL_PX, rtol=0, err_msg=where)
        np.testing.assert_allclose(ours[1], ref[1], atol=SCORE_TOL, rtol=0, err_msg=where)
        if len(found):
            worst_box = max(worst_box, float(np.abs(ours[0] - ref[0]).max()))
            worst_score = max(worst_score, float(np.abs(ours[1] - ref[1]).max()))
    print(f"{model} on {platform.machine()}: worst box {worst_box:.2e} px, worst score {worst_score:.2e}")
