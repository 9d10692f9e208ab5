"""One perception runner and one pairing rule for the flight and its replay.

The flight (small scene, shipped network, simulated sensors) is recorded losslessly
(``--record-images raw``), then replayed: the replay plays the recording through its own
``Sensors``/``Vehicle`` adapters into the same ``PerceptionRunner``. Reference: the flight
itself. With the same pixels the detector gives the same boxes, so every count of the pairing
and the pipeline must be equal, and the insulators must agree to the recording's precision
(points stored as float32 in livox_ros_driver2's PointCloud2 layout: 1e-3 m is generous).
A second replay with the pairing rule changed (the slack) shows the comparison can fail.
"""

import json

import pytest

from insulator_rs.app.cli import main
from insulator_rs.perception import pairing
from helpers.flights import small_scene

pytestmark = pytest.mark.slow
ARGS = ["--detect-period", "1.0", "--detect-scale", "0.25", "--photo-scale", "0.2", "--quiet",
        "--detector", "insulator-sim"]
PRECISION = 1e-3  # m: float32 points in the recording


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("one_pipeline")
    scene, mission = small_scene(tmp)
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(tmp / "flight"), *ARGS,
               "--record", str(tmp / "flight.mcap"), "--record-images", "raw"])
    assert rc == 0
    return tmp, json.loads((tmp / "flight" / "summary.json").read_text())


def _replay(tmp, name):
    rc = main(["replay", str(tmp / "flight.mcap"), "--out", str(tmp / name), "--quiet"])
    assert rc == 0
    return json.loads((tmp / name / "summary.json").read_text())


def _centres(summary):
    return sorted(tuple(r["center"]) for r in summary["insulators"])


def test_replay_pairs_and_localizes_as_the_flight_did(flown):
    tmp, flight = flown
    replay = _replay(tmp, "replay")
    assert flight["run"] == "flight" and replay["run"] == "replay"
    assert flight["insulators_found"] == 2
    assert replay["frames_detected"] == flight["frames_detected"] > 50
    assert replay["pairing_short"] == flight["pairing_short"]
    assert replay["perception"] == flight["perception"]
    assert replay["localizations"] == flight["localizations"] > 0
    for a, b in zip(_centres(flight), _centres(replay), strict=True):
        assert max(abs(x - y) for x, y in zip(a, b)) < PRECISION


def test_the_comparison_sees_another_pairing_rule(flown, monkeypatch):
    """With a frame handed over before its window's scans arrive (no wait, no slack), the replay
    pairs fewer points: the equality above is not vacuous."""
    tmp, flight = flown
    monkeypatch.setattr(pairing, "PAIRING_WAIT", -1.0)
    monkeypatch.setattr(pairing, "PAIRING_SLACK", 10.0)
    replay = _replay(tmp, "replay_other_rule")
    assert replay["perception"] != flight["perception"]
