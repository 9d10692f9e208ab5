"""The flight loop's detector port: a callable ``image -> boxes``.

``image`` is a (H, W, 3) uint8 BGR frame (:class:`insulator_rs.ports.sensors.CameraFrame`);
the result is (M, 4) or (M, 5) float64 pixel boxes ``x1, y1, x2, y2[, score]`` in that
image, ready for ``ir.points_in_boxes``. Adapters: :class:`NetworkDetector` (a YOLO ONNX
network on onnxruntime) here, and the simulator's ground-truth stand-in
(``insulator_rs.sim.ground_truth_detector``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from insulator_rs.detection.detector import Detections as Detections  # the port hands these on (replay read-ahead)
from insulator_rs.detection.detector import Detector, open_detector
from insulator_rs.detection.sanitize import DroppedDetections
from insulator_rs.models import REAL_PHOTO_MODEL, SIMULATOR_MODEL
from insulator_rs.ports.capabilities import CountsDrops, Named

STANDIN = "standin"  # --detector standin: the simulator's ground-truth stand-in, by name only
DETECT_CONF = 0.25  # detection-event confidence threshold of a network (Ultralytics predict default)


def default_model(live_camera: bool) -> str:
    """The shipped network that fits the camera the flight sees: rendered frames or a real camera."""
    return REAL_PHOTO_MODEL if live_camera else SIMULATOR_MODEL


class BoxDetector(Protocol):
    def __call__(self, image: np.ndarray) -> np.ndarray: ...


class NetworkDetector:
    """A YOLO network (:class:`insulator_rs.detection.detector.Detector`) as a box detector."""

    def __init__(self, network: Detector) -> None:
        self.network = network
        self.name = network.path.stem
        self.dropped = DroppedDetections()  # summed over the flight: what the sanitiser refused

    def __call__(self, image: np.ndarray) -> np.ndarray:
        return self.boxes(self.network(image))

    def detect_batch(self, images: Sequence[np.ndarray]) -> list[Detections]:
        """The network on several frames in one run (a replay reading ahead); each result becomes
        the port's boxes through :meth:`boxes` when its frame is asked for."""
        return self.network.detect_batch(images)

    def boxes(self, det: Detections) -> np.ndarray:
        """The network's detections of one frame as the port's boxes (what the sanitiser dropped
        is summed): for detections run ahead of the loop (a replay's batches) as for a call."""
        self.dropped = self.dropped + det.dropped
        return np.column_stack([det.boxes, det.scores]) if len(det) else np.zeros((0, 5))


def detector_name(detector: object) -> str:
    """What the report calls a detector: its ``name``, else its type's name."""
    return str(detector.name) if isinstance(detector, Named) else type(detector).__name__


def detections_dropped(detector: object) -> dict[str, int] | None:
    """The sanitiser's counts summed over the flight (a network), None for a detector without them."""
    dropped = detector.dropped if isinstance(detector, CountsDrops) else None
    return dropped.to_dict() if isinstance(dropped, DroppedDetections) else None


def open_network_detector(model: str, *, conf: float = DETECT_CONF, threads: int | None = None,
                          spinning: bool = True) -> NetworkDetector:
    """A shipped network (by name) or an ONNX file as the flight's box detector (``threads``
    and ``spinning``: see :class:`~insulator_rs.detection.detector.Detector`). ModelError (a
    ValueError) for a missing, truncated or foreign model."""
    return NetworkDetector(open_detector(model, conf=conf, threads=threads, spinning=spinning))
