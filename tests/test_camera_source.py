"""The OpenCV camera source on a real video file written with cv2.VideoWriter.

Reference: the frames written (each a solid colour that encodes its index; MJPG is
lossy, so colours are compared within 8 grey levels) and a fake vehicle clock whose
readings must be the frames' stamps, in order.
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from insulator_rs._core import CameraModel
from insulator_rs.drivers.camera import OpenCvCamera
from insulator_rs.exceptions import SensorError

W, H, N = 160, 120, 30


def write_video(path: Path, n: int = N) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (W, H))
    assert writer.isOpened()
    for i in range(n):
        writer.write(np.full((H, W, 3), (8 * i) % 256, np.uint8))
    writer.release()


def cam(w: int = W, h: int = H) -> CameraModel:
    return CameraModel(100.0, 100.0, w / 2, h / 2, w, h)


def test_video_file_frames_are_read_in_order_and_stamped_on_arrival(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    write_video(path)
    ticks = itertools.count()
    stamps: list[float] = []

    def now() -> float:
        t = 100.0 + 0.01 * next(ticks)
        stamps.append(t)
        return t

    with OpenCvCamera(str(path), camera=cam(), T_b_c=np.eye(4), now=now, keep_frames=N) as source:
        assert source.kind == "file"
        source.start()
        deadline = time.monotonic() + 10
        while not source.ended and time.monotonic() < deadline:
            time.sleep(0.01)
        assert source.ended
        frames = list(source._frames)
        health = source.health()
    assert health["camera_frames"] == N and health["camera_size_mismatch"] == 0
    assert [f.time for f in frames] == stamps[:N]
    for i, f in enumerate(frames):
        assert f.image.shape == (H, W, 3) and f.image.dtype == np.uint8
        assert abs(float(f.image.mean()) - (8 * i) % 256) < 8
        assert f.camera.width == W
    # latest(now) is the newest frame stamped at or before now.
    latest = frames[-1]
    assert source.latest(latest.time) is latest
    assert source.latest(frames[0].time - 1.0) is None


def test_frames_of_another_size_are_counted_not_delivered(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    write_video(path, 5)
    with OpenCvCamera(str(path), camera=cam(640, 480), T_b_c=np.eye(4), now=lambda: 0.0) as source:
        source.start()
        deadline = time.monotonic() + 10
        while not source.ended and time.monotonic() < deadline:
            time.sleep(0.01)
        assert source.size_mismatch == 5
        assert source.latest(1.0) is None


def test_bad_sources_raise_sensor_error_naming_them(tmp_path: Path) -> None:
    with pytest.raises(SensorError, match="no such video file"):
        OpenCvCamera(str(tmp_path / "missing.mp4"), camera=cam(), T_b_c=np.eye(4), now=lambda: 0.0)
    with pytest.raises(SensorError, match="v4l2 source '97'"):
        OpenCvCamera("97", camera=cam(), T_b_c=np.eye(4), now=lambda: 0.0)
    with pytest.raises(ValueError, match="T_b_c"):
        OpenCvCamera(0, camera=cam(), T_b_c=np.eye(3), now=lambda: 0.0)


def test_frames_before_the_vehicle_clock_exists_are_counted_not_fatal(tmp_path: Path) -> None:
    from insulator_rs.exceptions import TimeSyncError

    path = tmp_path / "clip.avi"
    write_video(path, 10)
    calls = itertools.count()

    def now() -> float:
        if next(calls) < 4:
            raise TimeSyncError("time sync: no vehicle telemetry yet")
        return 1.0

    with OpenCvCamera(str(path), camera=cam(), T_b_c=np.eye(4), now=now, keep_frames=10) as source:
        source.start()
        deadline = time.monotonic() + 10
        while not source.ended and time.monotonic() < deadline:
            time.sleep(0.01)
        assert (source.unstamped, source.frames) == (4, 6)


def test_an_mjpeg_http_stream_is_read_as_an_ip_camera_and_survives_its_server_restarting() -> None:
    """An MJPEG-over-HTTP stream (``multipart/x-mixed-replace``, what IP cameras and the SITL
    sensor head serve) read through OpenCV's FFmpeg backend: the source is a stream, not a
    file (no end), and the frames show what is published (grey level within 8: JPEG); when the
    server goes away the reads fail and are counted, and once a server is back on the same
    port the stream is reopened (counted) and frames flow again."""
    import threading

    from insulator_rs.sim.sensor_head import MjpegServer

    state = {"level": 40, "server": MjpegServer().start()}
    port = int(state["server"].url.rsplit(":", 1)[1].split("/")[0])
    url = state["server"].url
    stop = threading.Event()

    def publisher() -> None:  # a camera at 20 fps
        while not stop.wait(0.05):
            ok, jpeg = cv2.imencode(".jpg", np.full((H, W, 3), state["level"], np.uint8))
            state["server"].publish(jpeg.tobytes())

    def wait_level(source: OpenCvCamera, level: int, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            frame = source.latest(time.monotonic())
            if frame is not None and abs(float(frame.image.mean()) - level) < 8:
                return True
            time.sleep(0.02)
        return False

    thread = threading.Thread(target=publisher, daemon=True)
    thread.start()
    try:
        with OpenCvCamera(url, camera=cam(), T_b_c=np.eye(4), now=time.monotonic) as source:
            assert source.kind == "stream"
            source.start()
            for level in (40, 120, 200):
                state["level"] = level
                assert wait_level(source, level, 5.0), level
            state["server"].close()
            deadline = time.monotonic() + 40
            while source.read_failures == 0 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert source.read_failures > 0 and not source.ended
            state["level"] = 90
            state["server"] = MjpegServer(port=port).start()
            assert wait_level(source, 90, 40.0)
            assert source.reopens >= 1 and source.health()["camera_reopens"] == source.reopens
    finally:
        stop.set()
        thread.join(timeout=2)
        state["server"].close()
