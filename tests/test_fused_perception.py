"""The flight's deskew + cull is the fused kernel, and it gives what the two-step path gave.

``PerceptionPipeline.process`` deskews and culls each paired scan in one pass,
``ir.deskew_points_in_boxes`` (culling in L through ``T_c_l = T_c_w @ T_w_l``).

Reference: the two-step path the flight ran before, ``ir.deskew`` of each scan to W
(``paired_points_w``) then ``ir.points_in_boxes`` of the whole paired cloud in W through ``T_c_w``.
Tolerances: the deskewed points are bit-identical (the fused kernel's deskew is ``ir.deskew``'s,
and both go to W by the same numpy product); the index lists are equal except for a point
within :data:`EDGE_PX` of a box edge or of the camera's near limit, where projecting from L
instead of W may round to the other side (both chains are exact to ~1e-12 px at these ranges).
The localizations of a whole run of frames are then the same to the bit.
"""

import numpy as np
import pytest

import insulator_rs as ir
from insulator_rs.perception.pipeline import PerceptionPipeline
from insulator_rs.poses import pose_from_yaw
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped
from insulator_rs.synthetic import tower_cloud

CAM = ir.CameraModel(600.0, 600.0, 319.5, 239.5, 640, 480, dist=(-0.1, 0.02, 1e-4, -2e-4, 0.0))
T_B_C = np.array([[0.0, 0.0, 1.0, 0.05], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, -0.05], [0, 0, 0, 1.0]])
# the Mid-360 tilted and offset on the body, as mounted (not the identity: the chains must differ)
T_B_L = np.array([[0.0, 0.0, 1.0, 0.1], [0.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, -0.08], [0, 0, 0, 1.0]])
EDGE_PX = 1e-6
SCAN_S = 0.1  # one Mid-360 frame
POINTS_PER_SCAN = 20_000  # 200,000 points/s


class TwoStepPipeline(PerceptionPipeline):
    """The reference: deskew to W (``ir.deskew``), then ``ir.points_in_boxes`` in W."""

    def paired_points_in_boxes_w(self, time, T_c_w, camera, boxes):
        points_w = self.paired_points_w(time)
        return points_w, ir.points_in_boxes(points_w, T_c_w, camera, boxes)


def body_pose(t: float) -> np.ndarray:
    """Flying past the tower at 3 m/s and turning at up to 0.6 rad/s, pitching a little."""
    T = pose_from_yaw([-14.0 + 0.5 * t, -20.0 + 3.0 * t, 25.0 + 0.3 * t], 1.2 + 0.3 * np.sin(2.0 * t))
    c, s = np.cos(0.08 * np.sin(3.0 * t)), np.sin(0.08 * np.sin(3.0 * t))
    T[:3, :3] = T[:3, :3] @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return T


def scans_of(cloud_w: np.ndarray, t0: float, n_scans: int, rng, n_points: int = POINTS_PER_SCAN) -> list[LidarScan]:
    """Scans of 100 ms, each point of ``cloud_w`` seen from the body pose of its own time
    (times on a 0.1 ms raster, so the poses are computed once a raster step)."""
    out = []
    for k in range(n_scans):
        raster = t0 + k * SCAN_S + np.arange(1000) * SCAN_S / 1000
        T_l_w = np.array([np.linalg.inv(body_pose(t) @ T_B_L) for t in raster])
        step = np.sort(rng.integers(0, len(raster), n_points))
        pts_w = cloud_w[rng.choice(len(cloud_w), n_points, replace=n_points > len(cloud_w))]
        pts_l = np.einsum("nij,nj->ni", T_l_w[step, :3, :3], pts_w) + T_l_w[step, :3, 3]
        out.append(LidarScan(pts_l.astype(np.float32), raster[step], T_B_L))
    return out


def boxes_at(pipeline: PerceptionPipeline, time: float, rng, k: int = 3) -> np.ndarray:
    """``k`` boxes (with scores) around points the camera sees at ``time``."""
    T_c_w = np.linalg.inv(pipeline.poses.pose_at(time) @ T_B_C)
    uv, valid = ir.project_points(pipeline.paired_points_w(time), T_c_w, CAM)
    centres = uv[valid][rng.choice(int(valid.sum()), k, replace=False)]
    half = rng.uniform(15, 60, (k, 2))
    return np.column_stack([centres - half, centres + half, rng.uniform(0.5, 0.9, k)])


def fed(cls, scans, t_end):
    pipeline = cls(CAM, T_B_C, T_B_L, insulator_length=None)
    for t in np.arange(0.0, t_end + 1e-9, 0.05):  # poses at 20 Hz, as the flight loop feeds them
        pipeline.add_pose(PoseStamped(float(t), body_pose(t)))
    for scan in scans:
        pipeline.add_scan(scan)
    return pipeline


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(4)
    cloud_w = tower_cloud(60_000, seed=4)
    scans = scans_of(cloud_w, 0.0, 12, rng)
    return scans, rng


