"""The whole mission with the shipped simulation network (``insulator-sim``) in the loop.

A mission test, not a detection one: scripts/test-aarch64.sh runs the detection test files
under qemu, where this flight (every second frame through the network) took 1450 s; the
detector's aarch64 output is checked frame by frame there (test_detection_cross_arch.py) and
the main job from the wheel alone flies the small scene there."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from insulator_rs.app.cli import main

NAME = "insulator-sim"


@pytest.mark.slow
def test_inspection_with_the_sim_network_in_the_loop(tmp_path: Path) -> None:
    """The whole mission with the shipped network on the rendered detection images, which is
    inspect's default in the simulator (no --detector): both insulators of the small scene
    found and inspected; the sanitiser refused nothing the real network returned."""
    from helpers.flights import ARGS, small_scene

    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    default_args = [a for a in ARGS if a not in ("--detector", "standin")]  # the inspect tests pin the stand-in
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out),
               *default_args, "--detect-scale", "0.25"])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    g = json.loads((out / "score.json").read_text())  # the post-flight scorer's
    assert s["status"] == "finished" and s["detector"] == NAME
    assert s["detections_dropped_by_sanitiser"]["total"] == 0
    assert g["insulators_in_scene"] == 2 and g["insulators_matched"] == 2
    assert s["insulators_inspected"] >= 2
    assert all(r["error_m"] < 0.6 for r in g["insulators"] if r["error_m"] < 1.5)
