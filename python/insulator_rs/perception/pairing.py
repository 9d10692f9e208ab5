"""The one pairing rule: which LiDAR points go with a detection frame, and when the frame is due.

A frame is paired with the points of both sides of its instant (+- the pipeline's pairing
window, per-point times). It is handed to perception once the window past it is over and both
a scan and the pose history reach the window's end. Poses, because each point is moved to W
with the pose at its own time, and a recording's odometry may come later than its scans: a
point past the newest pose would be placed at it. Scans: a live 10 Hz driver delivers the scan
covering the window's end up to a frame period and its reorder grace later, the simulator
renders it at once, a replay delivers each recorded scan once the replay's clock has passed
what it covers. A frame still short
:data:`PAIRING_WAIT` s after its window goes with what is there, counted as short: a LiDAR that
stopped delivering costs the pairing, never the flight.

The flight and the replay both pair through :class:`FramePairing` (driven by
:class:`~insulator_rs.perception.runner.PerceptionRunner`), so there is one rule.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from insulator_rs.ports.sensors import CameraFrame

# s past the pairing window a frame may wait for the scan that covers the window's end. A live
# 10 Hz LiDAR delivers a scan once its 100 ms window is closed, plus the driver's reorder grace
# and the link's latency, when the computer keeps up. A loaded computer (a Jetson running the
# detector beside everything else; our two-core CI box running PX4, the sensor head and the
# client) delivers it late: measured against PX4 SITL with other jobs beside it, the sensor
# head's LiDAR sends were late by 75 ms at the median, 0.52 s at p90, 1.3 s at p99 and 1.85 s at
# worst; with 0.3 s here, 32 of 39 frames with boxes gave up and went unpaired (no insulator
# found). Late points are still stamped right, so waiting costs only the localization's latency;
# a frame still short after this goes with what is there: a LiDAR that stopped delivering costs
# the pairing, never the flight.
PAIRING_WAIT = 2.0
# s: a scan ending this close before the window's end covers it (the last shots of a window
# may have no return; shots are 5 us apart; a source that knows its window says so:
# LidarScan.window_end)
PAIRING_SLACK = 0.01
# s: comparisons of stamps on the vehicle clock tolerate this (float sums of control periods)
TIME_EPS = 1e-9


@dataclass(frozen=True)
class PendingFrame:
    """A detection frame with boxes, waiting for the LiDAR points after its instant."""

    frame: CameraFrame
    boxes: np.ndarray


class FramePairing:
    """Frames with boxes waiting for their window's points, oldest first (see the module docstring)."""

    def __init__(self, window: float) -> None:
        self.window = float(window)
        self.pending: deque[PendingFrame] = deque()
        self.short = 0  # frames with boxes handed over before the scans covered their whole window
        # s, per frame with boxes handed on: the caller's clock past the frame's exposure (how
        # long it waited), and how far short of its window's end the LiDAR horizon still was
        # (0: covered). What a loaded computer does to pairing, measured where it happens.
        self.waited_s: list[float] = []
        self.short_by_s: list[float] = []

    def add(self, frame: CameraFrame, boxes: np.ndarray) -> None:
        self.pending.append(PendingFrame(frame, boxes))

    def waiting_for_points(self, now: float) -> bool:
        """Whether the oldest frame's window is over, so the newest scan should be asked for."""
        return bool(self.pending) and now >= self.pending[0].frame.time + self.window - TIME_EPS

    def due(self, now: float, horizon: float, pose_horizon: float = math.inf) -> list[PendingFrame]:
        """The frames to hand to perception at ``now``, given the LiDAR ``horizon`` and the pose
        history's newest time (``pose_horizon``) reached."""
        out = []
        while self.pending:
            head = self.pending[0]
            due = head.frame.time + self.window
            if now < due - TIME_EPS:
                break
            if min(horizon, pose_horizon) < due - PAIRING_SLACK:
                if now < due + PAIRING_WAIT:
                    break
                if len(head.boxes):  # a frame without boxes needed its scans asked for, not its points
                    self.short += 1
            self._timed(head, now, horizon)
            out.append(self.pending.popleft())
        return out

    def _timed(self, p: PendingFrame, now: float, horizon: float) -> None:
        if len(p.boxes):
            self.waited_s.append(now - p.frame.time)
            self.short_by_s.append(max(0.0, p.frame.time + self.window - horizon))

    def timing(self) -> dict[str, float | None]:
        """The frames' waits and shortfalls (s): median, 90th percentile and worst (None: no frame)."""
        out: dict[str, float | None] = {}
        for name, values in (("waited_s", self.waited_s), ("short_by_s", self.short_by_s)):
            finite = [v for v in values if math.isfinite(v)]
            for label, q in (("p50", 50), ("p90", 90), ("max", 100)):
                out[f"{name}_{label}"] = round(float(np.percentile(finite, q)), 3) if finite else None
        return out

    def drain(self, horizon: float) -> list[PendingFrame]:
        """Every waiting frame (the stream or the search ended): they go with what there is,
        those with boxes whose window the LiDAR ``horizon`` does not reach counted as short, as
        :meth:`due` counts them (so a flight that stops perceiving and its replay, which waits
        out PAIRING_WAIT on the same recorded scans, count the same)."""
        out = list(self.pending)
        self.pending.clear()
        for p in out:
            self._timed(p, math.nan, horizon)
        self.short += sum(1 for p in out
                          if len(p.boxes) and horizon < p.frame.time + self.window - PAIRING_SLACK)
        return out
