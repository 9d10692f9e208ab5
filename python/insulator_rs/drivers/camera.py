"""A camera through OpenCV's VideoCapture, frames stamped in the vehicle clock.

Sources (``source`` argument, as on the command line):

* an integer or a string of digits: a V4L2 device index (``/dev/videoN``);
* a string containing ``!``: a GStreamer pipeline ending in ``appsink``, opened with
  ``cv2.CAP_GSTREAMER`` -- only where OpenCV was built with GStreamer, which pip's
  opencv-python-headless is not; ``--camera`` hands such a pipeline to
  :mod:`.gstreamer_camera` instead (:mod:`.camera_select`);
* a URL (``scheme://...``): a network stream OpenCV's FFmpeg backend reads (an IP camera's
  MJPEG over HTTP, RTSP); a read that fails is retried, the stream reopened after
  ``REOPEN_AFTER`` failures in a row (counted in ``camera_reopens``), never taken as its end;
* anything else: a video file (its end stops the source).

A thread reads frames as they come (for a file: at its own rate when ``realtime``); the
newest ``keep_frames`` are kept. A V4L2 frame is stamped at exposure from the driver's
buffer timestamp where that timestamp proves to be CLOCK_MONOTONIC (:meth:`OpenCvCamera._buffer_time`);
every other frame at arrival (``now()``, the vehicle time) minus ``latency_s``, the rig's
measured latency (:mod:`.camera_source`).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import cv2
import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs.drivers.camera_source import CameraSource
from insulator_rs.exceptions import SensorError

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


class OpenCvCamera(CameraSource):
    """A camera source through OpenCV (see :class:`~.camera_source.CameraSource` for the
    shared arguments). ``realtime``: a video file is read at its own frame rate."""

    def __init__(self, source: int | str, *, camera: CameraModel, T_b_c: np.ndarray,
                 now: Callable[[], float], keep_frames: int = 4, realtime: bool = False,
                 latency_s: float = 0.0) -> None:
        super().__init__(source, camera=camera, T_b_c=T_b_c, now=now, keep_frames=keep_frames,
                         latency_s=latency_s)
        self.realtime = realtime
        self._cap, self.kind = open_capture(source)
        fps = float(self._cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = fps if np.isfinite(fps) and fps > 0 else None
        self.read_failures = 0
        self.reopens = 0

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
            stamp = self.stamp(self._buffer_time(), time.monotonic)
            if stamp is not None:
                self._take(image, stamp)
            if period:
                next_t += period
                time.sleep(max(0.0, next_t - time.monotonic()))

    def _buffer_time(self) -> float | None:
        """V4L2 only: the driver's timestamp of the frame just read (s, CLOCK_MONOTONIC).

        OpenCV's V4L2 backend answers ``CAP_PROP_POS_MSEC`` with the ``timestamp`` of the
        buffer VIDIOC_DQBUF returned (``1000 * tv_sec + tv_usec / 1000``; 0 before the first
        frame), read in OpenCV's source (modules/videoio/src/cap_v4l.cpp). The kernel stamps
        that buffer in CLOCK_MONOTONIC for drivers that set V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC
        (uvcvideo: at the start of the frame; Tegra's VI: at start of frame too), which is
        Python's ``time.monotonic()`` on Linux. OpenCV does not pass the flag on, and no V4L2
        device was at hand to check one, so each timestamp must prove itself: an age outside
        ``[0, MAX_EXPOSURE_AGE_S]`` (another clock) is rejected and the frame stamped on
        arrival (``camera_stamps_rejected``). Other kinds (files, streams, OpenCV's own
        GStreamer backend) give positions in the stream, not capture times: None."""
        if self.kind != "v4l2":
            return None
        msec = float(self._cap.get(cv2.CAP_PROP_POS_MSEC) or 0.0)
        if not (np.isfinite(msec) and msec > 0.0):
            return None
        return 1e-3 * msec

    def _reopen(self) -> None:
        """A network stream that stopped answering: open it again (the server may be back)."""
        try:
            cap, _ = open_capture(self.source)
        except SensorError:
            return
        self._cap.release()
        self._cap = cap
        self.reopens += 1

    def health(self) -> dict[str, object]:
        out = super().health()
        out.update({"camera_read_failures": self.read_failures, "camera_reopens": self.reopens})
        return out

    def _release(self) -> None:
        self._cap.release()
