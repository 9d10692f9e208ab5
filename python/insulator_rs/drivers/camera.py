"""A camera through OpenCV's VideoCapture, frames stamped on arrival in the vehicle clock.

Sources (``source`` argument, as on the command line):

* an integer or a string of digits: a V4L2 device index (``/dev/videoN``);
* a string containing ``!``: a GStreamer pipeline ending in ``appsink`` (the Jetson's CSI
  cameras: ``nvarguscamerasrc ! ... ! appsink``), opened with ``cv2.CAP_GSTREAMER``;
* a URL (``scheme://...``): a network stream OpenCV's FFmpeg backend reads (an IP camera's
  MJPEG over HTTP, RTSP); a read that fails is retried, the stream reopened after
  ``REOPEN_AFTER`` failures in a row (counted in ``camera_reopens``), never taken as its end;
* anything else: a video file (its end stops the source).

A thread reads frames as they come (for a file: at its own rate when ``realtime``) and
stamps each with ``now()``, the vehicle time at arrival; the newest ``keep_frames`` are
kept. The stamp is the arrival, not the exposure: a camera's pipeline latency (tens of
ms on USB/CSI) is a constant ``latency_s`` the caller may subtract, measured for its rig.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from collections.abc import Callable

import cv2
import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs.exceptions import InsulatorError, SensorError
from insulator_rs.ports.sensors import CameraFrame

#: Failed reads in a row after which a network stream is reopened.
REOPEN_AFTER = 10


def open_capture(source: int | str) -> tuple[cv2.VideoCapture, str]:
    """Opens ``source`` (see the module docstring); returns the capture and its kind."""
    if isinstance(source, int) or (isinstance(source, str) and source.strip().isdigit()):
        index = int(source)
        cap, kind = cv2.VideoCapture(index, cv2.CAP_V4L2), "v4l2"
    elif "!" in source:
        cap, kind = cv2.VideoCapture(source, cv2.CAP_GSTREAMER), "gstreamer"
    elif "://" in source:
        cap, kind = cv2.VideoCapture(source), "stream"
    else:
        if not os.path.exists(source):
            raise SensorError(f"camera: no such video file {source!r}")
        cap, kind = cv2.VideoCapture(source), "file"
    if not cap.isOpened():
        cap.release()
        raise SensorError(f"camera: OpenCV cannot open {kind} source {source!r}")
    return cap, kind


class OpenCvCamera:
    """A camera source. ``camera``: the intrinsics of the frames (their size is checked;
    frames of another size are counted in ``size_mismatch`` and dropped). ``T_b_c``: the
    camera's extrinsics."""

    def __init__(self, source: int | str, *, camera: CameraModel, T_b_c: np.ndarray,
                 now: Callable[[], float], keep_frames: int = 4, realtime: bool = False,
                 latency_s: float = 0.0) -> None:
        T = np.asarray(T_b_c, np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_b_c: expected a finite 4x4 matrix, got shape {T.shape}")
        if keep_frames < 1:
            raise ValueError(f"keep_frames: must be >= 1, got {keep_frames}")
        if not (np.isfinite(latency_s) and latency_s >= 0):
            raise ValueError(f"latency_s: must be a finite number >= 0, got {latency_s}")
        self.source = source
        self.camera = camera
        self.T_b_c = T
        self._now = now
        self.realtime = realtime
        self.latency_s = float(latency_s)
        self._cap, self.kind = open_capture(source)
        fps = float(self._cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = fps if np.isfinite(fps) and fps > 0 else None
        self._frames: deque[CameraFrame] = deque(maxlen=keep_frames)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.frames = 0
        self.read_failures = 0
        self.size_mismatch = 0
        self.unstamped = 0
        self.reopens = 0
        self.ended = False

    def start(self) -> OpenCvCamera:
        self._thread = threading.Thread(target=self._run, name="opencv-camera", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        period = 1.0 / self.fps if (self.realtime and self.fps) else 0.0
        next_t = time.monotonic()
        failures_in_row = 0
        while not self._stop.is_set():
            ok, image = self._cap.read()
            if not ok or image is None:
                if self.kind == "file":
                    self.ended = True
                    return
                self.read_failures += 1
                failures_in_row += 1
                time.sleep(min(0.5, 0.01 * failures_in_row))
                if self.kind == "stream" and failures_in_row % REOPEN_AFTER == 0:
                    self._reopen()
                continue
            failures_in_row = 0
            try:
                stamp = self._now() - self.latency_s
            except InsulatorError:  # no vehicle time yet (before the first telemetry)
                self.unstamped += 1
                continue
            self._take(image, stamp)
            if period:
                next_t += period
                time.sleep(max(0.0, next_t - time.monotonic()))

    def _reopen(self) -> None:
        """A network stream that stopped answering: open it again (the server may be back)."""
        try:
            cap, _ = open_capture(self.source)
        except SensorError:
            return
        self._cap.release()
        self._cap = cap
        self.reopens += 1

    def _take(self, image: np.ndarray, stamp: float) -> None:
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        h, w = image.shape[:2]
        if (w, h) != (self.camera.width, self.camera.height):
            self.size_mismatch += 1
            return
        frame = CameraFrame(time=stamp, image=image, camera=self.camera, T_b_c=self.T_b_c)
        with self._lock:
            self._frames.append(frame)
            self.frames += 1

    def latest(self, now: float) -> CameraFrame | None:
        """The newest frame stamped at or before ``now``."""
        with self._lock:
            for frame in reversed(self._frames):
                if frame.time <= now:
                    return frame
        return None

    def health(self) -> dict[str, object]:
        return {"camera_source": str(self.source), "camera_kind": self.kind, "camera_frames": self.frames,
                "camera_read_failures": self.read_failures, "camera_size_mismatch": self.size_mismatch, "camera_unstamped": self.unstamped,
                "camera_reopens": self.reopens, "camera_ended": self.ended}

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._cap.release()

    def __enter__(self) -> OpenCvCamera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
