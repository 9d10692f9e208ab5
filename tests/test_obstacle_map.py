"""The LiDAR's obstacle map (planning/obstacle_map.py) and a flight beside a pole that the tower
model does not hold (issue 19 item 4): the map against an independent reference (brute-force
distances to the raw returns), and the small scene's mission with the pole beside its pass,
flown with the map (clear by the margin) and without it (closer than the margin)."""

import json
import re

import numpy as np
import pytest

from insulator_rs.app.cli import main
from insulator_rs.exceptions import ObstacleBlocked, ObstacleMapError
from insulator_rs.planning.obstacle_map import GROUND_BAND, ObstacleMap, SeenVolumes, bend_polyline
from insulator_rs.planning.safety import OrientedBox, SafetyVolumes
from insulator_rs.sim.scene import SceneError, load_scene

from helpers.flights import ARGS, POLE, POLE_END, POLE_RADIUS, POLE_START, small_scene
from helpers.reference_safety import cylinder_clearance

VOXEL = 0.4
DIAGONAL = np.sqrt(3.0) * VOXEL  # the map's distances are within one voxel diagonal of the truth


def _true_distance(points, returns):
    """Brute force: distance of each point to the nearest raw return."""
    return np.min(np.linalg.norm(points[:, None, :] - returns[None, :, :], axis=2), axis=1)


def _segment_distance(a, b, returns, step=0.005):
    n = int(np.ceil(np.linalg.norm(b - a) / step))
    samples = a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)
    return float(_true_distance(samples, returns).min())


def _cloud(rng, n=400):
    return rng.uniform([-5, -5, 2], [5, 5, 8], size=(n, 3))


def test_clearance_is_within_one_voxel_diagonal_below_the_true_distance():
    rng = np.random.default_rng(1)
    returns = _cloud(rng)
    m = ObstacleMap(known=None, ground_z=-100.0, voxel=VOXEL, min_hits=1)
    m.insert(returns)
    q = rng.uniform([-8, -8, 0], [8, 8, 10], size=(500, 3))
    got, truth = m.clearance(q), _true_distance(q, returns)
    assert np.all(got <= truth + 1e-9)  # conservative: never farther than a return
    assert np.all(got >= truth - DIAGONAL - 1e-9)


@pytest.mark.slow  # a dense reference sweep: about 11 s
def test_segments_clear_agrees_with_the_reference_outside_one_voxel_diagonal():
    rng = np.random.default_rng(2)
    returns = rng.uniform([-1, -1, 3], [1, 1, 6], size=(200, 3))
    m = ObstacleMap(known=None, ground_z=-100.0, voxel=VOXEL, min_hits=1)
    m.insert(returns)
    margin = 2.0
    a = rng.uniform([-8, -8, 0], [8, 8, 10], size=(150, 3))
    b = rng.uniform([-8, -8, 0], [8, 8, 10], size=(150, 3))
    clear = m.segments_clear(a, b, margin)
    truth = np.array([_segment_distance(p, q, returns) for p, q in zip(a, b)])
    assert np.all(truth[clear] >= margin - 1e-6)  # a clear segment is clear (never too close)
    assert np.all(clear[truth >= margin + DIAGONAL])  # and far enough is always clear
    assert clear.any() and (~clear).any()


def test_a_single_return_does_not_block_and_the_ground_and_the_boxes_are_not_mapped():
    box = OrientedBox(np.array([0.0, 0.0, 5.0]), np.eye(3), np.array([2.0, 2.0, 5.0]), "tower safety box")
    m = ObstacleMap(known=SafetyVolumes((box,), 10.0), ground_z=0.0, voxel=VOXEL, min_hits=2)
    m.insert(np.array([[10.0, 0.0, 5.0]]))  # one noise return
    assert len(m.occupied_centres()) == 0
    m.insert(np.array([[10.05, 0.05, 5.05]]))  # a second in the same voxel: occupied
    assert len(m.occupied_centres()) == 1
    m.insert(np.array([[0.5, 0.5, 5.0]] * 5 + [[20.0, 0.0, GROUND_BAND / 2]] * 5))  # the tower, the ground
    assert len(m.occupied_centres()) == 1
    m.insert(np.array([[30.0, 0.0, 5.0]] * 5), sensor_w=np.array([0.0, 0.0, 5.0]))  # beyond survey range
    assert len(m.occupied_centres()) == 1
    assert m.record()["occupied_voxels"] == 1


