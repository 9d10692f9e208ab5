"""The GStreamer camera source (PyGObject) on real ``videotestsrc`` pipelines.

Reference: a live ``videotestsrc`` stamps frame n with the running time n / fps (its "capture"
instant) and pushes it when the pipeline clock reaches it, so mapped to the vehicle clock the
stamps must be spaced at whole frame periods; the vehicle clock here is ``time.monotonic()``
+ 1000 s (the pipeline clock is CLOCK_MONOTONIC, so a wrong mapping shows as 1000 s). The
arrival of each frame is the value ``now()`` returned for it (the source reads ``now()``
exactly once per frame, at arrival). Tolerances: a stamp lies within STAMP_TOL_S (5 ms) of
a whole number of periods from the first (the only error is half the gap between the
pipeline-clock reads around the vehicle-clock read, microseconds unless the thread is
preempted on this shared 2-core machine: 5 ms allows for that, against the +-100 ms LiDAR
pairing window); exposure precedes arrival by 0 to 0.5 s; an ``identity sleep-time=50000``
after a queue (50 ms of processing per frame) adds 50 ms (35-90 ms in the median) to the
exposure-to-arrival age while the stamps stay on the frame grid: the PTS is what is used.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from insulator_rs._core import CameraModel
from insulator_rs.drivers import camera_select
from insulator_rs.exceptions import SensorError

GST_MISSING = camera_select.gstreamer_import_error()
pytestmark = pytest.mark.skipif(GST_MISSING is not None,
                                reason=f"GStreamer's Python bindings (gi, Gst) do not import: {GST_MISSING}")

W, H = 320, 240
OFFSET = 1000.0  # vehicle clock = monotonic + OFFSET
STAMP_TOL_S = 5e-3


def source(fps: int, extra: str = "") -> str:
    return (f"videotestsrc is-live=true pattern=ball ! video/x-raw,width={W},height={H},framerate={fps}/1"
            + (f" ! {extra}" if extra else ""))


def cam() -> CameraModel:
    return CameraModel(300.0, 300.0, W / 2, H / 2, W, H)


class RecordingClock:
    """The vehicle clock, recording every reading (one per frame: its arrival)."""

    def __init__(self) -> None:
        self.readings: list[float] = []
        self._lock = threading.Lock()

    def __call__(self) -> float:
        t = time.monotonic() + OFFSET
        with self._lock:
            self.readings.append(t)
        return t


def run(pipeline: str, n: int, **kwargs: object) -> tuple[list, list[float], dict]:
    """The first n frames of ``pipeline`` and their arrivals."""
    from insulator_rs.drivers.gstreamer_camera import GstCamera

    clock = RecordingClock()
    with GstCamera(pipeline, camera=cam(), T_b_c=np.eye(4), now=clock, keep_frames=n, **kwargs) as src:
        src.start()
        deadline = time.monotonic() + 20
        while src.frames < n and time.monotonic() < deadline:
            time.sleep(0.02)
        frames = list(src._frames)[:n]
        health = src.health()
    assert len(frames) == n, health
    return frames, clock.readings[:n], health


def on_grid(stamps: np.ndarray, period: float) -> np.ndarray:
    """How far (s) each stamp lies from a whole number of periods after the first."""
    k = np.round((stamps - stamps[0]) / period)
    return np.abs(stamps - stamps[0] - k * period)


def test_frames_are_bgr_and_stamped_at_exposure_before_arrival() -> None:
    frames, arrivals, health = run(source(30), 30)
    for f in frames:
        assert f.image.shape == (H, W, 3) and f.image.dtype == np.uint8 and f.image.flags.c_contiguous
    assert float(np.ptp(frames[-1].image)) > 0  # the ball on its background, not a blank buffer
    stamps = np.array([f.time for f in frames])
    assert np.all(np.diff(stamps) > 0)
    assert float(on_grid(stamps, 1 / 30).max()) < STAMP_TOL_S
    # most frames follow one period after the one before (the appsink may drop under load)
    assert np.mean(np.round(np.diff(stamps) * 30) == 1) > 0.8
    age = np.array(arrivals) - stamps
    assert np.all(age >= 0) and np.all(age < 0.5), age
    assert health["camera_live"] is True and health["camera_exposure_stamps"] == 30
    assert health["camera_arrival_stamps"] == 0 and health["camera_kind"] == "gstreamer"


def test_processing_latency_delays_arrival_but_not_the_exposure_stamp() -> None:
    """10 fps, so 50 ms of processing per frame keeps up with the camera (at 30 fps the queue
    would fill and the latency grow without bound)."""
    fast, fast_arrivals, _ = run(source(10), 12)
    slow, slow_arrivals, health = run(source(10, "queue ! identity sleep-time=50000"), 12)
    fast_age = float(np.median(np.array(fast_arrivals) - [f.time for f in fast]))
    slow_stamps = np.array([f.time for f in slow])
    slow_age = float(np.median(np.array(slow_arrivals) - slow_stamps))
    assert 0.035 <= slow_age - fast_age <= 0.090, (fast_age, slow_age)
    assert float(on_grid(slow_stamps, 0.1).max()) < STAMP_TOL_S
    assert abs(float(health["camera_exposure_age_ms"]) - 1e3 * slow_age) < 20


def test_a_non_live_pipeline_is_stamped_on_arrival_minus_the_rig_latency() -> None:
    """A non-live source's PTS is a position in the stream, not a capture instant."""
    frames, arrivals, health = run(f"videotestsrc num-buffers=5 ! video/x-raw,width={W},height={H},framerate=30/1",
                                   5, latency_s=0.04)
    assert health["camera_live"] is False and health["camera_arrival_stamps"] == 5
    assert np.allclose([f.time for f in frames], np.array(arrivals) - 0.04)


