"""Onboard perception for the mission: detection boxes + a LiDAR frame -> insulator localizations.

Per detection event (one camera image with its boxes and the LiDAR frame taken
with it) the points of each box are culled with ``ir.points_in_boxes`` and
moved into W with the vehicle's pose. Boxes are associated across events by
the W position of their points (median), so each track holds the culled points
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

Method = Literal["dbscan", "ransac", "dbscan+ransac", "dbscan+pca"]
EVENTS_PER_LOCALIZATION = 3
# m: a box whose points' median lies this close to a track's belongs to it.
ASSOCIATION_GATE = 2.5
# Fewer culled points than this and a box is not an event (nothing to localize).
MIN_POINTS_PER_BOX = 3
# A localization resting on fewer points than this is discarded: a handful of returns
# is as likely a lattice member or a conductor clamp as the insulator.
MIN_LOCALIZATION_POINTS = 10


@dataclass
class Track:
    """The recent detection events of one (putative) insulator: culled points in W."""

    anchor: np.ndarray
    events: deque = field(default_factory=lambda: deque(maxlen=EVENTS_PER_LOCALIZATION))


@dataclass(frozen=True)
class Localization:
    """An insulator localized in W: ``center`` (3,) m, unit ``axis``, ``n_points`` used."""

    center: np.ndarray
    axis: np.ndarray
    n_points: int


class OnboardPerception:
    """Turns detection events into localizations in W (see the module docstring)."""

    def __init__(self, camera: ir.CameraModel, T_b_c: np.ndarray, T_b_l: np.ndarray, *,
                 method: str = "dbscan+ransac") -> None:
        self.camera = camera
        self.T_b_l = np.asarray(T_b_l, dtype=np.float64)
        self.T_c_l = np.linalg.inv(np.asarray(T_b_c, dtype=np.float64)) @ self.T_b_l
        self.method = method
        self.tracks: list[Track] = []
        self.failures = 0

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
        for idx in culled:
            if len(idx) < MIN_POINTS_PER_BOX:
                continue
            pts_w = points_l[idx] @ T_w_l[:3, :3].T + T_w_l[:3, 3]
            anchor = np.median(pts_w, axis=0)
            track = self._associate(anchor)
            track.events.append(pts_w)
            if len(track.events) < EVENTS_PER_LOCALIZATION:
                continue
            acc_w = np.vstack(list(track.events))
            acc_b = acc_w @ T_b_w[:3, :3].T + T_b_w[:3, 3]
            try:
                est = ir.localize(acc_b, method=cast(Method, self.method))
            except ir.LocalizationError:
                self.failures += 1
                continue
            if est.n_points < MIN_LOCALIZATION_POINTS:
                self.failures += 1
                continue
            center = T_w_b[:3, :3] @ np.asarray(est.center) + T_w_b[:3, 3]
            axis = T_w_b[:3, :3] @ np.asarray(est.direction)
            track.anchor = center
            out.append(Localization(center, axis / np.linalg.norm(axis), int(est.n_points)))
        return out

    def _associate(self, anchor: np.ndarray) -> Track:
        if self.tracks:
            d = [float(np.linalg.norm(t.anchor - anchor)) for t in self.tracks]
            i = int(np.argmin(d))
            if d[i] <= ASSOCIATION_GATE:
                return self.tracks[i]
        track = Track(anchor=anchor)
        self.tracks.append(track)
        return track
