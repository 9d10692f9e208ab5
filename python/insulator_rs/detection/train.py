"""Offline YOLO11 training and ONNX export with Ultralytics (the ``train`` extra).

Nothing here may touch the network: the flight computer and the build machines
have none. Ultralytics would otherwise download a font (Arial.ttf, for label
plots and the dataset check), AMP-check weights (yolo11n.pt), pip packages
(AutoUpdate) and send usage events. :func:`prepare_offline` closes each of those
doors *before* Ultralytics is imported: ``YOLO_OFFLINE`` makes its online check
false, ``YOLO_AUTOINSTALL=False`` stops pip, ``YOLO_CONFIG_DIR`` points at a
private folder holding matplotlib's DejaVuSans under the Arial names, settings
``sync`` is turned off, AMP is off (CPU) and the model is built from the
architecture file ``yolo11n.yaml`` that ships inside the Ultralytics package.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from insulator_rs.models import REAL_CROP_MODEL

OFFLINE_ENV = {
    "YOLO_OFFLINE": "1",
    "YOLO_AUTOINSTALL": "False",
    "YOLO_VERBOSE": "True",
}
FONT_NAMES = ("Arial.ttf", "Arial.Unicode.ttf")


def prepare_offline(config_dir: Path, *, threads: int | None = None) -> None:
    """Make Ultralytics work with no network; call before importing ultralytics.

    ``config_dir`` becomes Ultralytics' settings folder (``YOLO_CONFIG_DIR``) and
    receives DejaVuSans from matplotlib as ``Arial.ttf``/``Arial.Unicode.ttf``
    so that ``check_font`` finds a file instead of downloading one.
    ``threads`` caps torch/OpenMP threads (shared machines).
    """
    import sys

    if "ultralytics" in sys.modules:
        # The settings folder and the online flag are read at import time: too late to change them.
        if os.environ.get("YOLO_OFFLINE") == OFFLINE_ENV["YOLO_OFFLINE"]:
            return  # an earlier call in this process already prepared it
        raise RuntimeError("prepare_offline must run before ultralytics is imported")
    user_dir = config_dir / "Ultralytics"  # Ultralytics appends this to YOLO_CONFIG_DIR
    user_dir.mkdir(parents=True, exist_ok=True)
    from matplotlib import font_manager

    dejavu = Path(font_manager.findfont("DejaVu Sans", fallback_to_default=True))
    for name in FONT_NAMES:
        target = user_dir / name
        if not target.exists():
            shutil.copyfile(dejavu, target)
    os.environ.update(OFFLINE_ENV)
    os.environ["YOLO_CONFIG_DIR"] = str(config_dir)
    if threads is not None:
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        os.environ["OMP_NUM_THREADS"] = str(threads)
        import torch

        torch.set_num_threads(threads)
    from ultralytics import settings

    # Usage events off, every logger integration off, and no folder outside config_dir.
    wanted: dict[str, Any] = {"sync": False, "datasets_dir": str(config_dir / "datasets"),
                              "weights_dir": str(config_dir / "weights"), "runs_dir": str(config_dir / "runs")}
    wanted.update({k: False for k, v in settings.items() if isinstance(v, bool) and k.endswith("_msg") is False})
    settings.update({k: v for k, v in wanted.items() if k in settings})


@dataclass
class TrainConfig:
    """Knobs of one training run (Ultralytics argument names where they exist)."""

    data_yaml: Path
    out_dir: Path
    name: str = REAL_CROP_MODEL
    model_cfg: str = "yolo11n.yaml"
    epochs: int = 100
    hours: float | None = None  # wall-clock budget: Ultralytics re-derives epochs from the first epoch's time
    imgsz: int = 320
    batch: int = 16
    workers: int = 0
    threads: int = 2
    seed: int = 0
    patience: int = 100
    cache: bool | str = True
    plots: bool = False
    start_weights: Path | None = None  # a .pt checkpoint or a shipped .onnx (warm start); None: from scratch
    uav_augment: bool = False  # blur, haze, sun flare on top of Ultralytics' own (uav_augment.py)
    resume: Path | None = None  # an Ultralytics last.pt of an interrupted run: continue it
    device: str = "cpu"  # Ultralytics' device argument: "cpu", or a CUDA index ("0") on the GPU machine
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class TrainResult:
    """Where the run left its files, and what Ultralytics' own validator reported."""

    weights: Path
    run_dir: Path
    epochs_run: int
    seconds: float
    val_metrics: dict[str, float]


