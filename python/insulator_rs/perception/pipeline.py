"""The perception pipeline: camera frames + LiDAR scans + poses -> insulator localizations in W.

One object, :class:`PerceptionPipeline`, does the whole job and is what the flight loop,
a bag replay and the studies call, so that what is measured offline is what flies:

1. **Pair** a camera frame with the LiDAR points of the same instant: the points of the
   buffered scans stamped within :data:`PAIRING_WINDOW` of the frame (per-point times,
   one vehicle clock).
2. **Deskew**: each point goes to W with the vehicle's pose at its own time, interpolated
   from the pose history (the vehicle's estimate, not ground truth), ``T_w_b(t_i) @ T_b_l``.
3. **Cull** to each detection box in the camera at the frame's instant,
   ``T_w_c = T_w_b(t_frame) @ T_b_c``. Steps 2 and 3 are one fused pass a scan,
   ``ir.deskew_points_in_boxes`` (deskew to L at the newest pose, then project and cull in L
   through ``T_c_l = T_c_w @ T_w_l`` while the chunk is in cache): it returns every deskewed
   point, which the tracks, the viewer and the studies need, and the index lists that
   ``ir.deskew`` then ``ir.points_in_boxes`` in W give (the same points to the bit, the same
   lists but for a point within float rounding of a box edge: tests/test_fused_perception.py),
   with one pass over the points where the two-step path made two. A frame costs the same
   within the noise either way (the numpy pairing and the localization dominate it):
   benches/bench_perception_frame.py prints both, side by side.
4. **Accumulate**: boxes are associated across events by the W position of their nearest
   points (median), so each track holds the culled points of the last
   :data:`EVENTS_PER_LOCALIZATION` detection events of one insulator, as the paper
   accumulates three.
5. **Localize** the accumulated points, expressed in the current body frame B, with
   ``ir.localize`` and the pipeline's method
   (:class:`~insulator_rs.perception.localization_method.LocalizationMethod`; the bounded one reads
   the track's boxes and, given the insulator's length, takes the string behind a conductor fitted
   in front of it, or refuses a box where the two fit about as well:
   ``AmbiguousLocalizationError``); the
   result goes back to W and is checked against the box's size and, with a known insulator
   length, against the shape of an insulator string (``insulator_shape``: the false-find
   filter).
6. **Birth**: a track's localizations are handed on only once one of its boxes was a confident
   one (score >= :data:`BIRTH_SCORE`); until then its low-score boxes only gather evidence.
   This is ByteTrack's rule (Zhang et al., ECCV 2022: high-score detections start tracks,
   low-score ones only continue them): the network's weak boxes on tower steel never reach
   the registry on their own, while a string seen once clearly is followed through its
   weaker views.
7. **Axis**: the fitted line lies on the surface the LiDAR saw; the centre handed on is moved
   behind it to the string's axis (``surface_offset``: the visible half of a circular section,
   its radius from the returns' spread across the line of sight).

Use it live (``add_pose`` every control tick, ``add_scan`` for each scan, ``process`` for
each frame with its boxes) or with a frame and a scan taken at one known pose
(:meth:`PerceptionPipeline.event`, the studies' form).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import insulator_rs as ir
from insulator_rs.perception.localization_method import DEFAULT_METHOD, LocalizationMethod
from insulator_rs.perception.insulator_shape import box_aspect_ratio, check_insulator_shape, cluster_shape, line_members
from insulator_rs.perception.surface_offset import surface_to_axis
from insulator_rs.poses import PoseHistory
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped

EVENTS_PER_LOCALIZATION = 3
# m: a box whose anchor lies this close to a track's belongs to it. Anchors are in W, so
# they do not move with the vehicle; the gate is below the spacing of neighbouring
# insulators (about 2.9 m between the two strings of a strain tower's arm tip).
ASSOCIATION_GATE = 1.2
# The anchor of a box is the median of its nearest points (this fraction by range): the
# insulator is in front of the lattice and conductors seen through the same box.
ANCHOR_NEAR_FRACTION = 0.3
# Fewer culled points than this and a box is not an event (nothing to localize).
MIN_POINTS_PER_BOX = 3
# The localized insulator, projected into the image of the latest event, must span the
# detection box to within this factor (the core's, which its ambiguity rule reads too).
SCALE_TOLERANCE = ir.SCALE_TOLERANCE
# A track's localizations count only once one of its boxes scored at least this (see the module
# docstring, step 6; ByteTrack's high-score threshold). With the shipped insulator-sim network at
# 320 px every true string's track on towers A and B has a box of 0.6-0.9, the tracks on tower
# steel that passed the shape filter peak at 0.3-0.5 (the one at 0.5 gathered 3 localizations:
# the mission's 4 confirmations stop it). Boxes without a score count as confident.
BIRTH_SCORE = 0.5
# A localization resting on fewer points than this is discarded: a handful of returns
# is as likely a lattice member or a conductor clamp as the insulator.
MIN_LOCALIZATION_POINTS = 10
# the not_insulator reason of a box the bounded method refused as ambiguous
# (ir.AmbiguousLocalizationError: another, larger line in the box fits the known length about as well)
AMBIGUOUS = "ambiguous: a larger line elsewhere in the box"
# s: LiDAR points stamped this close to a frame's exposure are "of the same instant": one
# Mid-360 frame (100 ms) on either side, so a scan ending at the exposure pairs whole.
PAIRING_WINDOW = 0.1
# s of LiDAR data kept for pairing, behind the newest point: a frame waits up to
# PAIRING_WAIT past its window for late scans (pairing.py), and its window's points must still
# be here then, however the scans were cut (a live driver's 100 ms scans, the simulator's
# windows, a replay's recorded scans). Counting scans instead (5 were kept) lost the window of a
# frame whose LiDAR came late in small pieces.
SCAN_KEEP_S = 3.0


@dataclass
class TrackEvidence:
    """What one track gathered over the run, for the per-track figures a crew or a model card
    reads (``summary.json`` ``tracks``): the evidence BIRTH_SCORE and the registry's
    confirmations judge. Counts of box events, of those scoring at least BIRTH_SCORE, of
    localizations handed on, of those held back until a confident box (birth rule), and of
    attempts refused (failed, implausible for the box, not an insulator's shape, ambiguous)."""

    boxes: int = 0
    confident_boxes: int = 0
    localizations: int = 0
    held_before_birth: int = 0
    refused: int = 0
    first_time: float = float("nan")
    last_time: float = float("nan")

    def add_box(self, score: float, time: float) -> None:
        self.boxes += 1
        self.confident_boxes += int(score >= BIRTH_SCORE)
        if self.boxes == 1:
            self.first_time = time
        self.last_time = time


@dataclass
class Track:
    """The recent detection events of one (putative) insulator: culled points in W."""

    anchor: np.ndarray
    events: deque[np.ndarray] = field(default_factory=lambda: deque(maxlen=EVENTS_PER_LOCALIZATION))
    # (box, T_w_c, camera) of each event in ``events``: the bounded method's image bounds.
    views: deque[tuple[np.ndarray, np.ndarray, ir.CameraModel]] = field(
        default_factory=lambda: deque(maxlen=EVENTS_PER_LOCALIZATION))
    # Shed relief (m) of each shape-checked localization of this track (insulator_shape).
    reliefs: list[float] = field(default_factory=list)
    # The best detection score among this track's boxes (birth rule, BIRTH_SCORE).
    best_score: float = 0.0
    evidence: TrackEvidence = field(default_factory=TrackEvidence)


@dataclass(frozen=True)
class LocalizedInsulator:
    """An insulator localized in W: ``center`` (3,) m, unit ``axis``, ``n_points`` used,
    ``time`` (s, vehicle clock) of the frame that completed it. (The Rust core's
    ``ir.Localization`` is the same estimate in B, before it is moved to W.)"""

    center: np.ndarray
    axis: np.ndarray
    n_points: int
    time: float = float("nan")


@dataclass
class PerceptionCounters:
    """What the pipeline did, for the report: frames processed, frames with no scan points or
    no pose to pair with, localizations that failed, were implausible (size vs box), did not
    look like an insulator (shape), or were made."""

    frames: int = 0
    unpaired: int = 0
    # frames whose instant the pose history does not cover (older than its oldest pose, or past
    # its newest by more than poses.POSE_GAP_S): refused, as a clamped pose would misplace them
    outside_poses: int = 0
    few_points: int = 0  # boxes with fewer than MIN_POINTS_PER_BOX culled points (no event)
    accumulating: int = 0  # box events of a track still short of EVENTS_PER_LOCALIZATION
    tracks: int = 0  # tracks started (a box whose anchor matched none within ASSOCIATION_GATE)
    failures: int = 0
    implausible: int = 0
    not_insulator: int = 0  # refused by the false-find filter (reasons in ``not_insulator``)
    unconfirmed: int = 0  # of a track without a confident box yet (BIRTH_SCORE)
    localizations: int = 0


class PerceptionPipeline:
    """Turns detection events into localizations in W (see the module docstring).

    ``camera``/``T_b_c``/``T_b_l`` are the rig's; :meth:`process` takes the intrinsics and
    camera pose of each frame and the extrinsics of each scan from the data themselves (a
    gimbal, a binned detection image), :meth:`event` uses these. ``method`` is a
    :class:`~insulator_rs.perception.localization_method.LocalizationMethod` (or its name); ``localize_params``
    are passed to ``ir.localize`` whatever the method (its defaults otherwise).
    """

    def __init__(self, camera: ir.CameraModel, T_b_c: np.ndarray, T_b_l: np.ndarray, *,
                 method: LocalizationMethod | str = DEFAULT_METHOD, insulator_length: float | None = None,
                 pairing_window: float = PAIRING_WINDOW, localize_params: dict[str, Any] | None = None,
                 deskew: bool = True) -> None:
        self.method = LocalizationMethod.parse(method)
        if not (np.isfinite(pairing_window) and pairing_window > 0):
            raise ValueError(f"pairing_window: must be a finite number > 0, got {pairing_window!r}")
        self.camera = camera
        self.T_b_c = np.asarray(T_b_c, dtype=np.float64)
        self.T_b_l = np.asarray(T_b_l, dtype=np.float64)
        self.insulator_length = insulator_length
        self.pairing_window = float(pairing_window)
        self.localize_params = dict(localize_params or {})  # ir.localize tuning overrides (eps, tau...)
        # False: a frame's nearest scan is used as measured, at the frame's pose (the comparison
        # a replay offers with --no-deskew: what motion compensation buys)
        self.deskew = bool(deskew)
        self.tracks: list[Track] = []
        self.poses = PoseHistory()
        self.scans: deque[LidarScan] = deque()
        self.counters = PerceptionCounters()
        # Localizations refused because the cluster does not look like an insulator, by reason.
        self.not_insulator: dict[str, int] = {}
        # the points (W) paired with the latest frame processed, and the body pose at its exposure
        self.last_paired: tuple[np.ndarray, np.ndarray] | None = None

    # kept as attributes for the studies' tables
    @property
    def failures(self) -> int:
        return self.counters.failures

    @property
    def implausible(self) -> int:
        return self.counters.implausible

    def track_records(self) -> list[dict[str, Any]]:
        """Each track that gathered enough box events for a localization attempt
        (EVENTS_PER_LOCALIZATION): where it is (its anchor in W, the last localization once it
        has one) and its evidence, most localizations first. Tracks of fewer boxes never reached
        the registry and are only counted (``perception.tracks``)."""
        rows = []
        for t in self.tracks:
            e = t.evidence
            if e.boxes < EVENTS_PER_LOCALIZATION:
                continue
            rows.append({"center": [float(v) for v in t.anchor], "boxes": e.boxes, "best_score": t.best_score,
                         "confident_boxes": e.confident_boxes, "localizations": e.localizations,
                         "held_before_birth": e.held_before_birth, "refused": e.refused,
                         "first_time": e.first_time, "last_time": e.last_time})
        return sorted(rows, key=lambda r: (-r["localizations"], -r["boxes"]))

    def refused_tracks(self, min_confident_boxes: int) -> list[Track]:
        """Tracks boxed with confidence (``min_confident_boxes`` at BIRTH_SCORE or more) whose every
        localization attempt the gates refused: never in the registry, so never a candidate. A
        string boxed in fragments looks so (the flight's second look, flight/second_look.py)."""
        return [t for t in self.tracks
                if t.evidence.localizations == 0 and t.evidence.held_before_birth == 0
                and t.evidence.refused > 0 and t.evidence.confident_boxes >= min_confident_boxes]

    # -- live / replay ----------------------------------------------------------------------
    def add_pose(self, pose: PoseStamped) -> None:
        """The vehicle's estimated pose (feed every control tick, in time order)."""
        self.poses.add(pose)

    def add_scan(self, scan: LidarScan) -> None:
        """A LiDAR scan with per-point times (kept for pairing with the next frames)."""
        if len(scan):
            self.scans.append(scan)
            newest = max(s.time_end for s in self.scans)
            while self.scans and self.scans[0].time_end < newest - SCAN_KEEP_S:
                self.scans.popleft()

    def process(self, frame: CameraFrame, boxes: np.ndarray) -> list[LocalizedInsulator]:
        """One detection event: ``frame`` and its detection ``boxes`` (K, 4 or 5) px, paired with
        the buffered scans' points of the same instant, deskewed with the pose history."""
        self.counters.frames += 1
        boxes = _as_boxes(boxes)
        if len(boxes) == 0:
            return []
        if len(self.poses) == 0:
            self.counters.unpaired += 1
            return []
        if not self.poses.covers(frame.time):
            self.counters.outside_poses += 1
            return []
        T_w_b = self.poses.pose_at(frame.time)
        culled: list[np.ndarray] | None = None
        if self.deskew:
            T_c_w = np.linalg.inv(T_w_b @ frame.T_b_c)
            points_w, culled = self.paired_points_in_boxes_w(frame.time, T_c_w, frame.camera, boxes)
        else:
            points_w = self._nearest_scan_w(frame.time)
        if len(points_w) == 0:
            self.counters.unpaired += 1
            return []
        self.last_paired = (points_w, T_w_b)  # for a viewer (the replay's Rerun log)
        return self._event_w(boxes, points_w, T_w_b, frame.camera, frame.T_b_c, frame.time, culled)

    def _paired_scans(self, time: float) -> list[tuple[LidarScan, np.ndarray]]:
        """Each buffered scan with points within the pairing window of ``time`` and the pose
        history's span, with the boolean mask of those points."""
        out = []
        for scan in self.scans:
            times = np.asarray(scan.times)
            near = (np.abs(times - time) <= self.pairing_window) & self.poses.covering(times)
            if np.any(near):
                out.append((scan, near))
        return out

    def paired_points_w(self, time: float) -> np.ndarray:
        """The buffered scans' points within the pairing window of ``time`` and the pose
        history's span, each moved to W with the pose at its own time."""
        parts = [self.scan_points_w(scan, near) for scan, near in self._paired_scans(time)]
        return np.vstack(parts) if parts else np.zeros((0, 3))

    def paired_points_in_boxes_w(self, time: float, T_c_w: np.ndarray, camera: ir.CameraModel,
                                 boxes: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """``paired_points_w(time)`` and, for each of ``boxes`` (K, 4 or 5) px, the ascending
        indices of those points inside it, seen by ``camera`` at ``T_c_w`` (4x4): what
        ``ir.points_in_boxes`` gives on them, deskewed and culled in one fused pass a scan."""
        parts: list[np.ndarray] = []
        lists: list[list[np.ndarray]] = [[] for _ in range(len(boxes))]
        offset = 0
        for scan, near in self._paired_scans(time):
            pts_w, culled = self._deskew_to_w(scan, near, (T_c_w, camera, boxes))
            for k, idx in enumerate(culled):
                lists[k].append(idx + offset)
            parts.append(pts_w)
            offset += len(pts_w)
        points_w = np.vstack(parts) if parts else np.zeros((0, 3))
        return points_w, [np.concatenate(k) if k else np.zeros(0, dtype=np.int64) for k in lists]

    def scan_points_w(self, scan: LidarScan, select: np.ndarray | None = None) -> np.ndarray:
        """The points of ``scan`` (those ``select`` picks, a boolean mask; all by default), each
        moved to W with the pose at its own time (the pose history's; empty before any pose)."""
        if len(self.poses) == 0:
            return np.zeros((0, 3))
        return self._deskew_to_w(scan, select)[0]

    def _deskew_to_w(self, scan: LidarScan, select: np.ndarray | None,
                     cull: tuple[np.ndarray, ir.CameraModel, np.ndarray] | None = None
                     ) -> tuple[np.ndarray, list[np.ndarray]]:
        """The points of ``scan`` that ``select`` picks (all with None) deskewed to W and, with
        ``cull = (T_c_w, camera, boxes)``, the indices of them inside each box (else none)."""
        knots_t, knots_T = self.poses.knots()
        keep = np.ones(len(scan.times), dtype=bool) if select is None else select
        # the history clamps outside its span (a point newer than the newest pose): as PoseTrack
        t = np.clip(np.asarray(scan.times, dtype=np.float64)[keep], knots_t[0], knots_t[-1])
        T_b_l = np.asarray(scan.T_b_l, dtype=np.float64)
        points_l, t_ref = np.asarray(scan.points_l)[keep], float(knots_t[-1])
        T_w_l = knots_T[-1] @ T_b_l
        # fusion_core's deskew (slerp + lerp per point) to L at the newest pose, then to W
        culled: list[np.ndarray] = []
        if cull is None:
            pts_l = ir.deskew(points_l, t, knots_t, knots_T, t_ref, T_b_l)
        else:
            T_c_w, camera, boxes = cull
            pts_l, culled = ir.deskew_points_in_boxes(points_l, t, knots_t, knots_T, t_ref, T_b_l,
                                                      T_c_w @ T_w_l, camera, boxes)
        return pts_l @ T_w_l[:3, :3].T + T_w_l[:3, 3], culled

    def _nearest_scan_w(self, time: float) -> np.ndarray:
        """The buffered scan nearest ``time`` (within the pairing window), all its points moved to
        W with the pose at ``time``: no motion compensation."""
        best, gap = None, float("inf")
        for scan in self.scans:
            d = max(scan.time_start - time, time - scan.time_end, 0.0)
            if d < gap:
                best, gap = scan, d
        if best is None or gap > self.pairing_window:
            return np.zeros((0, 3))
        T_w_l = self.poses.pose_at(time) @ np.asarray(best.T_b_l, dtype=np.float64)
        return np.asarray(best.points_l, dtype=np.float64) @ T_w_l[:3, :3].T + T_w_l[:3, 3]

    # -- one frame and one scan at a known pose -----------------------------------------------
    def event(self, boxes: np.ndarray, points_l: np.ndarray, T_w_b: np.ndarray,
              time: float = float("nan")) -> list[LocalizedInsulator]:
        """One detection event whose frame and LiDAR points were taken at one body pose ``T_w_b``
        (4x4): ``boxes`` (K, 4 or 5) px in the rig camera's image, ``points_l`` (N, 3) in L."""
        self.counters.frames += 1
        boxes = _as_boxes(boxes)
        if len(boxes) == 0 or len(points_l) == 0:
            return []
        T_w_l = np.asarray(T_w_b, dtype=np.float64) @ self.T_b_l
        points_w = np.asarray(points_l, dtype=np.float64) @ T_w_l[:3, :3].T + T_w_l[:3, 3]
        return self._event_w(boxes, points_w, np.asarray(T_w_b, dtype=np.float64), self.camera,
                             self.T_b_c, time)

    # -- the shared core ----------------------------------------------------------------------
    def _event_w(self, boxes: np.ndarray, points_w: np.ndarray, T_w_b: np.ndarray,
                 camera: ir.CameraModel, T_b_c: np.ndarray, time: float,
                 culled: list[np.ndarray] | None = None) -> list[LocalizedInsulator]:
        """One event from ``points_w`` and, when the fused pass made them, their box lists."""
        T_w_c = T_w_b @ T_b_c
        T_c_w = np.linalg.inv(T_w_c)
        if culled is None:
            culled = ir.points_in_boxes(points_w, T_c_w, camera, boxes)
        T_b_w = np.linalg.inv(T_w_b)
        out = []
        for box, idx in zip(boxes, culled):
            if len(idx) < MIN_POINTS_PER_BOX:
                self.counters.few_points += 1
                continue
            pts_w = points_w[idx]
            rng = np.linalg.norm(pts_w - T_w_c[:3, 3], axis=1)
            near = rng <= np.quantile(rng, ANCHOR_NEAR_FRACTION)
            anchor = np.median(pts_w[near], axis=0)
            track = self._associate(anchor)
            score = float(box[4]) if len(box) > 4 else 1.0
            track.best_score = max(track.best_score, score)
            track.evidence.add_box(score, time)
            track.events.append(pts_w)
            track.views.append((np.asarray(box[:4], dtype=np.float64), T_w_c, camera))
            if len(track.events) < EVENTS_PER_LOCALIZATION:
                self.counters.accumulating += 1
                continue
            acc_w = np.vstack(list(track.events))
            acc_b = acc_w @ T_b_w[:3, :3].T + T_b_w[:3, 3]
            try:
                est = self._localize(acc_b, track, T_b_w)
            except ir.AmbiguousLocalizationError:
                self.counters.not_insulator += 1
                self.not_insulator[AMBIGUOUS] = self.not_insulator.get(AMBIGUOUS, 0) + 1
                track.evidence.refused += 1
                continue
            except ir.LocalizationError:
                self.counters.failures += 1
                track.evidence.refused += 1
                continue
            if est.n_points < MIN_LOCALIZATION_POINTS:
                self.counters.failures += 1
                track.evidence.refused += 1
                continue
            center = T_w_b[:3, :3] @ np.asarray(est.center) + T_w_b[:3, 3]
            axis = T_w_b[:3, :3] @ np.asarray(est.direction)
            if not self._scale_plausible(center, axis, box, T_c_w, camera):
                self.counters.implausible += 1
                track.evidence.refused += 1
                continue
            if not self._looks_like_insulator(acc_b, est, center, axis, box, T_c_w, camera, track):
                self.counters.not_insulator += 1
                track.evidence.refused += 1
                continue
            track.anchor = center
            if track.best_score < BIRTH_SCORE:
                self.counters.unconfirmed += 1
                track.evidence.held_before_birth += 1
                continue
            self.counters.localizations += 1
            track.evidence.localizations += 1
            # the fitted line lies on the surface the LiDAR saw: report the string's axis behind it
            offset_b = surface_to_axis(acc_b, np.asarray(est.center), np.asarray(est.direction), self.T_b_l[:3, 3])
            center = center + T_w_b[:3, :3] @ offset_b
            out.append(LocalizedInsulator(center, axis / np.linalg.norm(axis), int(est.n_points), float(time)))
        return out

    def _localize(self, acc_b: np.ndarray, track: Track, T_b_w: np.ndarray) -> ir.Localization:
        """The configured method on the accumulated cloud (B of the latest event), with the
        track's boxes where the method reads them, and the tuning overrides whatever the method."""
        image: dict[str, Any] = {}
        if self.method.needs_boxes:
            image = {"boxes": np.array([b for b, _, _ in track.views]),
                     "T_b_c": np.array([T_b_w @ T_w_c for _, T_w_c, _ in track.views]),
                     "cam": track.views[-1][2], "insulator_length": self.insulator_length}
        return ir.localize(acc_b, self.method, **image, **self.localize_params)

    def _looks_like_insulator(self, acc_b: np.ndarray, est: ir.Localization,
                              center: np.ndarray, axis: np.ndarray, box: np.ndarray, T_c_w: np.ndarray,
                              camera: ir.CameraModel, track: Track) -> bool:
        """The false-find filter (insulator_shape): the points on the line and the box must look like
        a string of the mission's insulators. True without a known length."""
        if self.insulator_length is None:
            return True
        shape = cluster_shape(line_members(acc_b, np.asarray(est.center), np.asarray(est.direction)))
        if shape is not None:
            track.reliefs.append(shape.relief)
        aspect = box_aspect_ratio(center, axis, box, T_c_w, camera, length=self.insulator_length)
        verdict = check_insulator_shape(shape, insulator_length=self.insulator_length, aspect_ratio=aspect,
                                        relief_history=track.reliefs)
        for reason in verdict.reasons:
            key = reason.split(" (")[0]
            self.not_insulator[key] = self.not_insulator.get(key, 0) + 1
        return verdict.ok

    def _scale_plausible(self, center: np.ndarray, axis: np.ndarray, box: np.ndarray,
                         T_c_w: np.ndarray, camera: ir.CameraModel) -> bool:
        """Whether an insulator of the known length at ``center`` along ``axis`` (W) would span
        the box (its longer side, px) to within SCALE_TOLERANCE. True without a known length."""
        ratio = self._scale_ratio(center, axis, box, T_c_w, camera)
        return ratio is None or 1.0 / SCALE_TOLERANCE <= ratio <= SCALE_TOLERANCE

    def _scale_ratio(self, center: np.ndarray, axis: np.ndarray, box: np.ndarray,
                     T_c_w: np.ndarray, camera: ir.CameraModel) -> float | None:
        """The projected span (px) of an insulator of the known length at ``center`` along ``axis``
        (W) over the box's longer side; None without a known length or with an end behind the
        camera."""
        if self.insulator_length is None:
            return None
        half = 0.5 * self.insulator_length * axis / np.linalg.norm(axis)
        uv, _ = ir.project_points(np.stack([center - half, center + half]), T_c_w, camera)
        if not np.all(np.isfinite(uv)):
            return None  # an end behind the camera: no scale to compare
        predicted = float(np.max(np.abs(uv[1] - uv[0])))
        measured = float(max(box[2] - box[0], box[3] - box[1]))
        return predicted / max(measured, 1.0)

    def _associate(self, anchor: np.ndarray) -> Track:
        if self.tracks:
            # one array operation over the tracks (a tower holds ~130; a norm each was 5 % of a replay)
            d = np.linalg.norm(np.array([t.anchor for t in self.tracks]) - anchor, axis=1)
            i = int(np.argmin(d))
            if d[i] <= ASSOCIATION_GATE:
                return self.tracks[i]
        track = Track(anchor=anchor)
        self.tracks.append(track)
        self.counters.tracks += 1
        return track


def _as_boxes(boxes: np.ndarray) -> np.ndarray:
    boxes = np.asarray(boxes, dtype=np.float64)
    if boxes.size == 0:
        return np.zeros((0, 4))
    if boxes.ndim != 2 or boxes.shape[1] not in (4, 5):
        raise ValueError(f"boxes: expected shape (K, 4) or (K, 5), got {boxes.shape}")
    return boxes
