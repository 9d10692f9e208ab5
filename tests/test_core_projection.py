"""CameraModel, chain_transforms and project_points against OpenCV."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from helpers.reference_projection import cv2_project, random_camera, random_rigid

import insulator_rs as ir


def points_in_front(rng: np.random.Generator, t_c_l: np.ndarray, n: int) -> np.ndarray:
    """L-frame points that lie 0.5-30 m in front of the camera within a wide cone."""
    z = rng.uniform(0.5, 30.0, size=n)
    xy = rng.uniform(-0.8, 0.8, size=(n, 2)) * z[:, None]
    p_c = np.column_stack([xy, z])
    t_l_c = np.linalg.inv(t_c_l)
    return p_c @ t_l_c[:3, :3].T + t_l_c[:3, 3]


@pytest.mark.parametrize("trial", range(20))
def test_projection_matches_cv2(trial: int) -> None:
    """Reference: cv2.projectPoints with the same K, dist and pose (random intrinsics,
    distortion, poses). Tolerance: 1e-6 relative or 1e-3 px, per coordinate."""
    rng = np.random.default_rng(trial)
    cam = random_camera(rng)
    t_c_l = random_rigid(rng)
    pts = points_in_front(rng, t_c_l, 500)
    uv, valid = ir.project_points(pts, t_c_l, cam)
    expected = cv2_project(pts, t_c_l, cam)
    assert uv.shape == (500, 2) and uv.dtype == np.float64
    np.testing.assert_allclose(uv, expected, rtol=1e-6, atol=1e-3)
    inside = (
        (expected[:, 0] >= 0)
        & (expected[:, 0] < cam.width)
        & (expected[:, 1] >= 0)
        & (expected[:, 1] < cam.height)
    )
    # Points within 1e-6 px of the image border may fall either way.
    near_edge = np.min(
        np.abs(np.column_stack([expected, expected - [cam.width, cam.height]])), axis=1
    ) < 1e-6
    assert valid.dtype == np.bool_
    np.testing.assert_array_equal(valid[~near_edge], inside[~near_edge])


def test_points_behind_near_and_nonfinite_are_nan_and_invalid() -> None:
    """Behind, at the near limit, or NaN/Inf: uv NaN and valid False; others project."""
    cam = ir.CameraModel(500, 500, 320, 240, 640, 480)
    pts = np.array(
        [
            [0.0, 0.0, 5.0],
            [0.0, 0.0, -5.0],
            [0.0, 0.0, ir.NEAR_LIMIT],
            [np.nan, 0.0, 5.0],
            [0.0, np.inf, 5.0],
            [100.0, 0.0, 1.0],  # in front, outside the image
        ]
    )
    uv, valid = ir.project_points(pts, np.eye(4), cam)
    np.testing.assert_allclose(uv[0], [320.0, 240.0])
    assert np.isnan(uv[1:5]).all()
    np.testing.assert_allclose(uv[5], [320.0 + 500.0 * 100.0, 240.0])
    np.testing.assert_array_equal(valid, [True, False, False, False, False, False])


def test_empty_cloud_gives_empty_arrays() -> None:
    cam = ir.CameraModel(500, 500, 320, 240, 640, 480)
    uv, valid = ir.project_points(np.zeros((0, 3)), np.eye(4), cam)
    assert uv.shape == (0, 2) and valid.shape == (0,)


def test_chain_transforms_is_matrix_product(rng: np.random.Generator) -> None:
    """Reference: numpy matrix product T_c_b @ T_b_l; tolerance 1e-12 absolute."""
    t_c_b, t_b_l = random_rigid(rng), random_rigid(rng)
    np.testing.assert_allclose(ir.chain_transforms(t_c_b, t_b_l), t_c_b @ t_b_l, atol=1e-12)
    pts = points_in_front(rng, t_c_b @ t_b_l, 50)
    cam = ir.CameraModel(600, 600, 320, 240, 640, 480)
    uv_chain, _ = ir.project_points(pts, ir.chain_transforms(t_c_b, t_b_l), cam)
    np.testing.assert_allclose(uv_chain, cv2_project(pts, t_c_b @ t_b_l, cam), rtol=1e-6, atol=1e-3)


@pytest.mark.parametrize(
    ("matrix", "fragment"),
    [
        (np.diag([1.0, 1.0, -1.0, 1.0]), "det"),  # a reflection
        (np.diag([2.0, 1.0, 1.0, 1.0]), "orthonormal"),  # a scale
        (np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1.0]]), "last row"),
        (np.full((4, 4), np.nan), "finite"),
    ],
)
def test_non_rigid_pose_is_rejected(matrix: np.ndarray, fragment: str) -> None:
    cam = ir.CameraModel(500, 500, 320, 240, 640, 480)
    with pytest.raises(ValueError, match=rf"^T_c_l: .*{fragment}"):
        ir.project_points(np.zeros((3, 3)), matrix, cam)
    with pytest.raises(ValueError, match="^T_b_l: "):
        ir.chain_transforms(np.eye(4), matrix)


def test_pose_shape_and_type_errors_name_the_argument() -> None:
    cam = ir.CameraModel(500, 500, 320, 240, 640, 480)
    with pytest.raises(ValueError, match=r"T_c_l: expected shape \(4, 4\), got \(3, 3\)"):
        ir.project_points(np.zeros((3, 3)), np.eye(3), cam)
    with pytest.raises(TypeError, match="T_c_l"):
        ir.project_points(np.zeros((3, 3)), "identity", cam)
    with pytest.raises(TypeError):
        ir.project_points(np.zeros((3, 3)), np.eye(4), "not a camera")  # type: ignore[arg-type]
    # A pose given as nested lists or float32 is fine.
    uv, _ = ir.project_points(np.ones((1, 3)), np.eye(4).astype(np.float32).tolist(), cam)
    np.testing.assert_allclose(uv, [[820.0, 740.0]])


def test_camera_model_attributes_repr_pickle_and_equality() -> None:
    cam = ir.CameraModel(800.0, 820.0, 320.5, 240.25, 640, 480, dist=(0.1, -0.05, 0.001, 0.002, 0.01))
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (800.0, 820.0, 320.5, 240.25, 640, 480)
    assert cam.dist == (0.1, -0.05, 0.001, 0.002, 0.01)
    np.testing.assert_array_equal(cam.camera_matrix(), [[800, 0, 320.5], [0, 820, 240.25], [0, 0, 1]])
    assert eval(repr(cam), {"CameraModel": ir.CameraModel}) == cam
    assert pickle.loads(pickle.dumps(cam)) == cam
    assert cam != ir.CameraModel(800.0, 820.0, 320.5, 240.25, 640, 480)
    assert ir.CameraModel(1, 1, 0, 0, 1, 1).dist == (0.0,) * 5
    with pytest.raises(AttributeError):
        cam.fx = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("kwargs", "exc", "name"),
    [
        ({"fx": 0.0}, ValueError, "fx"),
        ({"fy": -1.0}, ValueError, "fy"),
        ({"cx": float("nan")}, ValueError, "cx"),
        ({"cy": float("inf")}, ValueError, "cy"),
        ({"width": 0}, ValueError, "width"),
        ({"height": -5}, ValueError, "height"),
        ({"width": 2**40}, ValueError, "width"),
        ({"width": 640.0}, TypeError, "width"),
        ({"dist": (0.1, 0.2)}, ValueError, "dist"),
        ({"dist": (0.1, 0.2, 0.0, 0.0, float("nan"))}, ValueError, "dist"),
        ({"dist": "abcde"}, TypeError, "dist"),
        ({"fx": "800"}, TypeError, "fx"),
    ],
)
def test_camera_model_rejects_bad_values(kwargs: dict[str, object], exc: type[Exception], name: str) -> None:
    args: dict[str, object] = {"fx": 800.0, "fy": 800.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480}
    args.update(kwargs)
    with pytest.raises(exc, match=name):
        ir.CameraModel(**args)  # type: ignore[arg-type]
