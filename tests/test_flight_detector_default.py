"""inspect's detector: the shipped network that fits the camera by default, the stand-in only by name;
the sanitiser's counts summed over a flight (a hostile ONNX model as the network)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from insulator_rs.detection.detector import Detector
from insulator_rs.ports.detector import (REAL_PHOTO_MODEL, SIMULATOR_MODEL, NetworkDetector, default_model,
                                          detections_dropped)
from insulator_rs.app.inspect_command import load_network
from helpers.onnx_models import hostile_model


def test_default_network_fits_the_camera() -> None:
    assert default_model(live_camera=False) == SIMULATOR_MODEL == "insulator-sim"
    assert default_model(live_camera=True) == REAL_PHOTO_MODEL
    net = load_network(None)
    assert isinstance(net, NetworkDetector) and net.name == SIMULATOR_MODEL
    assert load_network(None, live_camera=True).name == REAL_PHOTO_MODEL  # type: ignore[union-attr]
    assert load_network("standin") is None  # the simulator's ground-truth stand-in, only when asked
    with pytest.raises(ValueError, match="--detector standin: .*live camera"):
        load_network("standin", live_camera=True)


def test_network_detector_sums_what_the_sanitiser_dropped(tmp_path: Path) -> None:
    rows = [(100.0, 100.0, 20.0, 40.0, 0.9), (float("nan"), 1.0, 1.0, 1.0, 0.9), (50.0, 50.0, -4.0, 4.0, 0.9)]
    net = NetworkDetector(Detector(hostile_model(tmp_path / "h.onnx", rows), conf=0.25))
    image = np.zeros((320, 320, 3), np.uint8)
    for _ in range(3):
        boxes = net(image)
        np.testing.assert_allclose(boxes, [[90, 80, 110, 120, 0.9]], rtol=1e-6)
    assert detections_dropped(net) == {"non_finite_box": 3, "bad_score": 0, "inverted": 3, "degenerate": 0,
                                       "total": 6}
    assert detections_dropped(object()) is None
