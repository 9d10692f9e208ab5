"""What every live camera source shares: the frame buffer, the reading thread, the stamps.

A source (:mod:`.camera` through OpenCV, :mod:`.gstreamer_camera` through PyGObject) reads
frames in a thread of its own and hands each to :meth:`CameraSource._take` with its stamp
in the vehicle clock. The stamp is the frame's EXPOSURE time wherever the source knows
how old the frame is on arrival (a buffer timestamp in a clock this host can read now:
:meth:`CameraSource.stamp`): ``stamp = now() - age``, ``now()`` being the vehicle clock at
arrival and ``age`` the source clock's now minus the buffer's capture instant. Where it does not (a video file, a network stream, a device without buffer
timestamps) the stamp is the arrival minus the rig's measured latency (``[camera]
latency_s``, :mod:`insulator_rs.rig`). An age outside ``[0, MAX_EXPOSURE_AGE_S]`` is not a
capture time (a clock other than the one assumed, a driver that stamps something else):
such a frame is stamped on arrival too and counted in ``camera_stamps_rejected``.

``health()`` reports how each frame was stamped and the median exposure-to-arrival age
of the recent frames (``camera_exposure_age_ms``): on a real rig that is the measured
latency to put in the rig file for the sources that cannot stamp exposure.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable

import cv2
import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs.exceptions import InsulatorError
from insulator_rs.ports.sensors import CameraFrame

#: The oldest a frame may be on arrival and still be stamped from its buffer timestamp (s):
#: a CSI or USB camera delivers in tens of ms; a second means the timestamp is not the capture's.
MAX_EXPOSURE_AGE_S = 1.0
#: Recent exposure-to-arrival ages kept for ``camera_exposure_age_ms``.
AGE_WINDOW = 64


class CameraSource:
    """The shared part of a camera source. ``camera``: the intrinsics of the frames (their
    size is checked; frames of another size are counted in ``size_mismatch`` and dropped).
    ``T_b_c``: the camera's extrinsics. ``now``: the vehicle clock (s). ``keep_frames``: the
    newest frames kept for :meth:`latest`. ``latency_s``: arrival minus exposure (s), the
    rig's measured figure, subtracted where a frame's exposure time is not known."""

    #: The kind of source, as ``health()`` reports it (set by the subclass).
    kind = "camera"

    def __init__(self, source: int | str, *, camera: CameraModel, T_b_c: np.ndarray,
                 now: Callable[[], float], keep_frames: int = 4, latency_s: float = 0.0) -> None:
        T = np.asarray(T_b_c, np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_b_c: expected a finite 4x4 matrix, got shape {T.shape}")
        if keep_frames < 1:
            raise ValueError(f"keep_frames: must be >= 1, got {keep_frames}")
        if not (np.isfinite(latency_s) and abs(latency_s) <= 0.5):
            raise ValueError(f"latency_s: must be a finite number of seconds in [-0.5, 0.5], got {latency_s}")
        self.source = source
        self.camera = camera
        self.T_b_c = T
        self._now = now
        self.latency_s = float(latency_s)
        self._frames: deque[CameraFrame] = deque(maxlen=keep_frames)
        self._ages: deque[float] = deque(maxlen=AGE_WINDOW)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.frames = 0
        self.size_mismatch = 0
        self.unstamped = 0
        self.exposure_stamps = 0
        self.arrival_stamps = 0
        self.stamps_rejected = 0
        self.ended = False

    # -- the reading thread -------------------------------------------------------------

    def start(self) -> CameraSource:
        self._thread = threading.Thread(target=self._run, name=f"{self.kind}-camera", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:  # pragma: no cover - every source has its own
        raise NotImplementedError

    def _release(self) -> None:
        """Frees the device or pipeline (after the thread has stopped)."""

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._release()

    def __enter__(self) -> CameraSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- stamps and frames --------------------------------------------------------------

    def stamp(self, captured: float | None = None, clock: Callable[[], float] | None = None) -> float | None:
        """The vehicle-clock stamp of a frame arriving now. ``captured``: its capture instant in
        the source's ``clock`` (s; None: not known). The source clock is read just before and
        just after the vehicle clock, and the age of the frame taken at the midpoint, so the
        gap between the reads (a thread switch) costs at most half of it. None when there is
        no vehicle time yet (before the first telemetry; counted in ``unstamped``)."""
        before = clock() if (captured is not None and clock is not None) else None
        try:
            arrival = self._now()
        except InsulatorError:
            self.unstamped += 1
            return None
        if before is not None and clock is not None and captured is not None:
            age = 0.5 * (before + clock()) - captured
            if 0.0 <= age <= MAX_EXPOSURE_AGE_S:
                self.exposure_stamps += 1
                self._ages.append(age)
                return arrival - age
            self.stamps_rejected += 1
        self.arrival_stamps += 1
        return arrival - self.latency_s

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
        ages = list(self._ages)
        return {"camera_source": str(self.source), "camera_kind": self.kind, "camera_frames": self.frames,
                "camera_size_mismatch": self.size_mismatch, "camera_unstamped": self.unstamped,
                "camera_exposure_stamps": self.exposure_stamps, "camera_arrival_stamps": self.arrival_stamps,
                "camera_stamps_rejected": self.stamps_rejected,
                "camera_exposure_age_ms": round(1e3 * float(np.median(ages)), 3) if ages else None,
                "camera_ended": self.ended}