def test_a_source_stamping_on_arrival_has_the_rig_latency_subtracted() -> None:
    """``do-timestamp=true`` (a network camera's souphttpsrc): the PTS is when the source produced
    the buffer, so the rig's latency applies to it. The same live source without it is the
    reference: its stamps sit latency_s later than these, frame for frame, within the grid's
    tolerance (both are videotestsrc's 10 fps clock)."""
    latency = 0.2
    _, _, plain = run(source(10), 3, latency_s=latency)
    assert plain["camera_pts_at_arrival"] is False  # a capture's PTS: the latency is not taken off
    frames, arrivals, health = run(source(10).replace("is-live=true", "is-live=true do-timestamp=true"), 6,
                                   latency_s=latency)
    assert health["camera_pts_at_arrival"] is True and health["camera_exposure_stamps"] == 6
    age = np.array(arrivals) - [f.time for f in frames]
    assert np.all(age >= latency) and np.all(age < latency + 0.3), age


def test_grey_and_bgrx_appsinks_of_the_users_own_are_taken() -> None:
    for fmt in ("GRAY8", "BGRx"):
        frames, _, _ = run(source(30, f"videoconvert ! video/x-raw,format={fmt} ! appsink"), 2)
        assert frames[0].image.shape == (H, W, 3)


def test_bad_pipelines_are_sensor_errors_naming_camera_and_gstreamers_message() -> None:
    from insulator_rs.drivers.gstreamer_camera import GstCamera

    def open_(pipeline: str, **kw: object) -> None:
        camera_select.open_camera(pipeline, camera=cam(), T_b_c=np.eye(4), now=time.monotonic, **kw)

    with pytest.raises(SensorError, match=r"--camera: GStreamer cannot build .*no element \"nosuchelement\""):
        open_("nosuchelement ! appsink")
    with pytest.raises(SensorError, match="--camera: GStreamer cannot build"):
        open_("gst:videotestsrc ! ! appsink")
    # frames the detector cannot take: the error says how to end the pipeline
    t0 = time.monotonic()
    with pytest.raises(SensorError, match="--camera: the pipeline hands appsink I420 frames; end it with"):
        open_(f"videotestsrc is-live=true ! video/x-raw,format=I420,width={W},height={H} ! appsink")
    # a camera that is not there, a file that is not there: GStreamer's own message at start
    with pytest.raises(SensorError, match="--camera: the GStreamer pipeline cannot start: .*/dev/video97"):
        open_("gst:v4l2src device=/dev/video97")
    with pytest.raises(SensorError, match="--camera: the GStreamer pipeline cannot start: filesrc.*(not found|No such)"):
        open_("filesrc location=/nonexistent/clip.mp4 ! decodebin")
    # a pipeline that never gives a frame: a timeout, not a hang
    with pytest.raises(SensorError, match="--camera: no frame from the GStreamer pipeline within 0.5 s"):
        with GstCamera("videotestsrc is-live=true ! valve drop=true", camera=cam(), T_b_c=np.eye(4),
                       now=time.monotonic, start_timeout_s=0.5) as src:
            src.start()
    assert time.monotonic() - t0 < 10


def test_size_mismatch_is_counted_not_delivered() -> None:
    from insulator_rs.drivers.gstreamer_camera import GstCamera

    with GstCamera(source(30), camera=CameraModel(300.0, 300.0, 320, 240, 640, 480), T_b_c=np.eye(4),
                   now=time.monotonic) as src:
        src.start()
        deadline = time.monotonic() + 10
        while src.size_mismatch < 3 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert src.size_mismatch >= 3 and src.latest(1e12) is None


def test_selection_sends_pipelines_to_pygobject_and_the_rest_to_opencv() -> None:
    assert camera_select.camera_backend("gst:videotestsrc") == "gstreamer"
    assert camera_select.camera_backend("videotestsrc ! appsink") == "gstreamer"
    assert camera_select.camera_backend("0") == camera_select.camera_backend(0) == "opencv"
    assert camera_select.camera_backend("http://127.0.0.1:8080/stream.mjpg") == "opencv"
    assert camera_select.camera_backend("clip.mp4") == "opencv"


def test_open_camera_starts_a_pipeline_that_live_sensors_reads() -> None:
    from insulator_rs.drivers.live_sensors import LiveSensors

    src = camera_select.open_camera("gst:" + source(30), camera=cam(), T_b_c=np.eye(4),
                                    now=lambda: time.monotonic() + OFFSET)
    sensors = LiveSensors(None, src)
    try:
        deadline = time.monotonic() + 10
        while sensors.detection_frame(time.monotonic() + OFFSET) is None and time.monotonic() < deadline:
            time.sleep(0.02)
        frame = sensors.detection_frame(time.monotonic() + OFFSET)
        assert frame is not None and frame.image.shape == (H, W, 3)
        assert sensors.health()["camera_kind"] == "gstreamer"
    finally:
        sensors.close()
