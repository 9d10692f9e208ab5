"""``insulator-rs train``: train YOLO11n offline, export ONNX, evaluate, write the model card.

    insulator-rs train --data ../shared/data/insulator_photos --out runs/detection/real \\
        --name insulator-real --hours 1.4 --imgsz 320

Needs the ``train`` extra (``pip install .[train]``: ultralytics, onnx). Steps:
VOC -> YOLO labels split by source photo (or a ready YOLO ``data.yaml``),
training from ``yolo11n.yaml`` with no network, ONNX export with Ultralytics'
metadata, COCO mAP on the test split (pycocotools, through the onnxruntime
detector that ships), a training-curve plot and the model card beside the model.
"""

from __future__ import annotations

import argparse
import hashlib
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from insulator_rs.detection.training_plots import plot_training_curves
from insulator_rs.detection.voc import DEFAULT_FRACTIONS, IMAGE_SUFFIXES, convert_voc_dataset
from insulator_rs.models import REAL_CROP_MODEL
from insulator_rs.report.folder import parse_out_folder


def describe_yolo_dataset(data_yaml: Path) -> dict[str, object]:
    """Images and boxes per split of a YOLO dataset laid out as ``images/<split>``, ``labels/<split>``."""
    root = data_yaml.parent
    images: dict[str, int] = {}
    boxes: dict[str, int] = {}
    for split_dir in sorted((root / "images").glob("*")) if (root / "images").is_dir() else []:
        if not split_dir.is_dir():
            continue
        split = split_dir.name
        images[split] = sum(1 for p in split_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        labels = root / "labels" / split
        boxes[split] = sum(
            sum(1 for line in txt.read_text().splitlines() if line.strip())
            for txt in labels.glob("*.txt")) if labels.is_dir() else 0
    summary: dict[str, object] = {"yaml": str(data_yaml), "images": images, "boxes": boxes}
    views = root / "views.csv"
    if views.is_file():  # written by ``insulator-rs dataset``: where each rendered image was taken
        import csv
        from collections import Counter

        with views.open() as f:
            summary["rendered_images_per_scene"] = dict(Counter(row["scene"] for row in csv.DictReader(f)))
    return summary


def package_model(
    *,
    onnx_path: Path,
    test_split: Path | None,
    card: dict[str, Any],
    threads: int | None = None,
) -> dict[str, Any]:
    """Evaluate ``onnx_path`` on ``test_split`` (COCO, pycocotools) and write its card beside it."""
    from insulator_rs.detection.detector import Detector
    from insulator_rs.detection.evaluate import EVAL_CONF, coco_evaluate, load_split
    from insulator_rs.detection.train import write_model_card

    card = dict(card)
    card["file"] = onnx_path.name
    card["sha256"] = hashlib.sha256(onnx_path.read_bytes()).hexdigest()
    card["size_bytes"] = onnx_path.stat().st_size
    if test_split is not None and any(test_split.iterdir()):
        detector = Detector(onnx_path, conf=EVAL_CONF, threads=threads)
        samples = load_split(test_split, detector.names)

        def detect(image: Any) -> tuple[Any, Any, list[str]]:
            det = detector(image)
            return det.boxes, det.scores, det.labels

        metrics = coco_evaluate(samples, detect)
        card["test_metrics"] = {
            "evaluator": "pycocotools COCOeval (bbox), onnxruntime detector, conf 0.001, iou 0.7",
            "split": str(test_split),
            **metrics.to_dict(),
        }
    write_model_card(onnx_path, card)
    return card


PAPER_MAP = 0.17  # the paper's real-photo detector figure that issue 12 compares against


def field_comparison(onnx_path: Path, field_photos: Path, before: str | None, *,
                     threads: int | None = None) -> dict[str, Any]:
    """Field-geometry figures (held-back photos, full frames letterboxed) of the new model and of ``before``.

    ``before`` (a shipped model name or ONNX path, the starting point) is scored
    at its own input size and at the new model's, so the gain from the input
    size and the gain from training are told apart.
    """
    from insulator_rs.detection.detector import open_detector
    from insulator_rs.detection.evaluate import EVAL_CONF, evaluate_field_test

    new = open_detector(str(onnx_path), conf=EVAL_CONF, threads=threads)
    out: dict[str, Any] = {
        "evaluator": "pycocotools COCOeval (bbox), onnxruntime detector, conf 0.001, iou 0.7, full frames letterboxed",
        "split": f"field-test: photos of {field_photos} held back by photo (field_dataset.field_test_images)",
        "command": f"insulator-rs detect eval --split field-test --model {onnx_path.stem}",
        "paper_map": PAPER_MAP,
        "after": {"imgsz": list(new.imgsz), **evaluate_field_test(new, field_photos).to_dict()},
    }
    if before is not None:
        own = open_detector(before, conf=EVAL_CONF, threads=threads)
        out["before"] = {"model": before, "imgsz": list(own.imgsz),
                         **evaluate_field_test(own, field_photos).to_dict()}
        if own.imgsz != new.imgsz:
            same = open_detector(before, conf=EVAL_CONF, threads=threads, imgsz=new.imgsz[0])
            out["before_at_new_imgsz"] = {"model": before, "imgsz": list(same.imgsz),
                                          **evaluate_field_test(same, field_photos).to_dict()}
    return out


def run_train(args: argparse.Namespace) -> int:
    try:
        from insulator_rs.detection.train import TrainConfig, export_onnx, prepare_offline, result_dict, train_yolo
    except ModuleNotFoundError as exc:
        print(f"error: training needs the train extra (pip install 'insulator_rs[train]'): {exc}", file=sys.stderr)
        return 2
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    prepare_offline(out / "ultralytics_cfg", threads=args.threads)
    t_start = time.time()
    dataset: dict[str, object]
    if args.field_photos is not None:
        from insulator_rs.detection.field_dataset import build_field_dataset

        print(f"building the field-geometry dataset {args.field_photos} -> {out / 'data'} (split by photo)", flush=True)
        fsum = build_field_dataset(args.field_photos, out / "data", export_root=args.data, with_export=args.with_export,
                                   seed=args.seed)
        data_yaml, dataset = fsum.yaml_path, fsum.to_dict()
        split = ("field photos split by photo (hash rank, seed %d): 75/10/15 %%; export copies matched to their photo "
                 "by file-name stem (checked on pixels) and kept on its side" % args.seed)
        test_split = out / "data" / "images" / "test"
        print(f"  photos per split {fsum.photos}, export copies in train {fsum.export_copies_in_train}", flush=True)
    elif args.data.suffix in (".yaml", ".yml"):
        data_yaml, dataset = args.data, describe_yolo_dataset(args.data)
        split = "as laid out in the given data.yaml"
        test_split = args.data.parent / "images" / "test"
    else:
        print(f"converting VOC {args.data} -> {out / 'data'} (split by source photo)", flush=True)
        summary = convert_voc_dataset(args.data, out / "data", fractions=tuple(args.fractions), seed=args.seed,
                                      limit_per_split=args.limit_per_split)
        data_yaml, dataset = summary.yaml_path, summary.to_dict()
        split = "by source photo (Roboflow copies of one photo share a split)"
        test_split = out / "data" / "images" / "test"
        print(f"  images per split {summary.images}, source photos {summary.source_photos}", flush=True)
    steel_before: dict[str, Any] | None = None
    if args.hard_negatives is not None:
        data_yaml, dataset, steel_before = _add_hard_negatives(args, data_yaml, dataset, out)
    cfg = TrainConfig(data_yaml=data_yaml, out_dir=out, name="run", model_cfg=args.model_cfg, epochs=args.epochs,
                      hours=args.hours, imgsz=args.imgsz, batch=args.batch, workers=args.workers,
                      threads=args.threads, seed=args.seed, patience=args.patience,
                      start_weights=_resolve_start(args.start_weights), uav_augment=args.uav_augment, resume=args.resume,
                      extra={"close_mosaic": args.close_mosaic, "warmup_epochs": args.warmup_epochs, **({"cache": args.cache} if args.cache else {})})

    def on_epoch(epoch: int, epochs: int) -> None:
        print(f"[train] epoch {epoch}/{epochs} done at {time.time() - t_start:.0f} s", flush=True)

    result = train_yolo(cfg, on_epoch=on_epoch)
    onnx_path = export_onnx(result.weights, args.imgsz, out / f"{args.name}.onnx", dynamic=not args.static)
    curves = plot_training_curves(result.run_dir / "results.csv", out / f"{args.name}_training.png")
    card = {
        "name": args.name,
        "architecture": f"{args.model_cfg} (Ultralytics), " + (
            f"fine-tuned from {args.start_weights} (ONNX weights unfused, warm_start.py)" if args.start_weights
            else "trained from scratch: no pretrained weights"),
        "augmentation": "Ultralytics defaults (mosaic, scale, HSV, flips)" + (
            " + blur/haze/sun flare (uav_augment.py)" if args.uav_augment else ""),
        "data": dataset,
        "split": split,
        "epochs": result.epochs_run,
        "time_budget_hours": args.hours,
        "imgsz": args.imgsz,
        "onnx_input": "static" if args.static else "dynamic height/width (default input size = imgsz)",
        "batch": args.batch,
        "training_seconds": round(result.seconds, 1),
        "hardware": f"CPU ({platform.processor() or platform.machine()}), {args.threads} torch threads",
        "validation_metrics_ultralytics": result.val_metrics,
        "training_curves": curves.name if curves else None,
        "arguments": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items() if k != "func"},
        "train_result": result_dict(result),
    }
    if args.field_photos is not None:
        card["field_geometry_metrics"] = field_comparison(onnx_path, args.field_photos, args.start_weights,
                                                          threads=args.threads)
    if args.steel_eval is not None:
        card["steel_view_false_boxes"] = _steel_false_boxes(args, onnx_path, steel_before)
    card = package_model(onnx_path=onnx_path, test_split=test_split, card=card, threads=args.threads)
    tm = card.get("test_metrics")
    if tm:
        print(f"test split: mAP50-95 {tm['map50_95']:.4f}, mAP50 {tm['map50']:.4f} on {tm['images']} images")
    print(f"model: {onnx_path}\ncard: {onnx_path.with_suffix('.json')}")
    return 0


