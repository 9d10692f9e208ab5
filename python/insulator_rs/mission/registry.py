"""The world-frame insulator registry: one record per physical insulator.

A new localization within the gate distance of a known insulator's centre
updates that insulator (running mean of the centre, sign-aligned mean of the
axis) instead of creating a duplicate; otherwise it becomes a new insulator.
Each record knows its side of the tower, so the mission can defer insulators
on the far side until the vehicle is there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from insulator_rs.mission.geodesy import LineFrame


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


class InsulatorRegistry:
    """Insulators in W, deduplicated with a distance gate (m)."""

    def __init__(self, line: LineFrame, gate: float) -> None:
        if not gate > 0:
            raise ValueError(f"gate: must be > 0 m, got {gate}")
        self.line = line
        self.gate = gate
        self.insulators: list[Insulator] = []

    def __len__(self) -> int:
        return len(self.insulators)

    def nearest(self, center: np.ndarray) -> tuple[Insulator | None, float]:
        """The registered insulator nearest ``center`` and its distance (m); (None, inf) if empty."""
        if not self.insulators:
            return None, float("inf")
        d = [float(np.linalg.norm(ins.center - center)) for ins in self.insulators]
        i = int(np.argmin(d))
        return self.insulators[i], d[i]

    def observe(self, center: np.ndarray, axis: np.ndarray) -> tuple[Insulator, bool]:
        """Fuse one localization (W); returns the insulator and whether it is new."""
        c = np.asarray(center, dtype=np.float64).reshape(3)
        a = np.asarray(axis, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(a))) or np.linalg.norm(a) < 1e-9:
            raise ValueError("center/axis: must be finite and the axis non-zero")
        a = a / np.linalg.norm(a)
        known, dist = self.nearest(c)
        if known is not None and dist <= self.gate:
            n = known.observations
            known.center = (known.center * n + c) / (n + 1)
            aligned = a if a @ known.axis >= 0 else -a
            mean = known.axis * n + aligned
            known.axis = mean / np.linalg.norm(mean)
            known.observations = n + 1
            known.history.append(c)
            known.side = int(self.line.side(known.center))
            return known, False
        ins = Insulator(id=len(self.insulators) + 1, center=c, axis=a, observations=1,
                        side=int(self.line.side(c)), history=[c])
        self.insulators.append(ins)
        return ins, True
