"""Decode a YOLO11/YOLOv8 detection head and suppress duplicates.

The raw output is ``[1, 4 + nc, N]``: per anchor, a box centre/size
(cx, cy, w, h) in network-input pixels followed by ``nc`` class scores that are
already sigmoid (no objectness). :func:`decode_yolo` follows
``ultralytics.utils.nms.non_max_suppression`` with its defaults for detection
(best class per anchor, strict ``> conf`` threshold, at most ``max_nms``
candidates by score, class-aware NMS by offsetting boxes by ``class * 7680``,
``max_det`` kept) and :func:`nms` follows ``torchvision.ops.nms`` (greedy by
descending score, suppress IoU strictly above the threshold, areas without +1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_WH = 7680  # Ultralytics' class offset for class-aware NMS (pixels)
MAX_NMS = 30000  # most candidates handed to NMS


@dataclass(frozen=True)
class RawDetections:
    """Kept detections in network-input pixels (float32, as the network gives them)."""

    boxes: np.ndarray  # (M, 4) x1, y1, x2, y2
    scores: np.ndarray  # (M,)
    class_ids: np.ndarray  # (M,) int64


def xywh_to_xyxy(xywh: np.ndarray) -> np.ndarray:
    """(N, 4) centre x, centre y, width, height -> (N, 4) x1, y1, x2, y2 (same dtype)."""
    out = np.empty_like(xywh)
    half_w, half_h = xywh[:, 2] / 2, xywh[:, 3] / 2
    out[:, 0] = xywh[:, 0] - half_w
    out[:, 1] = xywh[:, 1] - half_h
    out[:, 2] = xywh[:, 0] + half_w
    out[:, 3] = xywh[:, 1] + half_h
    return out


def nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Greedy non-maximum suppression; returns kept indices by descending score.

    A box is dropped when its IoU with an already kept, higher-scoring box is
    strictly greater than ``iou_threshold`` (torchvision semantics). IoU of each
    kept box against all remaining ones is computed at once (vectorised).
    """
    if not 0.0 <= iou_threshold <= 1.0:
        raise ValueError(f"iou_threshold must be in [0, 1], got {iou_threshold}")
    boxes = np.asarray(boxes)
    scores = np.asarray(scores)
    if boxes.ndim != 2 or boxes.shape[1] != 4 or scores.shape != (boxes.shape[0],):
        raise ValueError(f"boxes must be (N, 4) and scores (N,), got {boxes.shape} and {scores.shape}")
    order = np.argsort(-scores, kind="stable")
    x1, y1, x2, y2 = (boxes[:, i] for i in range(4))
    areas = (x2 - x1) * (y2 - y1)
    keep = []
    while order.size:
        i = order[0]
        keep.append(i)
        rest = order[1:]
        w = np.clip(np.minimum(x2[i], x2[rest]) - np.maximum(x1[i], x1[rest]), 0, None)
        h = np.clip(np.minimum(y2[i], y2[rest]) - np.maximum(y1[i], y1[rest]), 0, None)
        inter = w * h
        iou = inter / (areas[i] + areas[rest] - inter)
        order = rest[~(iou > iou_threshold)]  # NaN IoU (zero-area pairs) keeps the box, as torchvision does
    return np.asarray(keep, dtype=np.int64)


def yolo_candidates(output: np.ndarray, *, conf: float) -> RawDetections:
    """Anchors of one image's head output ``[1, 4 + nc, N]`` (or ``[4 + nc, N]``) worth keeping, before NMS.

    Kept: best class score strictly above ``conf`` (Ultralytics), and also any
    non-finite score, so that the sanitiser can count it instead of it
    vanishing silently (NaN compares false) or winning NMS (+Inf). At most
    ``MAX_NMS`` by score.
    """
    if not 0.0 <= conf <= 1.0:
        raise ValueError(f"conf must be in [0, 1], got {conf}")
    pred = np.asarray(output)
    if pred.ndim == 3:
        if pred.shape[0] != 1:
            raise ValueError(f"output must hold one image, got batch {pred.shape[0]}")
        pred = pred[0]
    if pred.ndim != 2 or pred.shape[0] < 5:
        raise ValueError(f"output must be [1, 4 + nc, N] with nc >= 1, got {np.shape(output)}")
    pred = pred.T  # (N, 4 + nc)
    cls = pred[:, 4:]
    with np.errstate(invalid="ignore"):
        best = np.nan_to_num(cls, nan=-np.inf).argmax(axis=1)
        score = cls[np.arange(cls.shape[0]), best]
        cand = np.flatnonzero((score > conf) | ~np.isfinite(score))
    if cand.size == 0:
        return RawDetections(np.zeros((0, 4), pred.dtype), np.zeros(0, pred.dtype), np.zeros(0, np.int64))
    if cand.size > MAX_NMS:
        cand = cand[np.argsort(-np.nan_to_num(score[cand], nan=np.inf), kind="stable")[:MAX_NMS]]
    with np.errstate(invalid="ignore", over="ignore"):
        boxes = xywh_to_xyxy(pred[cand, :4])
    return RawDetections(boxes, score[cand], best[cand].astype(np.int64))


def suppress(cands: RawDetections, *, iou: float, max_det: int = 300, agnostic: bool = False) -> RawDetections:
    """Class-aware (or agnostic) NMS over candidates, at most ``max_det`` kept, by descending score."""
    if max_det < 1:
        raise ValueError(f"max_det must be >= 1, got {max_det}")
    if cands.boxes.shape[0] == 0:
        return cands
    offset = (0 if agnostic else MAX_WH) * cands.class_ids.astype(cands.boxes.dtype)
    keep = nms(cands.boxes + offset[:, None], cands.scores, iou)[:max_det]
    return RawDetections(cands.boxes[keep], cands.scores[keep], cands.class_ids[keep])


def decode_yolo(
    output: np.ndarray,
    *,
    conf: float,
    iou: float,
    max_det: int = 300,
    agnostic: bool = False,
) -> RawDetections:
    """Turn one image's head output ``[1, 4 + nc, N]`` (or ``[4 + nc, N]``) into kept boxes.

    No sanitising: this is Ultralytics' decode (parity tests); the detector
    sanitises candidates in image pixels between :func:`yolo_candidates` and
    :func:`suppress`.
    """
    if max_det < 1:
        raise ValueError(f"max_det must be >= 1, got {max_det}")
    cands = yolo_candidates(output, conf=conf)
    finite = np.isfinite(cands.scores)
    cands = RawDetections(cands.boxes[finite], cands.scores[finite], cands.class_ids[finite])
    return suppress(cands, iou=iou, max_det=max_det, agnostic=agnostic)
