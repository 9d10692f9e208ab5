"""The battery reserve (issue 19, item 3): read the charge, fit the consumption, come back in time.

References, never the code under test: the simulated airframe's own pack (``sim/kinematics.py``:
its drain parameters and its charge, the simulator's truth) against the fit and the reserve at
landing; hand-made MAVLink messages against the adapter's reading; a synthetic pack of known
rates against the least-squares fit. PX4 SIH's own battery: ``test_px4_sitl_battery.py``.
"""

from __future__ import annotations

import copy
import csv
import json

import numpy as np
import pytest
from helpers.mission_files import GOOD_MISSION
from helpers.flights import ARGS, small_scene
from helpers.reference_safety import footprint_distance, inside_any

from insulator_rs.app import inspect_command
from insulator_rs.app.cli import main
from insulator_rs.exceptions import ConfigError
from insulator_rs.flight.reserve import BatteryReserve
from insulator_rs.mavlink.telemetry import TelemetryStore
from insulator_rs.mavlink.wire import mavlink2 as M
from insulator_rs.mission.config import load_mission, parse_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.planning.abort import LANDING_CLEARANCE
from insulator_rs.planning.energy import MIN_FIT_DROP, fit_consumption, route_demand
from insulator_rs.ports.vehicle import VehicleState
from insulator_rs.sim.kinematics import AutopilotParameters, KinematicVehicle

TRUTH = AutopilotParameters()  # the simulated pack's drain (the airframe every flight here flies)


# -- the fit --------------------------------------------------------------------------------

def _synthetic_flight(per_s: float, per_m: float, start: float, quantise: bool):
    """A 300 s flight at 1 Hz: passes at 1 m/s, photo stops (hover), a 2 m/s transit; the pack
    drains at the given rates; the reading in whole percents when ``quantise`` (MAVLink)."""
    t = np.arange(0.0, 300.0, 1.0)
    speed = np.where((t % 60) < 45, 1.0, 0.0)  # 45 s of pass, 15 s of photo stop
    speed[t > 240] = 2.0
    d = np.concatenate([[0.0], np.cumsum(speed[:-1])])
    f = start - per_s * t - per_m * d
    return t, d, (np.round(f * 100) / 100 if quantise else f)


def test_fit_recovers_the_rates_of_a_known_pack():
    """Reference: the synthetic pack's own rates. Exact readings: 1e-9 relative; MAVLink's whole
    percents: the per-second rate within 3 %, the prediction of the next 100 s within 0.01."""
    t, d, f = _synthetic_flight(1 / 1500, 5e-5, 0.93, quantise=False)
    fit = fit_consumption(t, d, f)
    assert fit is not None
    assert fit.per_s == pytest.approx(1 / 1500, rel=1e-9) and fit.per_m == pytest.approx(5e-5, rel=1e-6)
    assert fit.start == pytest.approx(0.93) and fit.rms < 1e-12
    t, d, f = _synthetic_flight(1 / 1500, 5e-5, 0.93, quantise=True)
    fit = fit_consumption(t, d, f)
    assert fit is not None and fit.per_s == pytest.approx(1 / 1500, rel=0.03)
    assert fit.consumed(100.0, 80.0) == pytest.approx(100 / 1500 + 80 * 5e-5, abs=0.01)


def test_fit_waits_for_enough_flight_and_keeps_rates_non_negative():
    t, d, f = _synthetic_flight(1 / 1500, 5e-5, 0.9, quantise=True)
    assert fit_consumption(t[:15], d[:15], f[:15]) is None  # 15 s: no rate yet
    n = int(np.argmax(f[0] - f >= MIN_FIT_DROP - 1e-12)) + 1  # the first reading two steps down
    assert fit_consumption(t[:n], d[:n], f[:n]) is not None
    # a pack that only drains with time, flown at one speed: time and distance cannot be told
    # apart; neither rate may go negative (energy back for flying further)
    t = np.arange(0.0, 120.0)
    fit = fit_consumption(t, 1.5 * t, 0.8 - t / 600)
    assert fit is not None and fit.per_s >= 0 and fit.per_m >= 0
    assert fit.consumed(60.0, 90.0) == pytest.approx(0.1, rel=1e-6)
    with pytest.raises(ValueError, match="time_s, distance_m and fraction"):
        fit_consumption(t, t[:-1], t)


