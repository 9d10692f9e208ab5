"""Gaps in our own offboard setpoint stream, as PX4 sees them: what tells the report that PX4
failed safe for a moment.

PX4 v1.16 falls back to ``COM_OBL_RC_ACT`` (Return, as the mission sets it) once no setpoint came
for ``COM_OF_LOSS_T`` (1 s), and *clears* that fallback by itself when setpoints come again: in a
SITL flight (session 17) a 1.19 s stall of the companion put PX4 in RTL at 32.000 s and back in
OFFBOARD at 32.060 s. The client reads the mode from the autopilot's HEARTBEAT, sent at 1 Hz, and
never saw that blip, so the summary said no failsafe while PX4's log and the pilot's ground
station said one happened. The stream's own gaps do not depend on catching a heartbeat: a gap
of ``loss_timeout_s`` or more is, by PX4's rule, an offboard loss.

Gaps are measured between consecutive setpoints sent while the stream runs (not across the
pauses the client makes itself: take-off, landing, leaving OFFBOARD), in vehicle seconds (wall
seconds times the link's time scale, as PX4's timeout counts).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

#: s: PX4's COM_OF_LOSS_T as the mission sets it (planning/px4_failsafes.OFFBOARD_LOSS_TIMEOUT;
#: a test holds them equal; mavlink/ does not import planning/).
OFFBOARD_LOSS_TIMEOUT_S = 1.0
#: s: gaps this long are listed (half the loss timeout: a stream this late is near the edge).
LISTED_GAP_S = 0.5
#: How many of the longest gaps ``record()`` lists.
LONGEST_KEPT = 5


@dataclass
class SetpointGaps:
    """The longest gaps between consecutive setpoints of a running stream (thread-safe)."""

    time_scale: float = 1.0
    loss_timeout_s: float = OFFBOARD_LOSS_TIMEOUT_S
    sent: int = 0
    #: (wall time of the setpoint that ended the gap, gap in vehicle s), gaps >= LISTED_GAP_S
    gaps: list[tuple[float, float]] = field(default_factory=list)
    max_gap_s: float = 0.0
    _last: float | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def sent_at(self, wall: float) -> None:
        """A setpoint went out at ``wall`` (monotonic s)."""
        with self._lock:
            self.sent += 1
            if self._last is not None:
                gap = (wall - self._last) * self.time_scale
                self.max_gap_s = max(self.max_gap_s, gap)
                if gap >= LISTED_GAP_S:
                    self.gaps.append((wall, gap))
            self._last = wall

    def paused(self) -> None:
        """The client stopped the stream itself: the next setpoint starts a new run."""
        with self._lock:
            self._last = None

    def record(self) -> dict[str, Any]:
        """summary.json's ``setpoint_stream``: setpoints sent, the longest gap, the gaps of at
        least :data:`LISTED_GAP_S` (count, longest few) and how many reached PX4's offboard-loss
        timeout (each one a failsafe PX4 flew, if only for a moment)."""
        with self._lock:
            gaps = [g for _, g in self.gaps]
            return {"sent": self.sent, "max_gap_s": round(self.max_gap_s, 3), "listed_from_s": LISTED_GAP_S,
                    "gaps": len(gaps), "longest_s": [round(g, 3) for g in sorted(gaps, reverse=True)[:LONGEST_KEPT]],
                    "offboard_loss_timeout_s": self.loss_timeout_s,
                    "past_offboard_loss": sum(1 for g in gaps if g >= self.loss_timeout_s)}
