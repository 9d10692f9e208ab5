"""The YOLO dataset writer (sim.dataset) and the ``insulator-rs dataset`` command."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from insulator_rs.sim.dataset import (
    SPLITS,
    ViewSampling,
    look_at,
    sample_view,
    split_indices,
    write_data_yaml,
    yolo_lines,
)


def test_yolo_lines_match_the_ultralytics_format():
    """Reference: the YOLO txt format by hand (class, centre x/y, width, height, normalised)."""
    lines = yolo_lines(np.array([[100.0, 50.0, 300.0, 150.0], [0.0, 0.0, 640.0, 480.0]]), 640, 480)
    assert lines[0] == f"0 {200 / 640:.6f} {100 / 480:.6f} {200 / 640:.6f} {100 / 480:.6f}"
    assert lines[1] == "0 0.500000 0.500000 1.000000 1.000000"
    # Boxes reaching past the border are clipped to it.
    (clipped,) = yolo_lines(np.array([[-20.0, 400.0, 40.0, 500.0]]), 640, 480)
    assert clipped == f"0 {20 / 640:.6f} {440 / 480:.6f} {40 / 640:.6f} {80 / 480:.6f}"
    with pytest.raises(ValueError, match="boxes"):
        yolo_lines(np.array([[700.0, 0.0, 800.0, 10.0]]), 640, 480)
    with pytest.raises(ValueError, match="width"):
        yolo_lines(np.zeros((0, 4)), 0, 480)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(0, 400), a=st.floats(0, 1), b=st.floats(0, 1), seed=st.integers(0, 99))
def test_split_counts_follow_the_fractions(n, a, b, seed):
    """Property: every image gets one split; each split's count is within 1 of fraction * n
    (or 2 when a non-empty split had to borrow an image)."""
    a, b = sorted((a, b))
    fractions = (a, b - a, 1.0 - b)
    labels = split_indices(n, fractions, np.random.default_rng(seed))
    assert len(labels) == n and set(labels) <= set(SPLITS)
    for split, f in zip(SPLITS, fractions):
        assert abs(labels.count(split) - f * n) <= 2.0


def test_split_paper_ratio_and_bad_fractions():
    labels = split_indices(1500, (0.8, 0.1, 0.1), np.random.default_rng(0))
    assert [labels.count(s) for s in SPLITS] == [1200, 150, 150]
    assert labels[:20] != sorted(labels[:20])  # shuffled
    with pytest.raises(ValueError, match="split"):
        split_indices(10, (0.5, 0.5, 0.5), np.random.default_rng(0))


def test_look_at_centres_the_target():
    """Reference: cv2.projectPoints of the target through the look-at pose lands on the
    principal point (tol 1e-6 px), and a point above the target lands above it in the image."""
    K = np.array([[800.0, 0, 640], [0, 800.0, 480], [0, 0, 1]])
    eye = np.array([12.0, -7.0, 9.0])
    target = np.array([0.5, 1.0, 20.0])
    T_w_c = look_at(eye, target)
    np.testing.assert_allclose(T_w_c[:3, :3].T @ T_w_c[:3, :3], np.eye(3), atol=1e-12)
    assert np.linalg.det(T_w_c[:3, :3]) == pytest.approx(1.0)
    T_c_w = np.linalg.inv(T_w_c)
    rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
    pts = np.array([target, target + [0, 0, 1.0]])
    uv, _ = cv2.projectPoints(pts, rvec, T_c_w[:3, 3], K, np.zeros(5))
    uv = uv.reshape(-1, 2)
    np.testing.assert_allclose(uv[0], [640, 480], atol=1e-6)
    assert uv[1, 1] < uv[0, 1]  # image y points down, W's z up


def test_sampled_views_stay_in_their_ranges():
    rng = np.random.default_rng(3)
    sampling = ViewSampling(distance=(8.0, 20.0), height=(5.0, 25.0), aim_jitter_deg=10.0)
    aim = np.array([[0.0, 0.0, 20.0], [4.0, 1.0, 17.0]])
    for _ in range(200):
        T = sample_view(rng, aim, sampling)
        eye = T[:3, 3]
        assert 8.0 - 1e-9 <= math.hypot(eye[0], eye[1]) <= 20.0 + 1e-9
        assert 5.0 <= eye[2] <= 25.0
        to_aim = aim - eye
        cosines = (to_aim @ T[:3, 2]) / np.linalg.norm(to_aim, axis=1)
        # One aim point lies within the jitter cone (two axes of 10 degrees each).
        assert np.degrees(np.arccos(cosines.max())) <= 10.0 * math.sqrt(2) + 1e-6


def test_data_yaml_is_what_ultralytics_reads(tmp_path):
    path = write_data_yaml(tmp_path)
    doc = yaml.safe_load(path.read_text())
    assert doc["train"] == "images/train" and doc["val"] == "images/val"
    assert doc["test"] == "images/test" and doc["names"] == {0: "insulator"} and doc["nc"] == 1
    assert doc["path"] == str(tmp_path.resolve())


# --- the dataset command end to end ----------------------------------------------------

def _make(tmp_path, name="ds", seed=1):
    from insulator_rs.app.cli import main

    out = tmp_path / name
    code = main(["dataset", "--images", "6", "--width", "160", "--height", "120",
                 "--min-visible-pixels", "4", "--seed", str(seed), "--out", str(out), "--quiet"])
    assert code == 0
    return out


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return _make(tmp_path_factory.mktemp("dataset"))


def test_dataset_command_writes_the_yolo_layout(dataset):
    import csv

    doc = yaml.safe_load((dataset / "data.yaml").read_text())
    counts = {s: len(list((dataset / "images" / s).glob("*.png"))) for s in SPLITS}
    assert counts == {"train": 4, "val": 1, "test": 1}
    with (dataset / "views.csv").open() as f:
        views = list(csv.DictReader(f))
    assert len(views) == 6 and {v["scene"] for v in views} == {"tower_a", "tower_b"}
    n_boxes = 0
    for split in SPLITS:
        assert (dataset / doc[split]).is_dir()
        for img in (dataset / "images" / split).glob("*.png"):
            assert cv2.imread(str(img)).shape == (120, 160, 3)
            label = dataset / "labels" / split / f"{img.stem}.txt"
            for line in label.read_text().splitlines():
                fields = line.split()
                assert len(fields) == 5 and fields[0] == "0"
                values = np.array([float(v) for v in fields[1:]])
                assert np.all((values >= 0) & (values <= 1)) and values[2] > 0 and values[3] > 0
                n_boxes += 1
    assert n_boxes == sum(int(v["boxes"]) for v in views) > 0


def test_training_card_counts_a_rendered_dataset(dataset):
    """The model card of a model trained on a rendered data.yaml counts its images and boxes
    per split (reference: the files and views.csv the writer made)."""
    import csv

    from insulator_rs.app.train_command import describe_yolo_dataset

    summary = describe_yolo_dataset(dataset / "data.yaml")
    assert summary["images"] == {"train": 4, "val": 1, "test": 1}
    assert summary["rendered_images_per_scene"] == {"tower_a": 3, "tower_b": 3}
    with (dataset / "views.csv").open() as f:
        views = list(csv.DictReader(f))
    for split in SPLITS:
        assert summary["boxes"][split] == sum(int(v["boxes"]) for v in views if v["split"] == split)


def test_dataset_labels_sit_on_the_insulators(dataset):
    """Reference: cv2.projectPoints of points along each ground-truth insulator axis, through
    the pose in views.csv and the scaled default lens; every label box holds the projection of
    some insulator's axis (tol: the shed radius in pixels + 1 px)."""
    import csv

    from insulator_rs.sim.dataset import scaled_camera_model
    from insulator_rs.sim.towers import load_tower

    model = scaled_camera_model(160, 120)
    K = np.array([[model.fx, 0, model.cx], [0, model.fy, model.cy], [0, 0, 1]])
    towers = {n: load_tower(n) for n in ("tower_a", "tower_b")}
    with (dataset / "views.csv").open() as f:
        views = list(csv.DictReader(f))
    checked = 0
    for v in views:
        T_w_c = np.array([float(v[f"T_w_c_{r}{c}"]) for r in range(4) for c in range(4)]).reshape(4, 4)
        T_c_w = np.linalg.inv(T_w_c)
        rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
        tower = towers[v["scene"]]
        axes = []
        for ins in tower.insulators:
            a, b = ins.end_points
            pts = a + np.linspace(0, 1, 41)[:, None] * (b - a)
            uv, _ = cv2.projectPoints(pts, rvec, T_c_w[:3, 3], K, np.asarray(model.dist))
            depth = np.linalg.norm(ins.center - T_w_c[:3, 3])
            axes.append((uv.reshape(-1, 2), model.fx * ins.radius / depth + 1.0))
        for line in (dataset / "labels" / v["split"] / f"{v['image']}.txt").read_text().splitlines():
            _, cx, cy, w, h = (float(x) for x in line.split())
            x1, x2 = (cx - w / 2) * 160, (cx + w / 2) * 160
            y1, y2 = (cy - h / 2) * 120, (cy + h / 2) * 120
            assert any(np.any((uv[:, 0] >= x1 - tol) & (uv[:, 0] <= x2 + tol)
                              & (uv[:, 1] >= y1 - tol) & (uv[:, 1] <= y2 + tol)) for uv, tol in axes)
            checked += 1
    assert checked > 0


def test_dataset_is_deterministic_under_a_seed(dataset, tmp_path):
    again = _make(tmp_path, "again", seed=1)
    assert (again / "views.csv").read_text() == (dataset / "views.csv").read_text()
    for split in SPLITS:
        for img in (dataset / "images" / split).glob("*.png"):
            other = again / "images" / split / img.name
            assert np.array_equal(cv2.imread(str(img)), cv2.imread(str(other)))
            label = Path("labels") / split / f"{img.stem}.txt"
            assert (dataset / label).read_text() == (again / label).read_text()


def test_dataset_refuses_to_overwrite_and_bad_arguments(dataset):
    from insulator_rs.app.cli import main

    with pytest.raises(ValueError, match="out: .*already holds a dataset"):
        main(["dataset", "--images", "1", "--out", str(dataset), "--quiet"])
    with pytest.raises(ValueError, match="--width/--height"):
        main(["dataset", "--images", "1", "--width", "100", "--out", str(dataset / "x")])
    with pytest.raises(SystemExit):
        main(["dataset", "--images", "0", "--out", str(dataset / "y")])
    with pytest.raises(SystemExit):
        main(["dataset", "--split", "0.8", "0.1", "1.5", "--out", str(dataset / "z")])
