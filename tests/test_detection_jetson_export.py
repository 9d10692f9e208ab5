"""The Jetson's export path (detection/jetson_export.py, ``detect export-fp16``): the FP16 ONNX of
each shipped model against its float32 original on onnxruntime's CPU provider, and the TensorRT
provider's engine cache the detector asks for.

Reference and tolerance: the float32 model on the same images (the committed real photos); every
box it scores at 0.3 or more has a box of the FP16 model at IoU >= MIN_IOU with it and a score
within 0.01 (measured worst: 0.0013). Edges: within 0.16 px for insulator-sim and insulator-real
(IoU measured below, printed: 0.962 sim, 0.997 real and field; the session-20 field weights once
kept a neighbouring candidate of equal score in NMS, 5.1 px to the side of a 154 px box, 0.905). float16 keeps 11 significant bits: rounding, not a
different network."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.photos import PHOTOS

from insulator_rs.app.cli import main
from insulator_rs.detection import detector as detector_mod
from insulator_rs.detection.detector import Detector
from insulator_rs.detection.jetson_export import TRT_CACHE_ENV, export_fp16, tensorrt_cache_dir, tensorrt_provider_options
from insulator_rs.exceptions import ModelError
from insulator_rs.models import available_models, model_path

pytest.importorskip("onnx", reason="the FP16 export needs the onnx package (test and train extras)")
MIN_IOU = 0.85


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(available_models()))
def test_fp16_export_matches_the_float32_model(name: str, tmp_path: Path) -> None:
    half_path = export_fp16(model_path(name), tmp_path / f"{name}-fp16.onnx")
    assert half_path.stat().st_size < 0.6 * model_path(name).stat().st_size
    full, half = Detector.from_name(name, conf=0.25, threads=2), Detector(half_path, conf=0.25, threads=2)
    assert (half.names, half.imgsz, half.stride) == (full.names, full.imgsz, full.stride)
    compared, worst_iou = 0, 1.0
    for photo in sorted(PHOTOS.glob("*.jpg")):
        image = cv2.imread(str(photo))
        a, b = full(image), half(image)
        for box, score in zip(a.boxes, a.scores):
            if score < 0.3:
                continue
            assert len(b), f"{photo.name}: the FP16 model lost a box of score {score:.2f}"
            overlap = _iou(box, b.boxes)
            k = int(np.argmax(overlap))
            worst_iou = min(worst_iou, float(overlap[k]))
            assert overlap[k] >= MIN_IOU, (photo.name, box, b.boxes[k])
            assert abs(b.scores[k] - score) <= 0.01
            compared += 1
    print(f"{name}: {compared} boxes, the FP16 model's nearest at IoU >= {worst_iou:.3f}")
    assert compared >= 5


def _iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    w = np.clip(np.minimum(box[2], boxes[:, 2]) - np.maximum(box[0], boxes[:, 0]), 0, None)
    h = np.clip(np.minimum(box[3], boxes[:, 3]) - np.maximum(box[1], boxes[:, 1]), 0, None)
    inter = w * h
    area = lambda b: (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])  # noqa: E731
    return inter / (area(box) + area(boxes) - inter)


def test_the_command_writes_a_model_the_detector_reads_and_refuses_bad_input(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "sim16.onnx"
    assert main(["detect", "export-fp16", "insulator-sim", str(out), "--threads", "2"]) == 0
    assert "FP16 of" in capsys.readouterr().out and out.is_file()
    assert main(["detect", "export-fp16", "no-such-model", str(tmp_path / "x.onnx")]) == 2
    assert "no shipped model 'no-such-model'" in capsys.readouterr().err
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a protobuf" * 10)
    assert main(["detect", "export-fp16", str(junk), str(tmp_path / "y.onnx")]) == 2
    assert "junk.onnx: cannot be read as ONNX" in capsys.readouterr().err
    with pytest.raises(ModelError, match="junk.onnx"):
        export_fp16(junk, tmp_path / "z.onnx")


def test_tensorrt_engine_cache_is_per_model_content(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv(TRT_CACHE_ENV, str(tmp_path / "trt"))
    a, b = tmp_path / "m.onnx", tmp_path / "other" / "m.onnx"
    b.parent.mkdir()
    a.write_bytes(b"first model")
    b.write_bytes(b"second model")
    assert tensorrt_cache_dir(a).parent == tmp_path / "trt" and tensorrt_cache_dir(a).name.startswith("m-")
    assert tensorrt_cache_dir(a) != tensorrt_cache_dir(b)  # same name, other content: another engine
    opts = tensorrt_provider_options(a)
    assert opts["trt_engine_cache_enable"] == "True" and opts["trt_fp16_enable"] == "True"
    assert Path(opts["trt_engine_cache_path"]).is_dir()
    # the detector hands TensorRT its options and names the others plainly
    chosen = detector_mod._with_options(["TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider"], a)
    assert chosen[0] == ("TensorrtExecutionProvider", opts) and chosen[1:] == ["CUDAExecutionProvider", "CPUExecutionProvider"]
