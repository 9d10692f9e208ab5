"""The detector runtime: loading, bad models, bad images, conversions, the shipped model.

References: the VOC labels of the committed test photos (IoU >= 0.5), and the
same image given as BGR for the gray/BGRA conversions (identical results).
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.photos import PHOTOS

from insulator_rs.detection.detector import Detector, as_bgr_uint8, select_providers
from insulator_rs.detection.evaluate import load_split
from insulator_rs.exceptions import ModelError
from insulator_rs.models import available_models, model_card, model_path

FIXTURES = Path(__file__).parent / "fixtures" / "detection"
MATCH_IOU = 0.5


@pytest.fixture(scope="module")
def detector() -> Detector:
    return Detector.from_name("insulator-real", threads=2)


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU of (N, 4) and (M, 4) x1 y1 x2 y2 boxes."""
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(rb - lt, 0, None), axis=2)
    area = lambda x: (x[:, 2] - x[:, 0]) * (x[:, 3] - x[:, 1])  # noqa: E731
    return inter / (area(a)[:, None] + area(b)[None, :] - inter)


def test_shipped_model_loads_with_metadata_and_card(detector: Detector) -> None:
    assert "insulator-real" in available_models()
    assert detector.names == {0: "insulator"}
    card = model_card("insulator-real")
    assert tuple(detector.imgsz) == (card["imgsz"], card["imgsz"])
    # The card describes this very file, and its held-back-split figures are consistent.
    assert card["sha256"] == hashlib.sha256(model_path("insulator-real").read_bytes()).hexdigest()
    tm = card["test_metrics"]
    assert 0.0 <= tm["map50_95"] <= tm["map50"] <= 1.0 and tm["images"] == card["data"]["images"]["test"]
    assert "CPUExecutionProvider" in detector.providers


def test_shipped_model_finds_insulators_on_real_photos(detector: Detector) -> None:
    """Most labelled insulators in the held-back photos are found with IoU >= 0.5, and few false boxes."""
    samples = load_split(PHOTOS)
    found = total = false_pos = 0
    for s in samples:
        det = detector(cv2.imread(str(s.image)))
        total += len(s.boxes)
        if len(det) == 0:
            continue
        iou = iou_matrix(s.boxes, det.boxes)
        found += int((iou.max(axis=1) >= MATCH_IOU).sum())
        false_pos += int((iou.max(axis=0) < MATCH_IOU).sum())
    assert found / total >= 0.5, f"found {found} of {total}"
    assert false_pos <= total, f"{false_pos} false boxes for {total} insulators"


def test_dynamic_input_size_from_metadata_and_override(detector: Detector) -> None:
    """The shipped export has a dynamic height/width: metadata imgsz by default, 640 on request."""
    card = model_card("insulator-real")
    assert detector.dynamic
    assert detector.imgsz == (card["imgsz"], card["imgsz"])
    big = Detector.from_name("insulator-real", imgsz=640, threads=2)
    assert big.imgsz == (640, 640)
    image = cv2.imread(str(next(PHOTOS.glob("*.jpg"))))
    raw, geo = big.raw(image)
    assert raw.shape[0] == 1 and raw.shape[1] == 5 and raw.shape[2] == (640 // 8) ** 2 + (640 // 16) ** 2 + (640 // 32) ** 2
    assert geo.input_hw == (640, 640)
    # Rect mode (Ultralytics' predict for dynamic models): a 480x640 frame is not padded to a square.
    _, geo_rect = big.raw(cv2.resize(image, (640, 480)))
    assert geo_rect.input_hw == (480, 640)


def test_output_types_ready_for_points_in_boxes(detector: Detector) -> None:
    det = detector(cv2.imread(str(next(PHOTOS.glob("*.jpg")))))
    assert det.boxes.dtype == np.float64 and det.boxes.ndim == 2 and det.boxes.shape[1] == 4
    assert det.scores.dtype == np.float64 and det.class_ids.dtype == np.int64
    assert det.boxes.flags.c_contiguous
    assert (det.boxes[:, 2] >= det.boxes[:, 0]).all() and (det.boxes[:, 3] >= det.boxes[:, 1]).all()


def test_missing_model_file() -> None:
    with pytest.raises(ModelError, match="file not found"):
        Detector("no/such/model.onnx")


def test_truncated_model_file(tmp_path: Path) -> None:
    data = model_path("insulator-real").read_bytes()
    cut = tmp_path / "cut.onnx"
    cut.write_bytes(data[: len(data) // 3])
    with pytest.raises(ModelError, match="truncated or not ONNX"):
        Detector(cut)
    tiny = tmp_path / "tiny.onnx"
    tiny.write_bytes(b"\x08\x07")
    with pytest.raises(ModelError, match="truncated or not ONNX"):
        Detector(tiny)


@pytest.mark.parametrize("name", ["not_yolo_identity.onnx", "not_yolo_no_classes.onnx"])
def test_non_yolo_models(name: str) -> None:
    with pytest.raises(ModelError, match="not a YOLO detection export"):
        Detector(FIXTURES / name)


def test_model_errors_are_value_errors_and_name_the_file(tmp_path: Path) -> None:
    path = tmp_path / "x.onnx"
    shutil.copy(FIXTURES / "not_yolo_identity.onnx", path)
    with pytest.raises(ValueError, match=str(path)):
        Detector(path)


def test_unknown_shipped_model_name() -> None:
    with pytest.raises(ValueError, match="no shipped model 'nope'"):
        Detector.from_name("nope")


@pytest.mark.parametrize(
    ("image", "error", "match"),
    [
        (np.zeros((32, 32, 3), np.float32), TypeError, "dtype uint8"),
        ([[0, 0], [0, 0]], TypeError, "numpy array"),
        (np.zeros((32, 32, 5), np.uint8), ValueError, "1, 3 or 4 channels"),
        (np.zeros((0, 32, 3), np.uint8), ValueError, "empty"),
        (np.zeros((2, 32, 32, 3), np.uint8), ValueError, "shape"),
    ],
)
def test_bad_images(detector: Detector, image: object, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        detector(image)  # type: ignore[arg-type]


def test_gray_and_bgra_are_converted(detector: Detector) -> None:
    bgr = cv2.imread(str(next(PHOTOS.glob("*.jpg"))))
    gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    ref_gray = detector(cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR))
    for variant in (gray, gray[:, :, None]):
        got = detector(variant)
        np.testing.assert_array_equal(got.boxes, ref_gray.boxes)
    bgra = cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA)
    bgra[..., 3] = 7  # alpha must be ignored
    np.testing.assert_array_equal(detector(bgra).boxes, detector(bgr).boxes)
    assert as_bgr_uint8(bgr) is bgr  # no copy for BGR input


def test_provider_order_and_bad_knobs() -> None:
    assert select_providers(["CPUExecutionProvider", "CUDAExecutionProvider", "TensorrtExecutionProvider"]) == [
        "TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider"]
    assert select_providers(["CPUExecutionProvider", "AzureExecutionProvider"]) == ["CPUExecutionProvider"]
    with pytest.raises(RuntimeError, match="none of"):
        select_providers(["AzureExecutionProvider"])
    path = model_path("insulator-real")
    for kwargs, match in (({"conf": 1.5}, "conf"), ({"iou": -1}, "iou"), ({"threads": 0}, "threads"),
                          ({"max_det": 0}, "max_det"), ({"imgsz": 100}, "multiples of 32")):
        with pytest.raises(ValueError, match=match):
            Detector(path, warmup=False, **kwargs)  # type: ignore[arg-type]
