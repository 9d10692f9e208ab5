"""The pre-flight gate (issue 19, item 5): refused before arming, every failed check named.

Each check is made to fail on its own against the real parts (the in-process simulator, our
simulated PX4 over MAVLink on loopback, the live Mid-360 driver with no sensor sending, a shipped
network): the refusal names it and only it, the flight is refused before the arm command (the
simulated PX4 counts every command it received: no MAV_CMD_COMPONENT_ARM_DISARM), the operator's
console, the GCS's STATUSTEXT and summary.json say why, and no traceback. A healthy flight passes
the gate and flies exactly as it flew without it (the same trajectory, sample for sample).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.flights import ARGS, small_scene
from helpers.statustexts import Statustexts

from insulator_rs.app import inspect_command
from insulator_rs.app.cli import main
from insulator_rs.drivers.live_sensors import LiveSensors
from insulator_rs.drivers.livox import LivoxMid360
from insulator_rs.flight.autopilot_session import AutopilotSession
from insulator_rs.flight.loop import FlightLoop, FlightSettings
from insulator_rs.flight.preflight import (CLOCK_WAIT, STREAM_MAX_AGE, Check, Outcome, check_detector,
                                           check_sensors_waiting)
from insulator_rs.ports.sensors import StreamStatus
from insulator_rs.mavlink.gcs import MavlinkGcsObserver
from insulator_rs.mavlink.wire import mavlink2 as M
from insulator_rs.mission.config import load_mission
from insulator_rs.models import SIMULATOR_MODEL
from insulator_rs.ports.detector import NetworkDetector, open_network_detector
from insulator_rs.rig import simulator_rig
from insulator_rs.sim.ground_truth_detector import GroundTruthDetector
from insulator_rs.sim.px4 import start_simulated_px4
from insulator_rs.sim.sensors import SimulatedSensors, kinematic_true_pose, simulated_px4_true_pose
from insulator_rs.sim.towers import load_tower

ARM = "MAV_CMD_COMPONENT_ARM_DISARM"


def _outcomes(summary: dict) -> dict[str, str]:
    return {c["name"]: c["outcome"] for c in summary["preflight"]["checks"]}


def _failed(summary: dict) -> list[str]:
    return [c["name"] for c in summary["preflight"]["checks"] if c["outcome"] == "failed"]


def _reason(summary: dict, name: str) -> str:
    return next(c["reason"] for c in summary["preflight"]["checks"] if c["name"] == name)


# -- through our simulated PX4 -------------------------------------------------------------------

def _fly_px4(tmp_path: Path, *, battery: float | None = None, answer_timesync: bool = True, gps: bool = True,
             before_preflight=None):
    """The small scene flown by the flight loop through our simulated PX4 (time scale 4),
    simulated cameras and LiDAR; returns (summary, the simulated PX4, the STATUSTEXT the GCS
    got). ``before_preflight(loop)`` runs after the autopilot's parameters are set."""
    scene, mission_path = small_scene(tmp_path)
    tower = load_tower(str(scene))
    mission = load_mission(mission_path)
    rig = mission.rig if mission.rig is not None else simulator_rig()
    vehicle_sim = inspect_command.charged(inspect_command.kinematic_vehicle(mission, 0), battery)
    sim, vehicle = start_simulated_px4(time_scale=4.0, sim_options={
        "vehicle": vehicle_sim, "origin": (mission.tower.lat, mission.tower.lon, mission.tower.alt),
        "answer_timesync": answer_timesync})
    if not gps:
        sim.with_vehicle(lambda v: v.inject_position_loss())
    sensors = SimulatedSensors(tower.mesh, simulated_px4_true_pose(sim), rig, detect_scale=0.2, photo_scale=0.2,
                               seed=0)
    sink = Statustexts()
    gcs = MavlinkGcsObserver(sink, system_id=1)
    loop = FlightLoop(mission, vehicle, sensors, GroundTruthDetector(sensors, seed=0), tmp_path / "report", rig=rig,
                      settings=FlightSettings(detect_period=0.5, quiet=True), observer=gcs,
                      photo_camera=sensors.photo_model)
    if before_preflight is not None:
        configure = loop.autopilot.configure

        def configure_then(*args, **kwargs):
            configure(*args, **kwargs)
            before_preflight(loop)

        loop.autopilot.configure = configure_then  # type: ignore[method-assign]
    try:
        loop.fly()
        summary = loop.finish_report()
        gcs.flush()
    finally:
        gcs.close()
        vehicle.close()
    return summary, sim, sink.texts


def _refused_before_arming(summary: dict, sim, texts, name: str) -> str:
    """The flight refused on check ``name`` alone, before any arm command; its reason."""
    assert summary["status"].startswith(f"refused_preflight: {name}: "), summary["status"]
    assert _failed(summary) == [name], summary["preflight"]
    assert ARM not in sim.stats.commands, sim.stats.commands  # PX4 never saw an arm command
    assert sim.with_vehicle(lambda v: not v.armed and v.landed)
    assert summary["flight_time_s"] == 0.0 and summary["insulators_found"] == 0
    reason = _reason(summary, name)
    fails = [t for sev, t in texts if sev == M.MAV_SEVERITY_CRITICAL and t.startswith("Preflight Fail")]
    assert fails and fails[0].startswith(f"Preflight Fail: {name}: "), texts  # the pilot's GCS is told
    # the tower's parameters were set before the gate, and restored after the refusal
    assert summary["px4_parameters"]["restore"] == "restored", summary["px4_parameters"]
    return reason


