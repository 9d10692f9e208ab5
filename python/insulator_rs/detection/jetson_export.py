"""The Jetson's export path for a detector (issue 22 item 3): an FP16 ONNX of a shipped model,
and where onnxruntime's TensorRT provider keeps the engines it builds.

* :func:`export_fp16` converts the weights and activations to float16 with onnxruntime's own
  converter (``onnxruntime.transformers.float16``; onnxconverter-common's left a Cast node typed
  float32 in YOLO11's head, which onnxruntime refused to load), keeping float32 at the input and
  outputs so the detector's pre- and post-processing are unchanged, and keeping Ultralytics'
  metadata (names, imgsz, stride) that the detector reads. Half the file, and the form the
  Orin's GPU runs fastest; on a CPU it is no faster (measured: README, "Detection").
* :func:`tensorrt_cache_dir`: the TensorRT provider compiles an engine for the GPU on the first
  session (minutes on an Orin); with the cache it does so once per model file, kept under
  ``~/.cache/insulator_rs/tensorrt/<model>-<sha256[:12]>`` (``INSULATOR_RS_TRT_CACHE`` overrides
  the root), so a changed model never reuses a stale engine. The detector passes it with FP16
  enabled whenever onnxruntime offers ``TensorrtExecutionProvider`` (onnxruntime-gpu on JetPack).

``insulator-rs detect export-fp16 MODEL OUT`` writes the FP16 file.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

from insulator_rs.exceptions import ModelError

TRT_CACHE_ENV = "INSULATOR_RS_TRT_CACHE"


def tensorrt_cache_dir(model: Path) -> Path:
    """Where the TensorRT provider keeps the engines of ``model`` (one folder per file content)."""
    model = Path(model)
    digest = hashlib.sha256(model.read_bytes()).hexdigest()[:12]
    root = Path(os.environ.get(TRT_CACHE_ENV) or Path.home() / ".cache" / "insulator_rs" / "tensorrt")
    return root / f"{model.stem}-{digest}"


def tensorrt_provider_options(model: Path) -> dict[str, str]:
    """onnxruntime's TensorRT provider options: the engine cache (created) and FP16 kernels."""
    cache = tensorrt_cache_dir(model)
    cache.mkdir(parents=True, exist_ok=True)
    return {"trt_engine_cache_enable": "True", "trt_engine_cache_path": str(cache),
            "trt_timing_cache_enable": "True", "trt_timing_cache_path": str(cache),
            "trt_fp16_enable": "True"}


def export_fp16(src: Path, dst: Path) -> Path:
    """``src`` (a float32 YOLO detection ONNX) converted to float16 inside, float32 at its input
    and outputs, its metadata kept, written to ``dst``. Needs the ``onnx`` package (the train
    extra): the export is done on a workstation or on the Jetson, not in flight."""
    try:
        import onnx
        from onnxruntime.transformers.float16 import convert_float_to_float16
    except ImportError as exc:
        raise ModelError(f"export-fp16 needs the onnx package (pip install 'insulator_rs[train]'): {exc}") from exc
    src, dst = Path(src), Path(dst)
    try:
        model = onnx.load(str(src))
    except Exception as exc:  # onnx raises its own untyped errors for bad protobufs
        raise ModelError(f"model {src}: cannot be read as ONNX ({type(exc).__name__}: {exc})") from exc
    meta = {p.key: p.value for p in model.metadata_props}
    with warnings.catch_warnings():  # weights below float16's range are rounded to its smallest: expected
        warnings.simplefilter("ignore", UserWarning)
        half = convert_float_to_float16(model, keep_io_types=True)
    kept = {p.key for p in half.metadata_props}
    for key, value in meta.items():  # the converter keeps them today; the detector cannot do without
        if key not in kept:
            half.metadata_props.add(key=key, value=value)
    dst.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(half, str(dst))
    return dst
