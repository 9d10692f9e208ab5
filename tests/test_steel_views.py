"""Steel views (hard negatives): where the camera looks, what counts as a false box, and the
training set they join. References: the scene's ground truth (the tower spec, the rendered
instance image) and Ultralytics' own dataset loader."""

from __future__ import annotations

import importlib.util

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from insulator_rs.sim.steel_views import (
    MATCH_INSIDE,
    MATCH_IOU,
    SteelViewSampling,
    count_false_boxes,
    data_yaml_with_steel,
    is_false_box,
    sample_steel_view,
    steel_aim_points,
    write_image_list,
)


@pytest.fixture(scope="module")
def steel(tmp_path_factory):
    from insulator_rs.app.cli import main

    out = tmp_path_factory.mktemp("steel") / "views"
    assert main(["dataset", "--steel-views", "--images", "8", "--split", "1", "0", "0", "--seed", "3",
                 "--out", str(out), "--quiet"]) == 0
    return out


def test_aim_points_are_steel_not_insulators():
    """Every aim point lies on the tower's frame (inside its height and half-width) and at least a
    shed radius away from every insulator's axis (reference: the scene's ground truth)."""
    from insulator_rs.sim.towers import load_tower

    for name in ("tower_a", "tower_b"):
        tower = load_tower(name)
        points = steel_aim_points(tower)
        assert len(points) >= 10
        assert np.all(points[:, 2] <= tower.max_height + 1e-9) and np.all(points[:, 2] > 0)
        assert np.all(np.abs(points[:, :2]) <= 0.5 * tower.max_width + 1e-9)
        apex = np.array([0.0, 0.0, tower.max_height])
        assert np.any(np.all(np.isclose(points, apex), axis=1)) == (tower.spec.body.peak_height > 0)
        for ins in tower.insulators:
            a, b = ins.end_points
            t = np.clip((points - a) @ (b - a) / np.dot(b - a, b - a), 0.0, 1.0)
            dist = np.linalg.norm(points - (a + t[:, None] * (b - a)), axis=1)
            assert dist.min() > ins.radius


