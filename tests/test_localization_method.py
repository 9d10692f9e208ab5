"""The localization methods' one home: ``LocalizationMethod`` lists what the core offers, every
method honours every parameter it declares (``ir.localize_defaults(method)``), and the perception
pipeline hands the core every tuning override and, for the bounded method, the track's boxes."""

from __future__ import annotations

import argparse
import re
from typing import Any

import numpy as np
import pytest

import insulator_rs as ir
from insulator_rs.app import inspect_command, replay_command
from insulator_rs.perception.localization_method import DEFAULT_METHOD, LocalizationMethod
from insulator_rs.perception.pipeline import PerceptionPipeline
from insulator_rs.rig import simulator_rig
from insulator_rs.synthetic import insulator_cloud

# The simulator's default camera facing B's x (as tests/test_core_bounded.py).
CAM = ir.CameraModel(700.0, 700.0, 639.5, 479.5, 1280, 960, dist=(-0.12, 0.03, 0.0, 0.0, 0.0))
T_B_C = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])

# Extreme values tried for each parameter: one of them must change some cloud's result.
EXTREMES: dict[str, tuple[Any, ...]] = {
    "eps": (0.01, 5.0),
    "min_points": (1, 10_000),
    "tau": (0.005, 10.0),
    "ransac_threshold": (1e-4, 2.0),
    "max_iterations": (1, 2),
    "confidence": (1e-6,),
    "seed": (1, 2, 3),
    "insulator_length": (0.3, 4.0),
    "border_margin": (400.0,),
    "max_extent": (0.05,),
}


def box_of(center: np.ndarray, axis: np.ndarray, length: float) -> np.ndarray:
    """The pixel box of the segment (through the core's own projection), 8 px of rim around it."""
    s = np.linspace(-0.5, 0.5, 201)[:, None] * length
    uv, ok = ir.project_points(center + s * axis, np.linalg.inv(T_B_C), CAM)
    assert ok.all()
    return np.array([uv[:, 0].min() - 8, uv[:, 1].min() - 8, uv[:, 0].max() + 8, uv[:, 1].max() + 8])


