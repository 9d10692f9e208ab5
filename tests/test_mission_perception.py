"""Onboard perception: box culling, accumulation of three events, association, localization."""

import numpy as np

import insulator_rs as ir
from insulator_rs.perception.localization_method import DEFAULT_METHOD, LocalizationMethod
from insulator_rs.perception.pipeline import EVENTS_PER_LOCALIZATION, PerceptionPipeline

CAM = ir.CameraModel(300.0, 300.0, 159.5, 119.5, 320, 240)
T_B_C = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0, 0, 0, 1.0]])
T_B_L = np.eye(4)


def insulator(center, axis, n, rng):
    t = rng.uniform(-1.0, 1.0, n)[:, None]
    return center + t * axis + rng.normal(0, 0.02, (n, 3))


def string_of_sheds(center, axis, n, rng):
    """Returns from a string of sheds: along the axis, at a random radius between the core's
    (0.025 m) and the sheds' (0.12 m), all round it, with 2 cm noise (a string's shape, which the
    false-find filter checks)."""
    t = rng.uniform(-1.0, 1.0, n)[:, None]
    u = axis / np.linalg.norm(axis)
    e1 = np.cross(u, [0.0, 0.0, 1.0] if abs(u[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    a = rng.uniform(0.0, 2 * np.pi, n)[:, None]
    r = rng.uniform(0.025, 0.12, n)[:, None]
    return center + t * axis + r * (np.cos(a) * e1 + np.sin(a) * e2) + rng.normal(0, 0.02, (n, 3))


def box_of(points_w, T_w_b):
    T_c_w = np.linalg.inv(T_w_b @ T_B_C)
    uv, valid = ir.project_points(points_w, T_c_w, CAM)
    uv = uv[valid]
    return np.array([[uv[:, 0].min() - 3, uv[:, 1].min() - 3, uv[:, 0].max() + 3, uv[:, 1].max() + 3]])


def test_three_events_localize_the_insulator_in_front_of_the_lattice():
    """Reference: the true centre of the synthetic insulator; tolerance 0.15 m (2 cm noise,
    background 4 m behind it inside the same box)."""
    rng = np.random.default_rng(0)
    center, axis = np.array([8.0, 0.0, 10.0]), np.array([0.0, 1.0, 0.0])
    per = PerceptionPipeline(CAM, T_B_C, T_B_L)
    out = []
    for k in range(EVENTS_PER_LOCALIZATION):
        T_w_b = np.eye(4)
        T_w_b[:3, 3] = [0.0, 0.3 * k, 10.0]  # the vehicle moves between events
        ins = insulator(center, axis, 40, rng)
        wall = np.column_stack([np.full(300, 12.0), rng.uniform(-1.5, 1.5, 300), rng.uniform(9.5, 10.5, 300)])
        pts_w = np.vstack([ins, wall])
        pts_l = (pts_w - T_w_b[:3, 3]) @ T_w_b[:3, :3]  # L = B here
        out = per.event(box_of(ins, T_w_b), pts_l, T_w_b)
        if k < EVENTS_PER_LOCALIZATION - 1:
            assert out == []
    assert len(out) == 1 and len(per.tracks) == 1
    assert np.linalg.norm(out[0].center - center) < 0.15
    assert abs(out[0].axis @ axis) > 0.99


def test_separate_insulators_get_separate_tracks():
    rng = np.random.default_rng(1)
    per = PerceptionPipeline(CAM, T_B_C, T_B_L)
    T_w_b = np.eye(4)
    a = insulator(np.array([8.0, -1.5, 0.0]), np.array([0.0, 0.0, 0.5]), 40, rng)
    b = insulator(np.array([8.0, 1.5, 0.0]), np.array([0.0, 0.0, 0.5]), 40, rng)
    boxes = np.vstack([box_of(a, T_w_b), box_of(b, T_w_b)])
    for _ in range(EVENTS_PER_LOCALIZATION):
        out = per.event(boxes, np.vstack([a, b]), T_w_b)
    assert len(per.tracks) == 2 and len(out) == 2
    centers = sorted(o.center[1] for o in out)
    assert abs(centers[0] + 1.5) < 0.15 and abs(centers[1] - 1.5) < 0.15


def test_empty_inputs():
    per = PerceptionPipeline(CAM, T_B_C, T_B_L)
    assert per.event(np.zeros((0, 4)), np.zeros((5, 3)), np.eye(4)) == []
    assert per.event(np.array([[0, 0, 10, 10.0]]), np.zeros((0, 3)), np.eye(4)) == []


def test_scale_check_rejects_a_localization_that_does_not_fit_its_box():
    """An insulator 2 m long at 8 m fits its box; told the strings are 5 m long, the same
    localization looks 2.5 times too long for the box and is rejected: by the pipeline's scale
    gate for a method of the cloud alone, by the bounded method itself (its boxes bound the line to
    2 m, not 5: a failure) for the default."""
    for method, counter in ((LocalizationMethod.DBSCAN_RANSAC, "implausible"), (DEFAULT_METHOD, "failures")):
        for length, expected in ((2.0, 1), (5.0, 0)):
            rng = np.random.default_rng(2)
            per = PerceptionPipeline(CAM, T_B_C, T_B_L, method=method, insulator_length=length)
            T_w_b = np.eye(4)
            ins = string_of_sheds(np.array([8.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 60, rng)
            for _ in range(EVENTS_PER_LOCALIZATION):
                out = per.event(box_of(ins, T_w_b), ins, T_w_b)
            assert len(out) == expected and getattr(per, counter) == 1 - expected, (method, length)


def _moving_events(per, center, axis, rng, *, speed, yaw_swing):
    """Three detection events while the vehicle flies past at ``speed`` m/s, swinging its
    heading by ``yaw_swing`` rad (once a second, level at each frame: 2 pi yaw_swing rad/s
    then): each LiDAR scan spans the 0.1 s before its frame, every point taken from the pose
    of its own time; the pipeline gets the poses at 20 Hz, as the flight loop feeds them."""
    from insulator_rs.poses import pose_from_yaw
    from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped

    def T(t):  # flying north past the insulator
        return pose_from_yaw([0.0, speed * (t - 2.0), 10.0], yaw_swing * np.sin(2 * np.pi * t))

    out = []
    for k in range(EVENTS_PER_LOCALIZATION):
        t_frame = 1.0 + k
        for t in np.arange(t_frame - 1.0, t_frame + 1e-9, 0.05):
            per.add_pose(PoseStamped(float(t), T(t)))
        ins = insulator(center, axis, 60, rng)
        times = np.sort(rng.uniform(t_frame - 0.1, t_frame, len(ins)))
        pts_l = np.array([np.linalg.inv(T(t))[:3, :3] @ p + np.linalg.inv(T(t))[:3, 3] for p, t in zip(ins, times)])
        per.add_scan(LidarScan(pts_l, times, T_B_L))
        frame = CameraFrame(t_frame, np.zeros((CAM.height, CAM.width, 3), np.uint8), CAM, T_B_C)
        out = per.process(frame, box_of(ins, T(t_frame)))
    return out


def test_a_scan_taken_while_moving_is_deskewed_with_the_pose_history():
    """Reference: the same insulator points taken standing still (the same localization to
    1 cm: deskewing undoes the motion exactly, and what differs is the body frame the seeded
    RANSAC samples in), and the true centre (0.15 m, as the static test: the sampled string's
    extent). Flying at 1 m/s and turning at up to 100 deg/s.
    Contrast: the points all moved with the frame's pose (no deskew) land more than 0.5 m off
    (the turn during the scan, at 8 m)."""
    from insulator_rs.poses import pose_from_yaw

    center, axis = np.array([8.0, 0.0, 10.0]), np.array([0.0, 0.0, 1.0])  # a suspension string
    still = _moving_events(PerceptionPipeline(CAM, T_B_C, T_B_L), center, axis, np.random.default_rng(3),
                           speed=0.0, yaw_swing=0.0)
    per = PerceptionPipeline(CAM, T_B_C, T_B_L)
    out = _moving_events(per, center, axis, np.random.default_rng(3), speed=1.0, yaw_swing=0.28)
    assert len(out) == 1 and len(still) == 1
    np.testing.assert_allclose(out[0].center, still[0].center, atol=0.01)
    assert np.linalg.norm(out[0].center - center) < 0.15 and abs(out[0].axis @ axis) > 0.99
    assert out[0].time == 3.0 and per.counters.localizations == 1
    # the contrast: the last scan's points moved to W with the frame's pose only
    scan = per.scans[-1]
    T_frame = pose_from_yaw([0.0, 1.0, 10.0], 0.0)
    naive_w = scan.points_l @ T_frame[:3, :3].T + T_frame[:3, 3]
    assert np.median(np.linalg.norm(per.paired_points_w(3.0) - naive_w, axis=1)) > 0.5


def test_a_frame_without_a_scan_or_a_pose_is_counted_not_localized():
    from insulator_rs.ports.sensors import CameraFrame, PoseStamped

    per = PerceptionPipeline(CAM, T_B_C, T_B_L)
    frame = CameraFrame(1.0, np.zeros((CAM.height, CAM.width, 3), np.uint8), CAM, T_B_C)
    box = np.array([[10.0, 10.0, 50.0, 50.0]])
    assert per.process(frame, box) == [] and per.counters.unpaired == 1  # no pose yet
    per.add_pose(PoseStamped(1.0, np.eye(4)))
    assert per.process(frame, box) == [] and per.counters.unpaired == 2  # no scan near the frame
    assert per.process(frame, np.zeros((0, 4))) == [] and per.counters.frames == 3


def _scored_events(per, scores, rng):
    """One detection event per score, of the synthetic insulator ahead, its box carrying the score."""
    center, axis = np.array([8.0, 0.0, 10.0]), np.array([0.0, 1.0, 0.0])
    outs = []
    for k, score in enumerate(scores):
        T_w_b = np.eye(4)
        T_w_b[:3, 3] = [0.0, 0.3 * k, 10.0]
        ins = insulator(center, axis, 40, rng)
        pts_l = (ins - T_w_b[:3, 3]) @ T_w_b[:3, :3]
        box = np.column_stack([box_of(ins, T_w_b), [score]])
        outs.append(per.event(box, pts_l, T_w_b))
    return outs


def test_a_track_of_weak_boxes_is_not_handed_on_until_a_confident_box_joins_it():
    """ByteTrack's birth rule (BIRTH_SCORE): boxes below it gather evidence but a track made only
    of them yields no localization (counted as unconfirmed); the first confident box releases
    it, and its weaker boxes then keep it going. Reference: the same events with confident boxes."""
    from insulator_rs.perception.pipeline import BIRTH_SCORE

    weak = BIRTH_SCORE - 0.1
    per = PerceptionPipeline(CAM, T_B_C, T_B_L)
    outs = _scored_events(per, [weak] * 5, np.random.default_rng(3))
    assert all(out == [] for out in outs)
    assert per.counters.unconfirmed == 5 - EVENTS_PER_LOCALIZATION + 1 and per.counters.localizations == 0
    outs = _scored_events(per, [BIRTH_SCORE, weak, weak], np.random.default_rng(4))
    assert all(len(out) == 1 for out in outs) and len(per.tracks) == 1
    reference = PerceptionPipeline(CAM, T_B_C, T_B_L)
    ref = _scored_events(reference, [0.9] * 3, np.random.default_rng(3))
    assert len(ref[-1]) == 1 and reference.counters.unconfirmed == 0
    # boxes without a score column are taken as confident (a detector that gives none)
    plain = PerceptionPipeline(CAM, T_B_C, T_B_L)
    rng = np.random.default_rng(3)
    for k in range(EVENTS_PER_LOCALIZATION):
        T_w_b = np.eye(4)
        T_w_b[:3, 3] = [0.0, 0.3 * k, 10.0]
        ins = insulator(np.array([8.0, 0.0, 10.0]), np.array([0.0, 1.0, 0.0]), 40, rng)
        out = plain.event(box_of(ins, T_w_b), (ins - T_w_b[:3, 3]) @ T_w_b[:3, :3], T_w_b)
    assert len(out) == 1



def test_paired_points_match_the_numpy_pose_track_reference():
    """The pipeline deskews with fusion_core (``ir.deskew``); reference: the numpy ``PoseTrack``
    (geodesic rotation, linear translation, clamped outside the history), which the simulator
    casts its scans with. Tolerance 1e-9 m. Includes points newer than the newest pose (clamped)."""
    from insulator_rs.poses import pose_from_yaw
    from insulator_rs.ports.sensors import LidarScan, PoseStamped

    rng = np.random.default_rng(8)
    per = PerceptionPipeline(CAM, T_B_C, T_B_L)
    for k in range(60):  # 50 Hz, flying and turning
        t = 0.02 * k
        T = pose_from_yaw([1.5 * t, 0.3 * t, 10.0 + 0.2 * t], 0.9 * t)
        T[:3, :3] = T[:3, :3] @ np.array([[1, 0, 0], [0, np.cos(0.05 * t), -np.sin(0.05 * t)],
                                           [0, np.sin(0.05 * t), np.cos(0.05 * t)]])
        per.add_pose(PoseStamped(t, T))
    T_b_l = np.eye(4)
    T_b_l[:3, :3] = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]
    T_b_l[:3, 3] = [0.1, 0.0, -0.08]
    times = np.sort(rng.uniform(0.95, 1.25, 5000))  # the newest pose is at 1.18 s
    pts = rng.uniform(-20, 20, (5000, 3)).astype(np.float32)
    per.add_scan(LidarScan(pts, times, T_b_l))
    got = per.paired_points_w(1.1)
    near = np.abs(times - 1.1) <= per.pairing_window
    track = per.poses.track()
    pts_b = pts[near].astype(np.float64) @ T_b_l[:3, :3].T + T_b_l[:3, 3]
    expected = track.rotate(times[near], pts_b) + track.position(times[near])
    assert got.shape == expected.shape and np.any(times[near] > track.knots_t[-1])
    np.testing.assert_allclose(got, expected, atol=1e-9, rtol=0)
