"""A trainable Ultralytics model rebuilt from a shipped ONNX export (warm start).

Only the ONNX files of the shipped models are kept, no ``.pt``. Ultralytics'
ONNX export fuses every Conv+BatchNorm pair into one convolution with a bias,
and its initializers keep the PyTorch parameter names (``model.0.conv.weight``,
``model.0.conv.bias``...). :func:`model_from_onnx` builds the architecture from
its ``.yaml``, copies each fused weight into the convolution and sets the
BatchNorm that follows it to the identity (running mean 0, running variance 1,
scale sqrt(1 + eps), shift = the fused bias), so the rebuilt model computes the
same function as the ONNX file and still has BatchNorm layers to train.

Reference: the ONNX file itself, run by onnxruntime (``tests/test_warm_start.py``
compares the raw outputs).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any


def onnx_initializers(onnx_path: Path) -> dict[str, Any]:
    """Name -> numpy array of every initializer in ``onnx_path``."""
    import onnx
    from onnx import numpy_helper

    model = onnx.load(str(onnx_path))
    return {init.name: numpy_helper.to_array(init) for init in model.graph.initializer}


def model_from_onnx(onnx_path: Path, model_cfg: str = "yolo11n.yaml", nc: int = 1) -> Any:
    """An Ultralytics ``DetectionModel`` with the weights of ``onnx_path``, BatchNorm unfused to identity.

    Raises ValueError naming the parameter when the ONNX file does not hold a
    fused weight for a convolution of ``model_cfg`` or the shapes differ.
    """
    import torch
    from ultralytics.nn.tasks import DetectionModel

    weights = onnx_initializers(onnx_path)
    model = DetectionModel(model_cfg, nc=nc, verbose=False)
    used = 0
    with torch.no_grad():
        for name, module in model.named_modules():
            conv = getattr(module, "conv", None)
            bn = getattr(module, "bn", None)
            if isinstance(conv, torch.nn.Conv2d) and isinstance(bn, torch.nn.BatchNorm2d):
                w, b = _fetch(weights, f"{name}.conv", conv.weight.shape, onnx_path)
                conv.weight.copy_(torch.from_numpy(w))
                bn.running_mean.zero_()
                bn.running_var.fill_(1.0)
                bn.weight.fill_(math.sqrt(1.0 + bn.eps))
                bn.bias.copy_(torch.from_numpy(b))
                used += 2
            elif isinstance(module, torch.nn.Conv2d) and module.bias is not None and f"{name}.weight" in weights:
                w, b = _fetch(weights, name, module.weight.shape, onnx_path)
                module.weight.copy_(torch.from_numpy(w))
                module.bias.copy_(torch.from_numpy(b))
                used += 2
    if used == 0:
        raise ValueError(f"onnx_path: {onnx_path} holds no weight named like {model_cfg}'s layers")
    return model


def _fetch(weights: dict[str, Any], prefix: str, shape: Any, onnx_path: Path) -> tuple[Any, Any]:
    w, b = weights.get(f"{prefix}.weight"), weights.get(f"{prefix}.bias")
    if w is None or b is None:
        raise ValueError(f"onnx_path: {onnx_path} has no fused weight/bias for {prefix}")
    if tuple(w.shape) != tuple(shape):
        raise ValueError(f"onnx_path: {prefix}.weight has shape {tuple(w.shape)}, the model expects {tuple(shape)}")
    return w.copy(), b.copy()


def save_checkpoint(model: Any, out_path: Path, *, source: Path, names: dict[int, str]) -> Path:
    """Save ``model`` as an Ultralytics checkpoint that ``YOLO(out_path)`` can train from."""
    import torch
    from ultralytics import __version__

    model.args = {"imgsz": 640}
    model.names = dict(names)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"model": model, "epoch": -1, "optimizer": None, "train_args": {},
                "version": __version__, "date": None, "warm_start_from": str(source)}, out_path)
    return out_path