def train_yolo(cfg: TrainConfig, *, on_epoch: Callable[[int, int], None] | None = None) -> TrainResult:
    """Train ``cfg.model_cfg`` from scratch on ``cfg.data_yaml`` on the CPU.

    Call :func:`prepare_offline` first. ``on_epoch(epoch, epochs)`` is called
    after every epoch (progress display).
    """
    from ultralytics import YOLO

    if not cfg.model_cfg.endswith((".yaml", ".yml")):
        raise ValueError(f"model_cfg must be an architecture .yaml (no pretrained weights offline), got {cfg.model_cfg}")
    pretrained = False
    if cfg.resume is not None:
        model = YOLO(str(cfg.resume), task="detect")
    elif cfg.start_weights is None:
        model = YOLO(cfg.model_cfg, task="detect")
    else:
        model = YOLO(str(_warm_start_checkpoint(cfg)), task="detect")
        pretrained = True
    if on_epoch is not None:
        model.add_callback("on_fit_epoch_end", lambda tr: on_epoch(tr.epoch + 1, tr.epochs))
    args: dict[str, Any] = dict(
        data=str(cfg.data_yaml),
        epochs=cfg.epochs,
        imgsz=cfg.imgsz,
        batch=cfg.batch,
        workers=cfg.workers,
        device=cfg.device,
        amp=False,  # AMP's self-check downloads yolo26n.pt (offline here); fp32 is fast enough for YOLO11n
        pretrained=pretrained,
        seed=cfg.seed,
        deterministic=True,
        patience=cfg.patience,
        cache=cfg.cache,
        plots=cfg.plots,
        project=str(cfg.out_dir.resolve()),
        name=cfg.name,
        exist_ok=True,
        verbose=True,
    )
    if cfg.hours is not None:
        args["time"] = cfg.hours
    args.update(cfg.extra)
    args["trainer"] = trainer_class(uav_augment=cfg.uav_augment)
    if cfg.resume is not None:
        # Ultralytics restores every argument from the checkpoint; only these may change on resume
        # (data: the dataset may have been rebuilt at another path).
        args = {k: v for k, v in args.items() if k in ("trainer", "workers", "device", "cache", "batch", "data")}
        args["resume"] = str(cfg.resume)
    t0 = time.monotonic()
    model.train(**args)
    seconds = time.monotonic() - t0
    trainer = model.trainer
    if trainer is None:
        raise RuntimeError("Ultralytics returned without a trainer")
    weights = Path(trainer.best if Path(trainer.best).is_file() else trainer.last)
    metrics = {k: float(v) for k, v in (trainer.metrics or {}).items() if isinstance(v, (int, float))}
    return TrainResult(weights=weights, run_dir=Path(trainer.save_dir), epochs_run=int(trainer.epoch) + 1,
                       seconds=seconds, val_metrics=metrics)


