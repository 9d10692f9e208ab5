"""The replay applies a camera latency calibrated after the flight (issue 18, "one clock").

A flight's frames are stamped at arrival minus the rig's ``[camera] latency_s`` as it was then
(the recording keeps that value, ``FlightMetadata.camera_latency_s``); ``calibrate time-offset
--rig`` writes a new one afterwards. The replay hands each frame over when it arrived in the
recording and stamps it earlier by the difference. References: the recorded stamps themselves
(each delivered frame is compared with the one recorded), and the metadata record read back by
the ``mcap`` library.
"""

from __future__ import annotations

import shutil
from collections import deque
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from insulator_rs.mission.config import load_mission
from insulator_rs.ports.sensors import CameraFrame
from insulator_rs.recording.metadata import FlightMetadata
from insulator_rs.replay.batch import camera_latency
from insulator_rs.replay.sensors import ReplaySensors
from insulator_rs.rig import RIGS_DIR, simulator_rig, write_camera_latency

MISSIONS = Path(__file__).resolve().parents[1] / "python" / "insulator_rs" / "missions"


class _Player:
    def __init__(self, times):
        rig = simulator_rig()
        self.frames = deque(CameraFrame(t, np.zeros((2, 2, 3), np.uint8), rig.camera, np.eye(4)) for t in times)
        self.scans = deque()


def test_frames_are_handed_over_at_arrival_stamped_at_exposure():
    sensors = ReplaySensors(_Player([1.0, 1.5, 2.0]), camera_shift_s=0.072)
    assert sensors.detection_frame(0.99) is None
    f = sensors.detection_frame(1.2)  # arrived at 1.0: handed over, exposed 72 ms before
    assert f.time == pytest.approx(1.0 - 0.072, abs=1e-12)
    assert sensors.detection_frame(1.4) is None
    assert sensors.detection_frame(2.0).time == pytest.approx(2.0 - 0.072, abs=1e-12)  # 1.5 skipped, counted
    assert sensors.counts["frames_skipped"] == 1 and sensors.health()["camera_shift_s"] == 0.072
    same = ReplaySensors(_Player([1.0]))
    assert same.detection_frame(1.0).time == 1.0  # no calibration: the recorded stamp


@pytest.mark.parametrize("shift", [float("nan"), 1.5, -2.0])
def test_a_bad_shift_is_refused_by_name(shift):
    with pytest.raises(ValueError, match="camera_shift_s"):
        ReplaySensors(_Player([]), camera_shift_s=shift)


def test_the_shift_is_the_rig_latency_less_what_the_flight_applied(tmp_path):
    for name in ("simulator.toml", "simulator_camera.yaml", "simulator_inspection_camera.yaml"):
        shutil.copy(RIGS_DIR / name, tmp_path / name)
    rig = write_camera_latency(tmp_path / "simulator.toml", 0.072)
    mission = replace(load_mission(MISSIONS / "tower_a.toml"), rig=rig)
    assert camera_latency(FlightMetadata(camera_latency_s="0.0"), mission) == {
        "rig_s": 0.072, "recorded_s": 0.0, "shift_s": 0.072}
    assert camera_latency(FlightMetadata(camera_latency_s="0.05"), mission)["shift_s"] == pytest.approx(0.022)
    old = camera_latency(FlightMetadata(), mission)  # a recording from before the value was kept
    assert old["shift_s"] == 0.0 and "not applied" in old["note"]
    assert camera_latency(FlightMetadata(camera_latency_s="junk"), mission)["shift_s"] == 0.0
    assert "note" not in camera_latency(FlightMetadata(), replace(mission, rig=None))
