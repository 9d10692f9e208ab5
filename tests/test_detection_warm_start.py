"""Warm start: the shipped ONNX weights rebuilt as a trainable Ultralytics model compute the same function.

Reference: onnxruntime running the shipped ``insulator-real.onnx`` on the same
random input; tolerance 1e-3 relative to the output's scale (float32 rounding
of the unfused BatchNorm: x / sqrt(1 + eps) * sqrt(1 + eps)).
"""

from __future__ import annotations

from pathlib import Path

import importlib.util

import numpy as np
import pytest

if importlib.util.find_spec("ultralytics") is None:  # not imported here: it must be configured offline first
    pytest.skip("needs the train extra (ultralytics)", allow_module_level=True)


def test_model_from_onnx_matches_onnxruntime(tmp_path: Path) -> None:
    import onnxruntime as ort

    from insulator_rs.detection.train import prepare_offline

    prepare_offline(tmp_path / "cfg", threads=1)
    import torch

    from insulator_rs.detection.warm_start import model_from_onnx
    from insulator_rs.models import model_path

    onnx_path = model_path("insulator-real")
    model = model_from_onnx(onnx_path).eval()
    assert any(isinstance(m, torch.nn.BatchNorm2d) for m in model.modules())  # still trainable as Ultralytics' own
    x = np.random.default_rng(0).random((1, 3, 256, 320), dtype=np.float32)
    with torch.no_grad():
        ours = model(torch.from_numpy(x))[0].numpy()
    ref = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"]).run(None, {"images": x})[0]
    assert ours.shape == ref.shape
    assert np.abs(ours - ref).max() <= 1e-3 * np.abs(ref).max()


def test_model_from_onnx_rejects_a_foreign_graph(tmp_path: Path) -> None:
    from insulator_rs.detection.train import prepare_offline

    prepare_offline(tmp_path / "cfg", threads=1)
    from helpers.onnx_models import hostile_model

    from insulator_rs.detection.warm_start import model_from_onnx

    with pytest.raises(ValueError, match="no fused weight"):
        model_from_onnx(hostile_model(tmp_path / "h.onnx", [(1.0, 1.0, 1.0, 1.0, 0.5)]))
