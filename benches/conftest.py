"""pytest configuration for the side-by-side benchmarks (``pytest benches/ --benchmark-enable``).

* Collects ``bench_*.py`` files (they are not tests and stay out of the test suite).
* After the run, prints a ratio table: in every benchmark group that holds an
  ``insulator_rs`` row (``benchmark.extra_info["impl"]``), how many times slower each
  other implementation is, against the target where one is set; the real-time factor of
  rows that carry ``extra_info["flight_s"]`` (a replay); and for groups whose
  rows carry ``extra_info["n_points"]``, the scaling of time per point with N (in a group
  that also holds other implementations, insulator_rs's time per point).
"""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest

# The plain-numpy reference implementations live with the tests.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def pytest_collect_file(file_path: Path, parent: pytest.Collector) -> pytest.Module | None:
    if (
        file_path.suffix == ".py"
        and file_path.name.startswith("bench_")
        and not parent.session.isinitpath(file_path)  # given by name: pytest collects it itself
    ):
        return pytest.Module.from_parent(parent, path=file_path)
    return None


def _stat_s(bench: Any, field: str = "median") -> float | None:
    stats = getattr(bench, "stats", None)
    stats = getattr(stats, "stats", stats)
    return None if stats is None or not getattr(stats, "rounds", 0) else float(getattr(stats, field))


def _median_s(bench: Any) -> float | None:
    return _stat_s(bench, "median")


def _pair(bench: Any) -> tuple[float, float]:
    """(min, median) seconds of a benchmark that ran."""
    lo, mid = _stat_s(bench, "min"), _stat_s(bench, "median")
    assert lo is not None and mid is not None
    return lo, mid


def _fmt(seconds: float) -> str:
    if seconds < 1e-3:
        return f"{seconds * 1e6:8.1f} µs"
    return f"{seconds * 1e3:8.2f} ms"


def pytest_terminal_summary(terminalreporter: Any, config: pytest.Config) -> None:
    session = getattr(config, "_benchmarksession", None)
    if session is None or getattr(session, "disabled", True):
        return
    groups: dict[str, list[Any]] = defaultdict(list)
    for bench in session.benchmarks:
        if _median_s(bench) is not None and "impl" in bench.extra_info:
            groups[bench.group or bench.name].append(bench)
    if not groups:
        return
    write = terminalreporter.write_line
    write("")
    write(
        "insulator_rs side-by-side: min / median per call; ratio = other / insulator_rs "
        "(> 1: insulator_rs faster), on min and on median"
    )
    for group, benches in groups.items():
        ours = [b for b in benches if b.extra_info["impl"] == "insulator_rs"]
        if "n_points" in benches[0].extra_info and len(ours) == len(benches):
            _scaling(write, group, benches)
            continue
        if not ours:
            continue
        base_min, base_med = _pair(ours[0])
        target = ours[0].extra_info.get("target")
        n_points = ours[0].extra_info.get("n_points")
        write(
            f"  {group}: insulator_rs {_fmt(base_min)} / {_fmt(base_med)}"
            + (f"   ({base_min / n_points * 1e9:.0f} ns/point on min)" if n_points else "")
            + (f"   (absolute target {target})" if target else "")
        )
        flight_s = ours[0].extra_info.get("flight_s")
        if flight_s:  # a replay: recorded flight time over replay wall time
            goal = ours[0].extra_info.get("target_realtime")
            write(f"      real time: {flight_s:.0f} s of flight -> {flight_s / base_min:.1f}x (min) / "
                  f"{flight_s / base_med:.1f}x (median)"
                  + ("" if goal is None else f"   target >= {goal:g}x: "
                     + ("met" if flight_s / base_med >= goal else "missed on median")))
        for other in benches:
            if other is ours[0]:
                continue
            lo, mid = _pair(other)
            goal = other.extra_info.get("target_ratio")
            verdict = "" if goal is None else (
                f"   target >= {goal}x: " + ("met" if mid / base_med >= goal else "missed on median")
            )
            write(
                f"      vs {other.extra_info['impl']:<26} {_fmt(lo)} / {_fmt(mid)}   "
                f"ratio {lo / base_min:7.1f}x / {mid / base_med:7.1f}x{verdict}"
            )


def _scaling(write: Any, group: str, benches: list[Any]) -> None:
    rows = sorted(benches, key=lambda b: b.extra_info["n_points"])
    first_n = rows[0].extra_info["n_points"]
    first, _ = _pair(rows[0])
    write(f"  {group} (min per call; time per point relative to N = {first_n}; 1.0 = linear)")
    for bench in rows:
        n = bench.extra_info["n_points"]
        lo, _ = _pair(bench)
        write(f"      N = {n:>7}: {_fmt(lo)}   {lo / n * 1e9:8.1f} ns/point   x{(lo / n) / (first / first_n):5.2f}")