def clouds() -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(points, box, true length): a cluttered synthetic string whose box the frame clips on the
    right (one end bounded, so the known length places the centre), and an L of a string and a
    dense arm at its end (Algorithm 2 re-clusters there, so its tau matters)."""
    out = []
    c = insulator_cloud(seed=3, distance=9.0, azimuth=-0.5, length=2.0, radius=0.12)
    box = box_of(c.center, c.axis, c.length)
    box[0] = 0.0  # the string runs out of the frame on the left: an open end
    out.append((c.points, box, c.length))
    rng = np.random.default_rng(0)
    t = rng.uniform(-0.6, 0.6, 400)
    string = np.column_stack([np.full(400, 9.0), t, np.zeros(400)])
    s = rng.uniform(0.0, 1.5, 250)
    arm = np.column_stack([np.full(250, 9.0), np.full(250, -0.6), -s])
    pts = np.concatenate([string, arm]) + rng.normal(scale=0.01, size=(650, 3))
    out.append((pts, box_of(np.array([9.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 1.2), 1.2))
    return out


def outcome(points: np.ndarray, method: LocalizationMethod, box: np.ndarray, **kwargs: Any) -> tuple[Any, ...]:
    """Everything the core returns (or the error it raises), for exact comparison."""
    image = {"boxes": box[None], "T_b_c": T_B_C, "cam": CAM} if method.needs_boxes else {}
    try:
        est = ir.localize(points, method, **image, **kwargs)
    except ir.LocalizationError as e:
        return (type(e).__name__,)
    return (tuple(est.center), tuple(est.direction), est.n_points, est.n_clusters, est.ends_from_image,
            est.length, est.views_used)


def test_the_enum_is_the_cores_list() -> None:
    assert [m.value for m in LocalizationMethod] == ir.localize_methods()
    assert LocalizationMethod.BOUNDED == "bounded" and str(LocalizationMethod.DBSCAN_RANSAC) == "dbscan+ransac"
    assert [m for m in LocalizationMethod if m.needs_boxes] == [LocalizationMethod.BOUNDED]
    assert DEFAULT_METHOD is LocalizationMethod.BOUNDED
    with pytest.raises(ValueError, match="method: must be one of dbscan, ransac, dbscan\\+ransac"):
        LocalizationMethod.parse("kmeans")
    with pytest.raises(ValueError, match="method"):
        PerceptionPipeline(CAM, T_B_C, np.eye(4), method="kmeans")


def test_every_method_declares_its_parameters() -> None:
    """localize_defaults(method) names exactly what each method reads; its values are localize's
    own defaults (the signature's)."""
    line_fit = ir.localize_defaults()
    for m in LocalizationMethod:
        declared = ir.localize_defaults(m)
        assert declared and set(declared) <= set(EXTREMES), m
        for name, value in declared.items():
            assert line_fit.get(name, value) == value
    assert set(ir.localize_defaults("dbscan")) == {"eps", "min_points"}
    assert set(ir.localize_defaults("bounded")) == set(line_fit) | {"insulator_length", "border_margin",
                                                                    "max_extent"}


@pytest.mark.parametrize("method", list(LocalizationMethod))
def test_every_parameter_changes_the_result(method: LocalizationMethod) -> None:
    """Fails when a method drops a parameter it declares: for each one, some extreme value changes
    the result on one of the clouds."""
    cases = clouds()
    for name in ir.localize_defaults(method):
        # RANSAC's own knobs show only when it is cut short: try them with 3 hypotheses at most
        base = {"max_iterations": 3} if name in ("seed", "confidence") else {}
        changed = any(
            outcome(pts, method, box, **base, **extra) != outcome(pts, method, box, **base, **extra,
                                                                     **{name: value})
            for pts, box, length in cases
            for extra in ([{"insulator_length": length}] if method.needs_boxes and name != "insulator_length"
                          else [{}])
            for value in EXTREMES[name]
        )
        assert changed, f"{method}: {name} has no effect"


def test_inputs_a_method_does_not_read_are_refused() -> None:
    pts, box, _ = clouds()[0]
    for m in LocalizationMethod:
        if m.needs_boxes:
            with pytest.raises(ValueError, match="T_b_c: the bounded method needs it"):
                ir.localize(pts, m, boxes=box[None], cam=CAM)
        else:
            with pytest.raises(ValueError, match=re.escape(f"boxes: the {m} method reads the cloud alone")):
                ir.localize(pts, m, boxes=box[None], T_b_c=T_B_C, cam=CAM)
            with pytest.raises(ValueError, match="insulator_length"):
                ir.localize(pts, m, insulator_length=1.2)


@pytest.mark.parametrize("method", list(LocalizationMethod))
def test_the_pipeline_hands_the_core_its_parameters(method: LocalizationMethod, monkeypatch) -> None:
    """What the core received from the pipeline (a spy on ir.localize): every override, whatever
    the method, and for the bounded one the track's boxes, poses, camera and the length."""
    rig = simulator_rig()
    received: list[dict[str, Any]] = []
    real = ir.localize

    def spy(points: np.ndarray, method: str, **kwargs: Any) -> ir.Localization:
        received.append({"method": method, **kwargs})
        return real(points, method, **kwargs)

    monkeypatch.setattr(ir, "localize", spy)
    overrides = {"eps": 0.45, "min_points": 4, "tau": 0.25, "ransac_threshold": 0.09, "seed": 7}
    pipe = PerceptionPipeline(rig.camera, rig.T_b_c, rig.T_b_l, method=method, insulator_length=2.0,
                              localize_params=overrides)
    c = insulator_cloud(seed=1, distance=9.0, length=2.0, radius=0.12)
    T_b_l = rig.T_b_l
    points_l = (c.points - T_b_l[:3, 3]) @ T_b_l[:3, :3]  # B -> L
    box = np.array([[100.0, 100.0, rig.camera.width - 100.0, rig.camera.height - 100.0, 0.9]])
    for _ in range(3):
        pipe.event(box, points_l, np.eye(4))
    assert received, "the pipeline never called the core"
    got = received[-1]
    assert got["method"] == method
    for name, value in overrides.items():
        assert got[name] == value, name
    if method.needs_boxes:
        assert got["boxes"].shape == (3, 4) and got["T_b_c"].shape == (3, 4, 4)
        assert got["insulator_length"] == 2.0 and got["cam"] is rig.camera
    else:
        assert not {"boxes", "T_b_c", "cam", "insulator_length"} & set(got)


@pytest.mark.parametrize("module", [inspect_command, replay_command])
def test_cli_offers_the_enum(module: Any) -> None:
    """inspect and replay --method: the enum's members as choices, the product's default."""
    parser = argparse.ArgumentParser()
    module.register(parser.add_subparsers())
    (sub,) = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices.values()
    action = next(a for a in sub._actions if "--method" in a.option_strings)
    assert list(action.choices) == list(LocalizationMethod) and action.default is DEFAULT_METHOD
    assert action.type is LocalizationMethod