def _edge_distance_px(points_w, T_c_w, box):
    """Pixel distance of each point's projection to the nearest edge of ``box``."""
    uv, _ = ir.project_points(points_w, T_c_w, CAM)
    x1, y1, x2, y2 = box[:4]
    return np.min(np.abs(np.column_stack([uv[:, 0] - x1, uv[:, 0] - x2, uv[:, 1] - y1, uv[:, 1] - y2])), axis=1)


def test_fused_pass_gives_the_two_step_points_and_lists(scene):
    scans, rng = scene
    fused, two_step = fed(PerceptionPipeline, scans, 1.25), fed(TwoStepPipeline, scans, 1.25)
    n_inside = 0
    for time in (0.15, 0.42, 0.6, 0.87, 1.1):
        boxes = boxes_at(fused, time, rng)
        T_c_w = np.linalg.inv(fused.poses.pose_at(time) @ T_B_C)
        points, lists = fused.paired_points_in_boxes_w(time, T_c_w, CAM, boxes)
        ref_points, ref_lists = two_step.paired_points_in_boxes_w(time, T_c_w, CAM, boxes)
        assert len(points) > POINTS_PER_SCAN and np.array_equal(points, ref_points)
        assert len(lists) == len(ref_lists) == len(boxes)
        for box, got, want in zip(boxes, lists, ref_lists, strict=True):
            assert got.dtype == np.int64 and np.all(np.diff(got) > 0)
            differ = np.setxor1d(got, want)
            assert np.all(_edge_distance_px(points[differ], T_c_w, box) < EDGE_PX), differ
            n_inside += len(want)
    assert n_inside > 1000  # the boxes hold points: the comparison is not of empty lists


def test_the_flight_runs_the_fused_kernel(scene, monkeypatch):
    """``process`` calls ``ir.deskew_points_in_boxes`` (once a paired scan) and never the
    two-step ``ir.points_in_boxes``."""
    scans, rng = scene
    pipeline = fed(PerceptionPipeline, scans, 1.25)
    boxes = boxes_at(pipeline, 0.6, rng)
    calls = {"fused": 0}
    fused = ir.deskew_points_in_boxes

    def counting(*args):
        calls["fused"] += 1
        return fused(*args)

    def refused(*_args):
        raise AssertionError("the flight culled in a second pass")

    monkeypatch.setattr(ir, "deskew_points_in_boxes", counting)
    monkeypatch.setattr(ir, "points_in_boxes", refused)
    pipeline.process(frame_at(0.6), boxes)
    assert calls["fused"] == len(pipeline._paired_scans(0.6)) >= 2


def scans_with_string(seed: int) -> tuple[list[LidarScan], np.ndarray]:
    """12 scans of the tower with a 2 m string 8 m ahead of the camera mid-run (300 returns a
    scan on it), and the string's points in W."""
    rng = np.random.default_rng(seed)
    ahead = (body_pose(0.6) @ [8.0, 0.0, 0.0, 1.0])[:3]
    string_w = ahead + rng.uniform(-1, 1, (400, 1)) * [0.0, 0.0, 1.0] + rng.normal(0, 0.03, (400, 3))
    tower = scans_of(tower_cloud(60_000, seed=seed), 0.0, 12, rng)
    on_string = scans_of(string_w, 0.0, 12, rng, n_points=300)
    return [LidarScan(np.vstack([a.points_l, b.points_l]), np.concatenate([a.times, b.times]), T_B_L)
            for a, b in zip(tower, on_string)], string_w


def string_box(pipeline: PerceptionPipeline, string_w: np.ndarray, time: float) -> np.ndarray:
    """The detector's box of the string at ``time`` (4 px margin, score 0.8)."""
    T_c_w = np.linalg.inv(pipeline.poses.pose_at(time) @ T_B_C)
    uv, valid = ir.project_points(string_w, T_c_w, CAM)
    return np.array([[*(uv[valid].min(axis=0) - 4), *(uv[valid].max(axis=0) + 4), 0.8]])


def frame_at(time: float) -> CameraFrame:
    return CameraFrame(float(time), np.zeros((CAM.height, CAM.width, 3), np.uint8), CAM, T_B_C)


def test_a_run_of_frames_localizes_the_same():
    """Whole ``process`` calls, frame after frame, on the box of a string among the tower's
    returns: the fused pipeline's localizations, counters and tracks equal the two-step one's."""
    scans, string_w = scans_with_string(9)
    results = []
    for cls in (PerceptionPipeline, TwoStepPipeline):
        pipeline = fed(cls, scans, 1.25)
        outs = []
        for time in np.arange(0.2, 1.15, 0.1):
            outs += pipeline.process(frame_at(time), string_box(pipeline, string_w, time))
        results.append((outs, pipeline.counters, len(pipeline.tracks)))
    (fused_out, fused_counters, fused_tracks), (ref_out, ref_counters, ref_tracks) = results
    assert len(ref_out) > 0 and fused_counters == ref_counters and fused_tracks == ref_tracks
    for a, b in zip(fused_out, ref_out, strict=True):
        assert np.array_equal(a.center, b.center) and np.array_equal(a.axis, b.axis) and a.n_points == b.n_points
