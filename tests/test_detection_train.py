"""The training command: one tiny epoch, offline, on the committed photos.

Runs ``insulator-rs train`` in a subprocess whose sockets are disabled (every
``connect``/``getaddrinfo`` is recorded and refused), so any download attempt
by Ultralytics (fonts, AMP weights, pip AutoUpdate, usage events) is caught.
Skipped only when the ``train`` extra (ultralytics) is not installed.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from helpers.photos import PHOTOS

if importlib.util.find_spec("ultralytics") is None:  # not imported here: it must be configured offline first
    pytest.skip("the train extra (ultralytics) is not installed", allow_module_level=True)

NO_NETWORK_RUNNER = textwrap.dedent(
    """
    import socket, sys
    attempts = open(sys.argv[1], "a")
    def refuse(*args, **kwargs):
        attempts.write(repr(args[:2]) + "\\n"); attempts.flush()
        raise OSError("network disabled by the test")
    socket.socket.connect = refuse
    socket.socket.connect_ex = refuse
    socket.getaddrinfo = refuse
    socket.create_connection = refuse
    from insulator_rs.app.cli import main
    sys.exit(main(sys.argv[2:]))
    """
)


def card_weights(out: Path) -> str:
    return str(json.loads((out / "tiny.json").read_text())["train_result"]["weights"])


@pytest.mark.slow
def test_train_command_runs_one_epoch_offline(tmp_path: Path) -> None:
    attempts = tmp_path / "network_attempts.txt"
    attempts.touch()
    out = tmp_path / "run"
    cmd = [sys.executable, "-c", NO_NETWORK_RUNNER, str(attempts), "train", "--data", str(PHOTOS),
           "--out", str(out), "--name", "tiny", "--epochs", "1", "--imgsz", "128", "--batch", "4",
           "--threads", "2", "--close-mosaic", "0"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log[-4000:]
    assert attempts.read_text() == "", f"network attempted:\n{attempts.read_text()}"
    assert "Downloading" not in log, log[-4000:]

    # The split keeps every source photo in one split and covers all 8 photos.
    split = json.loads((out / "data" / "split.json").read_text())
    groups = split["source_photos"]
    assert sum(len(v) for v in groups.values()) == 8
    assert not (set(groups["train"]) & set(groups["valid"]) or set(groups["train"]) & set(groups["test"]))
    assert len(groups["valid"]) >= 1 and len(groups["test"]) >= 1

    # ONNX with Ultralytics metadata, loadable by the runtime, and its model card.
    from insulator_rs.detection.detector import Detector

    onnx = out / "tiny.onnx"
    det = Detector(onnx, conf=0.001)
    assert det.names == {0: "insulator"}
    assert det.imgsz == (128, 128) and det.dynamic

    # A static export of the same weights gives the same detections as the dynamic one at its size.
    from insulator_rs.detection.train import export_onnx, prepare_offline

    prepare_offline(tmp_path / "ultralytics_cfg")  # no DNS probe or settings write from this process either
    static = export_onnx(Path(card_weights(out)), 128, tmp_path / "static.onnx", dynamic=False)
    det_static = Detector(static, conf=0.001)
    assert not det_static.dynamic and det_static.imgsz == (128, 128)
    with pytest.raises(ValueError, match="rect=True needs a model with a dynamic input"):
        Detector(static, rect=True)
    import cv2

    image = cv2.imread(str(next(PHOTOS.glob("*.jpg"))))
    a, b = Detector(onnx, conf=0.001, rect=False)(image), det_static(image)  # both padded to the full square
    assert len(a) == len(b)
    np.testing.assert_allclose(a.boxes, b.boxes, atol=1e-2)
    np.testing.assert_allclose(a.scores, b.scores, atol=1e-4)
    card = json.loads((out / "tiny.json").read_text())
    assert card["epochs"] == 1 and card["imgsz"] == 128
    assert card["data"]["images"]["train"] == len(list((out / "data" / "images" / "train").iterdir()))
    assert 0.0 <= card["test_metrics"]["map50_95"] <= card["test_metrics"]["map50"] <= 1.0
    assert card["test_metrics"]["images"] == len(groups["test"])
    assert card["training_seconds"] > 0
    assert (out / "tiny.md").read_text().startswith("# Model card: tiny")
