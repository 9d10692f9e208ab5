"""``ir.deskew`` / ``ir.deskew_points_in_boxes`` against an independent numpy/scipy reference.

Reference: scipy's ``Slerp`` of the pose stream's rotations and ``np.interp`` of its
translations give T_w_b(t) for every point; each point is chained
``T_b_l^-1 T_w_b(t_ref)^-1 T_w_b(t_i) T_b_l p``. Tolerance 1e-9 m (f64 rounding over
clouds of tens of metres). The fused culling must equal ``ir.points_in_boxes`` on the
deskewed cloud exactly (same projection arithmetic).
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

import insulator_rs as ir

TOL = 1e-9


def pose(t, rotvec):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def stream(k=6, span=0.1, seed=0):
    rng = np.random.default_rng(seed)
    times = np.linspace(0.0, span, k)
    poses = np.stack([pose([3.0 * t, -1 + 0.5 * t, 10 + t], rng.normal(scale=0.3, size=3) + [0, 0, 1 + 5 * t])
                      for t in times])
    return times, poses


def reference(points, times, pose_times, poses, t_ref, T_b_l):
    slerp = Slerp(pose_times, Rotation.from_matrix(poses[:, :3, :3]))

    def T_at(t):
        R = slerp(t).as_matrix()
        p = np.stack([np.interp(t, pose_times, poses[:, j, 3]) for j in range(3)], axis=1)
        T = np.zeros((len(t), 4, 4))
        T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1
        return T

    M = np.linalg.inv(T_at(np.array([t_ref]))[0] @ T_b_l)
    A = M @ T_at(times) @ T_b_l
    return np.einsum("nij,nj->ni", A[:, :3, :3], points) + A[:, :3, 3]


def cloud(n, seed=1):
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(2, 20, n), rng.uniform(-8, 8, n), rng.uniform(-5, 5, n)])
    t = np.clip(np.linspace(0, 0.1, n) + rng.uniform(-0.003, 0.003, n), 0, 0.1)
    return pts, t


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("n", [500, 20_000])
def test_deskew_matches_scipy_reference(dtype, n):
    pose_times, poses = stream()
    pts, t = cloud(n)
    pts = pts.astype(dtype)
    T_b_l = pose([0.1, 0.0, -0.1], [0.0, 0.1, 0.0])
    got = ir.deskew(pts, t, pose_times, poses, 0.1, T_b_l)
    want = reference(pts.astype(np.float64), t, pose_times, poses, 0.1, T_b_l)
    assert got.shape == (n, 3) and got.dtype == np.float64
    assert np.max(np.abs(got - want)) < TOL


def test_fused_culling_equals_points_in_boxes_on_the_deskewed_cloud():
    pose_times, poses = stream()
    pts, t = cloud(20_000)
    T_b_l = pose([0.1, 0.0, -0.1], [0.0, 0.1, 0.0])
    cam = ir.CameraModel(900, 910, 640, 480, 1280, 960, dist=[-0.2, 0.05, 1e-3, -1e-3, 0.01])
    T_c_l = np.eye(4)
    T_c_l[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]  # camera looks along L's +x
    boxes = np.array([[100, 100, 700, 500], [600, 400, 1300, 1000], [-50, -50, 30, 30.0]])
    deskewed, idx = ir.deskew_points_in_boxes(pts, t, pose_times, poses, 0.05, T_b_l, T_c_l, cam, boxes)
    assert np.array_equal(deskewed, ir.deskew(pts, t, pose_times, poses, 0.05, T_b_l))
    expected = ir.points_in_boxes(deskewed, T_c_l, cam, boxes)
    assert all(len(i) > 0 for i in idx[:2])
    for a, b in zip(idx, expected):
        assert np.array_equal(a, b)


def test_motion_distortion_is_removed():
    """A wall 10 m ahead scanned while flying towards it at 10 m/s: raw points spread over
    1 m of range; deskewed to the scan's end they all sit at the wall's distance then."""
    pose_times = np.array([0.0, 0.1])
    poses = np.stack([pose([0, 0, 0], [0, 0, 0]), pose([1.0, 0, 0], [0, 0, 0])])
    t = np.linspace(0, 0.1, 101)
    pts = np.column_stack([10.0 - 10.0 * t, np.zeros_like(t), np.zeros_like(t)])  # the wall at x=10 in W
    out = ir.deskew(pts, t, pose_times, poses, 0.1, np.eye(4))
    assert np.ptp(pts[:, 0]) == pytest.approx(1.0)
    assert np.allclose(out[:, 0], 9.0, atol=1e-12)


def test_bad_arguments_are_named():
    pose_times, poses = stream()
    pts, t = cloud(10)
    I4 = np.eye(4)
    with pytest.raises(ValueError, match="times"):
        ir.deskew(pts, t + 1.0, pose_times, poses, 0.05, I4)  # outside the pose stream
    with pytest.raises(ValueError, match="times"):
        ir.deskew(pts, t[:5], pose_times, poses, 0.05, I4)
    with pytest.raises(ValueError, match="t_ref"):
        ir.deskew(pts, t, pose_times, poses, 5.0, I4)
    with pytest.raises(ValueError, match="pose_times"):
        ir.deskew(pts, t, pose_times[::-1], poses, 0.05, I4)
    with pytest.raises(ValueError, match="poses"):
        ir.deskew(pts, t, pose_times, poses[:, :3], 0.05, I4)
    bad = poses.copy()
    bad[2, 0, 0] = 5.0
    with pytest.raises(ValueError, match=r"poses\[2\]"):
        ir.deskew(pts, t, pose_times, bad, 0.05, I4)
    with pytest.raises(ValueError, match="T_b_l"):
        ir.deskew(pts, t, pose_times, poses, 0.05, np.eye(3))
    cam = ir.CameraModel(100, 100, 50, 50, 100, 100)
    with pytest.raises(ValueError, match="boxes"):
        ir.deskew_points_in_boxes(pts, t, pose_times, poses, 0.05, I4, I4, cam, np.array([[5, 5, 1, 1.0]]))
