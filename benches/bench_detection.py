"""Detection latency on this machine's CPU, side by side (pytest-benchmark).

    pytest benches/bench_detection.py --benchmark-enable [--benchmark-columns=min,median,mean,max]

Rows (one group, so the table shows ratios; a summary with ratios to the
network at 640 px is printed at the end):
- network only (onnxruntime ``session.run``) at the shipped input size and at 640 px,
- the whole detector call (letterbox + network + decode/NMS + mapping back),
- the whole frame: detect -> project the LiDAR cloud -> cull to each box
  (``ir.points_in_boxes``) -> localize every insulator (``ir.localize``,
  DBSCAN+RANSAC), on a 640x480 camera frame and a 30 000-point synthetic LiDAR
  scan with one insulator behind each detected box.
Threads: 2 (the flight computer's budget here). Target: network < 60 ms at 640 px.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

import insulator_rs as ir
from insulator_rs.detection.detector import Detector

PHOTO = Path(__file__).resolve().parents[1] / "tests" / "data" / "photos" / "0059_jpg.rf.850df7c663bac095d0ae74db06e0861e.jpg"
THREADS = 2
FRAME_WH = (640, 480)
BACKGROUND_POINTS = 30_000
POINTS_PER_INSULATOR = 400
INSULATOR_DEPTH_M = 12.0
RESULTS: dict[str, float] = {}

# LiDAR frame L = FLU (x forward, y left, z up); camera optical frame C (x right, y down, z forward).
T_C_L = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=np.float64)


@pytest.fixture(scope="module")
def frame() -> np.ndarray:
    return cv2.resize(cv2.imread(str(PHOTO)), FRAME_WH, interpolation=cv2.INTER_AREA)


@pytest.fixture(scope="module")
def shipped() -> Detector:
    return Detector.from_name("insulator-real", threads=THREADS)


@pytest.fixture(scope="module")
def at640() -> Detector:
    return Detector.from_name("insulator-real", threads=THREADS, imgsz=640)


def _record(benchmark, key: str) -> None:  # type: ignore[no-untyped-def]
    if benchmark.stats is not None:
        RESULTS[key] = float(benchmark.stats.stats.median)


def synthetic_scan(boxes: np.ndarray, cam: ir.CameraModel, rng: np.random.Generator) -> np.ndarray:
    """Random background plus, behind each box, a vertical insulator (noisy points) at 12 m, in L (metres)."""
    bg = np.column_stack([rng.uniform(2, 40, BACKGROUND_POINTS), rng.uniform(-20, 20, BACKGROUND_POINTS),
                          rng.uniform(-5, 15, BACKGROUND_POINTS)])
    parts = [bg]
    for x1, y1, x2, y2 in boxes:
        u = np.full(POINTS_PER_INSULATOR, (x1 + x2) / 2)
        v = rng.uniform(y1 + 0.1 * (y2 - y1), y2 - 0.1 * (y2 - y1), POINTS_PER_INSULATOR)
        d = INSULATOR_DEPTH_M
        pc = np.column_stack([(u - cam.cx) / cam.fx * d, (v - cam.cy) / cam.fy * d, np.full_like(u, d)])
        pc += rng.normal(0, 0.02, pc.shape)
        parts.append(pc @ T_C_L[:3, :3])  # C -> L (rotation only; inverse = transpose)
    return np.ascontiguousarray(np.vstack(parts))


@pytest.mark.benchmark(group="detection")
def test_network_shipped_size(benchmark, shipped: Detector) -> None:  # type: ignore[no-untyped-def]
    x = np.full((1, 3, *shipped.imgsz), 0.5, dtype=np.float32)
    benchmark(shipped.session.run, None, {shipped.input_name: x})
    _record(benchmark, f"network {shipped.imgsz[0]} px")


@pytest.mark.benchmark(group="detection")
def test_network_640(benchmark, at640: Detector) -> None:  # type: ignore[no-untyped-def]
    x = np.full((1, 3, 640, 640), 0.5, dtype=np.float32)
    benchmark(at640.session.run, None, {at640.input_name: x})
    _record(benchmark, "network 640 px")


@pytest.mark.benchmark(group="detection")
def test_detect_shipped_size(benchmark, shipped: Detector, frame: np.ndarray) -> None:  # type: ignore[no-untyped-def]
    det = benchmark(shipped, frame)
    assert len(det) >= 1
    _record(benchmark, f"detect (pre+net+post) {shipped.imgsz[0]} px")


@pytest.mark.benchmark(group="detection")
def test_detect_640(benchmark, at640: Detector, frame: np.ndarray) -> None:  # type: ignore[no-untyped-def]
    benchmark(at640, frame)
    _record(benchmark, "detect (pre+net+post) 640 px")


@pytest.mark.benchmark(group="detection")
def test_whole_frame(benchmark, shipped: Detector, frame: np.ndarray) -> None:  # type: ignore[no-untyped-def]
    h, w = frame.shape[:2]
    cam = ir.CameraModel(500.0, 500.0, w / 2, h / 2, w, h)
    boxes = shipped(frame).boxes
    assert len(boxes) >= 1, "the benchmark frame must contain a detection"
    scan = synthetic_scan(boxes, cam, np.random.default_rng(0))

    def one_frame() -> list[ir.Localization]:
        det = shipped(frame)
        culled = ir.points_in_boxes(scan, T_C_L, cam, det.boxes)
        return [ir.localize(scan[idx]) for idx in culled if idx.size >= 10]

    located = benchmark(one_frame)
    assert len(located) >= 1
    _record(benchmark, f"whole frame {shipped.imgsz[0]} px ({len(boxes)} boxes, {len(scan)} points)")


def test_print_summary() -> None:
    """Ratios to the network at 640 px (run last)."""
    if not RESULTS:
        pytest.skip("benchmarks disabled (use --benchmark-enable)")
    ref = RESULTS.get("network 640 px")
    print("\n\ndetection latency, median of each (2 threads, this machine's CPU):")
    for key, sec in RESULTS.items():
        ratio = f"  x{sec / ref:.2f} of network 640" if ref else ""
        print(f"  {key:<55s} {1000 * sec:8.2f} ms{ratio}")
