"""Hypothesis: random and adversarial input to every binding must either return a
well-formed result or raise ValueError/TypeError (LocalizationError for localize) —
never panic, abort, hang or return malformed output."""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import insulator_rs as ir

ACCEPTED = (ValueError, TypeError)
EXAMPLES = settings(max_examples=120)

# Coordinates that stress the maths: NaN, +-Inf, huge, tiny, signed zeros, repeats.
floats = st.floats(allow_nan=True, allow_infinity=True, width=64) | st.sampled_from(
    [0.0, -0.0, 1.0, 1e-300, 1e300, 1.7e308, -1.7e308, 5e-324]
)
floats32 = st.floats(allow_nan=True, allow_infinity=True, width=32) | st.sampled_from(
    [0.0, -0.0, 1.0, 1e-38, 3.4e38, -3.4e38, 1e-45]
)
moderate = st.floats(-50.0, 50.0, allow_nan=False)


@st.composite
def clouds(draw: st.DrawFn) -> Any:
    """Mostly (N,3) float32/float64 arrays (some strided, some wild values), sometimes
    wrong dtypes, shapes or non-arrays."""
    kind = draw(st.integers(0, 9))
    if kind == 0:
        return draw(st.sampled_from([None, 3.0, "points", [[1.0, 2.0, 3.0]], object()]))
    if kind == 1:
        dtype = draw(st.sampled_from([np.int32, np.int64, np.float16, np.bool_, np.complex64, np.uint8]))
        shape = draw(hnp.array_shapes(min_dims=1, max_dims=3, max_side=6))
        return np.zeros(shape, dtype=dtype)
    if kind == 2:
        shape = draw(hnp.array_shapes(min_dims=0, max_dims=3, max_side=6).filter(lambda s: len(s) != 2 or s[1] != 3))
        return np.zeros(shape)
    dtype = draw(st.sampled_from([np.float32, np.float64]))
    n = draw(st.integers(0, 40))
    if kind < 5:
        elements = floats if dtype == np.float64 else floats32
    else:
        elements = moderate if dtype == np.float64 else st.floats(-50.0, 50.0, width=32)
    base = draw(hnp.arrays(dtype, (n * 2 + 1, 5), elements=elements))
    if draw(st.booleans()):  # duplicate rows: DBSCAN/RANSAC degenerate cases
        base[1::2] = base[0]
    step = draw(st.sampled_from([1, 2, -1, -2]))
    start = draw(st.integers(0, 2))
    return base[::step][:n, start : start + 3]


