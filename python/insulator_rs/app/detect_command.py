"""``insulator-rs detect``: run a detector on images, or score it on a labelled split.

    insulator-rs detect run  --model insulator-real photo.jpg ... [--json out.json] [--draw DIR]
    insulator-rs detect eval --model insulator-real path/to/test [--json metrics.json]

``--model`` is a shipped model name or an ONNX path. ``eval`` reports COCO
mAP50-95 and mAP50 from pycocotools on a VOC folder or a YOLO ``images/<split>``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2

from insulator_rs.detection.detector import Detections, Detector
from insulator_rs.detection.detector import open_detector
from insulator_rs.models import REAL_CROP_MODEL
from insulator_rs.detection.evaluate import EVAL_CONF, CocoMetrics, coco_evaluate, evaluate_field_test, load_images, load_split
from insulator_rs.detection.field_dataset import DEFAULT_FIELD_PHOTOS, FIELD_TEST
from insulator_rs.detection.image_file import read_image
from insulator_rs.detection.sanitize import DroppedDetections
from insulator_rs.exceptions import ImageError, ModelError
from insulator_rs import bounds
from insulator_rs.ports.detector import DETECT_CONF


def draw(image: cv2.typing.MatLike, det: Detections) -> cv2.typing.MatLike:
    """A copy of ``image`` with the detections drawn (green boxes, score labels)."""
    out = image.copy()
    for box, score, label in zip(det.boxes, det.scores, det.labels):
        x1, y1, x2, y2 = (int(round(v)) for v in box)
        cv2.rectangle(out, (x1, y1), (x2, y2), (0, 200, 0), 2)
        cv2.putText(out, f"{label} {score:.2f}", (x1, max(y1 - 4, 10)), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (0, 200, 0), 1, cv2.LINE_AA)
    return out


def run_images(args: argparse.Namespace) -> int:
    """Detect in each image; a bad image is reported and skipped, the others still run and are saved."""
    detector = open_detector(args.model, conf=args.conf, iou=args.iou, threads=args.threads)
    results: list[dict[str, object]] = []
    failed = 0
    dropped = DroppedDetections()
    for path in args.images:
        try:
            image = read_image(path)
        except ImageError as exc:
            failed += 1
            print(f"error: {exc}", file=sys.stderr)
            results.append({"image": str(path), "error": str(exc)})
            continue
        det = detector(image)
        dropped = dropped + det.dropped
        results.append({"image": str(path), "boxes": det.boxes.tolist(), "scores": det.scores.tolist(),
                        "labels": det.labels, "dropped_by_sanitiser": det.dropped.to_dict()})
        print(f"{path}: {len(det)} detection(s)" + "".join(
            f"\n  {lbl} {s:.3f} [{b[0]:.1f} {b[1]:.1f} {b[2]:.1f} {b[3]:.1f}]"
            for b, s, lbl in zip(det.boxes, det.scores, det.labels)))
        if det.dropped.total:
            print(f"  sanitiser dropped {det.dropped.total} invalid detection(s): {det.dropped.to_dict()}")
        if args.draw is not None:
            args.draw.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(args.draw / f"{Path(path).stem}_det.jpg"), draw(image, det))
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    if failed:
        print(f"error: {failed} of {len(args.images)} image(s) could not be used (see above)", file=sys.stderr)
        return 2
    return 0


def evaluate_split(args: argparse.Namespace) -> int:
    if (args.split is None) == (args.named_split is None):
        print("error: give either a split folder or --split field-test", file=sys.stderr)
        return 2
    detector = open_detector(args.model, conf=args.conf, iou=args.iou, threads=args.threads, imgsz=args.imgsz)

    def progress(i: int, n: int) -> None:
        if i % 10 == 0 or i == n:
            print(f"  evaluated {i}/{n} images", file=sys.stderr, flush=True)

    if args.named_split is not None:
        try:
            metrics = evaluate_field_test(detector, args.field_photos, progress=progress)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        args.split = Path(f"{args.named_split} ({args.field_photos}, photos held back by photo)")
        return _report_metrics(args, detector, metrics)
    samples = load_split(args.split, detector.names)

    def detect(image: cv2.typing.MatLike) -> tuple[object, object, list[str]]:
        det = detector(image)
        return det.boxes, det.scores, det.labels

    return _report_metrics(args, detector, coco_evaluate(samples, detect, progress=progress))  # type: ignore[arg-type]


def _report_metrics(args: argparse.Namespace, detector: Detector, metrics: CocoMetrics) -> int:
    print(f"{args.split}: {metrics.images} images, {metrics.instances} instances, "
          f"mAP50-95 {metrics.map50_95:.4f}, mAP50 {metrics.map50:.4f}, mAP75 {metrics.map75:.4f}, "
          f"AR100 {metrics.recall100:.4f}, {metrics.ms_per_image:.1f} ms/image")
    if args.json is not None:
        args.json.write_text(json.dumps({"model": args.model, "split": str(args.split), "conf": args.conf,
                                         "iou": args.iou, "imgsz": list(detector.imgsz), **metrics.to_dict()},
                                        indent=1) + "\n")
    return 0


def _print_false_box_rates(what: str, unit: str, n: int, thresholds: tuple[float, ...],
                           false_boxes: dict[float, int], with_one: dict[float, int]) -> None:
    """One line per score threshold: false boxes per ``unit`` (a view, a tile) and the share with one."""
    for t in thresholds:
        print(f"{what}, score >= {t:g}: {false_boxes[t]} false boxes ({false_boxes[t] / max(n, 1):.3f} a {unit}), "
              f"{with_one[t]} {unit}s with one ({100.0 * with_one[t] / max(n, 1):.1f} %)")


def count_steel_false_boxes(args: argparse.Namespace) -> int:
    """``detect false-boxes``: a model's false boxes per steel view, and the views that have one."""
    from insulator_rs.sim.steel_views import count_false_boxes, write_image_list

    detector = open_detector(args.model, conf=args.conf, iou=args.iou, threads=args.threads)

    def detect(image: cv2.typing.MatLike) -> tuple[object, object]:
        det = detector(image)
        return det.boxes, det.scores

    try:
        count = count_false_boxes(detect, args.folder, thresholds=sorted({args.conf, 0.5}))  # type: ignore[arg-type]
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    _print_false_box_rates(f"{args.folder}: {count.views} steel views", "view", count.views, count.thresholds,
                           count.false_boxes, count.views_with_false_box)
    if args.list is not None:
        n = write_image_list(args.folder, count, args.list, min_score=args.conf)
        print(f"{n} views with a false box listed in {args.list} (an Ultralytics image list)")
    if args.json is not None:
        args.json.write_text(json.dumps({"model": args.model, "folder": str(args.folder), "conf": args.conf,
                                         **count.to_dict()}, indent=1) + "\n")
    return 0


