"""The perception stack: the pipeline and the runner that feeds it, wired one way wherever
perception runs (the flight, the replay, the studies).

The flight and the replay share one runner (sensors -> pairing -> detector -> pipeline,
driven by the data's own times), as PX4's log replay feeds recorded topics to the very
modules that flew; the studies feed the same pipeline by hand. What differs is said by the
arguments: a replay's recorded mounts (``T_b_c``, ``T_b_l``), its pairing window and deskew;
the rest comes from the rig.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from insulator_rs.exceptions import SensorError
from insulator_rs.perception.localization_method import DEFAULT_METHOD, LocalizationMethod
from insulator_rs.perception.pipeline import PAIRING_WINDOW, PerceptionPipeline
from insulator_rs.perception.runner import PerceptionRunner, RunnerViewer
from insulator_rs.ports.detector import BoxDetector
from insulator_rs.ports.sensors import Sensors
from insulator_rs.rig import SensorRig


class PerceptionStack(NamedTuple):
    """The pipeline (localizations) and the runner that drives it from the ports."""

    pipeline: PerceptionPipeline
    runner: PerceptionRunner


def rig_pipeline(rig: SensorRig, *, insulator_length: float | None, method: LocalizationMethod = DEFAULT_METHOD,
                 T_b_c: np.ndarray | None = None, T_b_l: np.ndarray | None = None,
                 pairing_window: float = PAIRING_WINDOW, localize_params: dict[str, Any] | None = None,
                 deskew: bool = True) -> PerceptionPipeline:
    """The perception pipeline of ``rig``: its camera, and its mounts unless ``T_b_c``/``T_b_l``
    (4x4, body <- camera / LiDAR) say others (a recording's); ``insulator_length`` m (None: no
    length check); the rest as :class:`PerceptionPipeline`'s."""
    return PerceptionPipeline(rig.camera, rig.T_b_c if T_b_c is None else T_b_c, rig.T_b_l if T_b_l is None else T_b_l,
                              method=method, insulator_length=insulator_length, pairing_window=pairing_window,
                              localize_params=localize_params, deskew=deskew)


def build_perception_stack(rig: SensorRig, sensors: Sensors, detector: BoxDetector, *,
                           insulator_length: float | None, detect_period: float, method: LocalizationMethod = DEFAULT_METHOD,
                           T_b_c: np.ndarray | None = None, T_b_l: np.ndarray | None = None,
                           pairing_window: float = PAIRING_WINDOW, deskew: bool = True,
                           on_sensor_error: Callable[[SensorError], None] | None = None,
                           viewer: RunnerViewer | None = None) -> PerceptionStack:
    """:func:`rig_pipeline` and a :class:`PerceptionRunner` feeding it from ``sensors`` through
    ``detector`` every ``detect_period`` s (0: every frame); ``on_sensor_error`` and ``viewer``
    as the runner's."""
    pipeline = rig_pipeline(rig, insulator_length=insulator_length, method=method, T_b_c=T_b_c, T_b_l=T_b_l,
                            pairing_window=pairing_window, deskew=deskew)
    runner = PerceptionRunner(sensors, detector, pipeline, detect_period=detect_period,
                              on_sensor_error=on_sensor_error, viewer=viewer)
    return PerceptionStack(pipeline, runner)
