"""The training command: one tiny epoch, offline, on the committed photos.

Runs ``insulator-rs train`` in a subprocess whose sockets are disabled (every
``connect``/``getaddrinfo`` is recorded and refused), so any download attempt
by Ultralytics (fonts, AMP weights, pip AutoUpdate, usage events) is caught.
Skipped only when the ``train`` extra (ultralytics) is not installed.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("ultralytics", reason="the train extra is not installed")

PHOTOS = Path(__file__).parent / "data" / "photos"

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
    from insulator_rs.cli import main
    sys.exit(main(sys.argv[2:]))
    """
)


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
    assert det.imgsz == (128, 128)
    card = json.loads((out / "tiny.json").read_text())
    assert card["epochs"] == 1 and card["imgsz"] == 128
    assert card["data"]["images"]["train"] == len(list((out / "data" / "images" / "train").iterdir()))
    assert 0.0 <= card["test_metrics"]["map50_95"] <= card["test_metrics"]["map50"] <= 1.0
    assert card["test_metrics"]["images"] == len(groups["test"])
    assert card["training_seconds"] > 0
    assert (out / "tiny.md").read_text().startswith("# Model card: tiny")
