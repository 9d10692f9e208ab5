"""The detector's edge (issue 13 item 4): hostile network outputs are clipped, dropped and counted.

References: a real ONNX graph (built here with the ``onnx`` package) in the
YOLO export format that returns hand-written hostile rows, run through the real
:class:`Detector` on onnxruntime; the expected boxes are computed by hand from
the rows (exact: 320 x 320 images need no letterbox scaling). The sanitiser is
fuzzed with hypothesis: whatever it gets, what it returns is finite, inside the
image, at least ``MIN_SIDE_PX`` wide and high, with scores in [0, 1], and every
input is either kept or counted; valid boxes come back bit-for-bit unchanged.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from helpers.onnx_models import hostile_model
from helpers.photos import PHOTOS
from insulator_rs.detection.detector import Detector
from insulator_rs.detection.sanitize import MIN_SIDE_PX, DroppedDetections, sanitize

NAN, INF = float("nan"), float("inf")

# (cx, cy, w, h, score) rows in network pixels, as a YOLO head emits them; what each must become.
HOSTILE_ROWS = [
    ((100.0, 100.0, 20.0, 40.0, 0.90), "kept [90, 80, 110, 120]"),
    ((NAN, 50.0, 10.0, 10.0, 0.90), "non_finite_box"),
    ((60.0, 60.0, INF, 10.0, 0.90), "non_finite_box"),
    ((200.0, 200.0, -10.0, 10.0, 0.90), "inverted"),
    ((150.0, 320.0, 30.0, 0.0, 0.90), "degenerate: zero height on the bottom edge"),
    ((310.0, 250.0, 40.0, 20.0, 0.80), "kept, clipped to [290, 240, 320, 260]"),
    ((1000.0, 1000.0, 20.0, 20.0, 0.90), "degenerate: wholly outside the image"),
    ((100.0, 100.0, 22.0, 42.0, INF), "bad_score: +Inf would otherwise win NMS over the valid box"),
    ((30.0, 30.0, 10.0, 10.0, NAN), "bad_score"),
    ((250.0, 60.0, 10.0, 10.0, 1.5), "bad_score"),
    ((40.0, 200.0, 10.0, 10.0, -0.5), "below the confidence threshold: not a candidate"),
]


def test_detector_sanitises_a_hostile_model(tmp_path: Path) -> None:
    detector = Detector(hostile_model(tmp_path / "hostile.onnx", [r for r, _ in HOSTILE_ROWS]), conf=0.25)
    det = detector(np.full((320, 320, 3), 90, np.uint8))
    order = np.argsort(det.boxes[:, 0])
    np.testing.assert_array_equal(det.boxes[order], [[90, 80, 110, 120], [290, 240, 320, 260]])
    np.testing.assert_allclose(det.scores[order], [0.9, 0.8], rtol=1e-6)
    assert np.isfinite(det.boxes).all() and ((det.scores >= 0) & (det.scores <= 1)).all()
    assert det.dropped == DroppedDetections(non_finite_box=2, bad_score=3, inverted=1, degenerate=2)
    assert det.dropped.total == 8


def test_detector_on_a_wholly_hostile_model_returns_nothing(tmp_path: Path) -> None:
    rows = [(NAN, NAN, NAN, NAN, NAN), (INF, -INF, INF, INF, INF), (10.0, 10.0, -5.0, -5.0, 0.9)]
    det = Detector(hostile_model(tmp_path / "worst.onnx", rows), conf=0.25)(np.zeros((480, 640, 3), np.uint8))
    assert len(det) == 0 and det.boxes.shape == (0, 4)
    assert det.dropped.total == 3 and det.dropped.non_finite_box == 2 and det.dropped.inverted == 1


def test_detector_on_a_real_model_drops_nothing() -> None:
    """Contrast: the shipped network on a real photo loses no detection to the sanitiser."""
    import cv2

    photo = sorted(PHOTOS.glob("*.jpg"))[0]
    det = Detector.from_name("insulator-real", conf=0.25, threads=1)(cv2.imread(str(photo)))
    assert len(det) > 0 and det.dropped.total == 0


coord = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32),
                  st.floats(min_value=-50, max_value=700, width=32))


@settings(max_examples=300, deadline=None)
@given(boxes=hnp.arrays(np.float32, st.tuples(st.integers(0, 30), st.just(4)), elements=coord),
       scores=st.data(), width=st.integers(1, 640), height=st.integers(1, 640))
def test_sanitize_output_is_always_usable(boxes: np.ndarray, scores: st.DataObject, width: int, height: int) -> None:
    s = scores.draw(hnp.arrays(np.float64, boxes.shape[0], elements=st.floats(allow_nan=True, allow_infinity=True)))
    kept, keep, dropped = sanitize(boxes, s, width, height)
    assert len(keep) + dropped.total == boxes.shape[0]
    assert kept.shape == (len(keep), 4) and np.isfinite(kept).all()
    assert (kept[:, [0, 2]] >= 0).all() and (kept[:, [0, 2]] <= width).all()
    assert (kept[:, [1, 3]] >= 0).all() and (kept[:, [1, 3]] <= height).all()
    assert (kept[:, 2] - kept[:, 0] >= MIN_SIDE_PX).all() and (kept[:, 3] - kept[:, 1] >= MIN_SIDE_PX).all()
    assert ((s[keep] >= 0) & (s[keep] <= 1)).all()


@st.composite
def valid_detections(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, int, int]:
    width, height = draw(st.integers(2, 4000)), draw(st.integers(2, 4000))
    n = draw(st.integers(0, 20))
    rows = []
    for _ in range(n):
        x1 = draw(st.floats(0, width - MIN_SIDE_PX))
        y1 = draw(st.floats(0, height - MIN_SIDE_PX))
        x2 = draw(st.floats(x1 + MIN_SIDE_PX, width))
        y2 = draw(st.floats(y1 + MIN_SIDE_PX, height))
        # Valid means: its width and height as computed in floating point reach MIN_SIDE_PX.
        assume(x2 - x1 >= MIN_SIDE_PX and y2 - y1 >= MIN_SIDE_PX)
        rows.append((x1, y1, x2, y2))
    scores = draw(hnp.arrays(np.float64, n, elements=st.floats(0.0, 1.0)))
    return np.array(rows, np.float64).reshape(-1, 4), scores, width, height


@settings(max_examples=300, deadline=None)
@given(valid_detections())
def test_sanitize_keeps_valid_boxes_unchanged(case: tuple[np.ndarray, np.ndarray, int, int]) -> None:
    boxes, scores, width, height = case
    kept, keep, dropped = sanitize(boxes, scores, width, height)
    assert dropped.total == 0
    np.testing.assert_array_equal(keep, np.arange(len(boxes)))
    np.testing.assert_array_equal(kept, boxes)


def test_sanitize_rejects_mismatched_arguments() -> None:
    with pytest.raises(ValueError, match="scores"):
        sanitize(np.zeros((2, 4)), np.zeros(3), 10, 10)
    with pytest.raises(ValueError, match="image size"):
        sanitize(np.zeros((0, 4)), np.zeros(0), 0, 10)
