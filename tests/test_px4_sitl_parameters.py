"""PX4 set for the tower, against the real autopilot: PX4 v1.16.0 SITL (SIH) from ``../shared/px4_sitl``.

* ``test_px4_answers_parameter_requests_as_the_simulated_px4_does``: the same parameter requests
  to PX4 and to our simulated PX4 (reads, a set with the right type, with the wrong type, of an
  unknown name, the same value twice, arming with NAV_DLL_ACT and no ground station); the
  answers (which PARAM_VALUEs come back, their types and bytewise values, the COMMAND_ACK) must
  agree, and PX4's defaults must be the simulated PX4's table (``sim/px4/parameters.py``).
* ``test_sitl_flight_sets_verifies_and_restores_the_parameters``: the small scene flown through
  PX4 with a ground station on PX4's GCS link: every tower value (NAV_DLL_ACT included) set and
  verified before arming, put back after PX4's landing, and PX4 itself, asked afterwards, holds
  its old values again (the session's one reference flight, ``sitl_reference_flight``, which
  two other SITL tests read too).
* ``test_companion_killed_mid_crossing_px4_returns_clear_of_the_tower``: the mission's process
  (``insulator-rs inspect`` in a subprocess) is SIGKILLed while PX4 reports the vehicle over the
  tower's safety box, in the top crossing. From PX4's own positions (LOCAL_POSITION_NED on its
  GCS link, 10 Hz) after the kill: PX4 enters Return (COM_OBL_RC_ACT 3 after COM_OF_LOSS_T), never
  descends while over a safety volume's footprint, no sample is inside the safety box or a
  conductor corridor (the mission file's geometry, rebuilt here), and it lands at home.

Each other test starts its own PX4 (``px4_sitl.Px4Sitl``) and kills it however the test ends; all are
skipped, saying so, when the SITL folder is absent.
"""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers.gcs_listener import GcsListener
from helpers.px4_sitl import FAILSAFE_LINE, REPO, companion_link, mission_at_home
from helpers.flights import ARGS, small_scene
from helpers.sitl_suite import SITL_MARKS, SPEED

import insulator_rs

pytestmark = SITL_MARKS
GCS_PORT = 18570  # PX4 SITL's GCS link: udp 18570 + instance
RETURN_TIMEOUT = 240.0  # wall s for PX4's own return and landing after the kill
# m: PX4 may sag this much below the height it was killed at while it brakes into its Return
# (the offboard setpoint's last velocity, then the RTL's climb setpoint): measured 0.45 m
SAG = 1.0
POSITION_RATE_HZ = 10.0  # LOCAL_POSITION_NED asked of PX4's GCS link
MID_CROSSING = 1.5  # m either side of the tower's axis: where the companion is killed
HOME_TOLERANCE = 3.0  # m: PX4 lands where it took off (its RTL's acceptance, GPS noise of SIH)
# m: the landed height against home's, both PX4's estimates minutes apart (its EKF's height
# drifts: measured 0.95 m after a 3 min flight)
LAND_Z_TOLERANCE = 1.5


def _i2f(value: int) -> float:
    return struct.unpack("<f", struct.pack("<i", value))[0]


