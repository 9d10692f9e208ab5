"""Per-track evidence (evaluation/track_evidence.py, scoring.score_tracks, the pipeline's
track records): the thresholds' judge on hand-made scored runs, whose answers are worked out
by hand below, and the pipeline's own bookkeeping on a scene of the simulator."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from insulator_rs.evaluation import track_evidence
from insulator_rs.evaluation.scoring import MATCH_DISTANCE, score_tracks
from insulator_rs.perception.pipeline import BIRTH_SCORE, EVENTS_PER_LOCALIZATION, TrackEvidence
from insulator_rs.sim.towers import InsulatorTruth


def _track(gt: int | None, localizations: int, best: float, held: int = 0, boxes: int = 40) -> dict:
    return {"center": [0.0, 0.0, 0.0], "boxes": boxes, "best_score": best, "confident_boxes": 0,
            "localizations": localizations, "held_before_birth": held, "refused": 0,
            "gt_instance_id": gt, "distance_m": 0.05 if gt is not None else 3.2, "true_insulator": gt is not None}


def _run(folder: Path, tracks: list[dict], in_scene: int = 2) -> Path:
    folder.mkdir(parents=True)
    (folder / "score.json").write_text(json.dumps({"insulators_in_scene": in_scene, "tracks": tracks}))
    return folder


def test_strings_fuse_their_tracks_and_false_tracks_are_judged_past_the_gates(tmp_path: Path) -> None:
    run = track_evidence.read_run(_run(tmp_path / "a", [
        _track(1, 30, 0.9), _track(1, 5, 0.4),  # string 1 seen as two tracks: 35 localizations, best 0.9
        _track(2, 12, 0.7),
        _track(None, 3, 0.55),  # on steel, born, 3 localizations: stopped by 4 confirmations only
        _track(None, 0, 0.45, held=6),  # on steel, held by the birth rule
        _track(None, 0, 0.95),  # on steel, stopped by the shape gates: never reached the birth rule
    ]))
    assert run.strings == {1: {"localizations": 35, "best_score": 0.9, "tracks": 2},
                           2: {"localizations": 12, "best_score": 0.7, "tracks": 1}}
    j = track_evidence.judge([run], birth_score=0.5, confirmations=4)
    assert j["false_tracks"] == 3 and j["false_tracks_past_the_gates"] == 2 and j["false_tracks_born"] == 1
    assert j["false_tracks_confirmed"] == 0 and j["false_past_the_gates_best_score_max"] == 0.55
    assert j["strings_best_score_min"] == 0.7 and j["strings_localizations_min"] == 12
    assert j["verdict"] == {"every_false_track_stopped": True, "every_tracked_string_passes": True,
                            "birth_score_separates": True, "confirmations_separate": True,
                            "birth_score_room": "above 0.55, up to 0.7", "confirmations_room": "above 3, up to 12"}
    # at 3 confirmations the steel track would have been registered
    assert not track_evidence.judge([run], birth_score=0.5, confirmations=3)["verdict"]["every_false_track_stopped"]
    # at a birth score of 0.8 string 2 (best box 0.7) would never be born
    assert not track_evidence.judge([run], birth_score=0.8, confirmations=4)["verdict"]["every_tracked_string_passes"]


def test_the_command_prints_the_table_and_refuses_a_report_without_tracks(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    good = _run(tmp_path / "good", [_track(1, 30, 0.9), _track(2, 20, 0.8)])
    assert track_evidence.main([str(good), "--json", str(tmp_path / "out.json"), "--plot", str(tmp_path / "p.png")]) == 0
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| good | 2 / 2 | 20 / 30 | 0.80 | 0 / 0 / 0 |" in capsys.readouterr().out
    assert json.loads((tmp_path / "out.json").read_text())["judgement"]["verdict"]["every_tracked_string_passes"]
    old = tmp_path / "old"
    old.mkdir()
    (old / "score.json").write_text(json.dumps({"insulators_in_scene": 2}))
    assert track_evidence.main([str(good), str(old)]) == 2
    assert f"{old / 'score.json'}: no per-track list" in capsys.readouterr().err
    assert track_evidence.main([str(tmp_path / "missing")]) == 2


def test_score_tracks_labels_each_track_by_its_nearest_string() -> None:
    truth = [InsulatorTruth(instance_id=7, center=np.array([0.0, 0.0, 10.0]), axis=np.array([0.0, 0.0, 1.0]),
                            length=2.0, side=1, arm=0, kind="strain", radius=0.1)]
    rows = score_tracks([{"center": [0.1, 0.0, 10.0]}, {"center": [0.0, MATCH_DISTANCE + 0.1, 10.0]}], truth)
    assert [r["true_insulator"] for r in rows] == [True, False]
    assert rows[0]["gt_instance_id"] == 7 and rows[0]["distance_m"] == pytest.approx(0.1)
    assert score_tracks([{"center": [0.0, 0.0, 0.0]}], [])[0]["true_insulator"] is False


def test_track_evidence_counts_boxes_and_confident_ones() -> None:
    e = TrackEvidence()
    for t, score in enumerate([0.3, BIRTH_SCORE, 0.9]):
        e.add_box(score, float(t))
    assert (e.boxes, e.confident_boxes, e.first_time, e.last_time) == (3, 2, 0.0, 2.0)
    assert EVENTS_PER_LOCALIZATION == 3  # track_records lists tracks from this many boxes on
