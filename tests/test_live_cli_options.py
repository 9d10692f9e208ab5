"""``--lidar``/``--camera``: refused combinations name the flag; a valid one opens both
drivers (listening Mid-360 on a free port, a real video file) on a vehicle clock."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from insulator_rs._core import CameraModel
from insulator_rs.app import live_options as cli_options
from insulator_rs.ports.sensors import Sensors


def parse(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    p.add_argument("--connection")
    p.add_argument("--detector")
    p.add_argument("--sim-sensors", action="store_true")
    cli_options.add_arguments(p)
    return p.parse_args(list(argv))


def test_no_live_flags_is_not_live() -> None:
    assert cli_options.check_arguments(parse()) is False


@pytest.mark.parametrize("argv, message", [
    (("--lidar", "mid360://192.168.1.12"), "--camera: a live flight needs both"),
    (("--camera", "0"), "--lidar: a live flight needs both"),
    (("--lidar", "mid360://h", "--camera", "0", "--detector", "m.onnx"), "add --connection"),
    (("--lidar", "mid360://h", "--camera", "0", "--connection", "udpin:0.0.0.0:14540", "--detector", "standin"),
     "a live camera needs a detection network"),
    (("--lidar", "mid360://h", "--camera", "0", "--connection", "c", "--detector", "d", "--sim-sensors"),
     "not with --sim-sensors"),
    (("--lidar", "velodyne://h", "--camera", "0", "--connection", "c", "--detector", "d"), "mid360://HOST"),
])
def test_refused_combinations_name_the_flag(argv: tuple[str, ...], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        cli_options.check_arguments(parse(*argv))


def test_open_from_arguments_starts_clock_lidar_and_camera(tmp_path: Path) -> None:
    video = tmp_path / "cam.avi"
    # 4 s of video at its own rate: frames that arrive before the vehicle clock has its first
    # telemetry pair are dropped (unstamped), which on a loaded machine can take a second
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (64, 48))
    for i in range(120):
        writer.write(np.full((48, 64, 3), 2 * i, np.uint8))
    writer.release()
    args = parse("--lidar", "mid360://listen:0", "--camera", str(video), "--connection", "c", "--detector", "d")
    assert cli_options.check_arguments(args)
    t0 = time.monotonic()
    vehicle = SimpleNamespace(state=lambda: SimpleNamespace(time=round(time.monotonic() - t0 + 100.0, 2)))
    rig = SimpleNamespace(T_b_l=np.eye(4), T_b_c=np.eye(4), camera=CameraModel(50, 50, 32, 24, 64, 48),
                          camera_latency_s=0.0, lidar_latency_s=0.0)
    sensors = cli_options.open_from_arguments(args, vehicle, rig)
    try:
        assert isinstance(sensors, Sensors)
        deadline = time.monotonic() + 10.0
        while sensors.detection_frame(1e9) is None and time.monotonic() < deadline:
            time.sleep(0.02)
        frame = sensors.detection_frame(1e9)
        assert frame is not None and 100.0 <= frame.time < 110.0
        assert sensors.lidar is not None and sensors.lidar.point_address[1] > 0
        assert "clock_errors" in sensors.health()
    finally:
        sensors.close()


def test_inspect_refuses_live_flags_that_cannot_fly(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Through ``insulator-rs inspect``: status 2, the flag named, nothing flown."""
    from insulator_rs.app.cli import main

    base = ["inspect", "--out", str(tmp_path / "r")]
    for extra, message in (
            (["--lidar", "mid360://192.168.1.12"], "--camera: a live flight needs both"),
            (["--lidar", "mid360://h", "--camera", "0", "--detector", "insulator-sim"], "add --connection"),
            (["--lidar", "mid360://h", "--camera", "0", "--connection", "udpin:127.0.0.1:14540", "--detector",
              "standin"], "a live camera needs a detection network"),
            (["--lidar", "ouster://h", "--camera", "0", "--connection", "udpin:127.0.0.1:14540", "--detector",
              "insulator-sim"], "mid360://HOST")):
        assert main([*base, *extra]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
