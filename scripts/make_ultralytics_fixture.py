"""Regenerate tests/fixtures/detection/ultralytics_predict.json with Ultralytics' own predict.

The reference for the detector's decoder: Ultralytics (PyTorch-side pre- and
post-processing, torchvision NMS) runs the shipped ONNX model on the committed
test photos and on exact derivatives of them (crops and side-by-side pairs, so
the letterbox pads on one axis and rescales by non-integer factors). Needs the
``train`` extra (ultralytics). Runs offline.

    python scripts/make_ultralytics_fixture.py [--model insulator-real]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PHOTOS = ROOT / "tests" / "data" / "photos"
OUT = ROOT / "tests" / "fixtures" / "detection" / "ultralytics_predict.json"
CONFS = (0.25, 0.01)
IOU = 0.7


def fixture_cases() -> list[dict[str, object]]:
    """The inputs: each photo whole, plus exact crops and a concatenation (no resampling)."""
    photos = sorted(p.name for p in PHOTOS.glob("*.jpg"))
    cases: list[dict[str, object]] = [{"photos": [p], "crop": None} for p in photos]
    cases.append({"photos": [photos[0]], "crop": [0, 300, 0, 412]})  # wide: pads top/bottom
    cases.append({"photos": [photos[1]], "crop": [20, 412, 100, 351]})  # tall, odd width
    cases.append({"photos": [photos[2], photos[3]], "crop": None})  # 412 x 824 side by side
    return cases


def build_image(case: dict[str, object]) -> np.ndarray:
    """The BGR uint8 image of a fixture case (also used by the parity test)."""
    images = [cv2.imread(str(PHOTOS / name), cv2.IMREAD_COLOR) for name in case["photos"]]  # type: ignore[union-attr]
    image = np.concatenate(images, axis=1) if len(images) > 1 else images[0]
    crop = case.get("crop")
    if crop is not None:
        y0, y1, x0, x1 = crop  # type: ignore[misc]
        image = image[y0:y1, x0:x1]
    return np.ascontiguousarray(image)


def write_non_yolo_models(folder: Path) -> None:
    """Two tiny valid ONNX files that are not YOLO detectors (for the construction errors)."""
    import onnx
    from onnx import TensorProto, helper

    x = helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 64, 64])
    # 1) identity: NCHW in, NCHW out.
    y = helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 3, 64, 64])
    g = helper.make_graph([helper.make_node("Identity", ["images"], ["output0"])], "identity", [x], [y])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 13)])
    m.ir_version = 8
    onnx.checker.check_model(m)
    onnx.save(m, folder / "not_yolo_identity.onnx")
    # 2) a [1, 4, N] output: boxes but no class channel.
    y2 = helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 4, 4096])
    inits = [helper.make_tensor("shape", TensorProto.INT64, [3], [1, 4, 4096]),
             helper.make_tensor("starts", TensorProto.INT64, [1], [0]),
             helper.make_tensor("ends", TensorProto.INT64, [1], [1]),
             helper.make_tensor("axes", TensorProto.INT64, [1], [1])]
    nodes = [helper.make_node("Slice", ["images", "starts", "ends", "axes"], ["s"]),
             helper.make_node("Concat", ["s", "s", "s", "s"], ["c"], axis=1),
             helper.make_node("Reshape", ["c", "shape"], ["output0"])]
    g2 = helper.make_graph(nodes, "boxes_only", [x], [y2], initializer=inits)
    m2 = helper.make_model(g2, opset_imports=[helper.make_opsetid("", 13)])
    m2.ir_version = 8
    m2.metadata_props.add(key="task", value="detect")
    onnx.checker.check_model(m2)
    onnx.save(m2, folder / "not_yolo_no_classes.onnx")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default="insulator-real", help="shipped model name or ONNX path")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)

    from insulator_rs.detection.train import prepare_offline

    prepare_offline(Path(tempfile.mkdtemp(prefix="ultralytics_cfg_")), threads=2)
    from ultralytics import YOLO

    from insulator_rs.models import model_path

    path = Path(args.model) if args.model.endswith(".onnx") else model_path(args.model)
    model = YOLO(str(path), task="detect")
    from insulator_rs.detection.detector import Detector

    imgsz = list(Detector(path, warmup=False).imgsz)  # Ultralytics would use 640 for a dynamic ONNX
    cases = []
    for case in fixture_cases():
        image = build_image(case)
        for conf in CONFS:
            result = model.predict(image, conf=conf, iou=IOU, imgsz=imgsz, device="cpu", verbose=False)[0]
            boxes = result.boxes
            cases.append({
                **case,
                "shape": list(image.shape),
                "conf": conf,
                "iou": IOU,
                "imgsz": imgsz,
                "boxes": boxes.xyxy.cpu().numpy().astype(float).tolist(),
                "scores": boxes.conf.cpu().numpy().astype(float).tolist(),
                "class_ids": boxes.cls.cpu().numpy().astype(int).tolist(),
            })
    import ultralytics

    payload = {
        "generator": "scripts/make_ultralytics_fixture.py",
        "ultralytics": ultralytics.__version__,
        "model": path.name,
        "model_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "cases": cases,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_non_yolo_models(args.out.parent)
    args.out.write_text(json.dumps(payload, indent=1) + "\n")
    print(f"wrote {args.out}: {len(cases)} cases, {sum(len(c['boxes']) for c in cases)} boxes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
