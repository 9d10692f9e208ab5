"""Replay of the recorded tower A flight, against real time (issue 10: >= 20x).

    pytest benches/bench_replay.py --benchmark-enable

The recording is ``$INSULATOR_REPLAY_BAG`` when set, else the default inspection of tower A
recorded once into ``benches/.cache/tower_a.mcap`` (``insulator-rs inspect --record``: about
3-4 min on the 2-core dev box, reused by later runs). The replay is the CLI's own
(``replay_one``): MCAP decoding, the shipped ``insulator-sim`` network at 320 px on every
recorded detection frame, deskew, pairing, localization (``bounded``), registry and report.
Side by side, in the same run: the network alone on the same frames (its share of the time).
The terminal summary prints the replay's real-time factor (recorded flight time / replay
wall time) against the 20x target.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import insulator_rs
from insulator_rs.app.replay_command import ReplayOptions, _detector, replay_one

CACHE = Path(__file__).resolve().parent / ".cache"
TARGET_REALTIME = 20.0


@pytest.fixture(scope="module")
def tower_a_bag() -> Path:
    given = os.environ.get("INSULATOR_REPLAY_BAG")
    if given:
        return Path(given)
    bag = CACHE / "tower_a.mcap"
    if not bag.exists():
        CACHE.mkdir(exist_ok=True)
        env = {**os.environ, "PYTHONPATH": str(Path(insulator_rs.__file__).parents[1])}
        subprocess.run([sys.executable, "-m", "insulator_rs.app.cli", "inspect", "--quiet", "--record", str(bag),
                        "--out", str(CACHE / "tower_a_report"), "--overwrite"], check=True, env=env, timeout=1800)
    return bag


def _flight_seconds(bag: Path) -> float:
    """Recorded flight time: the span of the odometry stamps (the recording's clock)."""
    from insulator_rs.recording.reader import FlightBag
    from insulator_rs.recording.types import Topics

    first = last = None
    with FlightBag(bag, Topics()) as flight:
        for item in flight.items():
            if item.kind == "pose":
                first = item.time if first is None else first
                last = item.time
    assert first is not None and last is not None, f"{bag}: no odometry"
    return float(last - first)


@pytest.mark.benchmark(group="replay tower A")
def test_replay_tower_a(benchmark: Any, tower_a_bag: Path, tmp_path: Path) -> None:
    flight_s = _flight_seconds(tower_a_bag)
    options = ReplayOptions(overwrite=True)
    summary = benchmark.pedantic(lambda: replay_one(tower_a_bag, tmp_path / "replay", options), rounds=2,
                                 iterations=1, warmup_rounds=0)
    assert summary["status"] == "finished", summary["status"]
    benchmark.extra_info.update(impl="insulator_rs", flight_s=flight_s, target_realtime=TARGET_REALTIME,
                                insulators=summary["insulators_found"])
    (tmp_path / "summary.json").write_text(json.dumps(summary, default=str))


@pytest.mark.benchmark(group="replay tower A")
def test_network_alone_on_the_recorded_frames(benchmark: Any, tower_a_bag: Path) -> None:
    """The detector on every recorded detection frame, decoded beforehand: its share of the replay."""
    from insulator_rs.recording.reader import FlightBag
    from insulator_rs.recording.types import Topics

    with FlightBag(tower_a_bag, Topics()) as flight:
        images = [item.value.image for item in flight.items() if item.kind == "frame"]
    assert images, "no frames recorded"
    detector = _detector("insulator-sim")

    def run() -> int:
        return sum(len(np.asarray(detector(image))) for image in images)

    t0 = time.perf_counter()
    benchmark.pedantic(run, rounds=2, iterations=1, warmup_rounds=0)
    benchmark.extra_info.update(impl="network alone (decoded frames)", frames=len(images),
                                per_frame_ms=(time.perf_counter() - t0) / 2 / len(images) * 1e3)
