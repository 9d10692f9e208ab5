"""An abort is a safe path, then a landing: never a descent through the tower or the conductors.

Tower B in the in-process simulator, the flight cut by ``--max-flight-time`` at moments of the
flight: in the top crossing (at 25 %, 50 % and 75 % of the time spent over the tower's
footprint, from a full flight measured once: over it from 237.7 s to 251.0 s) and during the
inspection visits of two insulators (one on each side). The reference is the scene's geometry,
independent of the planner: the mission's safety box and conductor corridors, rebuilt here from
the mission file, and the footprint of each (its outline seen from above, where a descent would
go into the boxes). From ``trajectory.csv``: after the abort no sample is inside a box, the
altitude never falls while over a footprint, the vehicle lands clear of every footprint, on its
side, and the summary names the reason and the landing point.

Beside the flights: the planner's cases on tower B's volumes, a property test over positions
round the tower (hypothesis, derandomized in CI), and the case with no route: the vehicle holds
in the autopilot's HOLD, the pilot gets a STATUSTEXT, and nothing descends.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from helpers.reference_safety import footprint_distance, inside_any
from helpers.statustexts import Statustexts
from pymavlink.dialects.v20 import common as M

from insulator_rs.app import inspect_command
from insulator_rs.app.cli import main
from insulator_rs.exceptions import PlanningError
from insulator_rs.flight.loop import FlightLoop, FlightSettings
from insulator_rs.mavlink.gcs import MavlinkGcsObserver
from insulator_rs.mission.config import load_mission
from insulator_rs.planning.abort import LANDING_CLEARANCE, AbortCase, plan_abort_route
from insulator_rs.planning.safety import SafetyVolumes, safety_volumes
from insulator_rs.sim.ground_truth_detector import GroundTruthDetector
from insulator_rs.rig import simulator_rig
from insulator_rs.sim.sensors import SimulatedSensors, kinematic_true_pose
from insulator_rs.sim.towers import load_tower

MISSION = inspect_command.MISSIONS_DIR / "tower_b.toml"
ARGS = ["--scene", "tower_b", "--detect-scale", "0.2", "--photo-scale", "0.2", "--quiet", "--detector", "standin"]
# s of flight: the top crossing is over the tower's footprint from 237.7 s to 251.0 s
CROSSING = {"25 %": 241.0, "50 %": 244.4, "75 %": 247.7}
# s of flight, inside the two visits (seed 0, this ARGS): take-off side 54.1-79.5 s, far side
# 272.9-299.8 s (session 16: the centres reported on the strings' axes and the shots aimed at the
# registry's centre; before, 54.0-79.3 and 302.8-325.3 s; the timeline moves with the flight, and
# the test asserts the cut fell in a visit)
ARM_VISITS = {"insulator 1 (take-off side)": 70.0, "insulator 3 (far side)": 286.0}
Z_TOLERANCE = 0.02  # m: the trajectory's rounding (mm) and the vehicle's tracking, level flight


def reference_volumes() -> SafetyVolumes:
    """The mission's boxes, from its own fields (tower at the W origin, the neighbours' line)."""
    m = load_mission(MISSION)
    return safety_volumes(m.line(), max_width=m.max_width, max_height=m.max_height,
                          margin=m.inspection.safety_margin)


def lateral_side(points: np.ndarray) -> np.ndarray:
    line = load_mission(MISSION).line()
    return np.sign(points[:, :2] @ line.lateral[:2])


def fly_cut(tmp_path, cut: float) -> tuple[dict, np.ndarray, list[str]]:
    out = tmp_path / "report"
    rc = main(["inspect", *ARGS, "--out", str(out), "--max-flight-time", str(cut)])
    assert rc == 1  # aborted
    summary = json.loads((out / "summary.json").read_text())
    with (out / "trajectory.csv").open() as f:
        rows = list(csv.reader(f))[1:]
    traj = np.array([[float(x) for x in r[:4]] for r in rows])
    return summary, traj, [r[5] for r in rows]


def check_safe_abort(summary: dict, traj: np.ndarray, states: list[str], cut: float) -> np.ndarray:
    """The checks every cut shares; returns the samples after the abort."""
    vol = reference_volumes()
    after = np.array([s == "abort" for s in states])
    assert after.any() and np.all(after[np.argmax(after):]), "the abort comes once and lasts"
    a = traj[after]
    assert a[0, 0] == pytest.approx(cut, abs=0.2)
    pts = a[:, 1:4]
    assert not inside_any(vol, pts).any(), f"{inside_any(vol, pts).sum()} samples inside a safety volume"
    over = footprint_distance(vol, pts) <= 0.0
    if over.any():  # never lower while over a footprint
        z = pts[over, 2]
        assert np.all(z >= np.maximum.accumulate(z) - Z_TOLERANCE), \
            f"descends by {np.max(np.maximum.accumulate(z) - z):.3f} m over the tower"
    assert pts[-1, 2] < 0.1, "it lands"
    assert footprint_distance(vol, pts[-1:])[0] >= LANDING_CLEARANCE - 0.1
    ab = summary["abort"]
    assert summary["status"] == f"aborted: flight time limit of {cut:.0f} s"
    assert ab["reason"] == f"flight time limit of {cut:.0f} s" and ab["handed_over"] is None
    assert np.linalg.norm(np.array(ab["landing_point"])[:2] - pts[-1, :2]) < 0.5, "landed where it says"
    return a


@pytest.mark.slow
@pytest.mark.parametrize("moment", list(CROSSING))
def test_an_abort_in_the_top_crossing_crosses_on_and_lands_clear(tmp_path, moment):
    cut = CROSSING[moment]
    summary, traj, states = fly_cut(tmp_path, cut)
    a = check_safe_abort(summary, traj, states, cut)
    vol = reference_volumes()
    assert footprint_distance(vol, a[:1, 1:4])[0] == 0.0, "the cut came over the tower"
    assert summary["abort"]["route"] == AbortCase.CROSS_ON.value
    # on across to the side the crossing was heading for (the take-off side is the first)
    takeoff_side = lateral_side(traj[:1, 1:4])[0]
    assert lateral_side(a[-1:, 1:4])[0] == -takeoff_side == summary["abort"]["side"]


@pytest.mark.slow
@pytest.mark.parametrize("visit", list(ARM_VISITS))
def test_an_abort_beside_an_arm_backs_out_the_way_it_came(tmp_path, visit):
    cut = ARM_VISITS[visit]
    summary, traj, states = fly_cut(tmp_path, cut)
    i = int(np.argmax([s == "abort" for s in states]))
    assert states[i - 1] == "inspect", "the cut came in an inspection visit"
    a = check_safe_abort(summary, traj, states, cut)
    assert summary["abort"]["route"] == AbortCase.BACK_OUT.value
    # the landing is further from the tower than the vehicle was, on its side
    vol = reference_volumes()
    assert footprint_distance(vol, a[-1:, 1:4])[0] > footprint_distance(vol, a[:1, 1:4])[0]
    assert lateral_side(a[-1:, 1:4])[0] == lateral_side(a[:1, 1:4])[0]


# -- the planner's cases (cheap) --------------------------------------------------------------
LINE = load_mission(MISSION).line()
VOL = reference_volumes()
PLAN = {"ground_z": 0.0, "land_height": 2.0, "crossing_clearance": 3.0}


def _descent_checks(start: np.ndarray, route) -> None:
    pts = np.vstack([start, *[leg[1] for leg in route.legs]]) if route.legs else start[None]
    for leg in route.legs:
        s = np.linspace(0.0, 1.0, 200)[:, None]
        samples = leg[0] + s * (leg[1] - leg[0])
        assert not inside_any(VOL, samples).any()
        over = footprint_distance(VOL, samples) <= 0.0
        if over.any():
            assert leg[1, 2] >= leg[0, 2] - 1e-9, "no leg descends over a footprint"
    assert footprint_distance(VOL, route.landing[None])[0] >= LANDING_CLEARANCE - 1e-6
    assert np.allclose(pts[-1, :2], route.landing[:2])
    assert route.landing[2] == 0.0


def test_over_the_tower_it_climbs_to_the_crossing_height_and_goes_on_across():
    p = LINE.to_world(np.array([0.0, 1.0, VOL.top + 1.0]))  # low over the tower
    r = plan_abort_route(LINE, VOL, p, toward_side=-1, back_to=None, **PLAN)
    assert r.case == AbortCase.CROSS_ON and r.side == -1
    assert r.legs[0][1, 2] == pytest.approx(VOL.top + 3.0) and np.allclose(r.legs[0][1, :2], p[:2])
    _descent_checks(p, r)


def test_beside_an_arm_it_backs_out_to_where_the_detour_began():
    p = LINE.to_world(np.array([0.0, -7.5, 16.0]))  # 1 m from the box's side
    back = LINE.to_world(np.array([3.0, -14.5, 16.0]))
    r = plan_abort_route(LINE, VOL, p, toward_side=-1, back_to=back, **PLAN)
    assert r.case == AbortCase.BACK_OUT and np.allclose(r.legs[0][1], back)
    _descent_checks(p, r)
    r = plan_abort_route(LINE, VOL, p, toward_side=-1, back_to=None, **PLAN)  # nowhere to go back to
    assert r.case == AbortCase.STEP_OUT
    _descent_checks(p, r)


def test_inside_a_volume_there_is_no_route():
    with pytest.raises(PlanningError, match="inside a safety volume"):
        plan_abort_route(LINE, VOL, np.array([0.0, 0.0, 10.0]), toward_side=1, back_to=None, **PLAN)


@given(a=st.floats(-40.0, 40.0), lat=st.floats(-30.0, 30.0), z=st.floats(3.0, 45.0),
       toward=st.sampled_from([-1, 1]))
@example(a=-0.015625, lat=0.0, z=31.0, toward=1)  # found by CI: the way off at 2.0 m read 1.9999999999999982
def test_every_route_it_plans_stays_clear_and_never_descends_over_the_tower(a, lat, z, toward):
    p = LINE.to_world(np.array([a, lat, z]))
    try:
        r = plan_abort_route(LINE, VOL, p, toward_side=toward, back_to=None, **PLAN)
    except PlanningError:
        assert inside_any(VOL, p[None])[0], "a route is refused only from inside a volume"
        return
    _descent_checks(p, r)
    if footprint_distance(VOL, p[None])[0] > 0.0:  # beside the tower: it lands on its side
        assert lateral_side(r.landing[None])[0] == lateral_side(p[None])[0]


# -- no route: hold, tell the pilot, never descend -------------------------------------------
@pytest.mark.slow
def test_with_no_route_it_holds_and_hands_over_without_descending(tmp_path):
    """The position estimate jumps into the tower's safety box (a GPS glitch) just before the
    flight-time limit: no route out can be planned from there, so the vehicle holds in HOLD,
    the pilot gets an ALERT STATUSTEXT, and it does not come down."""
    mission = load_mission(MISSION)
    tower = load_tower("tower_b")
    vehicle = inspect_command.kinematic_vehicle(mission, 0)
    rig = simulator_rig()
    sensors = SimulatedSensors(tower.mesh, kinematic_true_pose(vehicle), rig, detect_scale=0.2,
                               photo_scale=0.2, seed=0)
    sink = Statustexts()
    gcs = MavlinkGcsObserver(sink, system_id=1)
    cut = 30.0
    advance = vehicle.advance
    glitched = []

    def glitching(dt):
        st = advance(dt)
        if st.time - loop.t_start > cut - 0.2 and not glitched:  # reported over the tower axis
            glitched.append(st.time)
            vehicle.inject_gps_glitch(np.array([-st.position[0], -st.position[1], 0.0]))
        return st

    vehicle.advance = glitching
    loop = FlightLoop(mission, vehicle, sensors, GroundTruthDetector(sensors, seed=0), tmp_path / "report", rig=rig,
                      settings=FlightSettings(max_flight_time=cut, quiet=True), observer=gcs,
                      photo_camera=sensors.photo_model)
    loop.fly()
    summary = loop.finish_report()
    z_abort = vehicle.true_pose_at(vehicle.state().time)[2, 3]
    assert summary["status"].startswith(f"aborted: flight time limit of {cut:.0f} s; held for the pilot: "
                                        "no safe route to land")
    assert summary["abort"]["handed_over"] and summary["abort"]["landing_point"] is None
    assert vehicle.mode.value == "HOLD" and not vehicle.landed
    for _ in range(200):  # 10 s more in the autopilot's HOLD
        advance(0.05)
    assert vehicle.true_pose_at(vehicle.state().time)[2, 3] == pytest.approx(z_abort, abs=0.3), "no descent"
    alerts = [t for sev, t in sink.texts if sev == M.MAV_SEVERITY_ALERT]
    assert alerts and alerts[0].startswith("HOLD, take over: no safe route"), sink.texts
    assert math.isfinite(z_abort) and z_abort > 2.0


@pytest.mark.slow
def test_low_battery_aborts_by_the_safe_route_and_lands(tmp_path, monkeypatch):
    """The battery falls below the mission's reserve mid-flight (small scene; a charge that
    jumps down, faster than any fit: the reserve itself is the last check): the abort names it,
    flies its route out and lands clear of the small scene's volumes. The planned return before
    the reserve: tests/test_battery_reserve.py."""
    from helpers.flights import small_scene

    from insulator_rs.mission.geometry import MissionGeometry

    made = []
    original = inspect_command.kinematic_vehicle

    def draining(mission, seed):
        v = original(mission, seed)
        advance = v.advance

        def step(dt):
            st = advance(dt)
            if st.time > 20.0:
                v.battery_fraction = 0.2  # below the reserve, above PX4's critical level
            return st

        v.advance = step
        made.append(v)
        return v

    monkeypatch.setattr(inspect_command, "kinematic_vehicle", draining)
    scene, mission_file = small_scene(tmp_path)
    out = tmp_path / "report"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission_file), "--out", str(out),
               "--detect-scale", "0.2", "--photo-scale", "0.2", "--quiet", "--detector", "standin"])
    s = json.loads((out / "summary.json").read_text())
    reserve = load_mission(mission_file).inspection.battery_reserve
    assert rc == 1 and s["status"] == f"aborted: battery at the reserve (20%, reserve {reserve:.0%})", s["status"]
    assert s["abort"]["route"] is not None and s["abort"]["handed_over"] is None
    assert made[0].landed and s["failsafe"] is None
    vol = MissionGeometry.from_mission(load_mission(mission_file)).volumes
    with (out / "trajectory.csv").open() as f:
        rows = [r for r in list(csv.reader(f))[1:] if r[5] == "abort"]
    pts = np.array([[float(x) for x in r[1:4]] for r in rows])
    assert not inside_any(vol, pts).any() and footprint_distance(vol, pts[-1:])[0] >= LANDING_CLEARANCE - 0.1
