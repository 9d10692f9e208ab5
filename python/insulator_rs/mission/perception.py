"""Onboard perception for the mission: detection boxes + a LiDAR frame -> insulator localizations.

Per detection event (one camera image with its boxes and the LiDAR frame taken
with it) the points of each box are culled with ``ir.points_in_boxes`` and
moved into W with the vehicle's pose. Boxes are associated across events by
the W position of their nearest points (median), so each track holds the culled points
of the last :data:`EVENTS_PER_LOCALIZATION` detection events of one insulator,
as the paper accumulates three. Once a track has them, the accumulated points
are expressed in the current body frame B and localized with ``ir.localize``;
the result goes back to W.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Literal, cast

import numpy as np

import insulator_rs as ir
from insulator_rs.mission.insulator_shape import box_aspect_ratio, check_insulator_shape, cluster_shape, line_members

Method = Literal["dbscan", "ransac", "dbscan+ransac", "dbscan+pca"]
# The fifth method (ir.localize_bounded): the LiDAR line, its ends from the events' boxes.
BOUNDED = "bounded"
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
# detection box to within this factor: a far-side insulator seen through the lattice
# gets localized on the nearer lattice, and then looks too long for its box.
SCALE_TOLERANCE = 1.5
# A localization resting on fewer points than this is discarded: a handful of returns
# is as likely a lattice member or a conductor clamp as the insulator.
MIN_LOCALIZATION_POINTS = 10


@dataclass
class Track:
    """The recent detection events of one (putative) insulator: culled points in W."""

    anchor: np.ndarray
    events: deque = field(default_factory=lambda: deque(maxlen=EVENTS_PER_LOCALIZATION))
    # (box, T_w_b) of each event in ``events``: the bounded method's image bounds.
    views: deque = field(default_factory=lambda: deque(maxlen=EVENTS_PER_LOCALIZATION))
    # Shed relief (m) of each shape-checked localization of this track (insulator_shape).
    reliefs: list = field(default_factory=list)


@dataclass(frozen=True)
class Localization:
    """An insulator localized in W: ``center`` (3,) m, unit ``axis``, ``n_points`` used."""

    center: np.ndarray
    axis: np.ndarray
    n_points: int


class OnboardPerception:
    """Turns detection events into localizations in W (see the module docstring)."""

    def __init__(self, camera: ir.CameraModel, T_b_c: np.ndarray, T_b_l: np.ndarray, *,
                 method: str = "dbscan+ransac", insulator_length: float | None = None) -> None:
        self.camera = camera
        self.T_b_l = np.asarray(T_b_l, dtype=np.float64)
        self.T_c_l = np.linalg.inv(np.asarray(T_b_c, dtype=np.float64)) @ self.T_b_l
        self.method = method
        self.insulator_length = insulator_length
        self.T_b_c = np.asarray(T_b_c, dtype=np.float64)
        self.tracks: list[Track] = []
        self.failures = 0
        self.implausible = 0
        # Localizations refused because the cluster does not look like an insulator, by reason.
        self.not_insulator: dict[str, int] = {}

    def event(self, boxes: np.ndarray, points_l: np.ndarray, T_w_b: np.ndarray) -> list[Localization]:
        """One detection event: ``boxes`` (K, 4 or 5) px, the LiDAR frame ``points_l`` (N, 3) in L,
        the body pose ``T_w_b`` (4x4). Returns the localizations it made possible."""
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, boxes.shape[-1] if len(boxes) else 4)
        if len(boxes) == 0 or len(points_l) == 0:
            return []
        T_w_l = T_w_b @ self.T_b_l
        culled = ir.points_in_boxes(points_l, self.T_c_l, self.camera, boxes)
        T_b_w = np.linalg.inv(T_w_b)
        out = []
        for box, idx in zip(boxes, culled):
            if len(idx) < MIN_POINTS_PER_BOX:
                continue
            pts_w = points_l[idx] @ T_w_l[:3, :3].T + T_w_l[:3, 3]
            rng = np.linalg.norm(points_l[idx], axis=1)
            near = rng <= np.quantile(rng, ANCHOR_NEAR_FRACTION)
            anchor = np.median(pts_w[near], axis=0)
            track = self._associate(anchor)
            track.events.append(pts_w)
            track.views.append((np.asarray(box[:4], dtype=np.float64), np.asarray(T_w_b, dtype=np.float64)))
            if len(track.events) < EVENTS_PER_LOCALIZATION:
                continue
            acc_w = np.vstack(list(track.events))
            acc_b = acc_w @ T_b_w[:3, :3].T + T_b_w[:3, 3]
            try:
                est = self._localize(acc_b, track, T_b_w)
            except ir.LocalizationError:
                self.failures += 1
                continue
            if est.n_points < MIN_LOCALIZATION_POINTS:
                self.failures += 1
                continue
            center = T_w_b[:3, :3] @ np.asarray(est.center) + T_w_b[:3, 3]
            axis = T_w_b[:3, :3] @ np.asarray(est.direction)
            if not self._scale_plausible(center, axis, box, T_w_b):
                self.implausible += 1
                continue
            if not self._looks_like_insulator(acc_b, est, center, axis, box, T_w_b, track):
                continue
            track.anchor = center
            out.append(Localization(center, axis / np.linalg.norm(axis), int(est.n_points)))
        return out

    def _localize(self, acc_b: np.ndarray, track: Track, T_b_w: np.ndarray) -> ir.Localization | ir.BoundedLocalization:
        """The configured method on the accumulated cloud (B of the latest event)."""
        if self.method != BOUNDED:
            return ir.localize(acc_b, method=cast(Method, self.method))
        boxes = np.array([b for b, _ in track.views])
        T_b_c = np.array([T_b_w @ T @ self.T_b_c for _, T in track.views])
        return ir.localize_bounded(acc_b, boxes, T_b_c, self.camera, insulator_length=self.insulator_length)

    def _looks_like_insulator(self, acc_b: np.ndarray, est: ir.Localization | ir.BoundedLocalization,
                              center: np.ndarray, axis: np.ndarray, box: np.ndarray, T_w_b: np.ndarray,
                              track: Track) -> bool:
        """The false-find filter (insulator_shape): the points on the line and the box must look like
        a string of the mission's insulators. True without a known length."""
        if self.insulator_length is None:
            return True
        shape = cluster_shape(line_members(acc_b, np.asarray(est.center), np.asarray(est.direction)))
        if shape is not None:
            track.reliefs.append(shape.relief)
        T_c_w = np.linalg.inv(T_w_b @ self.T_b_c)
        aspect = box_aspect_ratio(center, axis, box, T_c_w, self.camera, length=self.insulator_length)
        verdict = check_insulator_shape(shape, insulator_length=self.insulator_length, aspect_ratio=aspect,
                                        relief_history=track.reliefs)
        for reason in verdict.reasons:
            key = reason.split(" (")[0]
            self.not_insulator[key] = self.not_insulator.get(key, 0) + 1
        return verdict.ok

    def _scale_plausible(self, center: np.ndarray, axis: np.ndarray, box: np.ndarray,
                         T_w_b: np.ndarray) -> bool:
        """Whether an insulator of the known length at ``center`` along ``axis`` (W) would span
        the box (its longer side, px) to within SCALE_TOLERANCE. True without a known length."""
        if self.insulator_length is None:
            return True
        half = 0.5 * self.insulator_length * axis / np.linalg.norm(axis)
        T_c_w = np.linalg.inv(T_w_b @ self.T_b_c)
        uv, _ = ir.project_points(np.stack([center - half, center + half]), T_c_w, self.camera)
        if not np.all(np.isfinite(uv)):
            return True  # an end behind the camera: no scale to compare
        predicted = float(np.max(np.abs(uv[1] - uv[0])))
        measured = float(max(box[2] - box[0], box[3] - box[1]))
        ratio = predicted / max(measured, 1.0)
        return 1.0 / SCALE_TOLERANCE <= ratio <= SCALE_TOLERANCE

    def _associate(self, anchor: np.ndarray) -> Track:
        if self.tracks:
            d = [float(np.linalg.norm(t.anchor - anchor)) for t in self.tracks]
            i = int(np.argmin(d))
            if d[i] <= ASSOCIATION_GATE:
                return self.tracks[i]
        track = Track(anchor=anchor)
        self.tracks.append(track)
        return track
