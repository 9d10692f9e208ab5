"""The summary assembly (flight/summary_assembly.py) and the run status (report/run_status.py),
without flying: the abort record (its landing point in WGS-84, the hand-over, what was left), the
status strings summary.json has always carried, and a loop built on the in-process simulator but
never flown whose summary says so.

Reference: pymap3d's ENU -> geodetic conversion for the landing point; the status strings as
crews' scripts read them (``finished``, ``aborted: <reason>``, ``refused_preflight: <check>: <why>``).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pymap3d
import pytest
from helpers.flights import small_scene

from insulator_rs.app.inspect_command import kinematic_vehicle
from insulator_rs.flight.loop import FlightLoop, FlightSettings
from insulator_rs.flight.summary_assembly import SummaryAssembly
from insulator_rs.geodesy import GeoPoint
from insulator_rs.mission.config import load_mission
from insulator_rs.mission.state_machine import AbortContext
from insulator_rs.planning.abort import AbortCase, AbortRoute
from insulator_rs.report.run_status import RunOutcome, RunStatus
from insulator_rs.rig import simulator_rig
from insulator_rs.sim.ground_truth_detector import GroundTruthDetector
from insulator_rs.sim.sensors import SimulatedSensors, kinematic_true_pose
from insulator_rs.sim.towers import load_tower


def test_the_status_strings_are_summary_jsons():
    assert str(RunOutcome()) == "running"
    assert str(RunOutcome(RunStatus.FINISHED)) == "finished"
    assert str(RunOutcome(RunStatus.INTERRUPTED)) == "interrupted"
    assert str(RunOutcome(RunStatus.ABORTED, "sensor lost: no camera frame for 10 s")) == \
        "aborted: sensor lost: no camera frame for 10 s"
    assert str(RunOutcome("refused_preflight", "battery: charge 27%")) == "refused_preflight: battery: charge 27%"
    with pytest.raises(ValueError, match="'landed'"):
        RunOutcome("landed")


def test_a_status_string_reads_back_as_its_enum():
    for outcome in (RunOutcome(RunStatus.FINISHED), RunOutcome(RunStatus.FAILED, "ValueError: x: y"),
                    RunOutcome(RunStatus.ABORTED, "planning failed: boxed in; held for the pilot: no route")):
        assert RunOutcome.parse(str(outcome)) == outcome
    with pytest.raises(ValueError, match="'finished, mostly'"):
        RunOutcome.parse("finished, mostly")


def test_only_an_abort_or_a_refusal_is_unsuccessful():
    bad = {s for s in RunStatus if RunOutcome(s).unsuccessful}
    assert bad == {RunStatus.ABORTED, RunStatus.REFUSED_PREFLIGHT}


ORIGIN = GeoPoint(47.0, 8.0, 500.0)


def _assembly(aborted, route=None, handed_over=None, left=None):
    parts = dict.fromkeys(SummaryAssembly.__dataclass_fields__)
    parts.update(sm=SimpleNamespace(aborted=aborted), origin=ORIGIN,
                 exit=SimpleNamespace(route=route, handed_over=handed_over, left=left))
    return SummaryAssembly(**parts)


def test_no_abort_no_record():
    assert _assembly(None).abort_record("whatever", 0.0) is None


def test_the_abort_record_places_the_landing_point_in_wgs84():
    landing = np.array([12.0, -30.0, 0.5])
    legs = (np.array([[0.0, 0.0, 10.0], [12.0, -30.0, 10.0]]), np.array([[12.0, -30.0, 10.0], landing]))
    route = AbortRoute(AbortCase.DESCEND, legs, landing, -1)
    left = {"insulators_uninspected": [2]}
    record = _assembly(AbortContext("battery reserve", 130.0, -1, None), route, None, left).abort_record(None, 100.0)
    assert record["reason"] == "battery reserve" and record["time_s"] == pytest.approx(30.0)
    lat, lon, alt = pymap3d.enu2geodetic(*landing, ORIGIN.lat, ORIGIN.lon, ORIGIN.alt)
    assert record["landing_wgs84"] == pytest.approx([lat, lon, alt], abs=1e-9)
    assert record["route"] == AbortCase.DESCEND.value and record["side"] == -1
    assert record["landing_point"] == landing.tolist() and record["legs"] == [leg.tolist() for leg in legs]
    assert record["left"] == left and record["handed_over"] is None


def test_a_hand_over_has_no_landing_point_and_the_loops_reason_wins():
    ctx = AbortContext("planning failed", 50.0, 1, None)
    record = _assembly(ctx, None, "no safe route to land").abort_record("planning failed; landing command failed", 0.0)
    assert record["reason"] == "planning failed; landing command failed"
    assert record["handed_over"] == "no safe route to land"
    assert record["landing_point"] is None and record["landing_wgs84"] is None and record["legs"] == []


def test_a_loop_not_flown_reports_running_and_an_abort_by_its_enum(tmp_path):
    scene, mission_path = small_scene(tmp_path)
    mission = load_mission(mission_path)
    rig = simulator_rig()
    vehicle = kinematic_vehicle(mission, 0)
    sensors = SimulatedSensors(load_tower(str(scene)).mesh, kinematic_true_pose(vehicle), rig, detect_scale=0.2,
                               photo_scale=0.2, seed=0)
    loop = FlightLoop(mission, vehicle, sensors, GroundTruthDetector(sensors, seed=0), tmp_path / "report", rig=rig,
                      settings=FlightSettings(quiet=True), photo_camera=sensors.photo_model)
    s = loop.summary().as_dict()
    assert s["status"] == "running" and s["state"] == "idle" and s["abort"] is None
    assert s["insulators_found"] == 0 and s["photos"] == [] and s["second_looks"] == []
    assert s["obstacle_map"]["enabled"] and s["obstacle_map"]["legs_bent"] == 0
    assert s["px4_parameters"] is None and s["preflight"] is None  # the in-process vehicle has none
    loop.outcome = RunOutcome(RunStatus.INTERRUPTED)
    assert loop.summary().status == loop.status == "interrupted"
    summary = loop.finish_report()
    assert summary["status"] == "interrupted"
    assert (tmp_path / "report" / "summary.json").is_file()
