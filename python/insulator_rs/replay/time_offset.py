"""The camera-to-LiDAR time offset of a recorded flight: how late the camera's stamps are.

A camera stamped at arrival is late by its pipeline's latency (tens of ms on USB/CSI); the
LiDAR's points carry their own per-point times, mapped into the vehicle clock at the driver.
A frame stamped ``t`` was exposed at ``t - offset``. The world is static, so the LiDAR points
in W (deskewed with the pose history, as the pipeline pairs them) do not depend on the offset;
only the camera's pose does: ``T_w_c = T_w_b(t - offset) @ T_b_c``. A wrong offset puts the
camera where it was not, and the projected insulator points slide out of the detector's boxes
(at 3 m/s and 6 m, 80 ms is 0.24 m, a box's width at the detection scale).

The score of an offset: for each detection box, its **nearest depth cluster** is found once
(``ir.dbscan`` on the points culled to the box grown by :data:`GROW` box sizes; the cluster
with the least near range: the insulator in front of the lattice),
and the score is the fraction of that cluster's points that ``ir.points_in_boxes`` (the
pipeline's own projection and culling) puts inside the box at ``t - offset``, averaged over
the boxes. The cluster is fixed while the offset moves, so the fraction is 1 only where the
points sit in the box and falls off on both sides as the camera pose slides away: a peak,
widened only by how tightly the box hugs the points. The scan is coarse (:data:`COARSE_STEP`
over ``[-max_offset, max_offset]``), then fine (:data:`FINE_STEP` within
:data:`FINE_HALF_WIDTH` of the best), and the estimate is the centroid of the fine scores
within :data:`PEAK_FRACTION` of the peak's height above the coarse median (a flat top's
middle, not its first point). The clusters are first found at the stamps' poses, which leans
them toward offset 0; they are found again at the estimate and the scan repeated
(:data:`REFINEMENTS` times).

A lean the refinement does not take off: a false box (on a lattice member) has no cluster of
its own; its nearest cluster is whatever lies in it at the offset it was found at, so its
score peaks there, and each refinement carries that lean along. Measured with 80 ms injected,
on the small scene as flown before 117cecc's pass spacing: at a 0.2 detection scale
(insulators 6 px wide) half of the shipped network's boxes were false (IoU < 0.3 with every
true box; 7 in 10 in the passes faster than 1.5 m/s that carry the timing) and the scan read
53 ms (clusters found at -100/0/80/200 ms gave -37/48/47/126 ms), the simulator's true boxes
82 ms, and at 0.4 scale (13 px, 13% false) the network 76 ms
(``docs/results/calibrate/time_offset_80ms.png``). On the flight of 15c78a9 the true boxes at
0.4 read 72 ms (the network 70 ms, its matched boxes alone 60 ms), but true boxes rendered at
the recorded poses' interpolation read 80.5 ms: the rest is the simulated airframe's attitude,
not this scan. Its velocity loop is dead-beat (``sim/kinematics.py``: the whole velocity step
in the first 10 ms substep of each 50 ms setpoint), so the tilt saw-tooths 2-3 degrees between
the 20 Hz poses the recording carries (2 degrees rms of roll at the 80 ms frames' exposures, 20
ms into a tick; none at 0 ms, on the ticks), and the LiDAR points deskewed with those poses
sit up to 0.2-0.6 m off (a scan's median in hard manoeuvres, far points most). With the PI
velocity loop of 0.1 s that replaced it (a continuous acceleration, so a continuous tilt), the
stand-in's boxes at 0.2 read 80 ms as 72.0 ms and 0 ms as 2.1 ms (``tests/test_calibrate_time_offset.py``).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import insulator_rs as ir
from insulator_rs.exceptions import BagError
from insulator_rs.perception.pipeline import ANCHOR_NEAR_FRACTION, PAIRING_WINDOW, PerceptionPipeline
from insulator_rs.poses import PoseHistory, interpolate_poses
from insulator_rs.ports.sensors import CameraFrame, LidarScan
from insulator_rs.recording.reader import FlightBag
from insulator_rs.recording.types import Topics

#: s: the offsets scanned by default, either sign.
MAX_OFFSET = 0.2
COARSE_STEP = 0.01
FINE_STEP = 0.001
FINE_HALF_WIDTH = 0.015
#: The box grown by this many of its sizes on each side to find its cluster (an offset's slide).
GROW = 0.5
#: Times the clusters are found again at the latest estimate and the scan repeated: the first
#: clusters are found at offset 0, and a cluster found at a wrong offset leans the score toward
#: it (a false box's cluster fully: module docstring).
REFINEMENTS = 2
#: ir.dbscan of a box's points (m, points): string discs are a few cm apart at 6-10 m.
CLUSTER_EPS = 0.3
CLUSTER_MIN_POINTS = 3
#: A box whose nearest cluster has fewer points says nothing.
MIN_CLUSTER_POINTS = 8
#: Fewer usable boxes than this and the flight cannot be calibrated.
MIN_BOXES = 10
#: The estimate: centroid of the fine scores above this fraction of the peak's height.
PEAK_FRACTION = 0.9


@dataclass
class _Box:
    points_w: np.ndarray  # (N, 3) the frame's paired LiDAR points, in W
    box: np.ndarray  # (4,) px
    camera: ir.CameraModel
    T_b_c: np.ndarray
    poses: Callable[[float], np.ndarray]  # exposure time -> T_w_b
    stamp: float
    cluster_w: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # its nearest cluster (W)

    def find_cluster(self, offset: float) -> bool:
        """The nearest depth cluster with the camera at ``stamp - offset``; False if too small."""
        T_w_c = self.poses(self.stamp - offset) @ self.T_b_c
        self.cluster_w = _nearest_cluster(self.points_w, np.linalg.inv(T_w_c), self.camera, self.box, T_w_c[:3, 3])
        return len(self.cluster_w) >= MIN_CLUSTER_POINTS


@dataclass(frozen=True)
class TimeOffsetResult:
    """``offset_s``: camera stamp minus exposure (s, positive = the camera is late);
    ``score``/``score_at_zero``: the score at it and at 0; ``boxes``/``frames``: what was
    scored; ``curve``: (offset s, score) of the coarse scan."""

    offset_s: float
    score: float
    score_at_zero: float
    boxes: int
    frames: int
    curve: list[tuple[float, float]]


def _nearest_cluster(points_w: np.ndarray, T_c_w: np.ndarray, camera: ir.CameraModel, box: np.ndarray,
                     camera_w: np.ndarray) -> np.ndarray:
    """The box's nearest depth cluster (points culled to the grown box, DBSCAN, least median range)."""
    w, h = box[2] - box[0], box[3] - box[1]
    grown = np.array([[box[0] - GROW * w, box[1] - GROW * h, box[2] + GROW * w, box[3] + GROW * h]])
    idx = ir.points_in_boxes(points_w, T_c_w, camera, grown)[0]
    if len(idx) < MIN_CLUSTER_POINTS:
        return np.zeros((0, 3))
    pts = points_w[idx]
    rng = np.linalg.norm(pts - camera_w, axis=1)
    labels = ir.dbscan(pts, CLUSTER_EPS, CLUSTER_MIN_POINTS)
    best, best_range = None, np.inf
    for label in set(labels.tolist()) - {-1}:
        members = labels == label
        r = float(np.quantile(rng[members], ANCHOR_NEAR_FRACTION))
        if members.sum() >= MIN_CLUSTER_POINTS and r < best_range:
            best, best_range = members, r
    return pts[best] if best is not None else np.zeros((0, 3))


