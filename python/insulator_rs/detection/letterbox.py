"""Ultralytics' letterbox: resize keeping the aspect ratio, pad with gray 114.

The geometry reproduces ``ultralytics.data.augment.LetterBox`` (``auto=False``,
``scaleup=True``, ``center=True``) and ``ultralytics.utils.ops.scale_boxes``
to the rounding: the resized size is ``round(side * r)`` per axis (at least 1
pixel), the padding is split as ``round(d/2 - 0.1)`` before and
``round(d/2 + 0.1)`` after (Python's round-half-to-even, like Ultralytics), and
boxes are mapped back with the per-axis gains ``new_w / w0`` and ``new_h / h0``.
With ``auto=True`` (what Ultralytics' predict does for models with a dynamic
input, ``rect=True``) the padding is only what reaches the next multiple of the
stride, so a 640x480 frame becomes a 640x480 input instead of 640x640.
Boxes are mapped back with the letterbox actually applied; Ultralytics'
``scale_boxes`` re-derives the gain from the padded input, which in rect mode
differs (by up to ~0.3 %) for rare sizes such as 251x501 into 320.

The resize is ``insulator_rs._core.resize_linear`` (Rust): the bytes of OpenCV's
``cv2.resize(INTER_LINEAR)`` on x86-64, in integer arithmetic, so the network
sees the same input on the x86 workstation and on the Jetson's aarch64 CPU
(OpenCV's own aarch64 build differs by +-1 in about a fifth of the values).

All coordinates are pixels, x right and y down, origin at the top-left corner
of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from insulator_rs._core import resize_linear

PAD_VALUE = 114


@dataclass(frozen=True)
class LetterboxGeometry:
    """How an original image of ``orig_hw`` sits inside a network input of ``input_hw``."""

    orig_hw: tuple[int, int]
    input_hw: tuple[int, int]
    resized_wh: tuple[int, int]  # (new_w, new_h) after resizing, before padding
    pad_top: int
    pad_bottom: int
    pad_left: int
    pad_right: int

    @property
    def gain_xy(self) -> tuple[float, float]:
        """Per-axis scale (input pixels per original pixel), as ``scale_boxes`` derives it."""
        return self.resized_wh[0] / self.orig_hw[1], self.resized_wh[1] / self.orig_hw[0]

    def to_input(self, boxes: np.ndarray) -> np.ndarray:
        """Map (M, 4) x1, y1, x2, y2 boxes from original to network-input pixels."""
        gx, gy = self.gain_xy
        out = np.array(boxes, dtype=np.float64, copy=True).reshape(-1, 4)
        out[:, [0, 2]] = out[:, [0, 2]] * gx + self.pad_left
        out[:, [1, 3]] = out[:, [1, 3]] * gy + self.pad_top
        return out

    def to_original(self, boxes: np.ndarray, *, clip: bool = True) -> np.ndarray:
        """Map (M, 4) x1, y1, x2, y2 boxes from network-input to original pixels.

        The arithmetic runs in the boxes' own float dtype (float32 from the
        network, as Ultralytics does) and ``clip`` clamps to [0, w] x [0, h].
        """
        out = np.array(boxes, copy=True).reshape(-1, 4)
        if not np.issubdtype(out.dtype, np.floating):
            out = out.astype(np.float64)
        gx, gy = self.gain_xy
        out[:, [0, 2]] -= self.pad_left
        out[:, [1, 3]] -= self.pad_top
        out[:, [0, 2]] /= out.dtype.type(gx)
        out[:, [1, 3]] /= out.dtype.type(gy)
        if clip:
            h, w = self.orig_hw
            out[:, [0, 2]] = out[:, [0, 2]].clip(0, w)
            out[:, [1, 3]] = out[:, [1, 3]].clip(0, h)
        return out


def letterbox_geometry(
    orig_hw: tuple[int, int], input_hw: tuple[int, int], *, auto: bool = False, stride: int = 32
) -> LetterboxGeometry:
    """Geometry of letterboxing an ``orig_hw`` (height, width) image into ``input_hw``.

    ``auto``: pad only up to a multiple of ``stride`` (minimum rectangle); the
    network input is then smaller than ``input_hw`` on one axis.
    """
    h0, w0 = (int(v) for v in orig_hw)
    hi, wi = (int(v) for v in input_hw)
    if h0 < 1 or w0 < 1:
        raise ValueError(f"orig_hw must be positive, got {orig_hw}")
    if hi < 1 or wi < 1:
        raise ValueError(f"input_hw must be positive, got {input_hw}")
    r = min(hi / h0, wi / w0)
    new_w, new_h = max(round(w0 * r), 1), max(round(h0 * r), 1)
    dw_total, dh_total = wi - new_w, hi - new_h
    if auto:
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        dw_total, dh_total = dw_total % stride, dh_total % stride
    dw, dh = dw_total / 2, dh_total / 2
    return LetterboxGeometry(
        orig_hw=(h0, w0),
        input_hw=(new_h + dh_total, new_w + dw_total),
        resized_wh=(new_w, new_h),
        pad_top=round(dh - 0.1),
        pad_bottom=round(dh + 0.1),
        pad_left=round(dw - 0.1),
        pad_right=round(dw + 0.1),
    )


def letterbox(
    image: np.ndarray, input_hw: tuple[int, int], *, auto: bool = False, stride: int = 32
) -> tuple[np.ndarray, LetterboxGeometry]:
    """Letterbox an (H, W, 3) uint8 image into ``input_hw``; returns (padded image, geometry)."""
    geo = letterbox_geometry(image.shape[:2], input_hw, auto=auto, stride=stride)
    if (image.shape[1], image.shape[0]) != geo.resized_wh:
        image = resize_linear(image, *geo.resized_wh)
    padded = cv2.copyMakeBorder(
        image, geo.pad_top, geo.pad_bottom, geo.pad_left, geo.pad_right,
        cv2.BORDER_CONSTANT, value=(PAD_VALUE, PAD_VALUE, PAD_VALUE),
    )
    return padded, geo


def to_network_input(letterboxed_bgr: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 BGR -> (1, 3, H, W) float32 RGB in [0, 1], as Ultralytics feeds it."""
    chw = np.ascontiguousarray(letterboxed_bgr[:, :, ::-1].transpose(2, 0, 1))
    return (chw.astype(np.float32) / np.float32(255.0))[None]