@st.composite
def poses(draw: st.DrawFn) -> Any:
    kind = draw(st.integers(0, 4))
    if kind == 0:
        return draw(hnp.arrays(np.float64, (4, 4), elements=floats))
    if kind == 1:
        return draw(st.sampled_from([np.eye(3), np.zeros(16), "eye", None, np.eye(4, dtype=np.int64), [[1.0] * 4] * 4]))
    q = np.array(draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4))) + [1e-3, 0, 0, 0]
    w, x, y, z = q / np.linalg.norm(q)
    t = np.eye(4)
    t[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    t[:3, 3] = draw(st.lists(moderate, min_size=3, max_size=3))
    if kind == 2:  # perturb: almost rigid
        t[draw(st.integers(0, 3)), draw(st.integers(0, 3))] += draw(st.floats(-1e-3, 1e-3))
    return t


@st.composite
def cameras(draw: st.DrawFn) -> ir.CameraModel:
    while True:
        try:
            return ir.CameraModel(
                draw(st.floats(1e-3, 1e6)),
                draw(st.floats(1e-3, 1e6)),
                draw(st.floats(-1e4, 1e4)),
                draw(st.floats(-1e4, 1e4)),
                draw(st.integers(1, 5000)),
                draw(st.integers(1, 5000)),
                dist=tuple(draw(st.floats(-1e3, 1e3)) for _ in range(5)),  # type: ignore[arg-type]
            )
        except ValueError:  # pragma: no cover - the ranges above are valid
            continue


boxes = st.one_of(
    hnp.arrays(np.float64, st.tuples(st.integers(0, 4), st.sampled_from([4, 5])), elements=floats),
    hnp.arrays(np.float64, st.tuples(st.integers(0, 4), st.sampled_from([4, 5])), elements=st.floats(-100, 6000)),
    st.sampled_from([[], [1, 2, 3, 4], [[1, 2, 3]], "boxes", None, np.zeros((2, 4), dtype=np.int8)]),
)
counts = st.integers(-5, 50) | st.sampled_from([0, 2**63, 2**64, -(2**70), 10**40]) | st.sampled_from([1.5, "5", None])
eps_values = floats | st.floats(1e-3, 5.0)


def is_cloud(x: Any) -> bool:
    return isinstance(x, np.ndarray) and x.dtype in (np.float32, np.float64) and x.ndim == 2 and x.shape[1] == 3


@EXAMPLES
@given(points=clouds(), pose=poses(), cam=cameras())
def test_project_points_never_crashes(points: Any, pose: Any, cam: ir.CameraModel) -> None:
    try:
        uv, valid = ir.project_points(points, pose, cam)
    except ACCEPTED:
        return
    assert is_cloud(points)
    assert uv.shape == (len(points), 2) and valid.shape == (len(points),)
    assert np.all(np.isfinite(uv[valid]))
    assert np.all((uv[valid, 0] >= 0) & (uv[valid, 0] < cam.width))


@EXAMPLES
@given(points=clouds(), pose=poses(), cam=cameras(), box_array=boxes)
def test_points_in_boxes_never_crashes(points: Any, pose: Any, cam: ir.CameraModel, box_array: Any) -> None:
    try:
        lists = ir.points_in_boxes(points, pose, cam, box_array)
    except ACCEPTED:
        return
    assert is_cloud(points)
    for idx in lists:
        assert idx.dtype == np.int64
        assert np.all(np.diff(idx) > 0) and np.all((idx >= 0) & (idx < len(points)))


@EXAMPLES
@given(points=clouds(), eps=eps_values, min_points=counts)
def test_dbscan_never_crashes(points: Any, eps: Any, min_points: Any) -> None:
    try:
        labels = ir.dbscan(points, eps, min_points)
    except ACCEPTED:
        return
    assert is_cloud(points)
    assert labels.shape == (len(points),) and labels.dtype == np.int32
    assert labels.min(initial=-1) >= -1
    nonfinite = ~np.all(np.isfinite(points), axis=1)
    assert np.all(labels[nonfinite] == -1)


@EXAMPLES
@given(points=clouds(), threshold=eps_values, iters=counts, confidence=floats, seed=counts)
def test_ransac_line_never_crashes(points: Any, threshold: Any, iters: Any, confidence: Any, seed: Any) -> None:
    try:
        fit = ir.ransac_line(points, threshold, max_iterations=iters, confidence=confidence, seed=seed)
    except ACCEPTED:
        return
    assert is_cloud(points)
    assert np.all(np.isfinite(fit.direction)) and abs(np.linalg.norm(fit.direction) - 1.0) < 1e-9
    assert len(fit.inliers) >= 1 and np.all(fit.inliers < len(points))


@EXAMPLES
@given(points=clouds())
def test_pca_never_crashes(points: Any) -> None:
    try:
        result = ir.pca(points)
    except ACCEPTED:
        return
    assert is_cloud(points)
    assert result.n_points >= 2
    assert result.eigenvectors.shape == (3, 3) and result.eigenvalues.shape == (3,)


@EXAMPLES
@given(
    points=clouds(),
    method=st.sampled_from(["dbscan", "ransac", "dbscan+ransac", "dbscan+pca", "", "DBSCAN", 3]),
    eps=eps_values,
    min_points=counts,
    tau=eps_values,
    seed=counts,
)
def test_localize_never_crashes(points: Any, method: Any, eps: Any, min_points: Any, tau: Any, seed: Any) -> None:
    try:
        est = ir.localize(points, method, eps=eps, min_points=min_points, tau=tau, seed=seed)
    except (*ACCEPTED, ir.LocalizationError):
        return
    assert is_cloud(points)
    assert np.all(np.isfinite(est.center)) and abs(np.linalg.norm(est.direction) - 1.0) < 1e-9
    assert est.n_points >= 1 and est.n_nonfinite <= len(points)


@EXAMPLES
@given(a=poses(), b=poses())
def test_chain_transforms_never_crashes(a: Any, b: Any) -> None:
    try:
        m = ir.chain_transforms(a, b)
    except ACCEPTED:
        return
    assert m.shape == (4, 4) and np.all(np.isfinite(m))
    np.testing.assert_allclose(m[3], [0, 0, 0, 1], atol=1e-9)


@settings(max_examples=200)
@given(
    fx=floats | st.sampled_from(["1", None]),
    fy=floats,
    cx=floats,
    cy=floats,
    width=counts,
    height=counts,
    dist=st.lists(floats, min_size=0, max_size=7) | st.sampled_from([None, "abcde", 5]),
)
def test_camera_model_never_crashes(fx: Any, fy: Any, cx: Any, cy: Any, width: Any, height: Any, dist: Any) -> None:
    try:
        cam = ir.CameraModel(fx, fy, cx, cy, width, height, dist=dist)
    except ACCEPTED:
        return
    assert cam.fx > 0 and cam.fy > 0 and cam.width >= 1 and cam.height >= 1
    assert all(np.isfinite(cam.dist)) and np.isfinite(cam.cx) and np.isfinite(cam.cy)