def test_route_demand_is_rest_to_rest_plus_stops():
    pts = np.array([[0.0, 0.0, 5.0], [10.0, 0.0, 5.0], [10.0, 0.0, 1.0]])
    dem = route_demand(pts, np.array([1.0, 1.0, 1.0]), np.array([3.0, 3.0, 3.0]), stops=2, stop_time=8.0)
    # 10 m at 1 m/s, 3 m/s^2: 10 + 1/3 s; 4 m: 4 + 1/3 s; two 8 s stops
    assert dem.distance_m == pytest.approx(14.0) and dem.time_s == pytest.approx(14 + 2 / 3 + 16)


# -- reading the charge -----------------------------------------------------------------------

def _sys_status(remaining: int):
    return M.MAVLink_sys_status_message(0, 0, 0, 200, 16000, -1, remaining, 0, 0, 0, 0, 0, 0)


def _battery_status(remaining: int, battery_id: int = 0):
    return M.MAVLink_battery_status_message(battery_id, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 2500,
                                            [16000] + [65535] * 9, -1, -1, -1, remaining)


def test_mavlink_charge_unknown_until_told_and_minus_one_is_unknown():
    """Reference: MAVLink's definition of battery_remaining (0-100 %, -1: not known)."""
    store = TelemetryStore()
    assert store.battery is None  # nothing read yet is not a full pack
    store.update(_battery_status(73), 0.0)
    assert store.battery == pytest.approx(0.73)
    store.update(_sys_status(72), 1.0)
    assert store.battery == pytest.approx(0.72)
    store.update(_battery_status(-1), 2.0)
    assert store.battery is None  # PX4 lost its estimate: unknown again, not the old value


def test_mavlink_out_of_range_charge_is_dropped_and_counted():
    store = TelemetryStore()
    store.update(_battery_status(60), 0.0)
    for bad in (101, 127, -2, -128):  # int8 values no battery monitor sends
        store.update(_battery_status(bad), 1.0)
        store.update(_sys_status(bad), 1.0)
    assert store.battery == pytest.approx(0.60) and store.battery_rejected == 8
    store.update(_battery_status(10, battery_id=1), 2.0)  # a second battery: not the flight pack
    assert store.battery == pytest.approx(0.60)


def test_simulated_px4_sends_battery_remaining_as_px4_does():
    """Our simulated PX4 rounds the charge to whole percents and sends -1 (and UINT16_MAX volts)
    without a battery monitor, on both BATTERY_STATUS and SYS_STATUS."""
    from insulator_rs.sim.px4 import SimulatedPx4

    vehicle = KinematicVehicle()
    sim = SimulatedPx4(vehicle=vehicle)
    vehicle.battery_fraction = 0.456
    assert sim._telemetry("BATTERY_STATUS").battery_remaining == 46
    assert sim._telemetry("SYS_STATUS").battery_remaining == 46
    vehicle.battery_fraction = None
    bs, ss = sim._telemetry("BATTERY_STATUS"), sim._telemetry("SYS_STATUS")
    assert bs.battery_remaining == -1 and ss.battery_remaining == -1
    assert bs.voltages[0] == 65535 and ss.voltage_battery == 65535
    store = TelemetryStore()
    store.update(bs, 0.0)
    assert store.battery is None


# -- the simulated pack -------------------------------------------------------------------------

@pytest.mark.slow
def test_simulated_pack_drains_with_time_and_distance():
    """Reference: the drain law written out (hover power per s plus a term per metre flown)."""
    v = KinematicVehicle(params=AutopilotParameters(battery_drain_per_s=1e-3, battery_drain_per_m=1e-3))
    v.send_setpoint(np.zeros(3))
    v.arm()
    v.start_offboard()
    dt, path = 0.05, 0.0
    for k in range(1200):  # 60 s: 20 s of climb and hover, then 40 s along x
        target = np.array([0.0, 0.0, 5.0]) if k < 400 else np.array([20.0, 0.0, 5.0])
        before = v.model.position.copy()
        v.send_setpoint(target)
        v.advance(dt)
        path += float(np.linalg.norm(v.model.position - before))
    assert path > 20.0
    assert v.battery_fraction == pytest.approx(1.0 - 1e-3 * 60.0 - 1e-3 * path, abs=2e-4)