def _steel_detect(model: str, threads: int | None) -> Callable[[Any], tuple[Any, Any]]:
    from insulator_rs.detection.detector import open_detector
    from insulator_rs.ports.detector import DETECT_CONF

    detector = open_detector(model, conf=DETECT_CONF, threads=threads)

    def detect(image: Any) -> tuple[Any, Any]:
        det = detector(image)
        return det.boxes, det.scores

    return detect


def _add_hard_negatives(args: argparse.Namespace, data_yaml: Path, dataset: dict[str, object],
                        out: Path) -> tuple[Path, dict[str, object], dict[str, Any] | None]:
    """The training set with the steel views of ``--hard-negatives`` added, and those where the start
    model draws a false box (mined at the flight's DETECT_CONF) repeated; the start model's
    false-box rate on ``--steel-eval`` (the card's "before")."""
    from insulator_rs.sim.steel_views import count_false_boxes, data_yaml_with_steel, write_image_list

    start = _resolve_start(args.start_weights)
    mined_txt: Path | None = None
    before: dict[str, Any] | None = None
    if start is not None and start.suffix == ".onnx":
        detect = _steel_detect(str(start), args.threads)
        mined = count_false_boxes(detect, args.hard_negatives, splits=("train",))
        mined_txt = out / "hard_negatives_mined.txt"
        n = write_image_list(args.hard_negatives, mined, mined_txt, min_score=min(mined.thresholds))
        print(f"hard negatives: {n} of {mined.views} steel views with a false box of the start model", flush=True)
        if args.steel_eval is not None:
            before = {"model": str(args.start_weights),
                      **count_false_boxes(detect, args.steel_eval).to_dict()}
    combined = data_yaml_with_steel(data_yaml, args.hard_negatives, mined_txt, out / "data_with_steel_views.yaml",
                                    mined_repeats=args.mined_repeats)
    dataset = {**dataset, "steel_views": describe_yolo_dataset(args.hard_negatives / "data.yaml"),
               "steel_views_mined": None if mined_txt is None else {
                   "list": str(mined_txt), "views": sum(1 for _ in mined_txt.open()),
                   "repeats": args.mined_repeats, "start_model": str(args.start_weights)},
               "combined_yaml": str(combined)}
    return combined, dataset, before


