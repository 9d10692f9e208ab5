"""The garbage collector's pauses during a flight: measured, and kept off the setpoint stream.

CPython's cyclic collector runs inside whichever thread allocates past its threshold and holds
the GIL for the whole collection: a full (generation 2) collection walks every tracked object
of the process. The companion's heap at take-off is about 139,000 such objects (numpy,
onnxruntime, OpenCV, pymavlink's message classes, the mission): a full collection took 74 ms on a
quiet box and 181 ms on a loaded one (session 17), and longer still when the process shares its
CPUs with PX4 and the sensors (a Jetson running TensorRT beside it): long enough to stop the
offboard setpoints PX4 fails safe on (``COM_OF_LOSS_T``). The stall watch
(``flight/stall_watch.py``) caught three stalls of 0.6-1.2 s in live SITL flights (session 17),
each at an allocation-heavy statement where the collector runs (the summary's trajectory copy,
twice; the planner's refinement loop).

* :class:`GcPauseLog` times every collection through ``gc.callbacks`` (per generation: count,
  longest, total; the longest few with their times) for ``summary.json``.
* :func:`startup_heap_frozen` collects once and then moves everything alive into the
  collector's permanent generation for the flight (``gc.freeze()``, as the CPython documentation
  suggests for long-lived startup state): the modules, the detector and the mission are not
  walked again, and a full collection in flight walks only what the flight itself allocated.
  Frozen objects that become garbage are still freed by their reference counts; only cycles
  among them wait, until the flight ends and ``gc.unfreeze()`` hands them back (a process that
  flies many times, as the tests do, does not keep them).
"""

from __future__ import annotations

import gc
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

#: How many of the longest collections ``record()`` lists.
LONGEST_KEPT = 5


@dataclass
class GcPauseLog:
    """Times the collector's runs while started (``gc.callbacks``)."""

    clock: Any = time.perf_counter
    #: (time since start s, generation, length s, objects collected) of every collection
    pauses: list[tuple[float, int, float, int]] = field(default_factory=list)
    _t0: float = 0.0
    _began: float | None = None
    _started: bool = False

    def start(self) -> GcPauseLog:
        self._t0 = self.clock()
        if not self._started:
            gc.callbacks.append(self._callback)
            self._started = True
        return self

    def stop(self) -> None:
        if self._started:
            gc.callbacks.remove(self._callback)
            self._started = False

    def _callback(self, phase: str, info: dict[str, int]) -> None:
        # Runs inside the collecting thread with the GIL held: only a clock read and an append.
        now = self.clock()
        if phase == "start":
            self._began = now
        elif self._began is not None:
            self.pauses.append((self._began - self._t0, int(info.get("generation", -1)), now - self._began,
                                int(info.get("collected", 0))))
            self._began = None

    def record(self) -> dict[str, Any]:
        """Per generation ``{"count", "max_ms", "total_s"}`` and the longest collections."""
        generations: dict[str, dict[str, float]] = {}
        for _, gen, length, _ in self.pauses:
            g = generations.setdefault(str(gen), {"count": 0, "max_ms": 0.0, "total_s": 0.0})
            g["count"] += 1
            g["max_ms"] = max(g["max_ms"], round(length * 1e3, 2))
            g["total_s"] = round(g["total_s"] + length, 4)
        worst = sorted(self.pauses, key=lambda p: -p[2])[:LONGEST_KEPT]
        return {"generations": generations, "frozen_objects": gc.get_freeze_count(),
                "longest": [{"time_s": round(t, 2), "generation": gen, "length_ms": round(length * 1e3, 2),
                             "collected": collected} for t, gen, length, collected in worst]}


@contextmanager
def startup_heap_frozen() -> Iterator[int]:
    """Within: every object alive at entry is out of the collector's walks (see the module
    docstring); gives how many objects that is. At exit they are handed back."""
    gc.collect()
    gc.freeze()
    try:
        yield gc.get_freeze_count()
    finally:
        gc.unfreeze()