def _parameter_answers(connection: str, names: list[str]) -> dict[str, object]:
    """What an autopilot answers to a fixed sequence of parameter requests: for each, the
    (name, type, decoded value) of every PARAM_VALUE within 1.5 s, or the COMMAND_ACK result."""
    from insulator_rs.mavlink.parameters import decode
    from insulator_rs.mavlink.wire import mavlink2 as M

    with companion_link(connection) as (link, t):
        INT32, REAL32 = M.MAV_PARAM_TYPE_INT32, M.MAV_PARAM_TYPE_REAL32

        def values(send, name: str | None = None) -> list[tuple[str, int, object]]:
            """The distinct answers about ``name`` (all, when None). PX4 broadcasts a change
            once more after its reply, at its own pace: the broadcast of one set may come in the
            next request's window, so answers about other parameters, and repeats, are left out."""
            send()
            got, deadline = [], time.monotonic() + 1.5
            while time.monotonic() < deadline:
                m = link.recv_match(type=["PARAM_VALUE", "COMMAND_ACK"], blocking=True, timeout=0.1)
                if m is None:
                    continue
                if m.get_type() == "COMMAND_ACK":
                    got.append(("ACK", int(m.command), int(m.result)))
                elif name is None or m.param_id == name:
                    got.append((m.param_id, int(m.param_type), decode(m.param_value, m.param_type)))
            return sorted(set(got), key=repr)

        answers: dict[str, object] = {f"read {n}": values(lambda n=n: link.mav.param_request_read_send(
            *t, n.encode(), -1), n) for n in names}
        probes = {
            "read unknown": lambda: link.mav.param_request_read_send(*t, b"NO_SUCH_PARAM", -1),
            "read lower case": lambda: link.mav.param_request_read_send(*t, b"rtl_return_alt", -1),
            "set unknown": lambda: link.mav.param_set_send(*t, b"NO_SUCH_PARAM", 1.0, REAL32),
            "set INT32 as REAL32": lambda: link.mav.param_set_send(*t, b"COM_OBL_RC_ACT", 3.0, REAL32),
            "set FLOAT as INT32": lambda: link.mav.param_set_send(*t, b"RTL_RETURN_ALT", _i2f(25), INT32),
            "set INT32 bytewise": lambda: link.mav.param_set_send(*t, b"COM_OBL_RC_ACT", _i2f(3), INT32),
            "set INT32 same again": lambda: link.mav.param_set_send(*t, b"COM_OBL_RC_ACT", _i2f(3), INT32),
            "set FLOAT out of range": lambda: link.mav.param_set_send(*t, b"RTL_RETURN_ALT", 1000.0, REAL32),
            "set NAV_DLL_ACT": lambda: link.mav.param_set_send(*t, b"NAV_DLL_ACT", _i2f(2), INT32),
            "arm, no GCS": lambda: link.mav.command_long_send(*t, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0,
                                                               0, 0),
        }
        probed = {"read unknown": "NO_SUCH_PARAM", "read lower case": "rtl_return_alt", "set unknown": "NO_SUCH_PARAM",
                  "set INT32 as REAL32": "COM_OBL_RC_ACT", "set FLOAT as INT32": "RTL_RETURN_ALT",
                  "set INT32 bytewise": "COM_OBL_RC_ACT", "set INT32 same again": "COM_OBL_RC_ACT",
                  "set FLOAT out of range": "RTL_RETURN_ALT", "set NAV_DLL_ACT": "NAV_DLL_ACT"}
        for name, send in probes.items():
            link.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
            answers[name] = values(send, probed.get(name, ""))  # "": the COMMAND_ACK only
        return answers


def test_px4_answers_parameter_requests_as_the_simulated_px4_does(px4) -> None:
    """Reference: PX4 v1.16.0 itself. The simulated PX4 must answer every request alike; PX4's
    values of the parameters the tower sets are the simulated PX4's defaults (its table is the
    SITL's, except what its airframe model sets itself: those are compared by type only)."""
    from insulator_rs.mavlink.parameters import same_value
    from insulator_rs.sim.px4 import SimulatedPx4
    from insulator_rs.sim.px4.parameters import AIRFRAME_FIELDS, SITL_DEFAULTS

    names = sorted(SITL_DEFAULTS)
    real = _parameter_answers(px4.connection, names)
    with SimulatedPx4(system_id=2) as sim:
        host, port = sim.address
        simulated = _parameter_answers(f"udpout:{host}:{port}", names)
    for name in names:  # PX4's defaults are the table's (REAL32s compared as 32-bit floats)
        kind, value = SITL_DEFAULTS[name]
        [(got_name, got_kind, got)] = real[f"read {name}"]
        assert (got_name, got_kind) == (name, kind) and same_value(got, value, kind), (name, got)
        if name in AIRFRAME_FIELDS:  # the airframe's own values: same type
            real[f"read {name}"] = [(n, t, None) for n, t, _ in real[f"read {name}"]]
            simulated[f"read {name}"] = [(n, t, None) for n, t, _ in simulated[f"read {name}"]]
    assert simulated == real
    assert real["set INT32 bytewise"] == [("COM_OBL_RC_ACT", 6, 3)]  # the value, bytewise
    assert real["set INT32 as REAL32"] == [] and real["read unknown"] == []
    assert real["arm, no GCS"] == [("ACK", 400, 1)]  # TEMPORARILY_REJECTED: no ground station


