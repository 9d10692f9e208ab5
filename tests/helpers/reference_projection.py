"""Random cameras and rigid poses, and OpenCV's projection of points through them: the
reference the core's projection and culling are checked against (``cv2.projectPoints``)."""

from __future__ import annotations

import cv2
import numpy as np

import insulator_rs as ir


def random_rigid(rng: np.random.Generator, max_translation: float = 2.0) -> np.ndarray:
    """A random proper rigid 4x4 transform (float64)."""
    rotation, _ = cv2.Rodrigues(rng.uniform(-np.pi, np.pi, size=3) / np.sqrt(3))
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = rng.uniform(-max_translation, max_translation, size=3)
    return t


def random_camera(rng: np.random.Generator) -> ir.CameraModel:
    """Random plausible intrinsics and OpenCV distortion."""
    width, height = int(rng.integers(320, 2000)), int(rng.integers(240, 1500))
    return ir.CameraModel(
        rng.uniform(300, 2000),
        rng.uniform(300, 2000),
        rng.uniform(0.3, 0.7) * width,
        rng.uniform(0.3, 0.7) * height,
        width,
        height,
        dist=(
            rng.uniform(-0.4, 0.4),
            rng.uniform(-0.2, 0.2),
            rng.uniform(-0.01, 0.01),
            rng.uniform(-0.01, 0.01),
            rng.uniform(-0.1, 0.1),
        ),
    )


def cv2_project(points_l: np.ndarray, t_c_l: np.ndarray, cam: ir.CameraModel) -> np.ndarray:
    """(N,2) pixels from cv2.projectPoints (no visibility test)."""
    rvec, _ = cv2.Rodrigues(t_c_l[:3, :3])
    uv, _ = cv2.projectPoints(
        np.asarray(points_l, dtype=np.float64).reshape(-1, 1, 3),
        rvec,
        t_c_l[:3, 3].copy(),
        cam.camera_matrix(),
        np.asarray(cam.dist, dtype=np.float64),
    )
    return uv.reshape(-1, 2)
