"""Train ``insulator-sim`` on a lent GPU machine in one call (issue 22): render, train, export, measure.

The GPU machine gets the repository's tracked tree plus at most 64 MiB in all, and the tree
is already 57 MB (the shipped ONNX models and checkpoints). A rendered training set does not
fit (the dataset command's 1280x960 PNGs are 1.6 MB each), so it is rendered there, on the
machine's CPUs, in one process a shard, while nothing else runs; then the GPU trains. Steps,
each printed with its elapsed time:

1. **render** (CPU, all cores): ``shards`` shards of tower views (``write_dataset``: both
   built-in towers, 7-30 m, time of day, weather, haze, noise) at ``render_size``, as many
   shards of steel views (``write_steel_views``: the cross-arms, peak, body and legs at the
   flight's 320x240, every visible insulator labelled: the hard negatives), a validation
   shard of tower views and a shard of steel views held back to count false boxes. Seeds are
   ``seed`` + offsets, none of them 6 (the card's test split: ``dataset --images 1500 --seed 6``).
2. **train** (GPU): Ultralytics from the shipped ``insulator-sim.onnx`` (unfused by
   ``warm_start.py``), fp32 (AMP's check would download weights), RAM cache, for what is left
   of ``deadline_s`` after rendering, less a reserve for the steps below.
3. **export**: the best epoch's weights to a dynamic ONNX at ``imgsz`` (as the shipped one).
4. **measure**: COCO mAP (pycocotools, the onnxruntime detector that ships, as the card) on the
   validation shard, and false boxes per steel view at scores 0.25 / 0.5, for the new model
   and the shipped one side by side.

Writes into ``out``: ``insulator-sim.onnx``, ``insulator-sim_best.pt``, ``results.csv``,
``training.png`` and ``summary.json``. The card's own test split is scored afterwards on the
build machine (``insulator-rs detect eval``), where it is rendered bit for bit.

Run by ``scripts/gpu/train_sim.sh`` on the device; ``scripts/gpu/dry_run_cpu.sh`` runs the same
steps here on the CPU with a few images and one epoch, with the packages the device lacks hidden.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from insulator_rs.models import SIMULATOR_MODEL as SIM_MODEL
from insulator_rs.models import model_path

SCENES = ("tower_a", "tower_b")
CARD_TEST_SEED = 6  # `insulator-rs dataset --images 1500 --seed 6`: the card's test split, never trained on


@dataclass(frozen=True)
class GpuRecipe:
    """What one device call renders and trains (defaults sized for a 10-minute call on 16 CPUs)."""

    shards: int = 15  # + the validation shard: one process each on the device's 16 CPUs
    tower_views_per_shard: int = 200
    steel_views_per_shard: int = 100
    val_views: int = 200
    steel_test_views: int = 150
    render_size: tuple[int, int] = (640, 480)
    seed: int = 100
    imgsz: int = 320  # the flight's detection size (steel_views.FLIGHT_DETECTION_SIZE's width)
    batch: int = 64
    epochs: int = 300  # an upper bound: the time budget ends the run (Ultralytics fits its schedule to it)
    fixed_epochs: bool = False  # train exactly ``epochs``, no time budget (the CPU dry run)
    workers: int = 12  # data loaders once rendering is over
    device: str = "0"
    deadline_s: float = 540.0  # from the start of this process to the last file written
    reserve_s: float = 75.0  # kept for export and measurement after training
    min_train_s: float = 30.0

    def __post_init__(self) -> None:
        for name in ("shards", "tower_views_per_shard", "steel_views_per_shard", "val_views",
                     "steel_test_views", "imgsz", "batch", "epochs"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: must be >= 1, got {getattr(self, name)}")
        if self.workers < 0:
            raise ValueError(f"workers: must be >= 0, got {self.workers}")
        if self.seed <= CARD_TEST_SEED <= self.seed + 3000 + self.shards:
            raise ValueError(f"seed: {self.seed} would render the card's test split (seed {CARD_TEST_SEED})")


@dataclass(frozen=True)
class RenderJob:
    """One shard: ``kind`` is "tower" or "steel"; ``split`` is where its images go."""

    kind: str
    name: str
    images: int
    seed: int
    split: tuple[float, float, float]
    size: tuple[int, int] | None


def render_jobs(recipe: GpuRecipe) -> list[RenderJob]:
    """The shards, largest first (they start first and finish together)."""
    train = (1.0, 0.0, 0.0)
    jobs = [RenderJob("tower", f"tower_{i:02d}", recipe.tower_views_per_shard, recipe.seed + i, train,
                      recipe.render_size) for i in range(recipe.shards)]
    jobs += [RenderJob("steel", f"steel_{i:02d}", recipe.steel_views_per_shard, recipe.seed + 1000 + i, train, None)
             for i in range(recipe.shards)]
    jobs.append(RenderJob("tower", "val", recipe.val_views, recipe.seed + 2000, (0.0, 1.0, 0.0), recipe.render_size))
    jobs.append(RenderJob("steel", "steel_test", recipe.steel_test_views, recipe.seed + 3000, (0.0, 0.0, 1.0), None))
    return sorted(jobs, key=lambda j: -j.images * (4 if j.kind == "tower" else 1))


def _render_one(job: RenderJob, root: str) -> tuple[str, int, int]:
    """Render one shard in this (worker) process; returns its name, images and boxes."""
    from insulator_rs.sim.dataset import write_dataset
    from insulator_rs.sim.steel_views import write_steel_views

    out = Path(root) / job.name
    if job.kind == "tower":
        summary = write_dataset(scenes=SCENES, out=out, n_images=job.images, split=job.split,
                                image_size=job.size, seed=job.seed)
    else:
        summary = write_steel_views(scenes=SCENES, out=out, n_images=job.images, split=job.split, seed=job.seed)
    return job.name, sum(summary.images.values()), summary.boxes


def _one_thread_each() -> None:
    """Each render process on one core: the shards are the parallelism."""
    for var in ("OMP_NUM_THREADS", "RAYON_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    import cv2

    cv2.setNumThreads(1)


def render_all(recipe: GpuRecipe, root: Path, processes: int, log: Progress) -> dict[str, dict[str, int]]:
    """Render every shard of :func:`render_jobs` under ``root`` with ``processes`` processes."""
    import multiprocessing

    jobs = render_jobs(recipe)
    done: dict[str, dict[str, int]] = {}
    # fork would copy whatever threads the parent holds; the shards start clean.
    with ProcessPoolExecutor(max_workers=processes, mp_context=multiprocessing.get_context("spawn"),
                             initializer=_one_thread_each) as pool:
        futures = [pool.submit(_render_one, job, str(root)) for job in jobs]
        for future in as_completed(futures):
            name, images, boxes = future.result()
            done[name] = {"images": images, "boxes": boxes}
            log(f"rendered {name}: {images} images, {boxes} boxes ({len(done)}/{len(jobs)} shards)")
    return done


def write_combined_yaml(root: Path, recipe: GpuRecipe) -> Path:
    """One data.yaml: every tower and steel shard's train images; the validation shard's val images."""
    import yaml

    train = [str((root / f"{kind}_{i:02d}" / "images" / "train").resolve())
             for kind in ("tower", "steel") for i in range(recipe.shards)]
    doc = {"path": str(root.resolve()), "train": train, "val": str((root / "val" / "images" / "val").resolve()),
           "names": {0: "insulator"}}
    out = root / "data.yaml"
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


class Progress:
    """Prints each step with the seconds since the start, flushed (the device returns the output's tail)."""

    def __init__(self) -> None:
        self.start = time.monotonic()

    def elapsed(self) -> float:
        return time.monotonic() - self.start

    def __call__(self, message: str) -> None:
        print(f"[{self.elapsed():6.1f} s] {message}", flush=True)


def measure(onnx_path: Path, root: Path) -> dict[str, Any]:
    """COCO mAP on the validation shard and false boxes per held-back steel view (one model)."""
    from insulator_rs.detection.detector import open_detector
    from insulator_rs.detection.evaluate import EVAL_CONF, coco_evaluate, load_split
    from insulator_rs.ports.detector import DETECT_CONF
    from insulator_rs.sim.steel_views import count_false_boxes

    evaluator = open_detector(str(onnx_path), conf=EVAL_CONF)
    samples = load_split(root / "val" / "images" / "val", evaluator.names)

    def detect_all(image: Any) -> tuple[Any, Any, list[str]]:
        det = evaluator(image)
        return det.boxes, det.scores, det.labels

    flight = open_detector(str(onnx_path), conf=DETECT_CONF)

    def detect_flight(image: Any) -> tuple[Any, Any]:
        det = flight(image)
        return det.boxes, det.scores

    false_boxes = count_false_boxes(detect_flight, root / "steel_test")  # at FALSE_BOX_THRESHOLDS
    return {"val_shard": coco_evaluate(samples, detect_all).to_dict(), "steel_test": false_boxes.to_dict()}


def run(recipe: GpuRecipe, out: Path, work: Path, *, processes: int | None = None) -> dict[str, Any]:
    """All four steps; returns (and writes as ``out/summary.json``) what was done and measured."""
    from insulator_rs.detection.train import TrainConfig, export_onnx, prepare_offline, train_yolo
    from insulator_rs.detection.training_plots import plot_training_curves
    from insulator_rs.sim.steel_views import FALSE_BOX_THRESHOLDS

    log = Progress()
    out.mkdir(parents=True, exist_ok=True)
    if work.exists() and any(work.iterdir()):
        raise ValueError(f"work: {work} is not empty (the shards are rendered into a fresh folder)")
    work.mkdir(parents=True, exist_ok=True)
    processes = processes or os.cpu_count() or 1
    summary: dict[str, Any] = {"recipe": asdict(recipe), "processes": processes, "python": sys.version.split()[0]}
    log(f"render: {len(render_jobs(recipe))} shards on {processes} processes")
    summary["rendered"] = render_all(recipe, work, processes, log)
    summary["render_s"] = round(log.elapsed(), 1)
    data_yaml = write_combined_yaml(work, recipe)

    prepare_offline(work / "ultralytics_cfg")
    train_s = recipe.deadline_s - log.elapsed() - recipe.reserve_s
    if train_s < recipe.min_train_s:
        raise RuntimeError(f"deadline_s: {train_s:.0f} s left to train after rendering (< {recipe.min_train_s:.0f} s); "
                           "render fewer views or allow more time")
    start_weights = model_path(SIM_MODEL)
    cfg = TrainConfig(data_yaml=data_yaml, out_dir=work / "train", name=SIM_MODEL, epochs=recipe.epochs,
                      hours=None if recipe.fixed_epochs else train_s / 3600.0, imgsz=recipe.imgsz, batch=recipe.batch, workers=recipe.workers,
                      patience=recipe.epochs, cache="ram", start_weights=start_weights, device=recipe.device)
    budget = f"{recipe.epochs} epochs" if recipe.fixed_epochs else f"up to {train_s:.0f} s"
    log(f"train: {budget} on device {recipe.device}, imgsz {recipe.imgsz}, batch {recipe.batch}, "
        f"from {start_weights.name}")
    result = train_yolo(cfg, on_epoch=lambda e, n: log(f"epoch {e}/{n}") if e <= n else None)  # not the final val
    summary["train"] = {"epochs_run": result.epochs_run, "seconds": round(result.seconds, 1),
                        "ultralytics_val": result.val_metrics}
    log(f"trained {result.epochs_run} epochs in {result.seconds:.0f} s: {result.val_metrics}")

    onnx_path = export_onnx(result.weights, recipe.imgsz, out / f"{SIM_MODEL}.onnx", dynamic=True)
    shutil.copyfile(result.weights, out / f"{SIM_MODEL}_best.pt")
    results_csv = result.run_dir / "results.csv"
    if results_csv.is_file():
        shutil.copyfile(results_csv, out / "results.csv")
        plot_training_curves(results_csv, out / "training.png")
    log(f"exported {onnx_path.name}")

    summary["new"] = measure(onnx_path, work)
    summary["shipped"] = measure(start_weights, work)
    summary["total_s"] = round(log.elapsed(), 1)
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    for label in ("new", "shipped"):
        m = summary[label]
        fb = m["steel_test"][f"score>={FALSE_BOX_THRESHOLDS[-1]:g}"]["false_boxes_per_view"]
        log(f"{label}: val mAP50-95 {m['val_shard']['map50_95']:.3f}, mAP50 {m['val_shard']['map50']:.3f}; "
            f"false boxes per steel view at {FALSE_BOX_THRESHOLDS[-1]:g}: {fb}")
    return summary


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 32 or h < 32:
        raise argparse.ArgumentTypeError(f"expected at least 32x32, got {text!r}")
    return w, h


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m insulator_rs.app.gpu_training --out DIR --work DIR [recipe options]``."""
    defaults = GpuRecipe()
    p = argparse.ArgumentParser(prog="python -m insulator_rs.app.gpu_training", description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, required=True, help="where the model, curves and summary.json go")
    p.add_argument("--work", type=Path, required=True, help="an empty folder for the shards and the run")
    p.add_argument("--processes", type=int, default=None, help="render processes (default: one a CPU)")
    for name, value in asdict(defaults).items():
        if name == "render_size":
            p.add_argument("--render-size", type=_size, default=value, help=f"tower views' size (default {value[0]}x{value[1]})")
        elif isinstance(value, bool):
            p.add_argument(f"--{name.replace('_', '-')}", action="store_true", help=f"default {value}")
        else:
            p.add_argument(f"--{name.replace('_', '-')}", type=type(value), default=value, help=f"default {value}")
    args = p.parse_args(argv)
    recipe = GpuRecipe(**{k: getattr(args, k) for k in asdict(defaults)})
    try:
        run(recipe, args.out, args.work, processes=args.processes)
    except (ValueError, RuntimeError) as exc:
        print(f"gpu_training: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
