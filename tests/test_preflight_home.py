"""The pre-flight knows where the vehicle stands (flight/preflight.py ``home``, flight/home.py).

A vehicle whose home (PX4's HOME_POSITION, here our simulated PX4's over UDP) is 13 m from the
mission's take-off point is refused before the arm command, the message naming both points and
the distance; the same vehicle with ``takeoff = "home"`` in the mission flies the small scene to
the end, taking off, planning its ground and landing from where it stands. The mission file's
``takeoff = "home"`` is parsed, and anything else there refused, naming the key.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from helpers.flights import ARGS, small_scene

from insulator_rs._toml import tomllib
from insulator_rs.app import inspect_command
from insulator_rs.app.cli import main
from insulator_rs.exceptions import ConfigError
from insulator_rs.flight.home import at_vehicle_home, vehicle_home
from insulator_rs.flight.preflight import HOME_MAX_DISTANCE, HOME_MAX_HEIGHT_OFF, Check, Outcome, check_home
from insulator_rs.geodesy import gps_to_enu
from insulator_rs.mission.config import load_mission, parse_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.sim.kinematics import KinematicVehicle
from insulator_rs.sim.px4 import SimulatedPx4, start_simulated_px4

AWAY = 13.0  # m the vehicle stands from the mission's take-off point (the SITL case)
ARM = "MAV_CMD_COMPONENT_ARM_DISARM"


def _away_from_takeoff(mission_path: Path, distance: float = AWAY, up: float = 0.0) -> np.ndarray:
    """A point ``distance`` m from the mission's take-off point, straight out from the line (away
    from the tower and the conductors), ``up`` m higher."""
    mission = load_mission(mission_path)
    takeoff = MissionGeometry.from_mission(mission).takeoff
    out = mission.line().lateral * mission.line().side(takeoff)
    return takeoff + distance * out / np.linalg.norm(out[:2]) + np.array([0.0, 0.0, up])


def _with_home_takeoff(mission_path: Path) -> Path:
    home = mission_path.with_name("home_mission.toml")
    home.write_text('takeoff = "home"\n' + mission_path.read_text())
    return home


# -- the mission file ------------------------------------------------------------------------------

def test_takeoff_home_is_parsed_and_anything_else_is_refused_naming_the_key(tmp_path):
    _, mission_path = small_scene(tmp_path)
    m = load_mission(_with_home_takeoff(mission_path))
    assert m.takeoff_home and m.takeoff is None
    plain = load_mission(mission_path)
    assert not plain.takeoff_home
    assert np.allclose(m.takeoff_enu(), plain.takeoff_enu())  # before the home is known: the default point
    data = tomllib.loads(mission_path.read_text())
    for bad in ("there", 5, ["home"]):
        with pytest.raises(ConfigError, match=r'takeoff: expected a table \(lat, lon, alt\) or "home"'):
            parse_mission({**data, "takeoff": bad}, "m.toml")


def test_a_home_far_from_the_tower_is_refused_naming_takeoff(tmp_path):
    _, mission_path = small_scene(tmp_path)
    m = load_mission(_with_home_takeoff(mission_path))
    far = KinematicVehicle(start_position=[600.0, 0.0, 0.0])  # beyond bounds.TAKEOFF_DISTANCE
    with pytest.raises(ConfigError, match=r'takeoff \("home"\): horizontal distance from the tower'):
        at_vehicle_home(m, far)


# -- the check against our simulated PX4's HOME_POSITION -------------------------------------------

def _px4_standing_at(position: np.ndarray, mission_path: Path):
    mission = load_mission(mission_path)
    tower = mission.tower
    return mission, start_simulated_px4(sim_options={
        "vehicle": KinematicVehicle(start_position=position), "origin": (tower.lat, tower.lon, tower.alt)})


@pytest.mark.parametrize("distance, up, passes", [(AWAY, 0.0, False), (0.5 * HOME_MAX_DISTANCE, 0.0, True),
                                                  (0.0, 1.5 * HOME_MAX_HEIGHT_OFF, False),
                                                  (0.0, -0.5 * HOME_MAX_HEIGHT_OFF, True)])
def test_the_home_check_against_px4s_home_position(tmp_path, distance, up, passes):
    _, mission_path = small_scene(tmp_path)
    where = _away_from_takeoff(mission_path, distance, up)
    mission, (sim, vehicle) = _px4_standing_at(where, mission_path)
    try:
        takeoff = MissionGeometry.from_mission(mission).takeoff
        home = vehicle_home(vehicle, mission.tower)
        result = check_home(vehicle, takeoff, mission.tower)
    finally:
        vehicle.close()
    assert home is not None and "HOME_POSITION" in home.source
    # the home read over MAVLink is where the simulated airframe stands (pymap3d both ways: mm)
    assert np.allclose(home.local, where, atol=0.01)
    assert np.allclose(gps_to_enu(home.gps, mission.tower), where, atol=0.01)
    assert result.check == Check.HOME
    assert result.outcome == (Outcome.PASSED if passes else Outcome.FAILED), result
    assert f"is {distance:.1f} m across and {up:+.1f} m in height from the mission's take-off point" in result.reason
    assert f"W [{where[0]:.1f}, {where[1]:.1f}, {where[2]:.1f}]" in result.reason  # both points, local ...
    assert f"W [{takeoff[0]:.1f}, {takeoff[1]:.1f}, {takeoff[2]:.1f}]" in result.reason
    assert f"{home.gps.lat:.7f} {home.gps.lon:.7f}" in result.reason  # ... and GPS
    if not passes:
        assert 'takeoff = "home"' in result.reason


def test_the_in_process_vehicle_is_checked_where_it_stands(tmp_path):
    _, mission_path = small_scene(tmp_path)
    mission = load_mission(mission_path)
    takeoff = MissionGeometry.from_mission(mission).takeoff
    result = check_home(KinematicVehicle(start_position=_away_from_takeoff(mission_path)), takeoff, mission.tower)
    assert result.outcome == Outcome.FAILED and "in-process vehicle's position" in result.reason
    assert f"is {AWAY:.1f} m across" in result.reason


# -- whole runs: refused before arming; flown from home ---------------------------------------------

def _standing_away(monkeypatch, mission_path: Path) -> tuple[np.ndarray, list[SimulatedPx4], list]:
    """The command line's simulated airframe set down 13 m from the take-off point; the simulated
    PX4s started and the flight loops built are recorded."""
    where = _away_from_takeoff(mission_path)
    original = inspect_command.kinematic_vehicle

    def set_down_away(mission, seed):
        v = original(mission, seed)
        return KinematicVehicle(start_position=where, start_yaw=v.model.yaw, seed=seed, limits=v.model.limits)

    monkeypatch.setattr(inspect_command, "kinematic_vehicle", set_down_away)
    sims: list[SimulatedPx4] = []
    start = SimulatedPx4.start
    monkeypatch.setattr(SimulatedPx4, "start", lambda self: (sims.append(self), start(self))[1])
    loops: list = []
    assemble = inspect_command.assemble_flight
    monkeypatch.setattr(inspect_command, "assemble_flight",
                        lambda *a, **k: (lambda f: (loops.append(f.loop), f)[1])(assemble(*a, **k)))
    return where, sims, loops


@pytest.mark.slow
def test_a_vehicle_13_m_from_the_takeoff_point_is_refused_before_arming(tmp_path, monkeypatch, capsys):
    scene, mission_path = small_scene(tmp_path)
    where, sims, _ = _standing_away(monkeypatch, mission_path)
    out = tmp_path / "report"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission_path), "--out", str(out),
               "--vehicle", "mavlink", "--time-scale", "4", *[a for a in ARGS if a != "--quiet"]])
    captured = capsys.readouterr()
    s = json.loads((out / "summary.json").read_text())
    assert rc == 1 and s["status"].startswith("refused_preflight: home: the autopilot's home (HOME_POSITION) at ")
    assert f"is {AWAY:.1f} m across and +0.0 m in height from the mission's take-off point" in s["status"]
    assert [c["name"] for c in s["preflight"]["checks"] if c["outcome"] == "failed"] == ["home"]
    assert f"{AWAY:.1f} m across" in captured.out and "Traceback" not in captured.out + captured.err
    (sim,) = sims
    assert ARM not in sim.stats.commands  # refused before the arm command
    assert not sim.with_vehicle(lambda v: v.armed)
    assert sim.with_vehicle(lambda v: np.allclose(v.model.position, where))


@pytest.mark.slow
def test_with_takeoff_home_the_same_vehicle_flies_the_small_scene_to_the_end(tmp_path, monkeypatch):
    scene, mission_path = small_scene(tmp_path)
    where, sims, loops = _standing_away(monkeypatch, mission_path)
    out = tmp_path / "report"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(_with_home_takeoff(mission_path)),
               "--out", str(out), "--vehicle", "mavlink", "--time-scale", "4", *ARGS])
    s = json.loads((out / "summary.json").read_text())
    assert rc == 0 and s["status"] == "finished", s["status"]
    assert s["insulators_found"] == 2 and s["insulators_inspected"] == 2
    home_check = next(c for c in s["preflight"]["checks"] if c["name"] == "home")
    assert home_check["outcome"] == "passed" and "is 0.0 m across" in home_check["reason"]
    (loop,) = loops
    # everything planned from where the vehicle stands: the take-off and landing point, the ground
    # the obstacle map leaves out
    assert np.allclose(loop.geom.takeoff, where, atol=0.01)
    assert loop.geom.path[0].position == pytest.approx(where, abs=0.01)
    assert loop.geom.path[-1].position == pytest.approx(where, abs=0.01)
    assert loop.legs.obstacles is not None and loop.legs.obstacles.ground_z == pytest.approx(where[2], abs=0.01)
    with (out / "trajectory.csv").open() as f:
        rows = [[float(x) for x in r[1:4]] for r in list(csv.reader(f))[1:]]
    assert np.linalg.norm(np.array(rows[0][:2]) - where[:2]) < 0.5  # took off where it stood
    assert np.linalg.norm(np.array(rows[-1][:2]) - where[:2]) < 0.5 and rows[-1][2] < where[2] + 0.1  # landed there
    assert sims[0].with_vehicle(lambda v: v.landed)


@pytest.mark.slow
def test_a_home_takeoff_flight_replays_from_where_it_took_off(tmp_path, monkeypatch):
    """Record -> replay with ``takeoff = "home"``: the in-process vehicle set down 13 m from the
    mission's default take-off point flies a short recorded flight (its home is where it stands);
    the replay, from the recorded mission and from the same mission file given again, plans from
    that point, not from the default one. Reference: the position the vehicle was set down at."""
    from insulator_rs.recording.metadata import read_metadata
    from insulator_rs.replay import run as replay_run
    from insulator_rs.replay.batch import ReplayOptions, replay_one

    scene, mission_path = small_scene(tmp_path)
    home_mission = _with_home_takeoff(mission_path)
    where, _, loops = _standing_away(monkeypatch, mission_path)
    recording = tmp_path / "flight.mcap"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(home_mission), "--out", str(tmp_path / "report"),
               "--record", str(recording), "--max-flight-time", "20", *ARGS])
    assert rc in (0, 1)
    (loop,) = loops
    assert np.allclose(loop.geom.takeoff, where, atol=0.01)  # the flight planned from where it stood
    default = MissionGeometry.from_mission(load_mission(mission_path)).takeoff
    assert np.linalg.norm(default - where) == pytest.approx(AWAY, abs=0.01)
    meta = read_metadata(recording)
    recorded = meta.mission(recording)
    assert recorded is not None and np.allclose(recorded.takeoff_enu(), where, atol=0.01)
    planned: list[np.ndarray] = []

    class Watched(replay_run.ReplayRun):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            planned.append(self.geom.takeoff)

    monkeypatch.setattr(replay_run, "ReplayRun", Watched)
    for name, options in (("recorded", ReplayOptions()), ("given", ReplayOptions(mission=str(home_mission)))):
        summary = replay_one(recording, tmp_path / f"replay_{name}", options)
        assert not summary["status"].startswith("failed"), summary["status"]
    assert len(planned) == 2 and all(np.allclose(p, where, atol=0.01) for p in planned)
