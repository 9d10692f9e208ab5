"""localize_bounded (the fifth method, ``ir.localize(..., "bounded", ...)``: LiDAR line, camera-bounded ends) against a numpy/OpenCV
reference, its accuracy on partly seen strings, and its error contract.

Reference: for the line the core returns (its centre and direction), the part of the line whose
projection through ``cv2.projectPoints`` (same K and distortion) falls inside the box, found by
sampling the line every 0.5 mm; its middle must be the core's centre within 2 mm (sampling plus
the core's 1e-6 m bisection), and its length the core's ``length`` within 2 mm.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import insulator_rs as ir
from insulator_rs.synthetic import insulator_cloud

# The simulator's default camera (1280x960, fx = fy = 700, mild barrel distortion), facing B's x.
CAM = ir.CameraModel(700.0, 700.0, 639.5, 479.5, 1280, 960, dist=(-0.12, 0.03, 0.0, 0.0, 0.0))
T_B_C = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def cv_project(points_b: np.ndarray, T_b_c: np.ndarray) -> np.ndarray:
    """Pixels of B-frame points through OpenCV (the independent projection)."""
    T_c_b = np.linalg.inv(T_b_c)
    rvec, _ = cv2.Rodrigues(T_c_b[:3, :3])
    uv, _ = cv2.projectPoints(points_b.reshape(-1, 1, 3), rvec, T_c_b[:3, 3], CAM.camera_matrix(),
                              np.array(CAM.dist))
    return uv.reshape(-1, 2)


def truth_box(center: np.ndarray, axis: np.ndarray, length: float, T_b_c: np.ndarray,
              radius: float = 0.12) -> np.ndarray:
    """The box (x1, y1, x2, y2) of the string: its axis segment (4001 OpenCV samples) and the rims
    of its end sheds (``radius``), padded by a hair so the half-open box holds them."""
    s = np.linspace(-0.5, 0.5, 4001)[:, None] * length
    e1 = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    a = np.linspace(0.0, 2 * np.pi, 64)[:, None]
    ring = radius * (np.cos(a) * e1 + np.sin(a) * e2)
    rims = np.vstack([center + 0.5 * length * axis + ring, center - 0.5 * length * axis + ring])
    uv = cv_project(np.vstack([center + s * axis, rims]), T_b_c)
    return np.array([uv[:, 0].min() - 1e-6, uv[:, 1].min() - 1e-6, uv[:, 0].max() + 1e-6, uv[:, 1].max() + 1e-6])


def reference_extent(center: np.ndarray, direction: np.ndarray, box: np.ndarray,
                     T_b_c: np.ndarray) -> tuple[float, float]:
    """(lo, hi) of the line parameter (m from ``center``) whose projection lies in the box."""
    t = np.arange(-4.0, 4.0, 0.0005)
    uv = cv_project(center + t[:, None] * direction, T_b_c)
    inside = (uv[:, 0] >= box[0]) & (uv[:, 0] < box[2]) & (uv[:, 1] >= box[1]) & (uv[:, 1] < box[3])
    assert inside.any(), "the line misses the box"
    return float(t[inside].min()), float(t[inside].max())


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("orientation", ["horizontal", "vertical"])
def test_matches_the_opencv_reference(seed: int, orientation: str) -> None:
    cloud = insulator_cloud(seed=seed, distance=9.0, azimuth=0.15 * (seed - 3) / 3,
                            orientation=orientation, length=2.0, radius=0.12)
    box = truth_box(cloud.center, cloud.axis, cloud.length, T_B_C)
    est = ir.localize_bounded(cloud.points, box[None], T_B_C, CAM)
    assert est.ends_from_image == 2 and est.views_used == 1
    lo, hi = reference_extent(est.center, est.direction, box, T_B_C)
    assert abs(0.5 * (lo + hi)) < 2e-3, (lo, hi)
    assert est.length is not None and abs(est.length - (hi - lo)) < 2e-3


def test_partly_seen_string_centre_comes_from_the_image() -> None:
    """Only the tower half of the string returned points: Algorithm 1's centre sits a quarter of the
    string off along the axis; the bounded one within 3 cm along it (the rest of its error is the
    fitted line lying on the visible surface, up to a shed radius off the axis: under 0.1 m)."""
    errs_alg1, errs_bounded = [], []
    for seed in range(8):
        cloud = insulator_cloud(seed=seed, distance=9.0, length=2.2, radius=0.12, conductor=False,
                                n_stray=0, n_insulator=200)
        t = (cloud.points - cloud.center) @ cloud.axis
        seen = cloud.points[(t < 0.0) | (cloud.source != 0)]
        box = truth_box(cloud.center, cloud.axis, cloud.length, T_B_C)
        a1 = ir.localize(seen, "dbscan+ransac")
        b = ir.localize_bounded(seen, box[None], T_B_C, CAM)
        errs_alg1.append(abs(float((a1.center - cloud.center) @ cloud.axis)))
        errs_bounded.append(abs(float((b.center - cloud.center) @ cloud.axis)))
        assert cloud.errors(b.center, b.direction)[0] < 0.1
    assert np.mean(errs_alg1) > 0.3
    assert max(errs_bounded) < 0.03, errs_bounded


def test_several_views_and_the_known_length() -> None:
    """Three events (the camera moved 0.4 m between them) give three boxes; a box clipped by the
    frame bounds one end only, and the known length places the centre."""
    cloud = insulator_cloud(seed=3, distance=9.0, length=2.0, radius=0.12)
    poses = []
    for dy in (-0.4, 0.0, 0.4):
        T = T_B_C.copy()
        T[1, 3] = dy
        poses.append(T)
    boxes = np.array([truth_box(cloud.center, cloud.axis, cloud.length, T) for T in poses])
    est = ir.localize_bounded(cloud.points, boxes, np.array(poses), CAM)
    assert est.views_used == 3 and est.ends_from_image == 2
    assert abs(float((est.center - cloud.center) @ cloud.axis)) < 0.03
    assert cloud.errors(est.center, est.direction)[0] < 0.1
    clipped = boxes[1].copy()
    clipped[2] = CAM.width  # the right edge on the frame's border: no bound there
    one = ir.localize_bounded(cloud.points, clipped[None], poses[1], CAM)
    assert one.ends_from_image == 1 and one.length is None
    with_length = ir.localize_bounded(cloud.points, clipped[None], poses[1], CAM, insulator_length=2.0)
    # The box spans the end sheds' rims too (0.12 m each side at most): within 0.15 m along the axis.
    assert abs(float((with_length.center - cloud.center) @ cloud.axis)) < 0.15


def test_bad_input_names_the_argument() -> None:
    cloud = insulator_cloud(seed=0)
    box = truth_box(cloud.center, cloud.axis, cloud.length, T_B_C)
    with pytest.raises(ValueError, match="boxes: need at least one"):
        ir.localize_bounded(cloud.points, np.zeros((0, 4)), np.zeros((0, 4, 4)), CAM)
    with pytest.raises(ValueError, match="T_b_c: 2 poses for 1 boxes"):
        ir.localize_bounded(cloud.points, box[None], np.stack([T_B_C, T_B_C]), CAM)
    with pytest.raises(ValueError, match="T_b_c: expected shape"):
        ir.localize_bounded(cloud.points, box[None], np.eye(3), CAM)
    with pytest.raises(ValueError, match="boxes: row 0"):
        ir.localize_bounded(cloud.points, np.array([[5.0, 5.0, 1.0, 1.0]]), T_B_C, CAM)
    with pytest.raises(ValueError, match="insulator_length"):
        ir.localize_bounded(cloud.points, box[None], T_B_C, CAM, insulator_length=-1.0)
    with pytest.raises(ValueError, match="max_extent"):
        ir.localize_bounded(cloud.points, box[None], T_B_C, CAM, max_extent=0.0)
    bent = T_B_C.copy()
    bent[0, 0] = 2.0
    with pytest.raises(ValueError, match="T_b_c"):
        ir.localize_bounded(cloud.points, box[None], bent, CAM)
    with pytest.raises(ir.LocalizationError):
        ir.localize_bounded(np.zeros((0, 3)), box[None], T_B_C, CAM)
    est = ir.localize_bounded(cloud.points, box[None], T_B_C, CAM)
    # the one result class of every method, with the bounded method's image fields in its repr
    assert isinstance(est, ir.Localization) and est.method == "bounded"
    assert repr(est).startswith('Localization(method="bounded", center=[') and "views_used=1" in repr(est)
