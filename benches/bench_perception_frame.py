"""The flight's perception, per camera frame: the fused deskew + cull against the two-step path.

    pytest benches/bench_perception_frame.py --benchmark-enable

What flies: ``PerceptionPipeline.process`` on one frame of a flight past a tower (a Mid-360's
200,000 points/s, the frame paired with the points within 0.1 s of it, from 3 scans: about
40,000 points; poses at 20 Hz; the box of a string that is localized every frame, and two more
on the tower's steel). ``insulator_rs`` is the pipeline as it flies, one
``ir.deskew_points_in_boxes`` pass a paired scan; the other row is the two-step path
(``ir.deskew`` of each scan, then ``ir.points_in_boxes`` of the paired cloud in W), the
reference of tests/test_fused_perception.py, which checks the two agree (same points, same
lists). A second group times the deskew + cull step alone (``paired_points_in_boxes_w``). The
ratio table at the end of the run prints two-step / fused.
"""

from __future__ import annotations

from typing import Any

import numpy as np
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
