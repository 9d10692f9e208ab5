"""Is the companion process stalling? A watch on the whole interpreter during a flight.

PX4 fails safe ``COM_OF_LOSS_T`` (1 s) after the last offboard setpoint, and the setpoints are
streamed by a Python thread (``mavlink/client.py``): a stall of the whole interpreter (one C call
holding the GIL, the process starved of CPU) stops the stream, the TIMESYNC answers and every
sensor's hand-off at once, while the flight loop itself notices nothing. Measured against PX4
SITL (session 15, tower B, a loaded box): PX4's ``offboard_control_signal_lost`` after a 2.6 s gap
in our setpoints, and PX4's own TIMESYNC log shows our answers stopped for 3.1 s; PX4's own
topics ran without a gap.

A daemon thread sleeps :data:`TICK_S` at a time and measures how late it wakes: a wake-up later
than ``threshold_s`` is a stall of the interpreter (that thread needs only the GIL and a CPU).
Each is counted with its length and time. With a ``dump`` file the watch also arms
``faulthandler.dump_traceback_later`` (a C thread that needs no GIL) and re-arms it on every tick:
when the interpreter stalls past the threshold, every thread's Python stack is written to that
file *during* the stall, naming the call that held it. The garbage collector's pauses are timed
beside it (:class:`~insulator_rs.flight.gc_pauses.GcPauseLog`), and each stall says how much of it
was a collection.
"""

from __future__ import annotations

import faulthandler
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from insulator_rs.flight.gc_pauses import GcPauseLog

#: s between the watch's wake-ups.
TICK_S = 0.05
#: s: a wake-up this late is a stall. Half of PX4's 1 s offboard-loss time: a stall this long
#: already costs a tenth of the setpoints of a 20 Hz stream in one go.
DEFAULT_THRESHOLD_S = 0.5
#: The report folder's file of the stacks written during stalls.
STALL_STACKS = "companion_stalls.txt"


@dataclass
class StallWatch:
    """Counts the interpreter's stalls (wake-ups later than ``threshold_s``) while started; with
    ``dump``, every thread's stack is written there when one passes the threshold."""

    threshold_s: float = DEFAULT_THRESHOLD_S
    dump: Path | None = None
    clock: Any = time.monotonic
    stalls: list[tuple[float, float]] = field(default_factory=list)  # (time since start, length s)
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _file: IO[str] | None = None
    _t0: float = 0.0
    gc_log: GcPauseLog | None = None

    def __post_init__(self) -> None:
        if not self.threshold_s > TICK_S:
            raise ValueError(f"threshold_s: must be > {TICK_S} s (the watch's tick), got {self.threshold_s!r}")

    def start(self) -> StallWatch:
        if self.dump is not None:
            self._file = open(self.dump, "w", encoding="utf-8")  # noqa: SIM115 (held until stop)
        self._t0 = self.clock()
        self.gc_log = GcPauseLog(clock=self.clock).start()
        self._arm()
        self._thread = threading.Thread(target=self._run, name="stall-watch", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self.gc_log is not None:
            self.gc_log.stop()
        if self._file is not None:
            faulthandler.cancel_dump_traceback_later()
            self._file.close()
            self._file = None

    def record(self) -> dict[str, Any]:
        """summary.json's ``companion_stalls``: threshold, count, longest and total, the longest
        few with their times (s since the watch started) and the collector's share of each
        (``gc_ms``), and the collector's pauses (``gc``)."""
        lengths = [s for _, s in self.stalls]
        worst = sorted(self.stalls, key=lambda s: -s[1])[:5]
        return {"threshold_s": self.threshold_s, "count": len(lengths),
                "max_s": round(max(lengths), 3) if lengths else 0.0,
                "total_s": round(sum(lengths), 3),
                "longest": [{"time_s": round(t, 2), "length_s": round(s, 3),
                             "gc_ms": round(self._collecting(t, t + TICK_S + s) * 1e3, 1)} for t, s in worst],
                "stacks": None if self.dump is None else str(self.dump),
                "gc": None if self.gc_log is None else self.gc_log.record()}

    def _collecting(self, t1: float, t2: float) -> float:
        """s of collector pauses within [t1, t2] (s since start)."""
        if self.gc_log is None:
            return 0.0
        return sum(max(0.0, min(t2, t + length) - max(t1, t)) for t, _, length, _ in self.gc_log.pauses)

    def _arm(self) -> None:
        if self._file is not None:
            faulthandler.dump_traceback_later(self.threshold_s, repeat=False, file=self._file)

    def _run(self) -> None:
        last = self.clock()
        while not self._stop.wait(TICK_S):
            now = self.clock()
            late = now - last - TICK_S
            if late > self.threshold_s:
                self.stalls.append((last - self._t0, late))
            self._arm()
            last = now
