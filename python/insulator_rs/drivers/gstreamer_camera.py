"""A camera through GStreamer itself (PyGObject), frames stamped at exposure in the vehicle clock.

pip's opencv-python-headless is built without GStreamer (``cv2.getBuildInformation()``:
``GStreamer: NO``), so a Jetson's CSI camera (``nvarguscamerasrc``) cannot be opened through
OpenCV without a custom build. This source runs the pipeline with GStreamer's own Python
bindings (``gi.repository.Gst``: PyGObject from PyPI, the ``gstreamer`` extra, or JetPack's
``python3-gi``) and pulls BGR frames from its ``appsink``.

The pipeline: ``source`` as ``gst-launch-1.0`` takes it. One that names no ``appsink`` gets
``! videoconvert ! video/x-raw,format=BGR ! appsink name=sink`` appended; one that ends in
its own appsink must hand it BGR, BGRx/BGRA or GRAY8 frames (the appsink named ``sink``, or
the first appsink found). The appsink is set to keep at most 2 frames (older ones dropped:
the newest frame matters) and, for a live source, not to wait on the clock.

The stamp is the EXPOSURE time. A live source stamps each buffer with its capture instant
as a running time (``v4l2src``: the driver's buffer timestamp; ``nvarguscamerasrc``: the
capture's; ``videotestsrc is-live=true``: when the frame is due), so ``base_time +
running_time(PTS)`` is the capture instant in the pipeline clock (GstSystemClock:
CLOCK_MONOTONIC). How that becomes vehicle time: at each sample the pipeline clock is read
just before and just after the vehicle clock ``now()``; the frame's stamp is ``now() - age``,
``age`` being the midpoint of the two pipeline-clock reads minus the capture instant
(:meth:`CameraSource.stamp`).

Why the age at each sample, not an affine map (``timesync.ClockMap``) from pipeline clock
to vehicle clock: both clocks are read on this computer, back to back, so there is no
transport delay for a one-way fit to estimate, and the vehicle clock is already the
fitted map of this host's clock to the autopilot's (``TelemetryClock``), refitted as
telemetry comes: a second fit on top would only lag behind its refits. Mapping the age, a
short interval (tens of ms), means a rate error between the clocks is multiplied by the age
alone (25 ppm of 50 ms is 1.25 us). The same holds whatever clock the pipeline runs on.

A source with ``do-timestamp=true`` (a network camera's ``souphttpsrc`` / ``rtspsrc``) stamps
each buffer when it produces it: its PTS is the frame's arrival there, and the rig's ``[camera]
latency_s`` (stamp minus exposure) is subtracted from it as from any arrival.

Where no capture time is known (a file or other non-live pipeline: its PTS is a position in
the stream; a buffer without PTS; an age outside ``[0, MAX_EXPOSURE_AGE_S]``) the frame is
stamped at arrival minus the rig's ``[camera] latency_s``, and counted (``health()``).

Every failure is a :class:`~insulator_rs.exceptions.SensorError` naming ``--camera`` and
GStreamer's own message: a pipeline that does not parse (``no element "nosuchelement"``),
one that fails to start or negotiate, one that gives no frame within ``start_timeout_s``.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import gi
import numpy as np

gi.require_version("Gst", "1.0")
gi.require_version("GstApp", "1.0")
from gi.repository import GLib, Gst, GstApp  # noqa: E402  (after require_version, as gi asks)

from insulator_rs._core import CameraModel  # noqa: E402
from insulator_rs.drivers.camera_source import CameraSource  # noqa: E402
from insulator_rs.exceptions import SensorError  # noqa: E402

#: What a pipeline that names no appsink gets appended: BGR frames, as the detector takes them.
APPSINK_TAIL = "videoconvert ! video/x-raw,format=BGR ! appsink name=sink"
#: Seconds ``start()`` waits for the pipeline's first frame before giving up. A network camera's
#: first frame comes after the session's set-up and the next keyframe (an RTSP camera at a 1-2 s
#: keyframe interval: 2-4 s), later on a busy computer: the PX4 SITL sensor head's MJPEG stream,
#: on a 2-core machine running two other PX4 SITL flights, gave none within 5 s.
START_TIMEOUT_S = 10.0
#: Seconds one pull waits for a frame before the thread looks at the bus and its stop flag.
PULL_SLICE_S = 0.1
#: Frames the appsink holds before it drops the oldest.
APPSINK_MAX_BUFFERS = 2
#: Bytes per pixel of the raw formats taken, and how many of them are the BGR (or grey) channels.
FORMATS = {"BGR": (3, 3), "BGRx": (4, 3), "BGRA": (4, 3), "GRAY8": (1, 1)}


def pipeline_description(source: str) -> str:
    """``source`` with the appsink tail appended when it names no appsink."""
    text = source.strip()
    if not text:
        raise SensorError("--camera: empty GStreamer pipeline")
    return text if "appsink" in text else f"{text} ! {APPSINK_TAIL}"


def _bus_error(pipeline: Gst.Pipeline) -> str | None:
    """The first error (or end of stream) waiting on the pipeline's bus, as text; other
    messages are popped and ignored."""
    bus = pipeline.get_bus()
    while True:
        msg = bus.pop()
        if msg is None:
            return None
        if msg.type == Gst.MessageType.ERROR:
            err, debug = msg.parse_error()
            where = msg.src.get_name() if msg.src is not None else "pipeline"
            return f"{where}: {err.message}" + (f" ({debug.splitlines()[0]})" if debug else "")
        if msg.type == Gst.MessageType.EOS:
            return "end of stream"


def _stamps_on_arrival(pipeline: Gst.Pipeline) -> bool:
    """Whether a source element of ``pipeline`` has ``do-timestamp`` on (its PTS is then the
    instant it produced the buffer, not a capture time)."""
    it = pipeline.iterate_sources()
    while True:
        ok, element = it.next()
        if ok != Gst.IteratorResult.OK:
            return False
        prop = element.find_property("do-timestamp")
        if prop is not None and bool(element.get_property("do-timestamp")):
            return True


def _find_appsink(pipeline: Gst.Pipeline) -> GstApp.AppSink | None:
    named = pipeline.get_by_name("sink")
    if isinstance(named, GstApp.AppSink):
        return named
    it = pipeline.iterate_sinks()
    while True:
        ok, element = it.next()
        if ok != Gst.IteratorResult.OK:
            return None
        if isinstance(element, GstApp.AppSink):
            return element


class GstCamera(CameraSource):
    """A GStreamer pipeline as a camera source (see the module docstring; the shared
    arguments are :class:`~.camera_source.CameraSource`'s). ``start_timeout_s``: how long
    :meth:`start` waits for the first frame."""

    kind = "gstreamer"

    def __init__(self, source: str, *, camera: CameraModel, T_b_c: np.ndarray, now: Callable[[], float],
                 keep_frames: int = 4, latency_s: float = 0.0, start_timeout_s: float = START_TIMEOUT_S) -> None:
        super().__init__(source, camera=camera, T_b_c=T_b_c, now=now, keep_frames=keep_frames, latency_s=latency_s)
        if not (np.isfinite(start_timeout_s) and start_timeout_s > 0):
            raise ValueError(f"start_timeout_s: must be a finite number > 0, got {start_timeout_s}")
        self.start_timeout_s = float(start_timeout_s)
        self.description = pipeline_description(source)
        ok, _ = Gst.init_check(None)
        if not ok:
            raise SensorError("--camera: GStreamer could not be initialised")
        try:
            pipeline = Gst.parse_launch(self.description)
        except GLib.Error as err:
            raise SensorError(f"--camera: GStreamer cannot build the pipeline {self.description!r}: "
                              f"{err.message}") from None
        if not isinstance(pipeline, Gst.Pipeline):
            raise SensorError(f"--camera: {self.description!r} is one element, not a pipeline ending in appsink")
        sink = _find_appsink(pipeline)
        if sink is None:
            raise SensorError(f"--camera: the GStreamer pipeline {self.description!r} has no appsink")
        sink.set_property("emit-signals", False)
        sink.set_property("max-buffers", APPSINK_MAX_BUFFERS)
        sink.set_property("drop", True)
        self._pipeline: Gst.Pipeline = pipeline
        self._sink: GstApp.AppSink = sink
        self.live = False
        # A source with do-timestamp=true stamps a buffer when it produces it, the arrival of a
        # network camera's frame (souphttpsrc, rtspsrc), not its capture: the rig's latency_s
        # (stamp minus exposure) then applies to it as to any arrival stamp.
        self.pts_at_arrival = _stamps_on_arrival(pipeline)
        self.unsupported = 0
        self.error: str | None = None

    # -- starting: every failure is a SensorError, nothing waits longer than start_timeout_s

    def start(self) -> GstCamera:
        try:
            self._start_pipeline()
            deadline = time.monotonic() + self.start_timeout_s
            while True:
                sample = self._sink.try_pull_sample(int(PULL_SLICE_S * Gst.SECOND))
                if sample is not None:
                    self._handle(sample, first=True)
                    break
                problem = _bus_error(self._pipeline)
                if problem is not None:
                    self._fail(f"the GStreamer pipeline stopped before its first frame: {problem}")
                if time.monotonic() > deadline:
                    self._fail(f"no frame from the GStreamer pipeline within {self.start_timeout_s:g} s")
        except BaseException:
            self._pipeline.set_state(Gst.State.NULL)
            raise
        super().start()
        return self

    def _start_pipeline(self) -> None:
        # PAUSED first: a live source answers NO_PREROLL (it produces only when playing),
        # which is how a capture (PTS = capture instant) is told from a file (PTS = position).
        paused = self._pipeline.set_state(Gst.State.PAUSED)
        if paused == Gst.StateChangeReturn.FAILURE:
            self._fail(f"the GStreamer pipeline cannot start: {_bus_error(self._pipeline) or 'state change failed'}")
        self.live = paused == Gst.StateChangeReturn.NO_PREROLL
        # A live camera's frame goes to us at once; a file plays at its own rate.
        self._sink.set_property("sync", not self.live)
        if self._pipeline.set_state(Gst.State.PLAYING) == Gst.StateChangeReturn.FAILURE:
            self._fail(f"the GStreamer pipeline cannot play: {_bus_error(self._pipeline) or 'state change failed'}")

    def _fail(self, what: str) -> None:
        raise SensorError(f"--camera: {what} ({self.description!r})")

    # -- reading ----------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            sample = self._sink.try_pull_sample(int(PULL_SLICE_S * Gst.SECOND))
            if sample is not None:
                self._handle(sample)
                continue
            problem = "end of stream" if self._sink.is_eos() else _bus_error(self._pipeline)
            if problem is not None:
                self.error = problem
                self.ended = True
                return

    def _pipeline_now(self) -> float:
        clock = self._pipeline.get_clock()
        return float(clock.get_time()) * 1e-9 if clock is not None else float("nan")

    def _capture_time(self, sample: Gst.Sample) -> float | None:
        """The buffer's capture instant in the pipeline clock (s): ``base_time`` + the running
        time of its PTS; None for a non-live pipeline or a buffer without a time in the segment."""
        if not self.live:
            return None
        pts = sample.get_buffer().pts
        if pts == Gst.CLOCK_TIME_NONE:
            return None
        running = sample.get_segment().to_running_time(Gst.Format.TIME, pts)
        if running == Gst.CLOCK_TIME_NONE:
            return None
        produced = float(self._pipeline.get_base_time() + running) * 1e-9
        return produced - self.latency_s if self.pts_at_arrival else produced

    def _handle(self, sample: Gst.Sample, *, first: bool = False) -> None:
        stamp = self.stamp(self._capture_time(sample), self._pipeline_now)
        image = self._image(sample, first=first)
        if image is not None and stamp is not None:
            self._take(image, stamp)

    def _image(self, sample: Gst.Sample, *, first: bool) -> np.ndarray | None:
        """The sample's pixels as an (H, W, 3) or (H, W) uint8 array (a copy: the buffer is
        GStreamer's). A format not taken fails ``start`` (first frame) or is counted."""
        structure = sample.get_caps().get_structure(0)
        fmt = structure.get_value("format")
        width, height = int(structure.get_value("width")), int(structure.get_value("height"))
        if fmt not in FORMATS:
            if first:
                self._fail(f"the pipeline hands appsink {fmt} frames; end it with "
                           f"'! {APPSINK_TAIL}'")
            self.unsupported += 1
            return None
        bpp, channels = FORMATS[fmt]
        buf = sample.get_buffer()
        ok, info = buf.map(Gst.MapFlags.READ)
        if not ok:
            self.unsupported += 1
            return None
        try:
            data = np.frombuffer(info.data, np.uint8)
            stride = data.size // height if height else 0  # rows may be padded (to 4 bytes)
            if stride < width * bpp:
                self.unsupported += 1
                return None
            rows = data[: stride * height].reshape(height, stride)[:, : width * bpp].reshape(height, width, bpp)
            image = rows[:, :, :channels].copy()  # a copy: the mapped memory goes back at unmap
        finally:
            buf.unmap(info)
        return image[:, :, 0] if channels == 1 else image

    def health(self) -> dict[str, object]:
        out = super().health()
        out.update({"camera_live": self.live, "camera_pts_at_arrival": self.pts_at_arrival,
                    "camera_unsupported": self.unsupported, "camera_error": self.error})
        return out

    def _release(self) -> None:
        self._pipeline.set_state(Gst.State.NULL)
