"""The flight's perception, per camera frame: the fused deskew + cull against the two-step path.

    pytest benches/bench_perception_frame.py --benchmark-enable
    python benches/bench_perception_frame.py [ROUNDS]   # the two alternated call by call


What flies: ``PerceptionPipeline.process`` on one frame of a flight past a tower (a Mid-360's
200,000 points/s, the frame paired with the points within 0.1 s of it, from 3 scans: about
40,000 points; poses at 20 Hz; the box of a string that is localized every frame, and two more
on the tower's steel). ``insulator_rs`` is the pipeline as it flies, one
``ir.deskew_points_in_boxes`` pass a paired scan; the other row is the two-step path
(``ir.deskew`` of each scan, then ``ir.points_in_boxes`` of the paired cloud in W), the
reference of tests/test_fused_perception.py, which checks the two agree (same points, same
lists). A second group times the deskew + cull step alone (``paired_points_in_boxes_w``). The
ratio table at the end of the run prints two-step / fused. On a loaded machine, run the script
itself: it alternates the two pipelines call by call, so both meet the same load, and prints the
minimum and the first quartile of each, and their ratios.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # as conftest.py does
from test_fused_perception import CAM, T_B_C, TwoStepPipeline, boxes_at, fed, frame_at, scans_with_string, string_box

from insulator_rs.perception.pipeline import PerceptionPipeline

TIME = 0.6  # s: the frame, mid-run (its window holds points of 3 scans)
SCANS, STRING_W = scans_with_string(9)
FRAME = "perception per frame: process (pair, deskew, cull, accumulate, localize), ~40k points, 3 boxes"
STEP = "perception per frame: deskew + cull only (paired_points_in_boxes_w), ~40k points, 3 boxes"


def _pipeline(cls: type[PerceptionPipeline]) -> tuple[PerceptionPipeline, np.ndarray]:
    pipeline = fed(cls, SCANS, 1.25)
    T_c_w = np.linalg.inv(pipeline.poses.pose_at(TIME) @ T_B_C)
    tower_boxes = boxes_at(pipeline, TIME, np.random.default_rng(5), k=2)
    tower_boxes[:, 4] = 0.3  # weak boxes on steel, as the network gives them
    boxes = np.vstack([string_box(pipeline, STRING_W, TIME), tower_boxes])
    points, lists = pipeline.paired_points_in_boxes_w(TIME, T_c_w, CAM, boxes)
    assert len(points) > 30_000 and all(len(k) > 0 for k in lists)
    for _ in range(3):  # the string's track holds its 3 events: every call below localizes it
        pipeline.process(frame_at(TIME), boxes)
    assert pipeline.counters.localizations > 0
    return pipeline, boxes


def _process(benchmark: Any, cls: type[PerceptionPipeline], impl: str) -> None:
    pipeline, boxes = _pipeline(cls)
    benchmark.group = FRAME
    benchmark.extra_info.update(impl=impl)
    frame = frame_at(TIME)
    benchmark(pipeline.process, frame, boxes)


def _step(benchmark: Any, cls: type[PerceptionPipeline], impl: str) -> None:
    pipeline, boxes = _pipeline(cls)
    benchmark.group = STEP
    benchmark.extra_info.update(impl=impl)
    T_c_w = np.linalg.inv(pipeline.poses.pose_at(TIME) @ T_B_C)
    benchmark(pipeline.paired_points_in_boxes_w, TIME, T_c_w, CAM, boxes)


def test_frame_fused_insulator_rs(benchmark: Any) -> None:
    _process(benchmark, PerceptionPipeline, "insulator_rs")


def test_frame_two_step(benchmark: Any) -> None:
    _process(benchmark, TwoStepPipeline, "two-step: deskew, points_in_boxes")


def test_deskew_cull_fused_insulator_rs(benchmark: Any) -> None:
    _step(benchmark, PerceptionPipeline, "insulator_rs")


def test_deskew_cull_two_step(benchmark: Any) -> None:
    _step(benchmark, TwoStepPipeline, "two-step: deskew, points_in_boxes")


def alternated(rounds: int) -> None:
    """Both pipelines, call by call in turn; min and first quartile of each, two-step / fused."""
    setups = {"fused": _pipeline(PerceptionPipeline), "two-step": _pipeline(TwoStepPipeline)}
    for what in ("deskew + cull", "process"):
        seconds: dict[str, list[float]] = {name: [] for name in setups}
        for _ in range(rounds):
            for name, (pipeline, boxes) in setups.items():
                T_c_w = np.linalg.inv(pipeline.poses.pose_at(TIME) @ T_B_C)
                start = time.perf_counter()
                if what == "process":
                    pipeline.process(frame_at(TIME), boxes)
                else:
                    pipeline.paired_points_in_boxes_w(TIME, T_c_w, CAM, boxes)
                seconds[name].append(time.perf_counter() - start)
        (f_min, f_q1), (t_min, t_q1) = ((min(v) * 1e3, float(np.percentile(v, 25)) * 1e3) for v in seconds.values())
        print(f"{what:14s} fused {f_min:6.2f} / {f_q1:6.2f} ms   two-step {t_min:6.2f} / {t_q1:6.2f} ms   "
              f"two-step / fused {t_min / f_min:4.2f}x / {t_q1 / f_q1:4.2f}x   (min / first quartile, {rounds} calls)")


if __name__ == "__main__":
    alternated(int(sys.argv[1]) if len(sys.argv) > 1 else 100)