def test_simulated_pack_is_a_25_minute_hover_class():
    assert 1 / TRUTH.battery_drain_per_s == pytest.approx(1500.0)  # 20-25 min: the class
    assert TRUTH.battery_floor == 0.0  # the whole pack (SIH's 50 % floor would hide the reserve)


# -- the mission setting ----------------------------------------------------------------------------

def test_battery_reserve_is_a_mission_field_with_a_default():
    assert parse_mission(copy.deepcopy(GOOD_MISSION), "m.toml").inspection.battery_reserve == 0.25
    d = copy.deepcopy(GOOD_MISSION)
    d["inspection"]["battery_reserve"] = 0.3
    assert parse_mission(d, "m.toml").inspection.battery_reserve == 0.3


@pytest.mark.parametrize("value, message", [
    (1.5, r"inspection.battery_reserve: must lie in \[0.1, 0.9\] of the pack"),
    (0.02, r"inspection.battery_reserve: must lie in \[0.1, 0.9\]"),
    ("20%", "inspection.battery_reserve: expected a number"),
    (float("nan"), "inspection.battery_reserve: must be finite"),
    (True, "inspection.battery_reserve: expected a number"),
])
def test_bad_battery_reserve_is_named(value, message):
    d = copy.deepcopy(GOOD_MISSION)
    d["inspection"]["battery_reserve"] = value
    with pytest.raises(ConfigError, match=f"^m.toml: {message}"):
        parse_mission(d, "m.toml")


def test_sim_battery_option_is_checked(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["inspect", "--sim-battery", "1.5", "--out", str(tmp_path / "r")])
    assert exit_info.value.code == 2
    assert "argument --sim-battery: must lie in (0, 1] of the pack" in capsys.readouterr().err
    # an outside autopilot has its own pack
    assert main(["inspect", "--sim-battery", "0.5", "--connection", "udpin:127.0.0.1:1", "--sim-sensors",
                 "--out", str(tmp_path / "r")]) == 2
    assert "--sim-battery: sets the charge of our simulated airframe" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


# -- the decision -------------------------------------------------------------------------------------

def _state(t, fraction, x=0.0):
    return VehicleState(time=t, position=np.array([x, 0.0, 5.0]), velocity=np.zeros(3), yaw=0.0, armed=True,
                        mode="OFFBOARD", landed=False, battery_fraction=fraction)


def test_no_charge_no_decision_and_the_report_says_so():
    reserve = BatteryReserve(0.25)
    for k in range(200):
        st = _state(float(k), None)
        reserve.observe(st)
        assert reserve.check(st, float(k), lambda: pytest.fail("no weighing without a charge")) is None
    rec = reserve.record()
    assert rec["known"] is False and "no reserve decision was possible" in rec["note"]
    assert rec["fit"] is None and rec["decision"] is None and rec["unknown_readings"] == 199


def test_the_reserve_itself_sends_the_vehicle_back_before_any_fit():
    reserve = BatteryReserve(0.25)
    reserve.observe(_state(0.0, 0.26))
    st = _state(1.0, 0.25)
    reserve.observe(st)
    assert reserve.check(st, 1.0, lambda: pytest.fail("no fit yet")) == "battery at the reserve (25%, reserve 25%)"


# -- flights -------------------------------------------------------------------------------------------

def _keep_vehicles(monkeypatch, *, monitor: bool = True) -> list[KinematicVehicle]:
    """The simulated airframes the composition root makes (in process or behind the simulated
    PX4), kept for the test to read their pack; ``monitor`` False: no battery monitor."""
    made: list[KinematicVehicle] = []
    original = inspect_command.kinematic_vehicle

    def keep(mission, seed):
        made.append(original(mission, seed))
        if not monitor:
            made[-1].battery_fraction = None
        return made[-1]

    monkeypatch.setattr(inspect_command, "kinematic_vehicle", keep)
    return made


