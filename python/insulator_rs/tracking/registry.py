"""The world-frame insulator registry: one record per physical insulator.

A new localization within the gate distance of a known insulator's centre
updates that insulator (running mean of the centre, sign-aligned mean of the
axis) instead of creating a duplicate; otherwise it becomes a new insulator.
Each record knows its side of the tower, so the mission can defer insulators
on the far side until the vehicle is there.

A record is only *confirmed* (reported, inspected) once ``confirmations``
localizations have fallen within its gate (the rule and its default:
:mod:`insulator_rs.tracking.confirmation`). A second cue may ``doubt`` a record (the LiDAR's
geometry finds no string where it was localized: :mod:`insulator_rs.flight.lidar_cue`): it is
then held for more evidence (more localizations), never confirmed nor dropped by that cue. The
registry stays the only place that confirms.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from insulator_rs.geodesy import LineFrame
from insulator_rs.tracking.confirmation import CONFIRMATIONS, check_confirmations, is_confirmed


@dataclass
class Insulator:
    """A registered insulator in W: ``center`` m, unit ``axis``, ``observations`` fused,
    ``side`` of the tower, whether it has been ``inspected``."""

    id: int
    center: np.ndarray
    axis: np.ndarray
    observations: int
    side: int
    inspected: bool = False
    history: list[np.ndarray] = field(default_factory=list)
    confirmed: bool = False
    # times the registry held it for more evidence, the second cue doubting it (see ``doubt``)
    held: int = 0


class InsulatorRegistry:
    """Insulators in W, deduplicated with a distance gate (m); a record is confirmed
    after ``confirmations`` localizations (1: at once, as the paper does; default: the
    mission's, CONFIRMATIONS). ``doubt(center)``: whether a second cue contradicts a record at
    ``center`` (W) now; such a record needs HELD_FACTOR times the confirmations (None: no doubt)."""

    def __init__(self, line: LineFrame, gate: float, confirmations: int = CONFIRMATIONS, *,
                 doubt: Callable[[np.ndarray], bool] | None = None) -> None:
        if not gate > 0:
            raise ValueError(f"gate: must be > 0 m, got {gate}")
        self.line = line
        self.gate = gate
        self.confirmations = check_confirmations(confirmations)
        self.doubt = doubt
        self._records: list[Insulator] = []

    @property
    def insulators(self) -> list[Insulator]:
        """The confirmed insulators, in order of confirmation (their ids 1, 2, ...)."""
        return sorted((ins for ins in self._records if ins.confirmed), key=lambda ins: ins.id)

    @property
    def candidates(self) -> list[Insulator]:
        """Localizations not yet confirmed (id 0)."""
        return [ins for ins in self._records if not ins.confirmed]

    def __len__(self) -> int:
        return len(self.insulators)

    def nearest(self, center: np.ndarray) -> tuple[Insulator | None, float]:
        """The confirmed insulator nearest ``center`` and its distance (m); (None, inf) if none."""
        return self._nearest(self.insulators, center)

    @staticmethod
    def _nearest(records: list[Insulator], center: np.ndarray) -> tuple[Insulator | None, float]:
        if not records:
            return None, float("inf")
        d = [float(np.linalg.norm(ins.center - center)) for ins in records]
        i = int(np.argmin(d))
        return records[i], d[i]

    def observe(self, center: np.ndarray, axis: np.ndarray) -> tuple[Insulator, bool]:
        """Fuse one localization (W); returns the record and whether it has just been
        confirmed (a new insulator for the mission)."""
        c = np.asarray(center, dtype=np.float64).reshape(3)
        a = np.asarray(axis, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(a))) or np.linalg.norm(a) < 1e-9:
            raise ValueError("center/axis: must be finite and the axis non-zero")
        a = a / np.linalg.norm(a)
        known, dist = self._nearest(self._records, c)
        if known is not None and dist <= self.gate:
            n = known.observations
            known.center = (known.center * n + c) / (n + 1)
            aligned = a if a @ known.axis >= 0 else -a
            mean = known.axis * n + aligned
            known.axis = mean / np.linalg.norm(mean)
            known.observations = n + 1
            known.history.append(c)
            known.side = int(self.line.side(known.center))
            return known, self._confirm(known)
        ins = Insulator(id=0, center=c, axis=a, observations=1,
                        side=int(self.line.side(c)), history=[c])
        self._records.append(ins)
        return ins, self._confirm(ins)

    def _confirm(self, ins: Insulator) -> bool:
        if ins.confirmed or not is_confirmed(ins.observations, self.confirmations):
            return False
        if self.doubt is not None and self.doubt(ins.center):
            ins.held += 1
            if not is_confirmed(ins.observations, self.confirmations, held=True):
                return False
        ins.confirmed = True
        ins.id = len(self.insulators)
        return True