@pytest.mark.slow
def test_battery_below_the_missions_need_is_refused_before_arming(tmp_path):
    """0.27 of the pack with the mission's 0.25 reserve: the small scene's exploration alone takes
    about 0.05 at the nominal rates. Every other check passes through the simulated PX4 (its
    sensors, its TIMESYNC, its GPS fix and home, its geofence as set for the tower)."""
    summary, sim, texts = _fly_px4(tmp_path, battery=0.27)
    reason = _refused_before_arming(summary, sim, texts, "battery")
    assert reason.startswith("charge 27%: the exploration path and landing") and "above the 25% reserve" in reason
    assert _outcomes(summary) == {"sensors": "passed", "clock": "passed", "gps_home": "passed", "home": "passed",
                                  "detector": "not_applicable", "battery": "failed", "geofence": "passed"}
    assert "3D fix" in _reason(summary, "gps_home") and "TIMESYNC" in _reason(summary, "clock")


@pytest.mark.slow
def test_no_gps_fix_is_refused_before_arming(tmp_path):
    summary, sim, texts = _fly_px4(tmp_path, gps=False)
    assert "no 3D GPS fix (no fix, 0 satellites)" in _refused_before_arming(summary, sim, texts, "gps_home")


@pytest.mark.slow
def test_an_autopilot_that_answers_no_timesync_is_refused_before_arming(tmp_path):
    summary, sim, texts = _fly_px4(tmp_path, answer_timesync=False)
    reason = _refused_before_arming(summary, sim, texts, "clock")
    assert reason.startswith(f"no clock map to the vehicle: the autopilot answered no TIMESYNC within {CLOCK_WAIT:g} s")


@pytest.mark.slow
def test_a_mission_outside_the_geofence_is_refused_before_arming(tmp_path):
    """The gate reads the fence back from the autopilot: one lowered after the tower's was set
    (a ground station's PARAM_SET) no longer holds the mission."""
    def shrink_fence(loop):
        loop.vehicle.parameters.set("GF_MAX_HOR_DIST", 15.0)

    summary, sim, texts = _fly_px4(tmp_path, before_preflight=shrink_fence)
    reason = _refused_before_arming(summary, sim, texts, "geofence")
    assert "m from home, beyond GF_MAX_HOR_DIST 15 m" in reason, reason


# -- in process ------------------------------------------------------------------------------------

def _loop_in_process(tmp_path: Path, *, detector="standin", silent_lidar: bool = False):
    scene, mission_path = small_scene(tmp_path)
    tower = load_tower(str(scene))
    mission = load_mission(mission_path)
    rig = mission.rig if mission.rig is not None else simulator_rig()
    vehicle = inspect_command.kinematic_vehicle(mission, 0)
    cameras = SimulatedSensors(tower.mesh, kinematic_true_pose(vehicle), rig, detect_scale=0.2, photo_scale=0.2,
                               seed=0)
    sensors: object = cameras
    if silent_lidar:  # the live adapter on the real Mid-360 driver, listening where no sensor sends
        sensors = LiveSensors(LivoxMid360(now=lambda: vehicle.state().time, T_b_l=rig.T_b_l, host_ip="127.0.0.1",
                                          point_port=0, imu_port=None).start(), None)
    det = GroundTruthDetector(cameras, seed=0) if detector == "standin" else detector
    loop = FlightLoop(mission, vehicle, sensors, det, tmp_path / "report", rig=rig,
                      settings=FlightSettings(detect_period=0.5, quiet=True), photo_camera=cameras.photo_model)
    return loop, vehicle, sensors


def _refused_in_process(loop, vehicle, name: str) -> str:
    loop.fly()
    summary = loop.finish_report()
    assert summary["status"].startswith(f"refused_preflight: {name}: "), summary["status"]
    assert _failed(summary) == [name] and not vehicle.armed and vehicle.landed
    assert json.loads((loop.out / "summary.json").read_text())["status"] == summary["status"]
    return _reason(summary, name)


@pytest.mark.slow
def test_a_silent_lidar_and_no_camera_are_refused_before_arming(tmp_path):
    loop, vehicle, sensors = _loop_in_process(tmp_path, silent_lidar=True)
    try:
        reason = _refused_in_process(loop, vehicle, "sensors")
    finally:
        sensors.close()
    assert reason.startswith("no camera; lidar: nothing received (for "), reason  # waited SENSORS_WAIT