def count_photo_negatives(args: argparse.Namespace) -> int:
    """``detect negatives``: a model's false boxes on the tiles of labelled photos that hold no insulator."""
    from insulator_rs.detection.field_dataset import field_test_images
    from insulator_rs.detection.negatives import count_negative_false_boxes, negative_tiles

    if (args.split is None) == (args.named_split is None):
        print("error: give either a labelled folder or --split field-test", file=sys.stderr)
        return 2
    detector = open_detector(args.model, conf=args.conf, iou=args.iou, threads=args.threads)
    try:
        if args.named_split is not None:
            samples = load_images(field_test_images(args.field_photos), voc_dir=Path(args.field_photos) / "labels")
            where = f"{args.named_split} ({args.field_photos})"
        else:
            samples = load_split(args.split, detector.names)
            where = str(args.split)
        tiles = negative_tiles(samples)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    def detect(image: cv2.typing.MatLike) -> tuple[object, object]:
        det = detector(image)
        return det.boxes, det.scores

    def progress(i: int, n: int) -> None:
        if i % 50 == 0 or i == n:
            print(f"  {i}/{n} tiles", file=sys.stderr, flush=True)

    try:
        count = count_negative_false_boxes(detect, tiles, thresholds=sorted({args.conf, 0.5}),  # type: ignore[arg-type]
                                           progress=progress)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    _print_false_box_rates(f"{where}: {count.tiles} tiles without an insulator from {count.photos} photos", "tile",
                           count.tiles, count.thresholds, count.false_boxes, count.tiles_with_false_box)
    if args.json is not None:
        args.json.write_text(json.dumps({"model": args.model, "source": where, "conf": args.conf,
                                         **count.to_dict()}, indent=1) + "\n")
    return 0