def _score(boxes: list[_Box], offset: float) -> float:
    """Mean over boxes of the fraction of the box's cluster inside it, the camera at stamp - offset."""
    total = 0.0
    for b in boxes:
        T_c_w = np.linalg.inv(b.poses(b.stamp - offset) @ b.T_b_c)
        inside = ir.points_in_boxes(b.cluster_w, T_c_w, b.camera, b.box[None, :4])[0]
        total += len(inside) / len(b.cluster_w)
    return total / len(boxes)


def collect_boxes(bag: FlightBag, detector: Callable[[np.ndarray], np.ndarray], *,
                  max_offset: float = MAX_OFFSET) -> tuple[list[_Box], int]:
    """Every detection box of the recording with its nearest cluster (W) and the poses around
    its frame, and how many frames gave boxes. Streams the recording as the replay does: poses
    and scans into a :class:`PerceptionPipeline` (its pairing and deskew), a frame taken once
    the data past ``stamp + max_offset`` are in."""
    history = PoseHistory()
    early_scans: list[LidarScan] = []  # before the first frame (the pipeline keeps what it needs of them)
    pipeline: PerceptionPipeline | None = None
    pending: deque[tuple[CameraFrame, np.ndarray]] = deque()
    out: list[_Box] = []
    frames = 0
    horizon = max(max_offset, PAIRING_WINDOW) + 0.05

    def take(upto: float) -> None:
        nonlocal frames
        while pending and pipeline is not None and pending[0][0].time + horizon <= upto:
            frame, boxes = pending.popleft()
            knots_t, knots_T = history.knots()
            window = np.abs(knots_t - frame.time) <= horizon + 0.1
            if not (len(knots_t) and knots_t[0] <= frame.time - max_offset and window.sum() >= 2):
                continue  # no poses around the frame
            points_w = pipeline.paired_points_w(frame.time)
            t_k, T_k = knots_t[window], knots_T[window]

            def poses(t: float, t_k: np.ndarray = t_k, T_k: np.ndarray = T_k) -> np.ndarray:
                return interpolate_poses(t_k, T_k, np.array([t]))[0]

            used = 0
            for box in boxes if len(points_w) else []:
                b = _Box(points_w, np.asarray(box[:4], np.float64), frame.camera,
                         np.asarray(frame.T_b_c, np.float64), poses, frame.time)
                if b.find_cluster(0.0):
                    out.append(b)
                    used += 1
            frames += used > 0

    for item in bag.items():
        if item.kind == "pose":
            history.add(item.value)
        elif item.kind == "scan":
            (pipeline.add_scan if pipeline is not None else early_scans.append)(item.value)
        elif item.kind == "frame":
            if pipeline is None:  # the first frame names the camera; the pipeline pairs with the history
                pipeline = PerceptionPipeline(item.value.camera, item.value.T_b_c, bag.T_b_l)
                pipeline.poses = history
                for scan in early_scans:
                    pipeline.add_scan(scan)
            boxes = np.asarray(detector(item.value.image), np.float64)
            if boxes.ndim == 2 and len(boxes):
                pending.append((item.value, boxes))
        take(item.time)
    take(np.inf)
    return out, frames