class LateStreams:
    """Streams whose LiDAR is a second behind until ``fresh_after`` looks (a Mid-360 just
    started, its clock map new; a receive thread behind on a loaded computer), then fresh."""

    def __init__(self, fresh_after: int) -> None:
        self.fresh_after = fresh_after
        self.looks = 0

    def streams(self, now: float) -> list[StreamStatus]:
        self.looks += 1
        lag = 0.05 if self.looks > self.fresh_after else STREAM_MAX_AGE + 0.5
        return [StreamStatus("camera", 10, now - 0.05), StreamStatus("lidar", 10, now - lag)]


def test_a_late_sensor_is_waited_for_and_a_stale_one_refused_after_the_wait():
    """One look refused a live flight against PX4 SITL ("lidar: silent for 1.5 s" 14 s after
    the driver started, on a loaded box): the gate now looks again until the streams are fresh."""
    late = LateStreams(fresh_after=3)
    ok = check_sensors_waiting(late, lambda: 100.0, wait=5.0)
    assert ok.outcome == Outcome.PASSED and late.looks == 4 and "(after " in ok.reason, ok
    stale = LateStreams(fresh_after=10**6)
    bad = check_sensors_waiting(stale, lambda: 100.0, wait=0.5)
    assert bad.outcome == Outcome.FAILED and bad.reason.startswith("lidar: silent for 1.5 s"), bad
    assert "(for 0." in bad.reason and stale.looks >= 2


def test_no_detector_is_refused_before_arming(tmp_path):
    loop, vehicle, _ = _loop_in_process(tmp_path, detector=None)
    assert _refused_in_process(loop, vehicle, "detector") == "no detector loaded"


def test_a_network_is_run_once_before_the_flight():
    """The shipped simulator network runs on a blank frame; the same network told to feed its
    session another input size (an export whose metadata lies) fails, named."""
    det = open_network_detector(SIMULATOR_MODEL)
    ok = check_detector(det)
    assert ok.outcome == Outcome.PASSED and ok.reason.startswith(f"network {det.name} runs"), ok
    assert det.dropped.to_dict() == NetworkDetector(det.network).dropped.to_dict()  # the flight's counts untouched
    h, w = det.network.imgsz
    det.network.imgsz = (h // 2 + 16, w // 2 + 16)
    det.network.rect = False
    bad = check_detector(det)
    assert bad.check == Check.DETECTOR and bad.outcome == Outcome.FAILED
    assert bad.reason.startswith(f"network {det.name} does not run: "), bad


@pytest.mark.slow
def test_low_charge_is_refused_from_the_command_line(tmp_path, capsys):
    """``insulator-rs inspect --sim-battery 0.27``: exit 1, the operator told each failed check,
    summary.json says so, and no traceback."""
    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out),
               *[a for a in ARGS if a != "--quiet"], "--sim-battery", "0.27"])
    captured = capsys.readouterr()
    assert rc == 1
    assert "PRE-FLIGHT FAILED, not armed: battery: charge 27%" in captured.out
    assert "Traceback" not in captured.out + captured.err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"].startswith("refused_preflight: battery: ") and _failed(s) == ["battery"]
    assert s["battery"]["fraction_at_takeoff"] is None and len((out / "trajectory.csv").read_text().splitlines()) <= 1


@pytest.mark.slow
def test_a_healthy_flight_passes_the_gate_and_flies_as_without_it(tmp_path, monkeypatch):
    """The small scene in process: every check passes or has no source there (named), and the
    flight is the one flown with the gate taken out, trajectory sample for sample (the
    simulator's probe renders outside its counts and seeds)."""
    scene, mission = small_scene(tmp_path)

    def fly(out: Path) -> tuple[int, dict, str]:
        rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS])
        return rc, json.loads((out / "summary.json").read_text()), (out / "trajectory.csv").read_text()

    rc, s, gated = fly(tmp_path / "gated")
    assert rc == 0 and s["status"] == "finished", s["status"]
    assert s["preflight"]["passed"] is True
    assert _outcomes(s) == {"sensors": "passed", "clock": "not_applicable", "gps_home": "not_applicable",
                            "home": "passed", "detector": "not_applicable", "battery": "passed",
                            "geofence": "not_applicable"}
    assert _reason(s, "sensors").startswith("camera 1 delivered, newest 0.00 s old, lidar 1 delivered")
    monkeypatch.setattr(AutopilotSession, "preflight", lambda self: None)
    rc2, s2, ungated = fly(tmp_path / "ungated")
    assert rc2 == 0 and s2["preflight"] is None
    assert gated == ungated
    def shots(summary: dict) -> list[dict]:
        # the photos but what the wall clock measured: their UTC stamps (at take-off) and the
        # photo check's cost (detect_s, check_s)
        out = []
        for p in summary["photos"]:
            p = {k: v for k, v in p.items() if k != "time_utc"}
            if isinstance(p.get("check"), dict):
                p["check"] = {k: v for k, v in p["check"].items() if k not in ("detect_s", "check_s")}
            out.append(p)
        return out

    assert s["insulators_found"] == s2["insulators_found"] and shots(s) == shots(s2)
    assert np.isclose(s["flight_time_s"], s2["flight_time_s"])