def _steel_false_boxes(args: argparse.Namespace, onnx_path: Path, before: dict[str, Any] | None) -> dict[str, Any]:
    """The new model's false boxes per view on the held-out steel views, beside the start model's."""
    from insulator_rs.sim.steel_views import count_false_boxes

    after = count_false_boxes(_steel_detect(str(onnx_path), args.threads), args.steel_eval).to_dict()
    print(f"steel views: false boxes per view {after}", flush=True)
    return {"folder": str(args.steel_eval), "counted_by": "sim/steel_views.py count_false_boxes, boxes at "
            "score >= DETECT_CONF matching no visible insulator (IoU < 0.1, under half inside one)",
            "after": after, "before": before}


def _resolve_start(value: str | None) -> Path | None:
    """A shipped model name (``insulator-real``) or a path to a .pt/.onnx file."""
    if value is None:
        return None
    path = Path(value)
    if path.suffix in (".pt", ".onnx"):
        return path
    from insulator_rs.models import model_path

    return model_path(value)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``train`` to the ``insulator-rs`` parser."""
    p = subparsers.add_parser("train", help="train YOLO11n offline and export ONNX (needs the train extra)")
    p.add_argument("--data", type=Path, required=True, help="VOC folder (with train/valid/test or flat) or data.yaml")
    p.add_argument("--out", type=parse_out_folder, required=True, help="output folder (runs, ONNX, model card)")
    p.add_argument("--name", default=REAL_CROP_MODEL, help="model name (file stem)")
    p.add_argument("--model-cfg", default="yolo11n.yaml", help="Ultralytics architecture file")
    p.add_argument("--epochs", type=int, default=100, help="training epochs")
    p.add_argument("--hours", type=float, default=None,
                   help="wall-clock budget in hours; overrides --epochs (default: none, --epochs decides)")
    p.add_argument("--imgsz", type=int, default=320, help="network input size, px")
    p.add_argument("--batch", type=int, default=16, help="images per batch")
    p.add_argument("--workers", type=int, default=0, help="data-loader worker processes (0: in the main process)")
    p.add_argument("--threads", type=int, default=2, help="PyTorch CPU threads")
    p.add_argument("--seed", type=int, default=0, help="random seed of the training (integer)")
    p.add_argument("--patience", type=int, default=100, help="epochs without improvement before stopping early")
    p.add_argument("--close-mosaic", type=int, default=5, help="last epochs without mosaic augmentation")
    p.add_argument("--cache", choices=("ram", "disk"), default=None,
                   help="keep decoded, resized images between epochs (large rendered PNGs decode slowly; "
                        "default: no cache)")
    p.add_argument("--fractions", type=float, nargs=3, default=list(DEFAULT_FRACTIONS),
                   metavar=("TRAIN", "VALID", "TEST"), help="source-photo fractions when re-splitting")
    p.add_argument("--static", action="store_true",
                   help="export a fixed input size (default: dynamic height/width, metadata imgsz = --imgsz)")
    p.add_argument("--field-photos", type=Path, default=None,
                   help="field photos (images/ + labels/ VOC, full frames): train/test on them, split by photo; "
                        "--data is then the Roboflow export whose copies are matched to the photos (default: none)")
    p.add_argument("--with-export", action="store_true",
                   help="with --field-photos: add the export's copies of training photos to the training split")
    p.add_argument("--start-weights", default=None,
                   help="shipped model name or .pt/.onnx to fine-tune from (default: from scratch)")
    p.add_argument("--warmup-epochs", type=float, default=3.0,
                   help="learning-rate warm-up in epochs (short fine-tunes want less)")
    p.add_argument("--uav-augment", action="store_true", help="add blur, haze and sun flare augmentation")
    p.add_argument("--resume", type=Path, default=None,
                   help="continue an interrupted run from its last.pt (default: a new run)")
    p.add_argument("--hard-negatives", type=Path, default=None,
                   help="a folder of steel views ('dataset --steel-views'): added to the training set, and those "
                        "where the start model draws a false box repeated (--mined-repeats; default: none)")
    p.add_argument("--mined-repeats", type=int, default=2, help="extra copies of each mined steel view (default 2)")
    p.add_argument("--steel-eval", type=Path, default=None,
                   help="held-out steel views: the card reports false boxes per view before and after (default: none)")
    p.add_argument("--limit-per-split", type=int, default=None,
                   help="keep only N images per split (smoke runs; default: all)")
    p.set_defaults(func=run_train)
