"""``insulator-rs inspect`` end to end on a small scene: one cross-arm, two insulators.

The flight writes ``summary.json`` (what it knows); the scorer writes ``score.json`` (the
report against the scene's ground truth, after the flight). Assertions on ground truth read
the scorer's output."""

import json

import pytest
from helpers.flights import ARGS, MISSIONS, small_scene

from insulator_rs.app.cli import main
from insulator_rs.evaluation import track_evidence
from insulator_rs.flight.photo_session import PhotoSession


@pytest.mark.slow
@pytest.mark.smoke  # the quick tier's one flight
def test_inspect_end_to_end_on_a_small_scene(tmp_path, capsys):
    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    g = json.loads((out / "score.json").read_text())
    assert s["status"] == "finished" and s["state"] == "finish"
    assert g["insulators_in_scene"] == 2 and g["insulators_matched"] == 2
    assert s["insulators_inspected"] >= 2 and g["insulators_inspected_matched"] == 2
    matched = [r for r in g["insulators"] if r["error_m"] < 1.5]
    assert all(r["error_m"] < 0.6 for r in matched)  # the paper's accuracy class
    assert len(s["photos"]) == 2 * s["insulators_inspected"]  # two waypoints per insulator
    for p in s["photos"]:
        assert (out / p["file"]).stat().st_size > 1000
    assert [p["file"] for p in g["photos"]] == [p["file"] for p in s["photos"]]
    assert all(p["insulator_visible"] for p in g["photos"])
    assert sum(p["insulator_whole_in_frame"] for p in g["photos"]) >= 2
    states = [t["to"] for t in s["transitions"]]
    for st in ("explore", "inspect", "return", "cross", "finish"):
        assert st in states
    # per-track evidence: every localization handed on belongs to a listed track; the scorer puts
    # each string's track on its string, and what the thresholds judge passes both strings
    assert sum(t["localizations"] for t in s["tracks"]) == s["perception"]["localizations"]
    on_strings = {t["gt_instance_id"] for t in g["tracks"] if t["true_insulator"] and t["localizations"] >= 4}
    assert len(on_strings) == 2
    assert track_evidence.judge([track_evidence.read_run(out)])["verdict"]["every_tracked_string_passes"]
    assert s["flight_time_s"] > 30 and (out / "trajectory.png").stat().st_size > 10_000
    rows = (out / "trajectory.csv").read_text().splitlines()
    assert len(rows) > s["flight_time_s"] / 0.05 * 0.9
    assert "finished" in capsys.readouterr().out


@pytest.mark.slow
def test_interruption_keeps_what_was_found(tmp_path, monkeypatch):
    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    original = PhotoSession.take_photo

    def photo_then_ctrl_c(self, wp):
        original(self, wp)
        raise KeyboardInterrupt

    monkeypatch.setattr(PhotoSession, "take_photo", photo_then_ctrl_c)
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS])
    assert rc == 130
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and len(s["photos"]) == 1
    assert (out / s["photos"][0]["file"]).is_file() and s["insulators_found"] >= 1
    assert (out / "trajectory.png").is_file()


def test_bad_arguments_are_named(tmp_path, capsys):
    """Refused by argparse (status 2, the flag named), no traceback (bounds.py)."""
    for flag, value in (("--detect-period", "0"), ("--v-max", "-1")):
        with pytest.raises(SystemExit) as exit_info:
            main(["inspect", flag, value, "--out", str(tmp_path / "r")])
        assert exit_info.value.code == 2
        assert f"argument {flag}: must lie in" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


@pytest.mark.slow
def test_unknown_or_broken_detector_is_refused_before_flying(tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["inspect", "--detector", "no-such-model", "--out", str(out)]) == 2
    assert "--detector: name: no shipped model 'no-such-model'; shipped: [" in capsys.readouterr().err
    assert main(["inspect", "--detector", str(tmp_path / "missing.onnx"), "--out", str(out)]) == 2
    assert "--detector: model " in (err := capsys.readouterr().err) and "missing.onnx: file not found" in err
    broken = tmp_path / "broken.onnx"
    broken.write_bytes(b"\x08\x01" * 10)
    assert main(["inspect", "--detector", str(broken), "--out", str(out)]) == 2
    assert "--detector: model " in (err := capsys.readouterr().err) and "broken.onnx" in err
    assert not out.exists()


def test_bad_mission_file_is_refused_before_flying(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text((MISSIONS / "tower_a.toml").read_text().replace("max_width = 10.0", "max_width = -3"))
    out = tmp_path / "report"
    rc = main(["inspect", "--mission", str(bad), "--out", str(out)])
    assert rc == 2 and not out.exists()
    assert "bad.toml: tower.max_width: must be > 0" in capsys.readouterr().err


@pytest.mark.slow
def test_the_live_log_holds_only_what_the_flight_knows(tmp_path, capsys):
    """No ground truth reaches the flight: the progress lines and summary.json mention no error
    against the truth; the scene's truth appears only in the scorer's score.json."""
    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out),
               "--detect-period", "1.0", "--detect-scale", "0.2", "--photo-scale", "0.2", "--max-flight-time", "90"])
    assert rc in (0, 1)
    log = capsys.readouterr().out.splitlines()
    assert any("localized at" in line for line in log)
    flight_lines = log[:-1]  # the last line is the post-flight score
    assert not any("ground truth" in line or "error" in line for line in flight_lines), flight_lines
    s = json.loads((out / "summary.json").read_text())
    text = json.dumps(s)
    for key in ("gt_instance_id", "error_m", "ground_truth", "insulators_matched", "insulator_visible"):
        assert key not in text
    g = json.loads((out / "score.json").read_text())
    assert len(g["ground_truth"]) == 2 and "scored after the flight" in log[-1]
