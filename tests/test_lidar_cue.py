"""The LiDAR cue's rules (flight/lidar_cue.py): which LiDAR strings become look candidates, which
camera records the geometry contradicts, the registry's hold, the tower cloud, the mission switch.

References: hand-made strings and records with their distances known by construction, and tower
B's simulated exploration cloud against the scene's truth (the strings' true centres; steel is
where the cloud is dense and no string is within 2 m).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from helpers.exploration_clouds import exploration_cloud
from scipy.spatial import cKDTree

import insulator_rs as ir
from insulator_rs._toml import tomllib
from insulator_rs.exceptions import ConfigError
from insulator_rs.evaluation.track_evidence import judge, read_run
from insulator_rs.flight.lidar_cue import (CLOUD_VOXEL, CONTRADICTED, COVER_MIN_POINTS, COVER_RADIUS, SUPPORT_REACH,
                                           LidarCue, TowerCloud, contradicts, uncovered_strings)
from insulator_rs.flight.second_look import KNOWN_STRING_REACH
from insulator_rs.geodesy import line_frame
from insulator_rs.mission.config import parse_mission
from insulator_rs.planning.obstacle_map import GROUND_BAND
from insulator_rs.tracking.confirmation import HELD_FACTOR
from insulator_rs.tracking.registry import Insulator, InsulatorRegistry

LINE = line_frame(np.array([[0.0, 100.0, 0.0], [0.0, -100.0, 0.0]]))  # the line along y
UP = np.array([0.0, 0.0, 1.0])


def string(center, length=1.5, score=20.0):
    """A LiDAR string as the finder reports one (the attributes the rules read)."""
    return SimpleNamespace(center=np.asarray(center, dtype=np.float64), axis=UP, length=length, score=score,
                           n_points=100, radius=0.1, elevation=np.pi / 2)


def record(center, observations=4, confirmed=True):
    c = np.asarray(center, dtype=np.float64)
    return Insulator(id=1 if confirmed else 0, center=c, axis=UP, observations=observations, side=LINE.side(c),
                     confirmed=confirmed)


# -- the candidate rule ---------------------------------------------------------------------
def test_a_lidar_string_with_no_camera_track_near_is_a_look_candidate():
    s = string([3.0, 0.0, 10.0])
    far = record([-3.0, 0.0, 10.0])
    assert uncovered_strings([s], [np.array([0.0, 0.0, 10.0])], [far], 2.0) == [s]


def test_a_lidar_string_with_a_registry_record_or_a_track_near_is_no_candidate():
    s = string([3.0, 0.0, 10.0])
    # a record's centre 1 m off the string's middle, and one off its end along its axis
    assert uncovered_strings([s], [], [record([3.0, 1.0, 10.0])], 2.0) == []
    assert uncovered_strings([s], [], [record([3.0, 0.0, 11.6], confirmed=False)], 2.0) == []
    # a perception track's anchor beside the string's lower end (no registry record at all)
    assert uncovered_strings([s], [np.array([3.5, 0.5, 9.4])], [], 2.0) == []
    # just past the reach from the segment: a candidate again
    assert uncovered_strings([s], [np.array([3.0 + KNOWN_STRING_REACH + 0.05, 0.0, 10.0])], [], 2.0) == [s]


def test_the_cue_keeps_one_target_per_string_across_runs():
    cue = LidarCue(LINE, 6.0, 2.0)
    cue.strings = [string([3.0, 0.0, 10.0])]
    first = cue.look_targets([], [])
    cue.strings = [string([3.03, 0.02, 10.01])]  # found again a few cm off
    again = cue.look_targets([], [])
    assert len(first) == len(again) == 1 and first[0] is again[0]
    assert first[0].id == 0 and first[0].observations == 0 and not first[0].confirmed  # never an insulator


# -- the contradiction rule -----------------------------------------------------------------
def test_a_track_with_no_structure_in_a_well_covered_map_is_held():
    s = string([3.0, 0.0, 10.0])
    assert contradicts(np.array([0.0, 0.0, 10.0]), [s], COVER_MIN_POINTS)
    assert contradicts(np.array([0.0, 0.0, 10.0]), [], 10 * COVER_MIN_POINTS)


def test_a_track_on_a_lidar_string_or_in_a_thin_map_is_not_held():
    s = string([3.0, 0.0, 10.0])
    assert not contradicts(np.array([3.0, SUPPORT_REACH - 0.05, 10.0]), [s], 10 * COVER_MIN_POINTS)
    assert not contradicts(np.array([0.0, 0.0, 10.0]), [s], COVER_MIN_POINTS - 1)  # the map barely saw it
    assert not contradicts(np.array([0.0, 0.0, 10.0]), [], 0)


def test_the_registry_holds_a_doubted_record_for_more_localizations_and_still_confirms_it():
    doubted = InsulatorRegistry(LINE, 1.5, 4, doubt=lambda c: True)
    plain = InsulatorRegistry(LINE, 1.5, 4, doubt=lambda c: False)
    c, a = np.array([3.0, 0.0, 10.0]), UP
    for k in range(1, 4 * HELD_FACTOR + 1):
        _, new_doubted = doubted.observe(c, a)
        _, new_plain = plain.observe(c, a)
        assert new_plain == (k == 4)
        assert new_doubted == (k == 4 * HELD_FACTOR)
    assert doubted.insulators[0].held == 4 * HELD_FACTOR - 4 + 1
    assert plain.insulators[0].held == 0


@pytest.mark.slow
def test_on_tower_b_the_rules_agree_with_the_truth():
    """Tower B, one exploration's cloud: with records on three true strings the fourth is the
    one candidate; a record on each true string is supported; records on steel (dense, no string
    within 2 m) are contradicted; a place beside the tower the scans barely reached is not."""
    tower, cloud = exploration_cloud("tower_b")
    cue = LidarCue(LINE, float(tower.max_width), 2.0)
    cue.add(cloud)
    cue.run()
    truth = [t.center for t in tower.insulators]
    assert len(cue.strings) == len(truth)
    records = [record(c) for c in truth[:3]]
    candidates = uncovered_strings(cue.strings, [], records, 2.0)
    assert len(candidates) == 1 and np.linalg.norm(candidates[0].center - truth[3]) < 0.2
    assert not any(cue.doubt(c) for c in truth)
    far = cloud[np.min(np.linalg.norm(cloud[:, None, :] - np.array(truth)[None], axis=2), axis=1) > 2.0]
    counts = np.array([len(i) for i in cKDTree(cloud).query_ball_point(far[::500], COVER_RADIUS)])
    steel = far[::500][counts >= COVER_MIN_POINTS]
    assert len(steel) > 10
    assert all(cue.doubt(p) for p in steel)
    empty = np.array([0.0, float(tower.max_width) / 2 + 1.5, 2.0])  # beside the tower, near the ground
    assert cue.cover(empty) < COVER_MIN_POINTS and not cue.doubt(empty)


def test_the_track_evidence_counts_what_the_geometry_contradicts(tmp_path):
    """Per-track evidence of both cues (evaluation/track_evidence.py): a string's tracks on a
    LiDAR string, two false tracks past the gates, one the geometry contradicts, one it cannot
    judge (not covered), and a false track stopped before the gates (not counted)."""
    def track(true, lidar, localizations=3, held=0):
        return {"center": [0, 0, 0], "boxes": 5, "best_score": 0.8, "confident_boxes": 5,
                "localizations": localizations, "held_before_birth": held, "refused": 0,
                "true_insulator": true, "gt_instance_id": 1, "distance_m": 0.1 if true else 2.0, "lidar": lidar}
    tracks = [track(True, "string", 40), track(False, CONTRADICTED, 2), track(False, "not covered", 1),
              track(False, CONTRADICTED, 0)]
    (tmp_path / "score.json").write_text(json.dumps({"tracks": tracks, "insulators_in_scene": 1}), encoding="utf-8")
    judged = judge([read_run(tmp_path)])
    assert judged["lidar"] == {"false_past_the_gates_with_lidar": 2, "false_past_the_gates_contradicted": 1,
                               "strings_with_a_contradicted_track": 0}
    tracks[0]["lidar"] = CONTRADICTED
    (tmp_path / "score.json").write_text(json.dumps({"tracks": tracks, "insulators_in_scene": 1}), encoding="utf-8")
    assert judge([read_run(tmp_path)])["lidar"]["strings_with_a_contradicted_track"] == 1


# -- the tower cloud --------------------------------------------------------------------------
def test_the_tower_cloud_keeps_what_is_near_the_tower_and_thins_when_full():
    cloud = TowerCloud(5.0, ground_z=0.5, max_points=1000)
    # near the tower; beyond its reach; on the ground (under GROUND_BAND); a driver's NaN
    cloud.add(np.array([[1.0, 1.0, 5.0], [6.0, 0.0, 5.0], [1.0, 1.0, 0.5 + GROUND_BAND - 0.1], [np.nan, 0.0, 0.0]]))
    assert len(cloud) == 1
    rng = np.random.default_rng(0)
    cloud.add(rng.uniform(-0.05, 0.05, (2000, 3)) + [0.0, 0.0, 5.0])  # 2000 returns in a 10 cm cube
    assert len(cloud) <= 1000 and cloud.thinned == 1
    keys = np.floor(cloud.points() / CLOUD_VOXEL).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == len(cloud)  # one return a voxel


def test_bad_tower_cloud_arguments_are_refused_by_name():
    with pytest.raises(ValueError, match="reach"):
        TowerCloud(float("nan"))
    with pytest.raises(ValueError, match="ground_z"):
        TowerCloud(5.0, ground_z=float("inf"))
    with pytest.raises(ValueError, match="max_points"):
        TowerCloud(5.0, max_points=0)


# -- the mission switch ---------------------------------------------------------------------
def _mission(extra: str) -> dict:
    path = Path(ir.__file__).resolve().parent / "missions" / "tower_b.toml"
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    data["inspection"].update(tomllib.loads(extra))
    return data


def test_the_mission_turns_the_cue_on_and_it_is_off_by_default():
    base = Path(ir.__file__).resolve().parent / "missions"
    assert parse_mission(_mission(""), base=base).inspection.lidar_cue is False
    assert parse_mission(_mission("lidar_cue = true"), base=base).inspection.lidar_cue is True
    with pytest.raises(ConfigError, match="inspection.lidar_cue"):
        parse_mission(_mission('lidar_cue = "yes"'), base=base)
