"""The operator's abort and the home check against PX4 v1.16.0 SITL (``../shared/px4_sitl``).

* QGroundControl's custom action (the shipped ``data/qgc_mavlink_actions.json``'s command) sent
  on PX4's GCS link mid-flight: PX4 forwards it to the companion, which acknowledges it, says so
  in a STATUSTEXT, flies the safe route out and lands; the report says ``aborted: operator``.
* Ctrl-C (SIGINT) to a real ``insulator-rs inspect`` process flying PX4: the same way out.
* A vehicle whose home is 13 m from the mission's take-off point is refused before arming, the
  distance named; PX4 never sees an arm command.
"""

from __future__ import annotations

import csv
import json
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pymap3d
from helpers.flights import ARGS, small_scene
from helpers.gcs_listener import GcsListener, M
from helpers.px4_sitl import PX4_HOME, Px4Sitl, mission_at_home
from helpers.sitl_suite import FOLDER, SITL_MARKS, SPEED

import insulator_rs
from insulator_rs.app.cli import main
from insulator_rs.mavlink.gcs import ABORT_ANNOUNCEMENT, ABORT_COMMAND, COMPANION_COMPONENT

pytestmark = SITL_MARKS

GCS_PORT = 18570  # PX4 SITL's GCS link: udp 18570 + instance
ACTIONS = Path(insulator_rs.__file__).parent / "data" / "qgc_mavlink_actions.json"
INTO_FLIGHT_S = 15.0  # s of flight (the first pass) before the operator aborts


def _mission(tmp_path: Path) -> tuple[Path, Path]:
    scene, mission = small_scene(tmp_path)
    mission.write_text(mission.read_text() + "confirmations = 1\n")
    return scene, mission_at_home(mission, tmp_path / "at_home.toml")


def _landed_by_the_safe_route(out: Path, summary: dict, px4: Px4Sitl) -> None:
    ab = summary["abort"]
    assert ab is not None and ab["route"] is not None and ab["handed_over"] is None, ab
    with (out / "trajectory.csv").open() as f:
        rows = list(csv.reader(f))[1:]
    states = [r[5] for r in rows]
    assert "abort" in states and all(s == "abort" for s in states[states.index("abort"):])
    last = np.array([float(x) for x in rows[-1][1:4]])
    # where the route ends; the height is PX4's estimate at its landing detection (0.6 m measured:
    # its barometric height drifts in flight), and PX4's own log says it landed
    assert np.linalg.norm(np.array(ab["landing_point"])[:2] - last[:2]) < 1.0
    assert last[2] < ab["landing_point"][2] + 1.0
    deadline = time.monotonic() + 20.0
    while "Disarmed by landing" not in px4.log() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert "Disarmed by landing" in px4.log()
    assert "Failsafe activated" not in px4.log()  # our route and landing, not PX4's offboard-loss


def test_qgc_custom_action_aborts_a_sitl_flight_by_the_safe_route(tmp_path):
    action = json.loads(ACTIONS.read_text())["actions"][0]
    scene, mission = _mission(tmp_path)
    out = tmp_path / "report"
    with Px4Sitl(FOLDER, speed=SPEED, workdir=tmp_path / "px4", first_instance=5) as px4:
        with GcsListener(("127.0.0.1", GCS_PORT + px4.instance), ask_camera=False) as gcs:
            assert gcs.wait_for(lambda: gcs.of("HEARTBEAT", 1), 10.0)

            def press() -> None:
                if gcs.wait_for(lambda: any("-> explore" in t for _, _, t in gcs.statustexts()), 300.0):
                    time.sleep(INTO_FLIGHT_S / SPEED)
                    system = gcs.of("HEARTBEAT", 1)[0].get_srcSystem()  # PX4 SITL instance N is system N + 1
                    gcs.command_long((system, action["compId"]), action["mavCmd"], action.get("param1", 0.0))

            presser = threading.Thread(target=press, daemon=True)
            presser.start()
            rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS,
                       "--connection", px4.connection, "--sim-sensors", "--time-scale", f"{SPEED:g}"])
            presser.join(timeout=5.0)
            summary = json.loads((out / "summary.json").read_text())
            _landed_by_the_safe_route(out, summary, px4)
            time.sleep(1.0)  # the last forwarded frames reach the ground station
    assert rc == 1 and summary["status"] == "aborted: operator: ground station", summary["status"]
    acks = [(a.command, a.result) for a in gcs.of("COMMAND_ACK", COMPANION_COMPONENT)]
    assert acks == [(ABORT_COMMAND, M.MAV_RESULT_ACCEPTED)]
    assert (COMPANION_COMPONENT, M.MAV_SEVERITY_CRITICAL, ABORT_ANNOUNCEMENT) in gcs.statustexts()


def test_ctrl_c_to_an_inspect_process_aborts_a_sitl_flight_by_the_safe_route(tmp_path):
    scene, mission = _mission(tmp_path)
    out = tmp_path / "report"
    with Px4Sitl(FOLDER, speed=SPEED, workdir=tmp_path / "px4", first_instance=5) as px4:
        proc = subprocess.Popen([sys.executable, "-m", "insulator_rs.app.cli", "inspect", "--scene", str(scene),
                                 "--mission", str(mission), "--out", str(out), *ARGS, "--connection", px4.connection,
                                 "--sim-sensors", "--time-scale", f"{SPEED:g}"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 300.0
            while time.monotonic() < deadline and proc.poll() is None:
                try:
                    s = json.loads((out / "summary.json").read_text())
                except (OSError, ValueError):
                    s = {}
                if s.get("status") == "running" and (s.get("flight_time_s") or 0.0) >= INTO_FLIGHT_S:
                    break
                time.sleep(0.2)
            assert proc.poll() is None, "the flight ended before the operator pressed Ctrl-C"
            proc.send_signal(signal.SIGINT)
            stdout, stderr = proc.communicate(timeout=600)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        summary = json.loads((out / "summary.json").read_text())
        _landed_by_the_safe_route(out, summary, px4)
    assert proc.returncode == 1, stderr[-2000:]
    assert summary["status"] == "aborted: operator: Ctrl-C"
    assert "operator abort (Ctrl-C): flying the safe route out and landing" in stderr
    assert stdout.strip().splitlines()[-2].startswith("aborted: operator: Ctrl-C: flight ")  # the final line


def test_a_sitl_vehicle_13_m_from_the_takeoff_point_is_refused_before_arming(tmp_path):
    """The mission moved so that its take-off point lies 13 m east of PX4's home."""
    scene, mission = small_scene(tmp_path)
    lat, lon, alt = pymap3d.enu2geodetic(13.0, 0.0, 0.0, *PX4_HOME)
    mission = mission_at_home(mission, tmp_path / "away.toml", home=(float(lat), float(lon), float(alt)))
    out = tmp_path / "report"
    with Px4Sitl(FOLDER, speed=SPEED, workdir=tmp_path / "px4", first_instance=5) as px4:
        rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS,
                   "--connection", px4.connection, "--sim-sensors", "--time-scale", f"{SPEED:g}"])
        log = px4.log()
    s = json.loads((out / "summary.json").read_text())
    assert rc == 1 and s["status"].startswith("refused_preflight: home: the autopilot's home (HOME_POSITION) at ")
    # PX4's home is its estimator's: 13.0-13.1 m across in our runs (GPS noise in SIH)
    across = re.search(r"is ([0-9.]+) m across", s["status"])
    assert across is not None and 12.5 < float(across.group(1)) < 13.5, s["status"]
    assert "Armed by" not in log and "Takeoff detected" not in log