def estimate_time_offset(boxes: list[_Box], frames: int, *, max_offset: float = MAX_OFFSET) -> TimeOffsetResult:
    """Coarse scan, fine scan around the best, centroid of the top; then the clusters found
    again at that estimate and the scan repeated (module docstring)."""
    result = _scan(boxes, frames, max_offset)
    for _ in range(REFINEMENTS):
        boxes = [b for b in boxes if b.find_cluster(result.offset_s)]
        result = _scan(boxes, frames, max_offset)
    return result


def _scan(boxes: list[_Box], frames: int, max_offset: float) -> TimeOffsetResult:
    if len(boxes) < MIN_BOXES:
        raise BagError(f"{len(boxes)} detection boxes with LiDAR points in the recording; at least {MIN_BOXES} "
                       "are needed to calibrate the camera time offset (a flight past the insulators)")
    coarse = np.arange(-max_offset, max_offset + COARSE_STEP / 2, COARSE_STEP)
    coarse_scores = np.array([_score(boxes, float(d)) for d in coarse])
    best = float(coarse[int(np.argmax(coarse_scores))])
    fine = np.arange(best - FINE_HALF_WIDTH, best + FINE_HALF_WIDTH + FINE_STEP / 2, FINE_STEP)
    fine = fine[np.abs(fine) <= max_offset + 1e-9]
    fine_scores = np.array([_score(boxes, float(d)) for d in fine])
    floor = float(np.median(coarse_scores))
    peak = float(fine_scores.max())
    top = fine_scores >= floor + PEAK_FRACTION * (peak - floor)
    weights = fine_scores[top] - floor
    offset = float(np.average(fine[top], weights=weights)) if weights.sum() > 0 else float(fine[np.argmax(fine_scores)])
    return TimeOffsetResult(offset_s=offset, score=_score(boxes, offset), score_at_zero=_score(boxes, 0.0),
                            boxes=len(boxes), frames=frames,
                            curve=[(round(float(d), 4), round(float(s), 4)) for d, s in zip(coarse, coarse_scores)])


def calibrate_time_offset(path: str | Path, detector: Callable[[np.ndarray], np.ndarray], *,
                          topics: Topics = Topics(), max_offset: float = MAX_OFFSET) -> TimeOffsetResult:
    """The camera time offset of the recorded flight at ``path`` (BagError names what is wrong
    with the recording)."""
    if not (np.isfinite(max_offset) and 0 < max_offset <= 0.5):
        raise ValueError(f"max_offset: must be in (0, 0.5] s, got {max_offset!r}")
    from insulator_rs.recording.metadata import read_metadata

    meta = read_metadata(Path(path))
    with FlightBag(Path(path), topics, scan_windows=bool(meta.mission_text)) as bag:
        boxes, frames = collect_boxes(bag, detector, max_offset=max_offset)
    return estimate_time_offset(boxes, frames, max_offset=max_offset)
