"""The efficiency study command on a small case, and its visibility model."""

import csv
import math

import numpy as np
import pytest

from insulator_rs.app.cli import main
from insulator_rs.evaluation.efficiency_study import VisibilityModel, waypoint_counts
from insulator_rs.sim.towers import load_tower


def test_waypoint_counts_round_robin():
    assert waypoint_counts(12, 4) == [1] * 4 + [0] * 8
    assert waypoint_counts(4, 10) == [3, 3, 2, 2]
    assert sum(waypoint_counts(12, 24)) == 24


def test_visibility_needs_the_camera_to_face_the_insulator():
    tower = load_tower("tower_b")
    vis = VisibilityModel(tower)
    ins = tower.insulators[0]
    side = np.array(tower.spec.lateral_direction) * ins.side
    p = ins.center + 8.0 * side
    look = -side
    yaw = math.atan2(look[1], look[0])
    assert vis.visible(p, yaw)[0]
    assert not vis.visible(p, yaw + math.pi)[0]           # looking away
    assert not vis.visible(ins.center + 30.0 * side, yaw)[0]  # out of range


@pytest.mark.slow
def test_eval_efficiency_writes_table_csv_and_plot(tmp_path, capsys):
    rc = main(["eval", "efficiency", "--towers", "tower_b", "--n", "4", "--out", str(tmp_path)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "tower_b" in out and "T_fusion" in out
    rows = list(csv.DictReader((tmp_path / "efficiency.csv").open()))
    assert len(rows) == 1
    r = rows[0]
    assert float(r["T_two_flight_s"]) == pytest.approx(float(r["T_scan_s"]) + float(r["T_tsp_s"]), abs=0.02)
    assert r["safe"] == "True"
    assert int(r["inspected"]) == int(r["insulators_to_inspect"]) == 4
    assert int(r["inspected_insertion"]) == 4
    assert float(r["T_fusion_s"]) > float(r["T_scan_s"])  # the detours cost time
    assert (tmp_path / "efficiency.png").stat().st_size > 10_000
