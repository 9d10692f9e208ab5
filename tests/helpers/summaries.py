"""Run summaries for the report tests: the typed schema (``report/summary.py``) the writer takes."""

from __future__ import annotations

from typing import Any

import numpy as np

from insulator_rs.report.summary import InsulatorRecord, PerceptionRecord, RunSummary


def run_summary(status: str, *, marker: str = "test", insulators: list[dict[str, Any]] = (),
                photos: list[dict[str, Any]] = ()) -> RunSummary:
    """A flight's summary with ``status``; ``marker`` is its detector's name (tells runs apart)."""
    records = [InsulatorRecord(int(r["id"]), np.asarray(r["center"], dtype=np.float64),
                               np.asarray(r["axis"], dtype=np.float64), int(r.get("observations", 1)),
                               int(r.get("side", 1)), bool(r.get("confirmed", True)), bool(r.get("inspected", False)),
                               list(r.get("photos", [])))
               for r in insulators]
    return RunSummary(run="flight", status=status, detector=marker, method="bounded", flight_time_s=0.0,
                      perception=PerceptionRecord(), insulators=records, photos=list(photos))