def test_bad_settings_and_points_are_named():
    for kwargs, field in (({"voxel": 0.0}, "voxel"), ({"voxel": float("nan")}, "voxel"),
                          ({"min_hits": 0}, "min_hits"), ({"max_voxels": 1.5}, "max_voxels")):
        with pytest.raises(ObstacleMapError, match=f"^{field}: "):
            ObstacleMap(known=None, ground_z=0.0, **kwargs)
    m = ObstacleMap(known=None, ground_z=0.0)
    with pytest.raises(ObstacleMapError, match="points_w: expected an"):
        m.insert(np.zeros((4, 2)))
    assert m.insert(np.full((3, 3), np.nan)) == 0  # a driver's padding: ignored


def _pole_space(x=0.0, y=0.0):
    z = np.arange(0.0, 12.0, 0.05)
    ring = np.stack([np.cos(np.linspace(0, 2 * np.pi, 24)), np.sin(np.linspace(0, 2 * np.pi, 24))], axis=1) * 0.15
    pole = np.array([[x + c[0], y + c[1], h] for h in z for c in ring])
    far = OrientedBox(np.array([100.0, 100.0, 0.0]), np.eye(3), np.ones(3), "tower safety box")
    m = ObstacleMap(known=SafetyVolumes((far,), 1.0), ground_z=0.0)
    m.insert(pole)
    return SeenVolumes.of(SafetyVolumes((far,), 1.0), m, 2.0), pole


def test_a_blocked_leg_is_bent_round_the_pole_and_a_waypoint_at_it_is_refused():
    space, pole = _pole_space()
    leg = np.array([[-8.0, 0.3, 6.0], [8.0, 0.3, 6.0]])
    assert not space.polyline_clear(leg)
    bent, bends = bend_polyline(leg, space)
    assert len(bent) > 2 and space.polyline_clear(bent)
    assert [b.segment for b in bends] == [0] and bends[0].points == len(bent) - 2
    assert bends[0].obstacle is not None and np.linalg.norm(bends[0].obstacle[:2]) < VOXEL  # the pole, at 0, 0
    for a, b in zip(bent[:-1], bent[1:]):
        assert _segment_distance(a, b, pole, step=0.05) >= 2.0  # the true clearance, not the map's
    with pytest.raises(ObstacleBlocked, match="within the safety margin of an obstacle the LiDAR saw"):
        bend_polyline(np.array([[-8.0, 0.0, 6.0], [1.0, 0.0, 6.0]]), space)


def test_bad_scene_obstacles_are_named(tmp_path):
    scene, _ = small_scene(tmp_path)
    base = scene.read_text()
    for table, message in (('start = [0, 0, 0]\nend = [0, 0, 5]\nradius = -1', "obstacles[0].radius"),
                           ('start = [0, 0, 0]\nend = [0, 0, 0.01]\nradius = 0.1', "obstacles[0].end"),
                           ('start = [0, 0]\nend = [0, 0, 5]\nradius = 0.1', "obstacles[0].start"),
                           ('start = [0, 0, 0]\nend = [0, 0, 5]\nradius = 0.1\ncolour = 1', "obstacles[0].colour")):
        scene.write_text(base + "\n[[obstacles]]\n" + table + "\n")
        with pytest.raises(SceneError, match=re.escape(f"field '{message}'")):
            load_scene(scene)


def _pole_clearance(out):
    """The flown trajectory's least distance (m) to the pole's true surface."""
    rows = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1, usecols=(1, 2, 3))
    return float(np.min(cylinder_clearance(rows, POLE_START, POLE_END, POLE_RADIUS)))


def _fly_beside_the_pole(tmp_path, *extra):
    scene, mission = small_scene(tmp_path)
    scene.write_text(scene.read_text() + POLE)
    out = tmp_path / "report"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS, *extra])
    return rc, out


@pytest.mark.slow
def test_the_mission_gets_round_a_pole_the_tower_model_does_not_hold(tmp_path):
    rc, out = _fly_beside_the_pole(tmp_path)
    s = json.loads((out / "summary.json").read_text())
    g = json.loads((out / "score.json").read_text())
    assert rc == 0 and s["status"] == "finished"
    assert g["insulators_matched"] == 2 and g["insulators_inspected_matched"] == 2
    om = s["obstacle_map"]
    assert om["enabled"] and om["occupied_voxels"] > 0 and om["legs_bent"] >= 1
    assert _pole_clearance(out) >= om["margin_m"]


@pytest.mark.slow
def test_without_the_map_the_same_flight_comes_closer_than_the_margin(tmp_path):
    rc, out = _fly_beside_the_pole(tmp_path, "--no-obstacle-map")
    s = json.loads((out / "summary.json").read_text())
    assert rc == 0 and s["obstacle_map"] == {"enabled": False}
    assert _pole_clearance(out) < 2.0  # the mission's safety margin: the map is what keeps it
