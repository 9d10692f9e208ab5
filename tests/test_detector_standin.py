"""The ground-truth-box detector stand-in (sim.detector_standin): statistics, determinism, input checks."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from insulator_rs.sim.detector_standin import FALSE_POSITIVE_ID, DetectorStandin

IMAGE = (1280, 960)


def _boxes(n: int, rng: np.random.Generator) -> np.ndarray:
    x1 = rng.uniform(300, 800, n)
    y1 = rng.uniform(300, 500, n)
    return np.column_stack([x1, y1, x1 + rng.uniform(40, 120, n), y1 + rng.uniform(20, 200, n)])


def test_perfect_detector_returns_the_ground_truth():
    gt = _boxes(7, np.random.default_rng(1))
    det = DetectorStandin(jitter=0.0, miss_rate=0.0, false_positives=0.0).detect(
        gt, IMAGE, instance_ids=np.arange(10, 17))
    np.testing.assert_array_equal(det.boxes[:, :4], gt)
    np.testing.assert_array_equal(det.instance_ids, np.arange(10, 17))
    assert np.all((det.boxes[:, 4] > 0) & (det.boxes[:, 4] <= 1))


def test_jitter_std_is_relative_to_box_size():
    """Reference: the edge displacement divided by the box width/height has std = jitter
    (tol 5 % on 20 000 boxes, far from the image border so nothing is clipped)."""
    rng = np.random.default_rng(2)
    gt = _boxes(20000, rng)
    det = DetectorStandin(jitter=0.08, seed=3).detect(gt, IMAGE)
    size = np.column_stack([gt[:, 2] - gt[:, 0], gt[:, 3] - gt[:, 1]])
    rel = (det.boxes[:, :4] - gt) / np.tile(size, 2)
    np.testing.assert_allclose(rel.std(axis=0), 0.08, rtol=0.05)
    np.testing.assert_allclose(rel.mean(axis=0), 0.0, atol=0.005)


def test_miss_rate_and_false_positive_rate():
    """Binomial miss count within 4 sigma; Poisson false-positive mean within 4 sigma."""
    rng = np.random.default_rng(4)
    d = DetectorStandin(jitter=0.0, miss_rate=0.3, false_positives=0.5, seed=5)
    kept = fps = 0
    n_images, per_image = 2000, 5
    for _ in range(n_images):
        det = d.detect(_boxes(per_image, rng), IMAGE)
        kept += int(np.sum(det.instance_ids != FALSE_POSITIVE_ID))
        fps += int(np.sum(det.instance_ids == FALSE_POSITIVE_ID))
    n = n_images * per_image
    assert abs(kept - 0.7 * n) < 4 * np.sqrt(n * 0.3 * 0.7)
    assert abs(fps - 0.5 * n_images) < 4 * np.sqrt(0.5 * n_images)


def test_seeded_runs_are_identical_and_seeds_differ():
    gt = _boxes(50, np.random.default_rng(6))
    a = DetectorStandin(jitter=0.1, miss_rate=0.2, false_positives=2, seed=9).detect(gt, IMAGE)
    b = DetectorStandin(jitter=0.1, miss_rate=0.2, false_positives=2, seed=9).detect(gt, IMAGE)
    c = DetectorStandin(jitter=0.1, miss_rate=0.2, false_positives=2, seed=10).detect(gt, IMAGE)
    np.testing.assert_array_equal(a.boxes, b.boxes)
    np.testing.assert_array_equal(a.instance_ids, b.instance_ids)
    assert a.boxes.shape != c.boxes.shape or not np.array_equal(a.boxes, c.boxes)


@settings(max_examples=80, deadline=None)
@given(
    boxes=st.lists(st.tuples(st.floats(-500, 2000), st.floats(-500, 2000),
                             st.floats(0.5, 900), st.floats(0.5, 900)), max_size=8),
    jitter=st.floats(0, 2), fp=st.floats(0, 5), width=st.integers(1, 2000),
    height=st.integers(1, 2000), seed=st.integers(0, 2**32),
)
def test_boxes_stay_valid_inside_the_image(boxes, jitter, fp, width, height, seed):
    """Property: whatever the input and noise, every box is ordered, inside the image and
    non-empty, and there is one instance id per box."""
    gt = np.array([[x, y, x + w, y + h] for x, y, w, h in boxes]).reshape(-1, 4)
    det = DetectorStandin(jitter=jitter, false_positives=fp, seed=seed).detect(gt, (width, height))
    b = det.boxes
    assert b.shape[1] == 5 and len(det.instance_ids) == len(b)
    assert np.all(b[:, 2] > b[:, 0]) and np.all(b[:, 3] > b[:, 1])
    assert np.all(b[:, [0, 2]] >= 0) and np.all(b[:, [0, 2]] <= width)
    assert np.all(b[:, [1, 3]] >= 0) and np.all(b[:, [1, 3]] <= height)


@pytest.mark.parametrize("kwargs,name", [
    ({"jitter": -0.1}, "jitter"), ({"jitter": float("nan")}, "jitter"),
    ({"miss_rate": 1.5}, "miss_rate"), ({"false_positives": -1}, "false_positives"),
    ({"fp_size": (0.5, 0.1)}, "fp_size"), ({"seed": -1}, "seed"),
])
def test_bad_configuration_names_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        DetectorStandin(**kwargs)


def test_bad_boxes_name_the_argument():
    d = DetectorStandin()
    with pytest.raises(ValueError, match="gt_boxes"):
        d.detect(np.zeros((3, 3)), IMAGE)
    with pytest.raises(ValueError, match="gt_boxes"):
        d.detect([[10, 10, 5, 20]], IMAGE)
    with pytest.raises(ValueError, match="gt_boxes"):
        d.detect([[10, 10, np.nan, 20]], IMAGE)
    with pytest.raises(ValueError, match="image_size"):
        d.detect([[10, 10, 20, 20]], (0, 480))
    with pytest.raises(ValueError, match="instance_ids"):
        d.detect([[10, 10, 20, 20]], IMAGE, instance_ids=[1, 2])
    assert len(d.detect(np.zeros((0, 4)), IMAGE)) == 0