def read_results_csv(path: Path) -> dict[str, list[int] | list[float]]:
    """Ultralytics' ``results.csv`` as {column: values by epoch}; {} when missing or unreadable.

    What Ultralytics 8.4's ``BaseTrainer.read_results_csv`` returns (it stores it in every
    checkpoint), read with the standard library instead of polars: polars' runtime wheel is
    54 MB, which the GPU machine's 64 MiB carry cannot hold beside the tree.
    """
    import csv

    try:
        with Path(path).open(newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
    except OSError:
        return {}
    if not rows:
        return {}
    header = [h.strip() for h in rows[0]]
    if any(len(row) != len(header) for row in rows[1:]):
        return {}  # a line cut short by an interrupted write: as Ultralytics, nothing rather than a part
    columns: dict[str, list[int] | list[float]] = {}
    for i, h in enumerate(header):
        text = [row[i].strip() for row in rows[1:]]
        try:  # a column of whole numbers (the epoch) stays integer, as polars infers it
            columns[h] = [int(v) for v in text]
        except ValueError:
            try:
                columns[h] = [float(v) for v in text]
            except ValueError:
                return {}
    return columns


def trainer_class(*, uav_augment: bool) -> type:
    """Ultralytics' DetectionTrainer (with :class:`UavPhotometric` when ``uav_augment``) reading
    ``results.csv`` with :func:`read_results_csv`, so that training needs no polars."""
    if uav_augment:
        from insulator_rs.detection.uav_augment import uav_trainer_class

        base = uav_trainer_class()
    else:
        from ultralytics.models.yolo.detect import DetectionTrainer

        base = DetectionTrainer

    class Trainer(base):  # type: ignore[misc, valid-type]  # ultralytics is untyped
        def read_results_csv(self) -> dict[str, list[int] | list[float]]:
            return read_results_csv(Path(self.csv))

    return Trainer


def _warm_start_checkpoint(cfg: TrainConfig) -> Path:
    """``cfg.start_weights`` as a ``.pt`` Ultralytics can train from (ONNX files are unfused first)."""
    start = Path(cfg.start_weights)  # type: ignore[arg-type]
    if not start.is_file():
        raise ValueError(f"start_weights: {start} is not a file")
    if start.suffix == ".pt":
        return start
    if start.suffix != ".onnx":
        raise ValueError(f"start_weights: {start} must be a .pt checkpoint or an Ultralytics .onnx export")
    from insulator_rs.detection.warm_start import model_from_onnx, save_checkpoint

    names = {0: "insulator"}
    model = model_from_onnx(start, cfg.model_cfg, nc=len(names))
    return save_checkpoint(model, cfg.out_dir / f"warm_start_{start.stem}.pt", source=start, names=names)


def export_onnx(weights: Path, imgsz: int, out_path: Path, *, dynamic: bool = False) -> Path:
    """Export a trained ``.pt`` to ONNX at ``out_path`` (opset chosen by Ultralytics).

    Ultralytics writes its metadata (``names``, ``imgsz``, ``stride``, ``task``)
    into the ONNX ``metadata_props``; the runtime reads names and input size
    from there. ``simplify`` stays off: it needs onnxslim, which would be
    pip-installed on the fly.
    """
    from ultralytics import YOLO

    exported = YOLO(str(weights), task="detect").export(
        format="onnx", imgsz=imgsz, dynamic=dynamic, simplify=False, half=False, device="cpu"
    )
    out_path.parent.mkdir(parents=True, exist_ok=True)
    shutil.move(str(exported), out_path)
    return out_path


def write_model_card(path: Path, card: dict[str, Any]) -> tuple[Path, Path]:
    """Write ``card`` as ``<path>.json`` and a readable ``<path>.md`` beside the model."""
    json_path, md_path = path.with_suffix(".json"), path.with_suffix(".md")
    json_path.write_text(json.dumps(card, indent=1, default=str) + "\n")
    lines = [f"# Model card: {card.get('name', path.stem)}", ""]
    for key, value in card.items():
        if isinstance(value, dict):
            lines.append(f"## {key}")
            lines += [f"- {k}: {v}" for k, v in value.items()]
            lines.append("")
        else:
            lines.append(f"- **{key}**: {value}")
    md_path.write_text("\n".join(lines) + "\n")
    return json_path, md_path


def result_dict(result: TrainResult) -> dict[str, Any]:
    """A JSON-ready view of a :class:`TrainResult`."""
    d = asdict(result)
    return {k: (str(v) if isinstance(v, Path) else v) for k, v in d.items()}