@settings(max_examples=50, derandomize=True, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_views_come_from_the_inspection_path(seed):
    """The camera sits 5-16 m (horizontally) from one aim point, at most 6 m below and 2 m above it
    (never under 2 m), and looks at it within the jitter cone."""
    rng = np.random.default_rng(seed)
    aim = np.array([[0.0, 0.0, 28.5], [4.5, 0.0, 17.0], [1.0, 1.0, 3.0]])
    s = SteelViewSampling()
    T = sample_steel_view(rng, aim, s)
    eye, axis = T[:3, 3], T[:3, 2]
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    ok = []
    for p in aim:
        d = np.hypot(*(eye[:2] - p[:2]))
        height_ok = max(s.min_height, p[2] - 6.0) - 1e-9 <= eye[2] <= max(s.min_height, p[2] + 2.0) + 1e-9
        to = (p - eye) / np.linalg.norm(p - eye)
        angle = np.degrees(np.arccos(np.clip(to @ axis, -1, 1)))
        ok.append(5.0 - 1e-9 <= d <= 16.0 + 1e-9 and height_ok and angle <= s.aim_jitter_deg * np.sqrt(2) + 1e-6)
    assert any(ok)


def test_false_box_rule():
    truth = np.array([[10.0, 10.0, 20.0, 50.0]])
    assert not is_false_box(np.array([10.0, 10.0, 20.0, 50.0]), truth)  # the insulator itself
    assert not is_false_box(np.array([11.0, 30.0, 19.0, 45.0]), truth)  # part of the string: inside it
    assert is_false_box(np.array([100.0, 10.0, 120.0, 50.0]), truth)  # elsewhere
    assert is_false_box(np.array([0.0, 0.0, 5.0, 5.0]), np.zeros((0, 4)))  # no insulator in view
    # A large box that just grazes the string: IoU and the inside share both under the rule's limits.
    graze = np.array([15.0, 0.0, 200.0, 100.0])
    inter = 5.0 * 40.0
    assert inter / (185.0 * 100.0) < MATCH_INSIDE and inter / (185.0 * 100 + 400 - inter) < MATCH_IOU
    assert is_false_box(graze, truth)


def test_steel_views_label_every_visible_insulator(steel):
    """Each view's labels are the insulators with at least MIN_LABEL_PIXELS visible (reference: the
    truth.json the renderer's instance image gave), all views at the flight's 320x240."""
    import cv2

    from insulator_rs.sim.steel_views import MIN_LABEL_PIXELS

    truth = json.loads((steel / "truth.json").read_text())
    assert len(truth) == 8
    for rel, entry in truth.items():
        assert cv2.imread(str(steel / rel)).shape == (240, 320, 3)
        lines = (steel / rel.replace("images/", "labels/").replace(".png", ".txt")).read_text().splitlines()
        assert len(lines) == sum(p >= MIN_LABEL_PIXELS for p in entry["pixels"])
        assert len(entry["boxes"]) == len(entry["pixels"])


def test_false_boxes_are_counted_against_the_truth(steel, tmp_path):
    """A detector that returns the truth boxes has no false box; one that adds a box in a corner
    no insulator covers has exactly one per view, at its score; the mined list names those views."""
    truth = json.loads((steel / "truth.json").read_text())
    import cv2

    by_shape: dict[bytes, str] = {}
    for rel in truth:
        by_shape[cv2.imread(str(steel / rel)).tobytes()] = rel

    def perfect(image):
        boxes = np.array(truth[by_shape[image.tobytes()]]["boxes"]).reshape(-1, 4)
        return boxes, np.full(len(boxes), 0.9)

    def with_sky_box(image):
        boxes, scores = perfect(image)
        rel = by_shape[image.tobytes()]
        extra = np.array([[0.0, 0.0, 3.0, 3.0]])
        if any(not is_false_box(extra[0], np.array([b])) for b in truth[rel]["boxes"]):
            extra = np.zeros((0, 4))  # an insulator happens to be in that corner
        return np.vstack([boxes, extra]), np.concatenate([scores, np.full(len(extra), 0.3)])

    clean = count_false_boxes(perfect, steel)
    assert clean.views == 8 and clean.false_boxes == {0.25: 0, 0.5: 0}
    dirty = count_false_boxes(with_sky_box, steel)
    assert dirty.false_boxes[0.5] == 0 and 1 <= dirty.false_boxes[0.25] == dirty.views_with_false_box[0.25] <= 8
    listed = tmp_path / "mined.txt"
    assert write_image_list(steel, dirty, listed, min_score=0.25) == dirty.views_with_false_box[0.25]
    assert all(line.endswith(".png") and (steel / "images") in Path(line).parents
               for line in listed.read_text().splitlines())
    assert write_image_list(steel, dirty, listed, min_score=0.5) == 0
    with pytest.raises(ValueError, match="truth.json"):
        count_false_boxes(perfect, tmp_path)


def test_combined_training_set_is_what_ultralytics_loads(steel, tmp_path):
    """Ultralytics' own dataset check and image-file loader read the combined yaml: the base's
    training images, every steel view, and the mined views repeated (reference: the file counts)."""
    if importlib.util.find_spec("ultralytics") is None:  # not imported here: prepare_offline comes first
        pytest.skip("the train extra (ultralytics) is not installed")
    from insulator_rs.app.cli import main
    from insulator_rs.detection.train import prepare_offline

    base = tmp_path / "base"
    assert main(["dataset", "--images", "5", "--width", "160", "--height", "120", "--seed", "1",
                 "--out", str(base), "--quiet"]) == 0
    mined = tmp_path / "mined.txt"
    views = sorted((steel / "images" / "train").glob("*.png"))
    mined.write_text("".join(f"{p}\n" for p in views[:2]))
    out = data_yaml_with_steel(base / "data.yaml", steel, mined, tmp_path / "combined.yaml", mined_repeats=3)
    doc = yaml.safe_load(out.read_text())
    assert doc["val"] == str((base / "images" / "val").resolve())
    prepare_offline(tmp_path / "cfg", threads=1)
    from ultralytics.data.base import BaseDataset

    files = BaseDataset.get_img_files(type("D", (), {"prefix": "", "fraction": 1.0})(), doc["train"])
    n_base = len(list((base / "images" / "train").glob("*.png")))
    assert len(files) == n_base + len(views) + 3 * 2
    with pytest.raises(ValueError, match="train"):
        (tmp_path / "bad.yaml").write_text("val: x\n")
        data_yaml_with_steel(tmp_path / "bad.yaml", steel, None, tmp_path / "c2.yaml")