def _inspect_args(tmp_path, px4) -> tuple[list[str], object]:
    from insulator_rs.mission.config import load_mission

    scene, mission = small_scene(tmp_path)
    mission.write_text(mission.read_text() + "confirmations = 1\n")
    mission = mission_at_home(mission, tmp_path / "at_home.toml")
    out = tmp_path / "report"
    return (["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS,
             "--connection", px4.connection, "--sim-sensors", "--time-scale", f"{SPEED:g}"], load_mission(mission))


# one worker flies the session's reference flight for all three tests that read it (conftest.py)
@pytest.mark.xdist_group("sitl_reference_flight")
def test_sitl_flight_sets_verifies_and_restores_the_parameters(reference_flight) -> None:
    """The session's one reference flight (``sitl_reference_flight``: a ground station on PX4's
    data link); PX4's values read back through a fresh connection once it has landed."""
    s = reference_flight.summary
    assert reference_flight.rc == 0 and s["status"] == "finished", s.get("status")
    record = s["px4_parameters"]
    print(json.dumps(record, indent=1))
    assert record["ground_station"] is True and record["restore"] == "restored"
    by_name = {r["name"]: r for r in record["parameters"]}
    assert by_name["NAV_DLL_ACT"]["set"] == 2 and by_name["COM_OBL_RC_ACT"]["set"] == 3
    assert by_name["RTL_RETURN_ALT"]["old"] == 30.0 and by_name["RTL_CONE_ANG"]["old"] == 45  # PX4's defaults
    for r in record["parameters"]:
        assert r["error"] is None and r["restored"] == r["old"] and r["set"] is not None, r
    assert reference_flight.parameters_after == {name: r["old"] for name, r in by_name.items()}
    assert FAILSAFE_LINE not in reference_flight.px4_log


def _local_to_w(local_ned: np.ndarray, home: object, tower: object) -> np.ndarray:
    """PX4's local NED positions (N, 3) in W, as the client converts them: W's origin at the
    tower base, PX4's local origin placed from HOME_POSITION (``mavlink/frames.py``)."""
    from insulator_rs.mavlink.frames import local_origin_in_w, ned_to_enu

    origin = local_origin_in_w((home.latitude * 1e-7, home.longitude * 1e-7, home.altitude * 1e-3),
                               [home.x, home.y, home.z], (tower.lat, tower.lon, tower.alt))
    return origin + ned_to_enu(np.asarray(local_ned, dtype=np.float64).reshape(-1, 3))


def _box_distance(volumes, points: np.ndarray) -> np.ndarray:
    """Each point's distance (m) to the nearest safety volume (0 inside one), from the boxes'
    own frames: the reference, not the planner's check."""
    best = np.full(len(points), np.inf)
    for box in volumes.boxes:
        q = np.maximum(np.abs(box.to_local(points)) - box.half_extents, 0.0)
        best = np.minimum(best, np.linalg.norm(q, axis=1))
    return best


