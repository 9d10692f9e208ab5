"""Write tests/fixtures/detection/x86_detections.json: the detector's output on x86-64.

The reference that tests/test_detection_cross_arch.py holds every other CPU to
(the Jetson's aarch64, run under qemu by scripts/test-aarch64.sh). For each
shipped model and each case of the Ultralytics fixture (the committed photos
whole, a crop padded top/bottom, a tall odd-width crop, a side-by-side pair, so
the resize runs at several non-integer factors), at conf 0.25 and 0.01:

* the SHA-256 of the network input tensor (float32, after letterbox, BGR->RGB,
  /255): the pre-processing must be the same bytes on every CPU;
* the boxes (x1, y1, x2, y2, original pixels), scores and class ids.

Only x86-64 may write it (that is what "the x86 reference" means). Runs offline,
with the package's runtime dependencies only.

    python scripts/make_x86_detections.py
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import platform
import sys
from pathlib import Path

import numpy as np
import onnxruntime

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "tests" / "fixtures" / "detection" / "x86_detections.json"
MODELS = ("insulator-real", "insulator-field", "insulator-sim")
CONFS = (0.25, 0.01)


def _load_fixture_module():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("make_fixture", ROOT / "scripts" / "make_ultralytics_fixture.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def network_input_sha256(detector, image: np.ndarray) -> str:  # type: ignore[no-untyped-def]
    """SHA-256 of the float32 tensor the detector feeds the network for ``image``."""
    from insulator_rs.detection.detector import as_bgr_uint8
    from insulator_rs.detection.letterbox import letterbox, to_network_input

    padded, _ = letterbox(as_bgr_uint8(image), detector.imgsz, auto=detector.rect, stride=detector.stride)
    tensor = np.ascontiguousarray(to_network_input(padded), dtype="<f4")
    return hashlib.sha256(tensor.tobytes()).hexdigest()


def main() -> int:
    if platform.machine().lower() not in ("x86_64", "amd64"):
        print(f"make_x86_detections: this is the x86-64 reference; this machine is {platform.machine()}",
              file=sys.stderr)
        return 2
    from insulator_rs.detection.detector import Detector
    from insulator_rs.models import model_path

    fx = _load_fixture_module()
    runs = []
    for name in MODELS:
        for conf in CONFS:
            detector = Detector.from_name(name, conf=conf, warmup=False, threads=1)
            for case in fx.fixture_cases():
                image = fx.build_image(case)
                det = detector(image)
                runs.append({
                    "model": name, "conf": conf, "photos": case["photos"], "crop": case["crop"],
                    "shape": list(image.shape), "input_sha256": network_input_sha256(detector, image),
                    "boxes": det.boxes.astype(float).tolist(), "scores": det.scores.astype(float).tolist(),
                    "class_ids": det.class_ids.astype(int).tolist(),
                })
    payload = {
        "generator": "scripts/make_x86_detections.py",
        "machine": platform.machine(),
        "onnxruntime": onnxruntime.__version__,
        "models": {name: hashlib.sha256(model_path(name).read_bytes()).hexdigest() for name in MODELS},
        "runs": runs,
    }
    OUT.write_text(json.dumps(payload, indent=1) + "\n")
    print(f"wrote {OUT}: {len(runs)} runs, {sum(len(r['scores']) for r in runs)} boxes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