def _fly_small(tmp_path, monkeypatch, charge: float | None, *extra: str):
    """The small scene with the pack at ``charge`` (None: no battery monitor); returns (rc,
    summary, the simulated vehicle, the mission file, the report folder)."""
    made = _keep_vehicles(monkeypatch, monitor=charge is not None)
    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    battery = [] if charge is None else ["--sim-battery", str(charge)]
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS,
               *battery, *extra])
    s = json.loads((out / "summary.json").read_text())
    print(_figures(s, made[0]))
    return rc, s, made[0], mission, out


def _figures(s, vehicle) -> str:
    """One line of what was measured (the test log's record): the fit against the simulator's
    drain, the weighing at the decision, the charge at touchdown."""
    b = s["battery"]
    fit, d = b["fit"], b["decision"]
    line = (f"{s['status'][:40]}: touchdown charge {vehicle.battery_fraction} (reserve {b['reserve']}), "
            f"flight {s['flight_time_s']:.1f} s")
    if fit is not None:
        line += (f", fit per_s {fit['per_s']:.4g} (truth {TRUTH.battery_drain_per_s:.4g}) per_m {fit['per_m']:.4g} "
                 f"(truth {TRUTH.battery_drain_per_m:.4g})")
    if d is not None:
        line += (f"; decision at {d['time_s']:.1f} s: read {d['fraction']:.4f}, available {d['available']:.4f}, "
                 f"finish needs {d['needed_finish']:.4f}, way out {d['needed_return']:.4f}; used after it "
                 f"{d['fraction'] - vehicle.battery_fraction:.4f}; left {s['abort']['left']}")
    return line


@pytest.mark.slow
def test_a_pack_that_cannot_finish_returns_with_the_reserve_intact(tmp_path, monkeypatch):
    """The small scene takes about 0.09 of the pack; from 0.32 with a 0.25 reserve it cannot
    finish. Reference: the simulator's own pack (its charge at touchdown, its drain
    parameters) and the scene's volumes."""
    rc, s, vehicle, mission_file, out = _fly_small(tmp_path, monkeypatch, 0.32)
    b = s["battery"]
    assert rc == 1 and s["status"].startswith("aborted: battery reserve: returning at"), s["status"]
    assert s["abort"]["route"] is not None and s["abort"]["handed_over"] is None and s["failsafe"] is None
    assert vehicle.landed
    # the reserve intact at touchdown, by the simulator's own pack, and not much more left over
    assert 0.25 <= vehicle.battery_fraction < 0.25 + 0.02, vehicle.battery_fraction
    assert b["fraction_last"] == pytest.approx(vehicle.battery_fraction, abs=1e-3)
    # the estimate at the decision against the truth
    d = b["decision"]
    assert d["can_finish"] is False and d["needed_return"] >= d["available"]
    assert d["fit"]["per_s"] == pytest.approx(TRUTH.battery_drain_per_s, rel=0.01)
    assert d["fit"]["per_m"] == pytest.approx(TRUTH.battery_drain_per_m, rel=0.05)
    used_after = d["fraction"] - vehicle.battery_fraction
    assert used_after <= d["needed_return"]  # the way out took no more than was set aside
    # what was left: the report names it
    left = s["abort"]["left"]
    assert left["exploration_waypoints"] > 0 and left["exploration_left_m"] > 0
    assert "came back early, leaving" in (out / "report.html").read_text()  # the crew's page says so
    # the way out is the safe one: clear of the volumes, landed outside the footprints
    vol = MissionGeometry.from_mission(load_mission(mission_file)).volumes
    with (out / "trajectory.csv").open() as f:
        rows = [r for r in list(csv.reader(f))[1:] if r[5] == "abort"]
    pts = np.array([[float(x) for x in r[1:4]] for r in rows])
    assert not inside_any(vol, pts).any() and footprint_distance(vol, pts[-1:])[0] >= LANDING_CLEARANCE - 0.1


@pytest.mark.slow
def test_a_pack_that_can_finish_does_not_return_early(tmp_path, monkeypatch):
    """From 0.40 the small scene (about 0.09) ends above the 0.25 reserve: it must finish."""
    rc, s, vehicle, _, _ = _fly_small(tmp_path, monkeypatch, 0.40)
    assert rc == 0 and s["status"] == "finished", s["status"]
    assert s["abort"] is None and vehicle.battery_fraction > 0.25
    est = s["battery"]["estimate"]
    assert est["can_finish"] is True and s["battery"]["decision"] is None
    assert s["battery"]["fit"]["per_s"] == pytest.approx(TRUTH.battery_drain_per_s, rel=0.01)


