"""YOLO head decoding and NMS.

References: a plain-Python greedy NMS written from the definition (below,
exact index equality), ``torchvision.ops.nms`` when the train extra is installed
(exact index equality on tie-free scores), and hand-built head outputs.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from insulator_rs.detection.postprocess import MAX_WH, decode_yolo, nms, xywh_to_xyxy


def reference_nms(boxes: list[list[float]], scores: list[float], thr: float) -> list[int]:
    """Greedy NMS from the definition: visit by descending score, keep unless IoU > thr with a kept box."""
    def iou(a: list[float], b: list[float]) -> float:
        iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
        ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
        inter = iw * ih
        union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
        return inter / union if union > 0 else 0.0

    keep: list[int] = []
    for i in sorted(range(len(scores)), key=lambda k: -scores[k]):
        if all(iou(boxes[i], boxes[k]) <= thr for k in keep):
            keep.append(i)
    return keep


box_sets = st.integers(1, 60).flatmap(lambda n: st.tuples(
    st.lists(st.tuples(st.floats(0, 300), st.floats(0, 300), st.floats(1, 120), st.floats(1, 120)),
             min_size=n, max_size=n),
    st.permutations(list(range(n))),
))


@settings(max_examples=60, deadline=None)
@given(data=box_sets, thr=st.sampled_from([0.3, 0.5, 0.7]))
def test_nms_matches_definition(data, thr: float) -> None:
    """Kept indices equal the plain-Python greedy reference (distinct scores, float64 boxes)."""
    raw, perm = data
    boxes = np.array([[x, y, x + w, y + h] for x, y, w, h in raw], dtype=np.float64)
    scores = (np.array(perm, dtype=np.float64) + 1) / (len(perm) + 1)
    assert nms(boxes, scores, thr).tolist() == reference_nms(boxes.tolist(), scores.tolist(), thr)


@pytest.mark.slow  # torchvision's NMS per example: about 11 s
@settings(max_examples=20, deadline=None)
@given(data=box_sets, thr=st.sampled_from([0.45, 0.7]))
def test_nms_matches_torchvision(data, thr: float) -> None:
    """Exact kept indices against torchvision.ops.nms (what Ultralytics calls), float32 boxes."""
    torch = pytest.importorskip("torch")
    torchvision = pytest.importorskip("torchvision")
    raw, perm = data
    boxes = np.array([[x, y, x + w, y + h] for x, y, w, h in raw], dtype=np.float32)
    scores = ((np.array(perm) + 1) / (len(perm) + 1)).astype(np.float32)
    ref = torchvision.ops.nms(torch.from_numpy(boxes), torch.from_numpy(scores), thr).numpy()
    np.testing.assert_array_equal(nms(boxes, scores, thr), ref)


def test_nms_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="iou_threshold"):
        nms(np.zeros((1, 4)), np.zeros(1), 1.5)
    with pytest.raises(ValueError, match="boxes"):
        nms(np.zeros((2, 3)), np.zeros(2), 0.5)


def _head(rows: list[tuple[float, float, float, float, list[float]]]) -> np.ndarray:
    """A [1, 4 + nc, N] head output from (cx, cy, w, h, class scores) rows."""
    return np.array([[cx, cy, w, h, *cls] for cx, cy, w, h, cls in rows], dtype=np.float32).T[None]


def test_decode_threshold_best_class_and_class_aware_nms() -> None:
    out = _head([
        (50, 50, 20, 40, [0.9, 0.1]),   # kept, class 0
        (51, 50, 20, 40, [0.8, 0.1]),   # overlaps the first, same class: suppressed
        (51, 50, 20, 40, [0.1, 0.85]),  # same place, other class: kept (class-aware)
        (200, 80, 10, 10, [0.25, 0.2]),  # exactly at conf: dropped (strict >)
        (150, 150, 30, 30, [0.3, 0.6]),  # best class 1
    ])
    det = decode_yolo(out, conf=0.25, iou=0.7)
    assert det.class_ids.tolist() == [0, 1, 1]
    np.testing.assert_allclose(det.scores, [0.9, 0.85, 0.6], rtol=1e-6)
    np.testing.assert_allclose(det.boxes[0], [40, 30, 60, 70])
    np.testing.assert_allclose(det.boxes[2], [135, 135, 165, 165])
    agnostic = decode_yolo(out, conf=0.25, iou=0.7, agnostic=True)
    assert agnostic.class_ids.tolist() == [0, 1]  # the class-1 twin is now suppressed by the class-0 box
    assert decode_yolo(out, conf=0.25, iou=0.7, max_det=1).scores.shape == (1,)


def test_decode_empty_and_bad_shapes() -> None:
    none = decode_yolo(_head([(5, 5, 2, 2, [0.1])]), conf=0.25, iou=0.7)
    assert none.boxes.shape == (0, 4) and none.scores.shape == (0,) and none.class_ids.dtype == np.int64
    with pytest.raises(ValueError, match="4 \\+ nc"):
        decode_yolo(np.zeros((1, 4, 10), np.float32), conf=0.25, iou=0.7)
    with pytest.raises(ValueError, match="batch"):
        decode_yolo(np.zeros((2, 5, 10), np.float32), conf=0.25, iou=0.7)
    with pytest.raises(ValueError, match="conf"):
        decode_yolo(np.zeros((1, 5, 10), np.float32), conf=-0.1, iou=0.7)


def test_xywh_to_xyxy_and_class_offset_exceeds_any_image() -> None:
    np.testing.assert_allclose(xywh_to_xyxy(np.array([[10.0, 20.0, 4.0, 6.0]])), [[8, 17, 12, 23]])
    assert MAX_WH >= 7680  # larger than any input side, so offset classes never overlap
