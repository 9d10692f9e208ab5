"""The ground-truth detector: the simulator's true boxes, degraded like a detector's output.

A simulator-side adapter of the flight loop's detector port (a callable image -> boxes):
it looks up the true insulator boxes of the detection image that
:class:`~insulator_rs.sim.sensors.SimulatedSensors` rendered, and degrades them with the
:class:`~insulator_rs.sim.detector_standin.DetectorStandin` (box jitter, misses, false
positives). It only works on the simulator's own frames, by construction: no real flight can
use it by mistake. The YOLO network is the other adapter
(:class:`insulator_rs.ports.detector.NetworkDetector`).

An inspection photo (the flight checks each one with its detector) is degraded by a second
stand-in of its own (:data:`PHOTO_JITTER`, no misses, no false boxes, its own random stream):
checking the photos leaves the detection frames' boxes, and every figure of a flight, as they
were.
"""

from __future__ import annotations

import numpy as np

from insulator_rs.sim.detector_standin import DetectorStandin
from insulator_rs.sim.sensors import SimulatedSensors

#: Box jitter (sigma, share of the box's size per edge) of the stand-in on inspection photos. A
#: detector's box on a string that fills a 12 MP frame is tight: edges to about 1 % (the 5 % of
#: the detection frames' stand-in, ~135 px on a 2700 px string, is a far view's error).
PHOTO_JITTER = 0.01
#: Offset of the photo stand-in's seed from the detection frames': its own random stream.
PHOTO_SEED_OFFSET = 7919


class GroundTruthDetector:
    """``detector(image) -> (M, 5) boxes x1, y1, x2, y2, score`` from the simulator's truth."""

    name = "ground-truth stand-in (simulator boxes, jittered)"

    def __init__(self, sensors: SimulatedSensors, standin: DetectorStandin | None = None, *,
                 seed: int = 0) -> None:
        self.sensors = sensors
        self.standin = standin if standin is not None else DetectorStandin(seed=seed)
        self.photo_standin = DetectorStandin(jitter=PHOTO_JITTER, seed=seed + PHOTO_SEED_OFFSET)

    def __call__(self, image: np.ndarray) -> np.ndarray:
        truth = self.sensors.ground_truth_boxes(image)
        if not truth:
            return np.zeros((0, 5))
        ids = list(truth)
        h, w = image.shape[:2]
        standin = self.photo_standin if self.sensors.is_photo(image) else self.standin
        return standin.detect(np.array([truth[i] for i in ids]), (w, h), ids).boxes

