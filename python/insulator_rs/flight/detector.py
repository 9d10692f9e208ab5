"""The flight loop's detector port: a callable ``image -> boxes``.

``image`` is a (H, W, 3) uint8 BGR frame (:class:`insulator_rs.sensors.CameraFrame`);
the result is (M, 4) or (M, 5) float64 pixel boxes ``x1, y1, x2, y2[, score]`` in that
image, ready for ``ir.points_in_boxes``. Adapters: :class:`NetworkDetector` (a YOLO ONNX
network on onnxruntime) here, and the simulator's ground-truth stand-in
(``insulator_rs.sim.ground_truth_detector``).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from insulator_rs.detection.detector import Detector


class BoxDetector(Protocol):
    def __call__(self, image: np.ndarray) -> np.ndarray: ...


class NetworkDetector:
    """A YOLO network (:class:`insulator_rs.detection.detector.Detector`) as a box detector."""

    def __init__(self, network: Detector) -> None:
        self.network = network
        self.name = network.path.stem

    def __call__(self, image: np.ndarray) -> np.ndarray:
        det = self.network(image)
        return np.column_stack([det.boxes, det.scores]) if len(det) else np.zeros((0, 5))


def detector_name(detector: object) -> str:
    """What the report calls a detector: its ``name``, else its type's name."""
    return str(getattr(detector, "name", type(detector).__name__))