def test_companion_killed_mid_crossing_px4_returns_clear_of_the_tower(px4, tmp_path) -> None:
    from insulator_rs.mavlink import px4_modes
    from insulator_rs.mavlink.wire import mavlink2 as M
    from insulator_rs.mission.geometry import MissionGeometry

    args, mission = _inspect_args(tmp_path, px4)
    geom = MissionGeometry.from_mission(mission)
    volumes = geom.volumes
    tower = volumes.boxes[0]
    # The package this test imported (the installed wheel in CI, python/ in a checkout): the
    # checkout's python/ has no compiled _core when the wheel is what is installed.
    package_parent = Path(insulator_rs.__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(package_parent), str(REPO / "tests"),
                                                        os.environ.get("PYTHONPATH", "")]))
    with GcsListener(("127.0.0.1", GCS_PORT + px4.instance)) as gcs:
        gcs.wait_for(lambda: gcs.of("HEARTBEAT", 1), 20)
        system = gcs.of("HEARTBEAT", 1)[0].get_srcSystem()
        gcs.command_long((system, 1), M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                         1e6 / POSITION_RATE_HZ)
        gcs.command_long((system, 1), M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HOME_POSITION, 1e6)
        proc = subprocess.Popen([sys.executable, "-m", "insulator_rs.app.cli", *args], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        killed_at = None
        try:
            deadline = time.monotonic() + 900
            home = local = None
            while killed_at is None and proc.poll() is None and time.monotonic() < deadline:
                for m in gcs.messages[-300:]:  # the newest only: the list grows all flight
                    kind = m.get_type()
                    if kind == "HOME_POSITION":
                        home = m
                    elif kind == "LOCAL_POSITION_NED":
                        local = np.array([[m.x, m.y, m.z]])
                if home is not None and local is not None:
                    p = _local_to_w(local, home, mission.tower)
                    # the middle of the crossing: over the tower's axis (its box's lateral centre)
                    if abs(tower.to_local(p)[0, 1]) < MID_CROSSING and p[0, 2] > volumes.top:
                        os.kill(proc.pid, signal.SIGKILL)  # the companion dies mid-crossing
                        killed_at = (len(gcs.messages), len(gcs.of("LOCAL_POSITION_NED")), p[0])
                time.sleep(0.05)
        finally:
            if proc.poll() is None and killed_at is None:
                proc.kill()
            output = proc.communicate(timeout=30)[0]
        assert killed_at is not None, f"the flight never crossed the tower (rc {proc.returncode}):\n{output[-3000:]}"
        assert proc.returncode == -signal.SIGKILL
        # PX4 alone now: its own return, until it has landed and disarmed
        landed = gcs.wait_for(lambda: "Disarmed by landing" in px4.log(), RETURN_TIMEOUT)
        time.sleep(0.5)
        h = gcs.of("HOME_POSITION")[-1]
        after = gcs.of("LOCAL_POSITION_NED")[killed_at[1]:]
        modes, samples, rtl_after = [], 0, None  # PX4's modes after the kill; samples until Return
        for m in gcs.messages[killed_at[0]:]:
            if m.get_type() == "LOCAL_POSITION_NED":
                samples += 1
            elif m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1:
                modes.append(px4_modes.decode_custom_mode(m.custom_mode))
                if modes[-1] == "RTL" and rtl_after is None:
                    rtl_after = samples / POSITION_RATE_HZ
    summary = json.loads((tmp_path / "report" / "summary.json").read_text())
    log = px4.log()
    assert landed, [line for line in log.splitlines() if "WARN" in line or "ERROR" in line][-10:]
    # the tower's values were set before take-off (the kill left them set, as they must be)
    record = summary["px4_parameters"]
    assert record["restore"] == "set; not restored yet"
    return_alt = next(r["set"] for r in record["parameters"] if r["name"] == "RTL_RETURN_ALT")
    assert "RTL" in modes and FAILSAFE_LINE in log
    points = _local_to_w(np.array([[m.x, m.y, m.z] for m in after]), h, mission.tower)
    home_w = _local_to_w(np.array([[h.x, h.y, h.z]]), h, mission.tower)[0]  # where PX4 took off, in W
    clearance = _box_distance(volumes, points)
    over = volumes.footprint_distance(points) == 0.0
    lowest_over = points[over, 2].min(initial=np.inf)  # the lowest PX4 flew over a volume's footprint
    landing = points[-1]
    print(f"PX4 in Return mode {rtl_after} s (vehicle time, from its positions) after the kill; modes {set(modes)}")
    print(f"killed over the tower at {np.round(killed_at[2], 2).tolist()} (W, m); after the kill "
          f"{len(points)} PX4 samples: min clearance to the safety volumes {clearance.min():.2f} m, "
          f"highest {points[:, 2].max():.2f} m (return altitude {return_alt} m above home at "
          f"{home_w[2]:.2f} m), lowest over a volume {lowest_over:.2f} m (killed at {killed_at[2][2]:.2f} m), "
          f"landed at {np.round(landing, 2).tolist()} ({np.linalg.norm(landing[:2] - home_w[:2]):.2f} m from home)")
    assert clearance.min() > 0.0  # never inside the safety box or a conductor corridor
    assert lowest_over > killed_at[2][2] - SAG  # over the tower it climbs or holds, never descends
    assert points[:, 2].max() >= home_w[2] + return_alt - 1.0  # climbed to the return altitude
    assert np.linalg.norm(landing[:2] - home_w[:2]) < HOME_TOLERANCE  # landed ("Disarmed by landing") at home
    assert abs(landing[2] - home_w[2]) < LAND_Z_TOLERANCE
