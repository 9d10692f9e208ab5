"""The perception-stack factory (perception/stack.py): the pipeline built from the rig, the
runner feeding that very pipeline, and the overrides a replay gives (recorded mounts, pairing
window, deskew) reaching the pipeline."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from insulator_rs.perception.pipeline import PAIRING_WINDOW
from insulator_rs.perception.stack import build_perception_stack, rig_pipeline
from insulator_rs.rig import simulator_rig

SENSORS: Any = object()  # the runner only keeps them until it runs
DETECTOR: Any = object()


def test_the_pipeline_is_the_rigs_and_the_runner_feeds_it() -> None:
    rig = simulator_rig()
    stack = build_perception_stack(rig, SENSORS, DETECTOR, insulator_length=2.2, detect_period=0.5)
    pipe, runner = stack
    assert runner.pipeline is pipe and runner.sensors is SENSORS and runner.detector is DETECTOR
    assert runner.detect_period == 0.5
    np.testing.assert_array_equal(pipe.T_b_c, rig.T_b_c)
    np.testing.assert_array_equal(pipe.T_b_l, rig.T_b_l)
    assert pipe.camera is rig.camera and pipe.insulator_length == 2.2
    assert pipe.pairing_window == PAIRING_WINDOW and pipe.deskew


def test_a_replays_overrides_reach_the_pipeline() -> None:
    rig = simulator_rig()
    T_b_c = rig.T_b_c.copy()
    T_b_c[:3, 3] += [0.01, 0.02, 0.03]
    T_b_l = rig.T_b_l.copy()
    T_b_l[:3, 3] += [0.04, 0.0, -0.05]
    pipe, runner = build_perception_stack(rig, SENSORS, DETECTOR, insulator_length=None, detect_period=0.0,
                                          T_b_c=T_b_c, T_b_l=T_b_l, pairing_window=0.05, deskew=False)
    np.testing.assert_array_equal(pipe.T_b_c, T_b_c)
    np.testing.assert_array_equal(pipe.T_b_l, T_b_l)
    assert pipe.pairing_window == 0.05 and not pipe.deskew and pipe.insulator_length is None
    assert runner.pairing.window == 0.05  # the runner pairs with the pipeline's window


def test_the_studies_pipeline_is_the_same_build() -> None:
    rig = simulator_rig()
    pipe = rig_pipeline(rig, insulator_length=2.0, localize_params={"eps": 0.3})
    np.testing.assert_array_equal(pipe.T_b_c, rig.T_b_c)
    assert pipe.insulator_length == 2.0 and pipe.localize_params == {"eps": 0.3}


def test_bad_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="detect_period"):
        build_perception_stack(simulator_rig(), SENSORS, DETECTOR, insulator_length=2.0, detect_period=-1.0)
    with pytest.raises(ValueError, match="pairing_window"):
        rig_pipeline(simulator_rig(), insulator_length=2.0, pairing_window=0.0)
