"""Re-process one recorded flight offline: detection, fusion, localization, registry, report.

The recording is read as a :class:`~insulator_rs.recording.reader.FlightBag` stream and fed
to the flight's own :class:`~insulator_rs.perception.pipeline.PerceptionPipeline` as the
flight loop feeds it: every pose (``add_pose``), every scan (``add_scan``), and each camera
frame with the flight's detector's boxes (``process``: paired with the scans' points of
+-``pairing_window``, deskewed with the pose history) once the stream has passed the frame's
time by the pairing window, as the loop waits for the scan after a frame. Localizations feed
the flight's :class:`~insulator_rs.tracking.registry.InsulatorRegistry`. With deskew off, a
frame's nearest scan is used as measured at the frame's pose (``PerceptionPipeline.event``).

The report folder has the flight's layout (``summary.json``, ``insulators.csv``,
``trajectory.csv``, ``trajectory.png``). A broken recording (a :class:`BagError` mid-way) ends
the replay with status ``failed: <error>``; everything processed before it stays in the report.
"""

from __future__ import annotations

import math
import time as wallclock
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import insulator_rs as ir
from insulator_rs.exceptions import BagError
from insulator_rs.ports.detector import detector_name
from insulator_rs.mission.config import Mission
from insulator_rs.geodesy import GeoPoint
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.perception.pipeline import BOUNDED, PAIRING_WINDOW, PerceptionPipeline
from insulator_rs.tracking.registry import InsulatorRegistry
from insulator_rs.report.writer import ReportWriter
from insulator_rs.recording.reader import FlightBag, Item
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped

# s of poses kept behind the oldest pending scan.
POSE_KEEP = 2.0
RERUN_FILE = "replay.rrd"
# m: a localized insulator this close to a true one counts as finding it.
MATCH_DISTANCE = 1.5


@dataclass(frozen=True)
class ReplaySettings:
    """``method``: localization method; ``deskew``: motion-compensate scans (default on);
    ``detect_period``: s between detection events (0: every frame); ``pairing_window`` s."""

    method: str = BOUNDED  # the flight's default
    deskew: bool = True
    detect_period: float = 0.0
    pairing_window: float = PAIRING_WINDOW
    quiet: bool = True
    progress: bool = False


@dataclass
class _Poses:
    """The pose stream read so far (times strictly increasing)."""

    times: list[float] = field(default_factory=list)
    T: list[np.ndarray] = field(default_factory=list)

    def add(self, p: PoseStamped) -> None:
        if self.times and p.time <= self.times[-1]:
            return
        self.times.append(p.time)
        self.T.append(p.T_w_b)

    def drop_before(self, t: float) -> None:
        k = 0
        while k + 2 < len(self.times) and self.times[k + 1] < t:
            k += 1
        if k:
            del self.times[:k]
            del self.T[:k]


def _interpolate(times: list[float], poses: list[np.ndarray], t: float) -> np.ndarray:
    """The pose at ``t``: the image of the body origin and axes under ``ir.deskew``'s motion
    (so frames and points use one interpolation), clamped to the stream's ends."""
    t = min(max(t, times[0]), times[-1])
    k = int(np.searchsorted(times, t, side="right")) - 1
    k = min(max(k, 0), len(times) - 2)
    # Body origin and unit axes at time t, expressed in the body frame of times[k] ...
    probe = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    q = ir.deskew(probe, np.full(4, t), np.array(times[k:k + 2]), np.stack(poses[k:k + 2]), times[k], np.eye(4))
    # ... then into W with that knot's pose.
    T_k = poses[k]
    pw = q @ T_k[:3, :3].T + T_k[:3, 3]
    T = np.eye(4)
    T[:3, 3] = pw[0]
    T[:3, :3] = (pw[1:] - pw[0]).T
    return T


