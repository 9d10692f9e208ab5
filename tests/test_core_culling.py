"""points_in_boxes against a numpy filter over cv2.projectPoints."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.reference_projection import cv2_project, random_camera, random_rigid

import insulator_rs as ir
from insulator_rs.synthetic import lidar_frame


def numpy_cull(
    points_l: np.ndarray, t_c_l: np.ndarray, cam: ir.CameraModel, boxes: np.ndarray
) -> tuple[list[np.ndarray], np.ndarray]:
    """Per box, indices of points in front (z > NEAR_LIMIT), inside the image and the
    half-open box, from cv2 pixels; plus a mask of points within 1e-6 px of an edge."""
    z = points_l @ t_c_l[2, :3] + t_c_l[2, 3]
    uv = cv2_project(points_l, t_c_l, cam)
    front = z > ir.NEAR_LIMIT
    in_image = front & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    edges_u = np.concatenate([[0.0, cam.width], boxes[:, 0], boxes[:, 2]])
    edges_v = np.concatenate([[0.0, cam.height], boxes[:, 1], boxes[:, 3]])
    ambiguous = (np.abs(uv[:, :1] - edges_u).min(axis=1) < 1e-6) | (
        np.abs(uv[:, 1:] - edges_v).min(axis=1) < 1e-6
    )
    out = []
    for x1, y1, x2, y2 in boxes[:, :4]:
        inside = in_image & (uv[:, 0] >= x1) & (uv[:, 0] < x2) & (uv[:, 1] >= y1) & (uv[:, 1] < y2)
        out.append(np.flatnonzero(inside))
    return out, ambiguous


def random_boxes(rng: np.random.Generator, cam: ir.CameraModel, m: int) -> np.ndarray:
    """m boxes, some reaching past the image border, with a score column."""
    x1 = rng.uniform(-0.2, 0.9, size=m) * cam.width
    y1 = rng.uniform(-0.2, 0.9, size=m) * cam.height
    w = rng.uniform(0.05, 0.5, size=m) * cam.width
    h = rng.uniform(0.05, 0.5, size=m) * cam.height
    return np.column_stack([x1, y1, x1 + w, y1 + h, rng.uniform(0, 1, size=m)])


@pytest.mark.parametrize("trial", range(10))
def test_cull_matches_numpy_over_cv2(trial: int) -> None:
    """Reference: numpy half-open box filter over cv2.projectPoints pixels of the points in
    front of the camera and inside the image. Tolerance: identical index sets, except points
    within 1e-6 px of a box or image edge (excluded from the comparison)."""
    rng = np.random.default_rng(100 + trial)
    cam = random_camera(rng)
    t_c_l = random_rigid(rng, max_translation=0.5)
    pts = lidar_frame(5000, seed=trial, max_range=30.0)
    boxes = random_boxes(rng, cam, int(rng.integers(1, 6)))
    got = ir.points_in_boxes(pts, t_c_l, cam, boxes)
    expected, ambiguous = numpy_cull(pts, t_c_l, cam, boxes)
    assert len(got) == len(boxes)
    for g, e in zip(got, expected, strict=True):
        assert g.dtype == np.int64
        assert np.all(np.diff(g) > 0), "indices must be ascending"
        np.testing.assert_array_equal(np.setdiff1d(g, np.flatnonzero(ambiguous)), np.setdiff1d(e, np.flatnonzero(ambiguous)))
    assert sum(len(e) for e in expected) > 0, "the test needs points inside some box"


def test_cull_agrees_with_project_points(rng: np.random.Generator) -> None:
    """Same pixels as project_points: the box lists equal a filter over its (uv, valid)."""
    cam = random_camera(rng)
    t_c_l = random_rigid(rng, max_translation=0.5)
    pts = lidar_frame(3000, seed=3)
    boxes = random_boxes(rng, cam, 4)
    uv, valid = ir.project_points(pts, t_c_l, cam)
    for (x1, y1, x2, y2, _), got in zip(boxes, ir.points_in_boxes(pts, t_c_l, cam, boxes), strict=True):
        inside = valid & (uv[:, 0] >= x1) & (uv[:, 0] < x2) & (uv[:, 1] >= y1) & (uv[:, 1] < y2)
        np.testing.assert_array_equal(got, np.flatnonzero(inside))


def test_box_edges_are_half_open_and_outside_boxes_are_empty() -> None:
    cam = ir.CameraModel(100, 100, 50, 50, 100, 100)
    # Pixels (50,50), (60,50), (50,60), (99.5, 50): z = 1, x = (u - 50) / 100.
    pts = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.0, 0.1, 1.0], [0.495, 0.0, 1.0]])
    boxes = [
        [50, 50, 60, 60],  # contains (50,50) only: x2 and y2 are exclusive
        [40, 40, 200, 200],  # reaches past the image: only in-image points
        [200, 200, 300, 300],  # wholly outside the image
    ]
    got = ir.points_in_boxes(pts, np.eye(4), cam, boxes)
    assert [g.tolist() for g in got] == [[0], [0, 1, 2, 3], []]


def test_empty_inputs() -> None:
    cam = ir.CameraModel(100, 100, 50, 50, 100, 100)
    assert ir.points_in_boxes(np.zeros((0, 3)), np.eye(4), cam, [[0, 0, 10, 10]])[0].shape == (0,)
    assert ir.points_in_boxes(np.ones((5, 3)), np.eye(4), cam, np.zeros((0, 4))) == []
    assert ir.points_in_boxes(np.ones((5, 3)), np.eye(4), cam, []) == []
    assert ir.points_in_boxes(np.ones((5, 3)), np.eye(4), cam, np.zeros((0, 5))) == []


@pytest.mark.parametrize(
    ("boxes", "exc", "pattern"),
    [
        ([[10, 10, 5, 20]], ValueError, r"^boxes: row 0: .*x2 > x1"),  # inverted
        ([[0, 0, 10, 10], [10, 10, 20, 10]], ValueError, r"^boxes: row 1: "),  # zero area
        ([[0, 0, np.nan, 10]], ValueError, r"^boxes: row 0: .*finite"),
        ([[0, 0, 10, np.inf, 0.5]], ValueError, r"^boxes: row 0: "),
        ([0, 0, 10, 10], ValueError, r"^boxes: expected shape \(M, 4\) or \(M, 5\).*got \(4,\)"),
        ([[0, 0, 10]], ValueError, r"^boxes: expected shape"),
        ([["a", "b", "c", "d"]], TypeError, r"^boxes: "),
    ],
)
def test_bad_boxes_name_boxes_and_row(boxes: object, exc: type[Exception], pattern: str) -> None:
    cam = ir.CameraModel(100, 100, 50, 50, 100, 100)
    with pytest.raises(exc, match=pattern):
        ir.points_in_boxes(np.ones((5, 3)), np.eye(4), cam, boxes)


def test_nan_score_column_is_ignored_and_nonfinite_points_never_returned() -> None:
    cam = ir.CameraModel(100, 100, 50, 50, 100, 100)
    pts = np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.0], [0.0, np.inf, 1.0]])
    got = ir.points_in_boxes(pts, np.eye(4), cam, [[0, 0, 100, 100, np.nan]])
    assert got[0].tolist() == [0]