@pytest.mark.slow
def test_a_vehicle_without_a_battery_monitor_is_refused_and_says_so(tmp_path, monkeypatch):
    """No charge at all (PX4's -1 through our simulated PX4 over MAVLink): the pre-flight gate
    cannot show that the pack holds the mission, so the flight is refused before arming
    (tests/test_preflight.py), named, no traceback; the reserve's record says no decision was
    possible."""
    rc, s, vehicle, _, _ = _fly_small(tmp_path, monkeypatch, None, "--vehicle", "mavlink", "--time-scale", "4")
    b = s["battery"]
    assert rc == 1 and s["status"].startswith("refused_preflight: battery: the vehicle reports no charge"), s["status"]
    assert [c["name"] for c in s["preflight"]["checks"] if c["outcome"] == "failed"] == ["battery"]
    assert b["known"] is False and "no reserve decision was possible" in b["note"] and b["decision"] is None
    assert s["flight_time_s"] == 0.0 and not vehicle.armed


@pytest.mark.slow
def test_tower_b_returns_in_time(tmp_path, monkeypatch):
    """``insulator-rs inspect --scene tower_b --detector standin``: tower B takes about 0.47 of
    the pack. From 0.6 it cannot finish above the 0.25 reserve: it comes back before the reserve
    is touched (the simulator's charge at touchdown) and says what it left. (That a pack which can
    finish is not called back is the small scene's test above; tower B from a full pack finishing
    is the main job's, which CI flies from the bare wheel.) Reference: the simulator's own pack,
    the scene (score.json)."""
    made = _keep_vehicles(monkeypatch)
    out = tmp_path / "report"
    # photos at 0.2 of the 12 MP camera: the pack and the route do not depend on the JPEGs' size
    # (the sim's clock, not the render's wall time, drains it), and full-size renders made this
    # the slowest test of CI (460 s a case)
    rc = main(["inspect", "--scene", "tower_b", "--detector", "standin", "--quiet", "--out", str(out),
               "--sim-battery", "0.6", "--photo-scale", "0.2"])
    s = json.loads((out / "summary.json").read_text())
    b, vehicle = s["battery"], made[0]
    print(_figures(s, vehicle))
    assert b["fit"]["per_s"] == pytest.approx(TRUTH.battery_drain_per_s, rel=0.01)
    assert b["fit"]["per_m"] == pytest.approx(TRUTH.battery_drain_per_m, rel=0.05)
    assert vehicle.landed and vehicle.battery_fraction >= 0.25
    assert rc == 1 and s["status"].startswith("aborted: battery reserve: returning at"), s["status"]
    assert vehicle.battery_fraction < 0.25 + 0.02  # inspected what it could, then came back
    d = b["decision"]
    assert d["needed_finish"] > d["available"] and d["fraction"] - vehicle.battery_fraction <= d["needed_return"]
    left = s["abort"]["left"]
    assert left["exploration_waypoints"] > 0 or left["inspection_waypoints"] > 0 or left["insulators_uninspected"]
    assert s["abort"]["handed_over"] is None and s["abort"]["route"] is not None


@pytest.mark.slow
def test_over_mavlink_the_whole_percents_still_keep_the_reserve(tmp_path, monkeypatch):
    """The same pack that cannot finish, read through our simulated PX4 (BATTERY_STATUS in whole
    percents, as PX4 sends it): the return still lands with the simulator's own pack at or
    above the reserve."""
    rc, s, vehicle, _, _ = _fly_small(tmp_path, monkeypatch, 0.32, "--vehicle", "mavlink", "--time-scale", "4")
    assert rc == 1 and s["status"].startswith("aborted: battery reserve: returning at"), s["status"]
    assert vehicle.landed and vehicle.battery_fraction >= 0.25, vehicle.battery_fraction
    fit = s["battery"]["decision"]["fit"]
    assert fit["per_s"] + 1.0 * fit["per_m"] == pytest.approx(TRUTH.battery_drain_per_s + TRUTH.battery_drain_per_m,
                                                              rel=0.15)  # a 1 m/s pass, read in 1 % steps