class ReplayRun:
    """One recorded flight re-processed (see the module docstring)."""

    def __init__(self, bag: FlightBag, out: Path, *, mission: Mission, detector: Any,
                 settings: ReplaySettings = ReplaySettings(), ground_truth: list[Any] | None = None,
                 rerun: bool = False, overwrite: bool = False) -> None:
        self.bag = bag
        self.out = Path(out)
        self.mission = mission
        self.geom = MissionGeometry.from_mission(mission)
        self.detector = detector
        self.settings = settings
        self.ground_truth = ground_truth
        self.registry = InsulatorRegistry(self.geom.line, mission.inspection.registry_gate,
                                          mission.inspection.confirmations)
        self.perception: PerceptionPipeline | None = None
        self.report = ReportWriter(self.out, origin=GeoPoint(mission.tower.lat, mission.tower.lon, mission.tower.alt),
                                   overwrite=overwrite)
        self.rerun: Any = None
        if rerun:  # inside the report folder being written (swapped in with it)
            from insulator_rs.replay.rerun_log import RerunLog

            self.rerun = RerunLog(self.report.layout.path / RERUN_FILE, name=bag.path.name)
        self.poses = _Poses()
        self.scans: deque[LidarScan] = deque(maxlen=8)
        self.pending: deque[CameraFrame] = deque()
        self._early: list[tuple[str, Any]] = []
        self.counts = {"poses": 0, "scans": 0, "frames": 0, "detection_events": 0, "unpaired_frames": 0,
                       "localizations": 0}
        self.status = "running"
        self.error: str | None = None
        self.t0: float | None = None
        self.t_last = 0.0
        self._next_detect = -math.inf
        self.wall = 0.0

    # -- the stream ---------------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        wall0 = wallclock.perf_counter()
        bar = None
        if self.settings.progress:
            from tqdm import tqdm

            bar = tqdm(total=self.bag.counts.get(self.bag.image_topic, 0), unit="frame",
                       desc=self.bag.path.name, dynamic_ncols=True)
        try:
            for item in self.bag.items():
                self._take(item)
                if bar is not None and item.kind == "frame":
                    bar.update(1)
                    bar.set_postfix(insulators=len(self.registry), refresh=False)
            self._flush_pending(final=True)
            self.status = "finished"
        except BagError as exc:
            self._flush_pending(final=True)
            self.status = f"failed: {exc}"
            self.error = str(exc)
        except KeyboardInterrupt:
            self.status = "interrupted"
        finally:
            if bar is not None:
                bar.close()
            self.wall = wallclock.perf_counter() - wall0
        return self.finish()

    def _take(self, item: Item) -> None:
        if self.t0 is None:
            self.t0 = item.time
        self.t_last = max(self.t_last, item.time)
        # A frame is handed over once the stream has passed its time by the pairing window:
        # the flight loop waits as long for the scan after the frame (flight.loop._pair_pending).
        while self.pending and item.time >= self.pending[0].time + self.settings.pairing_window - 1e-9:
            self._event(self.pending.popleft())
        if item.kind == "pose":
            p: PoseStamped = item.value
            self.poses.add(p)
            self.counts["poses"] += 1
            self._feed("pose", p)
            R = p.T_w_b[:3, :3]
            self.report.log_pose(p.time - self.t0, p.T_w_b[:3, 3], math.atan2(R[1, 0], R[0, 0]), "replay")
            if self.rerun is not None:
                self.rerun.pose(p)
        elif item.kind == "scan":
            self.scans.append(item.value)
            self.counts["scans"] += 1
            self._feed("scan", item.value)
        else:
            self.counts["frames"] += 1
            frame: CameraFrame = item.value
            if self.settings.detect_period > 0 and frame.time < self._next_detect:
                return
            self._next_detect = frame.time + self.settings.detect_period
            if self.perception is None:
                self._start_perception(frame)
            self.pending.append(frame)
        if self.scans:
            self.poses.drop_before(self.scans[0].time_start - POSE_KEEP)

    def _feed(self, kind: str, value: Any) -> None:
        """Poses and scans go to the perception pipeline as the flight loop feeds it (kept
        until the first frame brings the camera the pipeline is built with)."""
        if self.perception is None:
            self._early.append((kind, value))
        elif kind == "pose":
            self.perception.add_pose(value)
        else:
            self.perception.add_scan(value)

    def _start_perception(self, frame: CameraFrame) -> None:
        self.perception = PerceptionPipeline(frame.camera, frame.T_b_c, self.bag.T_b_l, method=self.settings.method,
                                             insulator_length=self.mission.inspection.insulator_length,
                                             pairing_window=self.settings.pairing_window)
        early, self._early = self._early, []
        for kind, value in early:
            self._feed(kind, value)

    def _flush_pending(self, final: bool) -> None:
        """At the end of the stream (or at a break) the waiting frames go with what there is."""
        while final and self.pending:
            self._event(self.pending.popleft())

    def _paired_scan(self, t: float) -> LidarScan | None:
        best, gap = None, math.inf
        for s in self.scans:
            d = max(s.time_start - t, t - s.time_end, 0.0)
            if d < gap:
                best, gap = s, d
        return best if gap <= self.settings.pairing_window else None

    # -- one detection event ------------------------------------------------------------------
    def _event(self, frame: CameraFrame) -> None:
        """The flight's detection event: detector, then the pipeline pairs the frame with the
        buffered scans' points of +-pairing_window, deskewed with the pose history (or, with
        deskew off, the nearest scan as measured at the frame's pose)."""
        boxes = np.asarray(self.detector(frame.image), dtype=np.float64)
        if self.rerun is not None:
            self.rerun.frame(frame, boxes[:, :4])
        if len(boxes) == 0 or self.perception is None:
            return
        self.counts["detection_events"] += 1
        scan = self._paired_scan(frame.time)
        if self.settings.deskew:
            locs = self.perception.process(frame, boxes)
        elif scan is None or not self.poses.times:
            self.counts["unpaired_frames"] += 1
            return
        else:
            locs = self.perception.event(boxes, scan.points_l, _interpolate(self.poses.times, self.poses.T, frame.time))
        if self.rerun is not None and scan is not None:
            self.rerun.culled(frame, scan.T_b_l, self._deskewed(scan, frame.time), boxes[:, :4])
        for loc in locs:
            self.counts["localizations"] += 1
            self.registry.observe(loc.center, loc.axis)
        if self.rerun is not None and locs:
            self.rerun.insulators(frame.time, self.registry.insulators)

    def _deskewed(self, scan: LidarScan, t_ref: float) -> np.ndarray:
        """The scan's points in L at ``t_ref``, deskewed with ``ir.deskew`` against the recorded
        poses (for the Rerun view; as measured with deskew off or fewer than two poses)."""
        if not self.settings.deskew or len(self.poses.times) < 2:
            return np.asarray(scan.points_l)
        lo, hi = self.poses.times[0], self.poses.times[-1]
        # At the recording's ends a point may lie beyond the pose stream: hold the end pose there.
        times = np.clip(scan.times, lo, hi)
        return ir.deskew(scan.points_l, times, np.array(self.poses.times), np.stack(self.poses.T),
                         min(max(t_ref, lo), hi), scan.T_b_l)

    # -- report -------------------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        insulators = []
        errors = []
        for ins in self.registry.insulators:
            rec: dict[str, Any] = {"id": ins.id, "center": ins.center, "axis": ins.axis,
                                   "observations": ins.observations, "side": ins.side,
                                   "confirmed": ins.confirmed,
                                   "inspected": False, "photos": []}  # a replay flies nowhere
            if self.ground_truth:
                d = [float(np.linalg.norm(g.center - ins.center)) for g in self.ground_truth]
                k = int(np.argmin(d))
                rec.update(gt_instance_id=self.ground_truth[k].instance_id, error_m=d[k])
                errors.append(d[k])
            insulators.append(rec)
        duration = self.t_last - self.t0 if self.t0 is not None else 0.0
        matched = {r["gt_instance_id"] for r in insulators if r.get("error_m", math.inf) < MATCH_DISTANCE}
        return {
            "status": self.status,
            "error": self.error,
            "recording": str(self.bag.path),
            "topics": {"lidar": self.bag.lidar_topic, "image": self.bag.image_topic,
                       "odometry": self.bag.odometry_topic},
            "detector": detector_name(self.detector),
            "method": self.settings.method,
            "deskew": self.settings.deskew,
            "flight_time_s": duration,
            "wall_time_s": self.wall,
            "speed_vs_real_time": duration / self.wall if self.wall > 0 else None,
            **self.counts,
            "insulators_found": len(insulators),
            "insulators_in_scene": len(self.ground_truth) if self.ground_truth else None,
            "insulators_matched": len(matched) if self.ground_truth else None,
            "mean_error_m": float(np.mean(errors)) if errors else None,
            "insulators": insulators,
            "rerun": RERUN_FILE if self.rerun is not None else None,
        }

    def finish(self) -> dict[str, Any]:
        if self.rerun is not None:
            self.rerun.close()
        self.report.flush()
        summary = self.summary()
        self.report.write_summary(summary)
        found = np.array([i.center for i in self.registry.insulators]) if len(self.registry) else np.zeros((0, 3))
        truth = (np.array([g.center for g in self.ground_truth]) if self.ground_truth else np.zeros((0, 3)))
        try:
            self.report.plot(self.geom.volumes, np.zeros((0, 3)), found, truth,
                             f"replay of {self.bag.path.name}: {summary['status'][:40]}, "
                             f"{summary['insulators_found']} insulators")
        finally:
            self.report.close()
        return summary
