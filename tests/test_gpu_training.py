"""The GPU machine's training call (app/gpu_training.py, scripts/gpu/), dry-run on the CPU.

The end-to-end test runs scripts/gpu/dry_run_cpu.sh: the same module the device runs, with the
packages the device's image lacks hidden (scripts/gpu/device_like.py), two shards of a few
rendered views, one epoch, the ONNX export and the measurements. The results.csv reader that
stands in for Ultralytics' polars one is checked against polars itself, on a file written by
Ultralytics' own ``save_metrics``.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace

import pytest

from insulator_rs.app.gpu_training import CARD_TEST_SEED, GpuRecipe, render_jobs, write_combined_yaml
from insulator_rs.detection.train import prepare_offline, read_results_csv

REPO = Path(__file__).resolve().parent.parent
needs_ultralytics = pytest.mark.skipif(importlib.util.find_spec("ultralytics") is None,
                                       reason="the train extra (ultralytics) is not installed")


def _ultralytics_results_csv(path: Path, epochs: int) -> None:
    """Write results.csv with Ultralytics' BaseTrainer.save_metrics (its own format, %.6g)."""
    # offline first, as every test that imports Ultralytics (a worker runs several such modules)
    prepare_offline(Path(tempfile.gettempdir()) / "insulator_rs_ultralytics_cfg")
    from ultralytics.engine.trainer import BaseTrainer

    trainer = SimpleNamespace(csv=path, train_time_start=0.0, epoch=0)
    for epoch in range(epochs):
        trainer.epoch = epoch
        metrics = {"train/box_loss": 1.5 / (epoch + 1), "metrics/mAP50(B)": 0.1 * epoch,
                   "metrics/mAP50-95(B)": 0.0123456789 * epoch, "lr/pg0": 3.3e-5, "val/cls_loss": 0.0}
        BaseTrainer.save_metrics(trainer, metrics)


@needs_ultralytics
def test_results_csv_reads_as_polars_does(tmp_path: Path) -> None:
    """Reference: polars.read_csv(...).to_dict(as_series=False), what Ultralytics 8.4 stores; exact."""
    polars = pytest.importorskip("polars")
    csv = tmp_path / "results.csv"
    _ultralytics_results_csv(csv, epochs=4)
    ours = read_results_csv(csv)
    reference = polars.read_csv(csv.read_bytes(), infer_schema_length=None).to_dict(as_series=False)
    assert ours == reference
    assert ours["epoch"] == [1, 2, 3, 4] and all(isinstance(v, int) for v in ours["epoch"])


def test_results_csv_unreadable_is_empty(tmp_path: Path) -> None:
    """Missing, empty or cut short by an interrupted write: {} (as Ultralytics' reader), never a raise."""
    assert read_results_csv(tmp_path / "missing.csv") == {}
    (tmp_path / "empty.csv").write_text("")
    assert read_results_csv(tmp_path / "empty.csv") == {}
    (tmp_path / "cut.csv").write_text("epoch,time,metrics/mAP50(B)\n1,2.5,0.1\n2,5.0\n")
    assert read_results_csv(tmp_path / "cut.csv") == {}
    (tmp_path / "text.csv").write_text("epoch,time\n1,abc\n")
    assert read_results_csv(tmp_path / "text.csv") == {}


def test_shards_never_render_the_cards_test_split() -> None:
    recipe = GpuRecipe()
    jobs = render_jobs(recipe)
    seeds = [j.seed for j in jobs]
    assert len(set(seeds)) == len(seeds) and CARD_TEST_SEED not in seeds
    names = {j.name for j in jobs}
    assert len(names) == len(jobs) == 2 * recipe.shards + 2
    assert sum(j.images for j in jobs if j.name.startswith("tower_")) == recipe.shards * recipe.tower_views_per_shard
    val = next(j for j in jobs if j.name == "val")
    assert val.split == (0.0, 1.0, 0.0) and val.images == recipe.val_views
    with pytest.raises(ValueError, match="seed"):
        GpuRecipe(seed=0)
    with pytest.raises(ValueError, match="shards"):
        GpuRecipe(shards=0)
    with pytest.raises(ValueError, match="workers"):
        GpuRecipe(workers=-1)


def test_combined_yaml_lists_every_training_shard(tmp_path: Path) -> None:
    import yaml

    recipe = GpuRecipe(shards=3)
    doc = yaml.safe_load(write_combined_yaml(tmp_path, recipe).read_text())
    assert [Path(t).parts[-3] for t in doc["train"]] == ["tower_00", "tower_01", "tower_02",
                                                         "steel_00", "steel_01", "steel_02"]
    assert all(Path(t).parts[-2:] == ("images", "train") for t in doc["train"])
    assert Path(doc["val"]).parts[-3:] == ("val", "images", "val") and doc["names"] == {0: "insulator"}


@pytest.mark.slow  # a whole training call on the CPU: about 80 s
@needs_ultralytics
def test_dry_run_on_the_cpu_writes_what_the_device_returns(tmp_path: Path) -> None:
    """scripts/gpu/dry_run_cpu.sh end to end: the files the device call brings back, readable."""
    out = tmp_path / "out"
    env = {**os.environ, "PYTHON": sys.executable}
    proc = subprocess.run(["bash", str(REPO / "scripts" / "gpu" / "dry_run_cpu.sh"), str(out)], env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert {p.name for p in out.iterdir()} == {"insulator-sim.onnx", "insulator-sim_best.pt", "results.csv",
                                              "training.png", "summary.json"}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["train"]["epochs_run"] == 1
    assert set(summary["rendered"]) == {"tower_00", "tower_01", "steel_00", "steel_01", "val", "steel_test"}
    for label in ("new", "shipped"):
        assert 0.0 <= summary[label]["val_shard"]["map50_95"] <= 1.0
        assert summary[label]["steel_test"]["views"] == 6
    assert len(read_results_csv(out / "results.csv")["epoch"]) == 1

    from insulator_rs.detection.detector import open_detector

    detector = open_detector(str(out / "insulator-sim.onnx"), conf=0.25)
    assert detector.imgsz == (320, 320) and detector.names == {0: "insulator"}