def export_fp16_model(args: argparse.Namespace) -> int:
    """``detect export-fp16``: a model's FP16 ONNX for the Jetson's GPU, checked by loading it."""
    from insulator_rs.detection.jetson_export import export_fp16
    from insulator_rs.models import model_path

    try:
        src = Path(args.model) if args.model.endswith(".onnx") or Path(args.model).exists() else model_path(args.model)
        out = export_fp16(src, args.out)
        half = Detector(out, threads=args.threads)  # the detector reads it (names, input size) or says why not
    except (ModelError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{out}: FP16 of {src} ({out.stat().st_size / 1e6:.1f} MB, was {src.stat().st_size / 1e6:.1f} MB), "
          f"input {half.imgsz}, classes {half.names}")
    return 0


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``detect run`` and ``detect eval`` to the ``insulator-rs`` parser."""
    parser = subparsers.add_parser("detect", help="run or evaluate the insulator detector")
    sub = parser.add_subparsers(dest="detect_command", required=True)

    def common(p: argparse.ArgumentParser, conf: float) -> None:
        p.add_argument("--model", default=REAL_CROP_MODEL, help="shipped model name or ONNX path")
        p.add_argument("--conf", type=float, default=conf, help="confidence threshold (default %(default)s)")
        p.add_argument("--iou", type=float, default=0.7, help="NMS IoU threshold (default %(default)s)")
        p.add_argument("--threads", type=bounds.option("--threads"), default=None,
                       help="onnxruntime CPU threads (default: onnxruntime's choice)")
        p.add_argument("--json", type=Path, default=None,
                       help="write the results as JSON to this file (default: printed only)")

    def split_arguments(p: argparse.ArgumentParser) -> None:
        p.add_argument("split", type=Path, nargs="?", default=None, help="VOC folder or YOLO images/<split> folder")
        p.add_argument("--split", dest="named_split", choices=[FIELD_TEST], default=None,
                       help="a named split: field-test = the field photos held back from training (by photo; "
                            "default: none, the split folder given)")
        p.add_argument("--field-photos", type=Path, default=DEFAULT_FIELD_PHOTOS,
                       help="field-photo set for --split field-test (default %(default)s)")

    run = sub.add_parser("run", help="detect insulators in images")
    common(run, DETECT_CONF)
    run.add_argument("images", nargs="+", type=Path)
    run.add_argument("--draw", type=Path, default=None,
                     help="write annotated copies into this folder (default: none written)")
    run.set_defaults(func=run_images)

    ev = sub.add_parser("eval", help="COCO mAP50-95/mAP50 on a labelled split (pycocotools)")
    common(ev, EVAL_CONF)
    split_arguments(ev)
    ev.add_argument("--imgsz", type=int, default=None, help="network input size (default: the model's own)")
    ev.set_defaults(func=evaluate_split)

    fb = sub.add_parser("false-boxes", help="false boxes per view on rendered steel views (`dataset --steel-views`)")
    common(fb, DETECT_CONF)
    fb.add_argument("folder", type=Path, help="a folder written by `insulator-rs dataset --steel-views`")
    fb.add_argument("--list", type=Path, default=None,
                    help="write the views with a false box to this file (an image list a training data.yaml can name; "
                         "default: not written)")
    fb.set_defaults(func=count_steel_false_boxes)

    ng = sub.add_parser("negatives", help="false boxes per tile on the parts of labelled photos without an "
                                          "insulator (detection/negatives.py)")
    common(ng, DETECT_CONF)
    split_arguments(ng)
    ng.set_defaults(func=count_photo_negatives)

    ex = sub.add_parser("export-fp16", help="write a model's FP16 ONNX for the Jetson's GPU (needs the onnx package)")
    ex.add_argument("model", help="shipped model name or ONNX path")
    ex.add_argument("out", type=Path, help="the FP16 ONNX file to write")
    ex.add_argument("--threads", type=bounds.option("--threads"), default=None,
                    help="onnxruntime CPU threads for the check that loads it (default: onnxruntime's choice)")
    ex.set_defaults(func=export_fp16_model)
