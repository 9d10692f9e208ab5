"""The simulated Livox Mid-360 (``insulator_rs.sim.lidar``): pattern statistics,
noise, range limits, return losses, motion distortion, determinism, bad input.

References: the sensor's data sheet figures the model is built to (200,000
points/s, 10 Hz, -7..52 deg x 360 deg, 2 cm 1 sigma); exact geometry of planes
for the noise and motion checks (ray/plane distance computed here in numpy);
Rodrigues' rotation for pose interpolation. Tolerances are stated per test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from insulator_rs.poses import PoseTrack, interpolate_poses
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.mesh import InstanceInfo, Mesh, box, cylinder, plane


def pose(position=(0.0, 0.0, 0.0), yaw: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = position
    return T


def room(half: float = 10.0, wall_id: int = 1) -> Mesh:
    """Inside of a big box: a floor and four walls facing inward, ceiling open."""
    walls = [
        plane([half, 0, 10], [-1, 0, 0], (40, 40), instance_id=wall_id),
        plane([-half, 0, 10], [1, 0, 0], (40, 40), instance_id=wall_id + 1),
        plane([0, half, 10], [0, -1, 0], (40, 40), instance_id=wall_id + 2),
        plane([0, -half, 10], [0, 1, 0], (40, 40), instance_id=wall_id + 3),
    ]
    floor = plane([0, 0, 0], [0, 0, 1], (40, 40), instance_id=0, info=InstanceInfo("floor", "ground"))
    return Mesh.concatenate([floor, *walls])


def test_point_rate_frame_length_and_timestamps() -> None:
    lidar = Mid360()
    t, dirs = lidar.shots(2.0)
    assert len(t) == 20_000 == lidar.points_per_frame
    np.testing.assert_allclose(np.diff(t), 1 / 200_000, rtol=1e-9)
    assert t[0] == pytest.approx(2.0) and t[-1] < 2.1
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    t2, _ = lidar.shots(2.1)
    assert t2[0] == pytest.approx(t[-1] + 1 / 200_000)  # frames tile time without gaps
    assert len(Mid360(point_rate=100_000, frame_rate=20).shots(0)[0]) == 5_000


def test_field_of_view_and_angular_uniformity() -> None:
    """Elevation within [-7, 52] deg reaching both ends within 0.1 deg; azimuth and
    elevation histograms flat within 15 % (the model's design: ~1 point/deg^2)."""
    _, d = Mid360().shots(0.0)
    el = np.degrees(np.arcsin(d[:, 2]))
    az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    assert el.min() >= -7 - 1e-9 and el.max() <= 52 + 1e-9
    assert el.min() < -6.9 and el.max() > 51.9
    az_hist, _ = np.histogram(az, bins=36, range=(-180, 180))
    el_hist, _ = np.histogram(el, bins=10, range=(-7, 52))
    assert az_hist.min() > 0.85 * az_hist.mean() and az_hist.max() < 1.15 * az_hist.mean()
    assert el_hist.min() > 0.85 * el_hist.mean() and el_hist.max() < 1.15 * el_hist.mean()


def test_pattern_is_non_repetitive_and_fills_in() -> None:
    """Coverage of 1x1 deg cells: 1 frame covers > 50 %, 10 frames > 90 %, and
    successive frames differ."""
    lidar = Mid360()

    def cells(frames: int) -> float:
        seen = np.zeros((360, 59), bool)
        for k in range(frames):
            _, d = lidar.shots(0.1 * k)
            az = (np.degrees(np.arctan2(d[:, 1], d[:, 0])) + 180).astype(int) % 360
            el = np.clip((np.degrees(np.arcsin(d[:, 2])) + 7).astype(int), 0, 58)
            seen[az, el] = True
        return seen.mean()

    one, ten = cells(1), cells(10)
    assert one > 0.5 and ten > 0.9 and ten > one + 0.2
    d0, d1 = lidar.shots(0.0)[1], lidar.shots(0.1)[1]
    assert np.abs(d0 - d1).max() > 0.1


def test_range_noise_is_two_centimetres() -> None:
    """Reference: exact distance to the walls of a box room from the room centre.
    Noise std within 5 % of 0.02 m, mean within 4 sigma/sqrt(n)."""
    mesh = room()
    T_b_l = np.eye(4)
    lidar = Mid360(T_b_l, grazing_start_deg=89.0, grazing_end_deg=90.0)
    frame = lidar.scan(mesh, (pose((0, 0, 5)), pose((0, 0, 5))), 0.0, seed=3)
    walls = frame.instance_id >= 1
    p = frame.points_l[walls]
    rng_meas = np.linalg.norm(p, axis=1)
    d = p / rng_meas[:, None]
    # Distance from (0,0,5) to the wall planes |x| = 10, |y| = 10 along d.
    with np.errstate(divide="ignore"):
        t = np.minimum(np.where(d[:, 0] != 0, 10 / np.abs(d[:, 0]), np.inf),
                       np.where(d[:, 1] != 0, 10 / np.abs(d[:, 1]), np.inf))
    err = rng_meas - t
    assert len(err) > 5000
    assert abs(err.std() - 0.02) < 0.001
    assert abs(err.mean()) < 4 * 0.02 / math.sqrt(len(err))


def test_min_and_max_range() -> None:
    far = room(half=50.0)
    lidar = Mid360(np.eye(4), max_range=40.0)
    frame = lidar.scan(far, (pose((0, 0, 1)), pose((0, 0, 1))), 0.0, seed=0)
    assert np.all(frame.instance_id == 0)  # walls at 50 m: only the floor (within 40 m)
    assert np.linalg.norm(frame.points_l, axis=1).max() <= 40.0 + 0.1
    near = Mid360(np.eye(4), max_range=100.0).scan(far, (pose((0, 0, 1)), pose((0, 0, 1))), 0.0, seed=0)
    assert np.any(near.instance_id >= 1)
    # A surface closer than min_range is not reported.
    # A 6 cm square 5 cm in front of the sensor: every point on it is closer than 0.07 m.
    tiny = Mesh.concatenate([far, plane([0.05, 0, 1], [-1, 0, 0], (0.06, 0.06), instance_id=9)])
    frame = Mid360(np.eye(4), min_range=0.1).scan(tiny, (pose((0, 0, 1)), pose((0, 0, 1))), 0.0, seed=0)
    assert not np.any(frame.instance_id == 9)
    frame = Mid360(np.eye(4), min_range=0.01).scan(tiny, (pose((0, 0, 1)), pose((0, 0, 1))), 0.0, seed=0)
    assert np.any(frame.instance_id == 9)


def test_returns_are_lost_at_grazing_incidence_and_on_thin_objects() -> None:
    """Floor seen from 1 m up: incidence = 90 deg - depression angle. Beyond 88 deg
    nothing survives; below 65 deg everything. A thin instance with return
    probability 0.5 keeps 50 % +- 5 % of its returns."""
    mesh = room(half=30.0)
    lidar = Mid360(np.eye(4), max_range=100.0)
    origin = pose((0, 0, 1))
    t, d = lidar.shots(0.0)
    frame = lidar.scan(mesh, (origin, origin), 0.0, seed=1)
    floor = frame.points_l[frame.instance_id == 0]
    incidence = np.degrees(np.arccos(np.abs(floor[:, 2]) / np.linalg.norm(floor, axis=1)))
    assert incidence.max() <= 88.0 + 0.05
    # All downward shots steeper than 25 deg below horizontal (incidence < 65 deg) hit the floor.
    steep = np.degrees(np.arcsin(-d[:, 2])) > 25.0
    assert np.sum(incidence < 65.0) == np.sum(steep)

    wire = cylinder([-20, 3, 1], [20, 3, 1], 0.5, instance_id=50, segments=16,
                    info=InstanceInfo("wire", "conductor", return_probability=0.5, thin=True))
    solid = cylinder([-20, 3, 1], [20, 3, 1], 0.5, instance_id=50, segments=16,
                     info=InstanceInfo("pipe", "tower"))
    pose_wire = pose((0, 0, 1))
    counts = []
    for m in (Mesh.concatenate([mesh, wire]), Mesh.concatenate([mesh, solid])):
        n = 0
        for k in range(5):
            f = lidar.scan(m, (pose_wire, pose_wire), 0.1 * k, seed=k)
            n += int(np.sum(f.instance_id == 50))
        counts.append(n)
    hits_wire, hits_solid = counts
    # The solid pipe also loses grazing returns, so compare with the ray count instead.
    cast = Mesh.concatenate([mesh, wire]).raycaster
    total = 0
    for k in range(5):
        tk, dk = lidar.shots(0.1 * k)
        total += int(np.sum(cast.cast(np.tile([0, 0, 1.0], (len(tk), 1)), dk, 100.0).instance_id == 50))
    assert abs(hits_wire / total - 0.5) < 0.05
    assert hits_solid < total and hits_solid > hits_wire


def test_motion_distorts_the_frame_like_a_real_sensor() -> None:
    """Moving at 5 m/s toward a wall 10 m ahead: in L, the wall's x coordinate
    shrinks by 0.5 m over the frame (fit slope -5 m/s within 2 %); every point, placed with
    its own pose, lies on the wall (|x - 10| < 5 sigma); placed with the frame-start
    pose instead, the points smear by up to 0.5 m."""
    wall = plane([10, 0, 5], [-1, 0, 0], (200, 200), instance_id=1)
    lidar = Mid360(np.eye(4))
    start, end = pose((0, 0, 5)), pose((0.5, 0, 5))
    frame = lidar.scan(wall, (start, end), 0.0, seed=2)
    on = frame.instance_id == 1
    p, t = frame.points_l[on], frame.timestamps[on]
    assert len(p) > 3000
    slope = np.polyfit(t, p[:, 0], 1)[0]
    assert slope == pytest.approx(-5.0, rel=0.02)
    assert np.abs(frame.points_w[on, 0] - 10.0).max() < 5 * 0.02
    naive = p + start[:3, 3]
    assert np.abs(naive[:, 0] - 10.0).max() > 0.4
    # A callable trajectory gives the same frame as the equivalent start/end pair.
    frame2 = lidar.scan(wall, lambda time: pose((5.0 * time, 0, 5)), 0.0, seed=2)
    np.testing.assert_allclose(frame2.points_w, frame.points_w, atol=1e-9)
    np.testing.assert_allclose(frame.T_w_l_end[:3, 3], [0.5, 0, 5])


def test_yawing_sensor_points_land_on_the_true_geometry() -> None:
    """Yawing at 6 rad/s inside a box room: each point mapped to W with its own pose
    lies on a wall or the floor within 5 sigma of the range noise."""
    mesh = room()
    lidar = Mid360(np.eye(4))
    frame = lidar.scan(mesh, lambda time: pose((1, -2, 4), yaw=6.0 * time), 0.0, seed=5)
    w = frame.points_w
    dist_to_surface = np.minimum.reduce([np.abs(np.abs(w[:, 0]) - 10), np.abs(np.abs(w[:, 1]) - 10), np.abs(w[:, 2])])
    assert len(w) > 10_000 and dist_to_surface.max() < 5 * 0.02


def test_interpolation_of_poses() -> None:
    """Reference: a rotation by angle a about z sampled at fraction s is a rotation by s a."""
    knots = np.stack([pose((0, 0, 0), 0.0), pose((2, 4, 6), 1.2)])
    out = interpolate_poses(np.array([0.0, 1.0]), knots, np.array([-1.0, 0.0, 0.25, 1.0, 2.0]))
    np.testing.assert_allclose(out[1], knots[0], atol=1e-12)
    np.testing.assert_allclose(out[3], knots[1], atol=1e-12)
    np.testing.assert_allclose(out[2], pose((0.5, 1, 1.5), 0.3), atol=1e-12)
    np.testing.assert_allclose(out[0], knots[0], atol=1e-12)  # clamped
    track = PoseTrack(np.array([0.0, 1.0]), knots)
    v = np.random.default_rng(0).normal(size=(5, 3))
    t = np.linspace(0, 1, 5)
    expected = np.einsum("nij,nj->ni", interpolate_poses(track.knots_t, knots, t)[:, :3, :3], v)
    np.testing.assert_allclose(track.rotate(t, v), expected, atol=1e-12)


def test_a_pose_track_of_many_segments_rotates_as_scipys_slerp() -> None:
    """Reference: scipy's Slerp through the same knots (a frame's 21 pose samples, one segment
    not turning), at 20 000 times in and beyond the knots (clamped): to 1e-12."""
    from scipy.spatial.transform import Rotation, Slerp

    rng = np.random.default_rng(3)
    knots_t = np.linspace(0.0, 0.1, 21)
    knots = np.tile(np.eye(4), (21, 1, 1))
    knots[:, :3, :3] = Rotation.from_rotvec(rng.normal(size=(21, 3)) * 0.3).as_matrix()
    knots[4, :3, :3] = knots[3, :3, :3]
    knots[:, :3, 3] = rng.normal(size=(21, 3))
    t = np.sort(rng.uniform(-0.01, 0.11, 20_000))
    v = rng.normal(size=(20_000, 3))
    expected = Slerp(knots_t, Rotation.from_matrix(knots[:, :3, :3]))(np.clip(t, 0.0, 0.1)).apply(v)
    np.testing.assert_allclose(PoseTrack(knots_t, knots).rotate(t, v), expected, atol=1e-12)


def test_same_seed_same_frame_other_seed_other_noise() -> None:
    mesh = room()
    lidar = Mid360()
    traj = (pose((0, 0, 3)), pose((0.2, 0.1, 3), 0.1))
    a = lidar.scan(mesh, traj, 1.0, seed=11)
    b = lidar.scan(mesh, traj, 1.0, seed=11)
    c = lidar.scan(mesh, traj, 1.0, seed=12)
    for name in ("points_l", "timestamps", "instance_id", "points_w"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert len(a) != len(c) or np.any(a.points_l != c.points_l)


def test_bad_input_gets_clear_errors() -> None:
    for kwargs, name in [
        ({"point_rate": 0}, "point_rate"), ({"point_rate": -5}, "point_rate"),
        ({"frame_rate": 0}, "frame_rate"), ({"frame_rate": math.nan}, "frame_rate"),
        ({"max_range": 0}, "max_range"), ({"min_range": 50}, "min_range"),
        ({"range_noise": -0.1}, "range_noise"), ({"fov_down_deg": 60}, "fov_down_deg"),
        ({"grazing_start_deg": 95}, "grazing_start_deg"),
    ]:
        with pytest.raises(ValueError, match=name):
            Mid360(**kwargs)
    with pytest.raises(ValueError, match="T_b_l"):
        Mid360(np.ones((4, 4)))
    mesh = Mesh.concatenate([room(), box([0, 0, 5], [2, 2, 2], instance_id=20, info=InstanceInfo("block", "tower"))])
    lidar = Mid360(np.eye(4))
    with pytest.raises(ValueError, match="inside geometry.*block"):
        lidar.scan(mesh, (pose((0, 0, 5)), pose((0, 0, 5))), 0.0, seed=0)
    with pytest.raises(ValueError, match="inside geometry.*floor"):
        lidar.scan(mesh, (pose((3, 3, -1)), pose((3, 3, -1))), 0.0, seed=0)
    with pytest.raises(TypeError, match="trajectory"):
        lidar.scan(mesh, 42, 0.0, seed=0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="trajectory"):
        lidar.scan(mesh, lambda t: np.eye(3), 0.0, seed=0)
    with pytest.raises(ValueError, match="t_start"):
        lidar.scan(mesh, (pose((3, 3, 3)), pose((3, 3, 3))), math.inf, seed=0)
