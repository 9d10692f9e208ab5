"""The perception runner: sensors -> detector -> pairing -> :class:`PerceptionPipeline`.

One runner serves the flight loop and the replay of a recorded flight, driven by the data's
times (the vehicle clock of each pose, frame and point):

* every pose the vehicle reports goes to the pipeline's pose history (:meth:`add_pose`);
* every ``detect_period`` s (:meth:`step`) the newest camera frame is taken from the
  :class:`~insulator_rs.ports.sensors.Sensors` port and run through the detector; a frame with
  boxes, with the newest LiDAR scan, waits for the points of its instant
  (:mod:`~insulator_rs.perception.pairing`: the one pairing rule), then goes to the pipeline;
* what the pipeline localizes is returned to the caller, who decides what it means (the flight
  tells its state machine, a replay its registry).

A sensor error costs that detection event, never the caller (it is counted and handed to
``on_sensor_error``); so does a detector that raises (counted as ``detector_errors``). What the
caller cannot see event by event, :meth:`lost` says: the LiDAR asked for points and silent, or
the detector failing on every frame, for longer than a timeout (the flight loop aborts on it).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from insulator_rs.exceptions import DetectorError, SensorError
from insulator_rs.perception.pairing import FramePairing, PendingFrame
from insulator_rs.perception.pipeline import LocalizedInsulator, PerceptionPipeline
from insulator_rs.ports.detector import BoxDetector
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped, ScanIntake, Sensors


class RunnerViewer(Protocol):
    """Who watches perception (the replay's Rerun log): each detection frame with its boxes,
    and the points paired with it (W) with the body pose at its exposure."""

    def frame(self, frame: CameraFrame, boxes: np.ndarray) -> None: ...

    def paired(self, frame: CameraFrame, boxes: np.ndarray, points_w: np.ndarray, T_w_b: np.ndarray) -> None: ...


@dataclass
class RunnerCounts:
    """What the runner did: detection ``events`` (a frame asked for), ``frames`` run through the
    detector, ``events_with_boxes`` (frames with boxes handed to the pipeline), ``repeated_frames`` (a source handing the same frame again:
    not run twice), ``sensor_errors``, ``localizations``, ``detector_errors`` (frames the detector
    raised on)."""

    events: int = 0
    frames: int = 0
    events_with_boxes: int = 0
    repeated_frames: int = 0
    sensor_errors: int = 0
    localizations: int = 0
    detector_errors: int = 0


class PerceptionRunner:
    """Sensors, detector and pipeline, stepped by the caller's clock (see the module docstring)."""

    def __init__(self, sensors: Sensors, detector: BoxDetector, pipeline: PerceptionPipeline, *,
                 detect_period: float, on_sensor_error: Callable[[SensorError], None] | None = None,
                 viewer: RunnerViewer | None = None) -> None:
        if not (math.isfinite(detect_period) and detect_period >= 0):
            raise ValueError(f"detect_period: must be a finite number >= 0, got {detect_period!r}")
        self.sensors = sensors
        self.detector = detector
        self.pipeline = pipeline
        self.detect_period = float(detect_period)
        self.on_sensor_error = on_sensor_error
        self.viewer = viewer
        self.intake = ScanIntake()
        self.pairing = FramePairing(pipeline.pairing_window)
        self.counts = RunnerCounts()
        self._next_detect = -math.inf
        self._last_frame_time = -math.inf
        # the boxes of the latest detection event (an observer draws them; None before the first)
        self.last_boxes: np.ndarray | None = None
        # vehicle times of the first and the latest ask for LiDAR points since new ones last came
        # (None: they came). Asks are made only while frames wait for points, so the LiDAR is
        # lost when the asks themselves went unanswered that long, not when no ask was made
        # (a late LiDAR's frames given up on, then nothing in view to ask for: not a silent one)
        self.lidar_unanswered_since: float | None = None
        self.lidar_unanswered_until: float | None = None
        # vehicle time of the first detector failure since it last ran, and that failure
        self.detector_failing_since: float | None = None
        self.detector_error: DetectorError | None = None

    @property
    def pairing_short(self) -> int:
        return self.pairing.short

    def add_pose(self, pose: PoseStamped) -> None:
        """The vehicle's estimated pose (every control tick, or every recorded pose, in time order)."""
        self.pipeline.add_pose(pose)

    def step(self, now: float) -> list[LocalizedInsulator]:
        """One tick at vehicle time ``now``: pair what is due, then a detection event if one is due."""
        fixes = self._pair_due(now)
        if now >= self._next_detect:
            self._next_detect = now + self.detect_period
            self._detection_event(now)
        return fixes

    @property
    def waiting(self) -> bool:
        """Whether frames with boxes still wait for their points."""
        return bool(self.pairing.pending)

    def caught_up(self, time: float) -> bool:
        """Whether every frame with boxes exposed at or before ``time`` (vehicle clock) has been
        handed to perception: none of them still waits for its LiDAR points."""
        return not any(len(p.boxes) and p.frame.time <= time for p in self.pairing.pending)

    def finish(self, now: float) -> list[LocalizedInsulator]:
        """A recorded stream has ended at ``now``, or the flight stops perceiving: the newest
        scan goes in, and every waiting frame with it."""
        self._take_scan(self._ask_scan(now), now)
        return self._process(self.pairing.drain(self.intake.horizon))

    def lost(self, now: float, timeout: float) -> str | None:
        """Why perception is lost at vehicle time ``now``, if it is: the LiDAR asked for points and
        delivering nothing new for more than ``timeout`` s, or the detector raising on every frame
        for that long; None while both work (or were not needed)."""
        since, until = self.lidar_unanswered_since, self.lidar_unanswered_until
        if since is not None and until is not None and min(until, now) - since > timeout:
            return f"sensor lost: no LiDAR scan for {timeout:.0f} s"
        since = self.detector_failing_since
        if since is not None and now - since > timeout:
            return f"detector failed for {timeout:.0f} s ({self.detector_error})"
        return None

    def survey(self, now: float) -> np.ndarray:
        """The newest scan's points not taken before, in W (deskewed with the pose history), for
        the obstacle map; they go to perception's buffer as well, through the same intake, so
        perception (and a replay of the recorded flight) sees the same scans either way. A
        sensor error costs this survey only (counted, handed on)."""
        # a survey that brings nothing is not a silent LiDAR: with nothing in range (above the
        # tower, the Mid-360 looks at the sky) a live driver has no new scan with points to hand
        new = self._take_scan(self._ask_scan(now), now, silence_counts=False)
        return np.zeros((0, 3)) if new is None or not len(new) else self.pipeline.scan_points_w(new)

    # -- internals ------------------------------------------------------------------------
    def _sensor_error(self, exc: SensorError) -> None:
        self.counts.sensor_errors += 1
        if self.on_sensor_error is not None:
            self.on_sensor_error(exc)

    def _ask_scan(self, now: float) -> LidarScan | None:
        try:
            return self.sensors.lidar_scan(now)
        except SensorError as exc:
            self._sensor_error(exc)
            return None

    def _take_scan(self, scan: LidarScan | None, now: float, *, silence_counts: bool = True) -> LidarScan | None:
        """The new part of ``scan`` (None: nothing new), handed to the pipeline; an ask for a
        frame's points that brought nothing new is kept for :meth:`lost` (``silence_counts``)."""
        new = self.intake.take(scan)
        if new is None:
            if not silence_counts:
                return None
            if self.lidar_unanswered_since is None:
                self.lidar_unanswered_since = now
            self.lidar_unanswered_until = now
            return None
        self.lidar_unanswered_since = self.lidar_unanswered_until = None
        self.pipeline.add_scan(new)
        return new

    def _detect(self, image: np.ndarray) -> np.ndarray | None:
        """The detector's boxes on ``image``; None (counted, the failure kept for :meth:`lost`)
        when its runtime raised: any adapter's failure costs this event, never the flight."""
        try:
            boxes = np.asarray(self.detector(image), dtype=np.float64)
        except Exception as exc:  # noqa: BLE001 - a network runtime raises kinds of its own
            self.counts.detector_errors += 1
            self.detector_error = DetectorError(f"{type(exc).__name__}: {exc}")
            if self.detector_failing_since is None:
                self.detector_failing_since = self._last_frame_time
            return None
        self.detector_failing_since = None
        return boxes

    def _detection_event(self, now: float) -> None:
        """Take a detection frame and run the detector; a frame with boxes waits for the LiDAR
        points of its instant, with the newest scan taken now."""
        self.counts.events += 1
        try:
            frame = self.sensors.detection_frame(now)
            if frame is None:
                return
            if not frame.time > self._last_frame_time:
                self.counts.repeated_frames += 1
                return
            self._last_frame_time = frame.time
            self.counts.frames += 1
            detected = self._detect(frame.image)
            if detected is None:
                return
            boxes = self.last_boxes = detected
            if self.viewer is not None:
                self.viewer.frame(frame, boxes[:, :4])
            if len(boxes) == 0:
                return  # nothing to localize: no points are asked for
            scan = self.sensors.lidar_scan(now)
        except SensorError as exc:
            self._sensor_error(exc)
            return
        self._take_scan(scan, now)
        self.pairing.add(frame, boxes)

    def _pair_due(self, now: float) -> list[LocalizedInsulator]:
        """Once the window past the oldest waiting frame is over, the newest scan is asked for
        every tick and its new points go to the pipeline; the frames then due are processed."""
        if not self.pairing.waiting_for_points(now):
            return []
        self._take_scan(self._ask_scan(now), now)
        newest = self.pipeline.poses.newest
        pose_horizon = -math.inf if newest is None else newest.time
        return self._process(self.pairing.due(now, self.intake.horizon, pose_horizon))

    def _process(self, frames: list[PendingFrame]) -> list[LocalizedInsulator]:
        fixes: list[LocalizedInsulator] = []
        for p in frames:
            if len(p.boxes) == 0:
                continue
            self.counts.events_with_boxes += 1
            self.pipeline.last_paired = None
            fixes.extend(self.pipeline.process(p.frame, p.boxes))
            if self.viewer is not None and self.pipeline.last_paired is not None:
                self.viewer.paired(p.frame, p.boxes[:, :4], *self.pipeline.last_paired)
        self.counts.localizations += len(fixes)
        return fixes
