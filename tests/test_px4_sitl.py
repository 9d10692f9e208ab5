"""Against the real autopilot: PX4 v1.16.0 SITL (SIH quadrotor, no Gazebo) from ``../shared/px4_sitl``.

Each test starts its own PX4 with ``run.sh`` on a free instance (ports 14540+N...) and kills
its process group in the fixture's finalizer, always. The folder is found through
``$INSULATOR_RS_PX4_SITL`` or beside the repository (see ``px4_sitl.sitl_folder``); the
tests are skipped, saying so, only when it is absent.

* ``test_px4_answers_commands_as_the_simulated_px4_does``: the same commands to PX4 and to
  our simulated PX4 on the ground; the COMMAND_ACK results (or their absence) must agree:
  that is how the differences were found (and stay fixed).
* ``test_small_scene_inspection_against_px4_sitl``: ``insulator-rs inspect --connection
  ... --sim-sensors`` flies the small scene (two insulators) with the tower placed relative
  to PX4's home; every insulator found and photographed, no "Failsafe activated" in PX4's
  log. PX4 runs in real time (``-s 1``; ``$INSULATOR_RS_PX4_SPEED`` overrides): the client
  and PX4 hold at ``-s 2`` and ``-s 4`` too (no failsafe, the mission finishes), but the
  simulated sensors' rendering takes wall time while PX4 flies on, so a loaded two-core box
  then gets too few detection events to find both insulators every time (measured: 1 of 2
  at -s 4; 2 of 2 in two runs and 1 of 2 in one at -s 2, beside other jobs).
* ``test_small_scene_live_sensor_inspection_against_px4_sitl``: the same flight with the LIVE
  drivers: ``insulator-rs inspect --lidar mid360://listen:PORT --camera http://...`` in a
  subprocess, fed by the sensor head (``insulator_rs.sim.sensor_head``, a process of its own)
  that reads PX4's pose from PX4's GCS link and streams Livox SDK2 datagrams on UDP (sensor
  clock offset 1234.5 s, +25 ppm) and an MJPEG stream OpenCV reads; the shipped
  ``insulator-sim`` network detects. Scored here against the scene's ground truth.
  Measured (PX4 -s 1, this 2-core box shared with other jobs, load 2-8): the flight takes
  126-192 s (+8 s of wall time); every run had no LiDAR datagram lost, malformed, unmapped or
  unstamped and 380-530 camera frames; the insulators found were 0.02-0.25 m from the truth
  (the larger errors along the string: its ends come from the network's boxes on 320 x 240
  frames). What varies is how many localizations the flight gets (15-46) and the network's
  occasional boxes on the tower body, so ``confirmations`` (localizations before an
  insulator is registered) decides: with 1 (the ``--sim-sensors`` flights'), 3 of 4 runs
  passed with 1-3 false finds each, and one aborted (a false find's inspection waypoint had
  no safe trajectory); with the mission default 4, 2 of 3 passed (no false find) and one
  found only 1 of 2; with ``LIVE_CONFIRMATIONS`` = 2, 3 of 3 passed (0.075 / 0.135,
  0.129 / 0.053 and 0.037 / 0.086 m; 0, 1 and 0 false finds). 1-17 frames per flight were paired short (the sensor
  head's sends are up to 0.15-0.3 s late at p99 on this box). The LiDAR drift estimate
  (sensor clock -25 ppm in truth) read -68 to +490 ppm: the sensor head's and the client's
  vehicle clocks are each a fit to PX4's telemetry, so it is reported, not asserted (the
  in-process wire flight asserts it to 5 ppm).
"""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from px4_sitl import FAILSAFE_LINE, Px4Sitl, mission_at_home, sitl_folder
from test_mission_inspect import small_scene

from insulator_rs.app.cli import main

FOLDER = sitl_folder()
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(FOLDER is None, reason="PX4 SITL folder absent: no ../shared/px4_sitl beside the "
                                              "repository and INSULATOR_RS_PX4_SITL not set"),
]
SPEED = float(os.environ.get("INSULATOR_RS_PX4_SPEED", "1"))
# s of wall time to wait for PX4's own disarm after the landing (COM_DISARM_LAND 2 s; loaded box)
DISARM_WAIT = 20.0
# Detection twice a second, as the simulated-PX4 flight of the same scene
# (test_mission_inspect_mavlink): each insulator is in view for a few seconds only.
ARGS = ["--detect-period", "0.5", "--detect-scale", "0.2", "--photo-scale", "0.2", "--quiet",
        "--detector", "standin"]  # flight logic under test: the ground-truth stand-in, named


@pytest.fixture
def px4(tmp_path):
    """A fresh PX4 SITL, ready for take-off; killed (process group) however the test ends."""
    sitl = Px4Sitl(FOLDER, speed=SPEED, workdir=tmp_path / "px4")
    try:
        yield sitl.start()
    finally:
        sitl.stop()


def _ack(link, target: tuple[int, int], command: int, *params: float, timeout: float = 1.5) -> int | None:
    """Send COMMAND_LONG; the MAV_RESULT of its COMMAND_ACK, or None if none came."""
    link.mav.command_long_send(*target, command, 0, *(list(params) + [0.0] * (7 - len(params))))
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ack = link.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.1)
        if ack is not None and ack.command == command:
            return int(ack.result)
    return None


def _answers(connection: str) -> dict[str, int | None]:
    from insulator_rs.mavlink.wire import mavlink2 as M
    from insulator_rs.mavlink.wire import mavutil

    link = mavutil.mavlink_connection(connection, source_system=1, source_component=191)
    try:
        link.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
        heartbeat = link.recv_match(type="HEARTBEAT", blocking=True, timeout=30)
        assert heartbeat is not None, f"no HEARTBEAT on {connection}"
        target = (heartbeat.get_srcSystem(), 1)
        custom = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        probes = {
            "IMAGE_START_CAPTURE (autopilot)": (M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1),
            "DO_GIMBAL_MANAGER_PITCHYAW": (M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, -45, 0, math.nan, math.nan),
            "DO_MOUNT_CONTROL": (M.MAV_CMD_DO_MOUNT_CONTROL, -45, 0, 0, 0, 0, 0, M.MAV_MOUNT_MODE_MAVLINK_TARGETING),
            "SET_MESSAGE_INTERVAL (not streamed)": (M.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1e5),
            "SET_MESSAGE_INTERVAL (LOCAL_POSITION_NED)": (M.MAV_CMD_SET_MESSAGE_INTERVAL,
                                                          M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 2e4),
            "DO_SET_MODE (unknown main mode 99)": (M.MAV_CMD_DO_SET_MODE, custom, 99, 0),
            "DO_SET_MODE (POSCTL, no RC)": (M.MAV_CMD_DO_SET_MODE, custom, 3, 0),
            "DO_SET_MODE (OFFBOARD, no setpoints)": (M.MAV_CMD_DO_SET_MODE, custom, 6, 0),
            "DO_SET_MODE (HOLD)": (M.MAV_CMD_DO_SET_MODE, custom, 4, 3),
            "ARM": (M.MAV_CMD_COMPONENT_ARM_DISARM, 1),
            "ARM (armed)": (M.MAV_CMD_COMPONENT_ARM_DISARM, 1),
            "DISARM": (M.MAV_CMD_COMPONENT_ARM_DISARM, 0),
            "DISARM (disarmed)": (M.MAV_CMD_COMPONENT_ARM_DISARM, 0),
            "unknown command 12345": (12345,),
        }
        return {name: _ack(link, target, *probe) for name, probe in probes.items()}
    finally:
        link.close()


def test_px4_answers_commands_as_the_simulated_px4_does(px4) -> None:
    """Reference: PX4 v1.16.0 itself. Our simulated PX4 must give the same COMMAND_ACK results
    on the ground (disarmed, then armed and disarmed again), None meaning no ACK at all."""
    from insulator_rs.sim.px4 import SimulatedPx4

    real = _answers(px4.connection)
    with SimulatedPx4(system_id=2) as sim:
        host, port = sim.address
        simulated = _answers(f"udpout:{host}:{port}")
    assert simulated == real


def test_small_scene_inspection_against_px4_sitl(px4, tmp_path) -> None:
    """The whole inspection through PX4 itself: take-off, offboard exploration, every
    insulator localized, inspected and photographed, landed; PX4's log shows no failsafe."""
    scene, mission = small_scene(tmp_path)
    mission.write_text(mission.read_text() + "confirmations = 1\n")
    mission = mission_at_home(mission, tmp_path / "at_home.toml")
    out = tmp_path / "report"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS,
               "--connection", px4.connection, "--sim-sensors", "--time-scale", f"{SPEED:g}"])
    s = json.loads((out / "summary.json").read_text())
    g = json.loads((out / "score.json").read_text())  # the post-flight scorer's, against the scene
    # PX4 disarms COM_DISARM_LAND (2 s) after it detects the landing, which may come after the
    # client has returned (CI saw the landing line without the disarm): wait for it, bounded
    deadline = time.monotonic() + DISARM_WAIT
    while "Disarmed by landing" not in px4.log() and time.monotonic() < deadline:
        time.sleep(0.2)
    log = px4.log()
    assert FAILSAFE_LINE not in log, [line for line in log.splitlines() if "WARN" in line or "ERROR" in line]
    assert rc == 0 and s["status"] == "finished", s["status"]
    # every insulator of the scene found and photographed (a perception false find, if any,
    # is inspected too: the flight cannot know it is one)
    assert g["insulators_in_scene"] == 2 and g["insulators_matched"] == 2 and s["insulators_inspected"] >= 2
    assert len(s["photos"]) == 2 * s["insulators_inspected"]
    assert all((out / p["file"]).stat().st_size > 1000 for p in s["photos"])
    assert {p["insulator_id"] for p in s["photos"]} == {r["id"] for r in s["insulators"]}
    assert sum(p["insulator_visible"] for p in g["photos"]) >= 4
    assert "Landing detected" in log and "Disarmed by landing" in log


def test_hostile_traffic_mid_flight_against_px4_sitl(px4, tmp_path, monkeypatch, capsys) -> None:
    """Once PX4 has taken off, a stranger on loopback sends the client's port a HEARTBEAT of an
    autopilot with system id 42 (POSCTL) twice a second and ~900 truncated 10-byte MAVLink 2
    headers per second for 4 s. The mission finishes as without them (every insulator found
    and photographed, no PX4 failsafe); the client dropped and counted every datagram and
    sent nothing to the stranger, and the run's last line reports the counts."""
    import socket
    import threading

    from insulator_rs.mavlink.client import MavlinkVehicle
    from insulator_rs.mavlink.wire import mavlink2 as M

    stats: list[dict[str, int]] = []
    original_close = MavlinkVehicle.close

    def close_and_keep_stats(self):
        stats.append(self.link_stats.as_dict())
        original_close(self)

    monkeypatch.setattr(MavlinkVehicle, "close", close_and_keep_stats)
    heartbeat = M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4,
                                            M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3 << 16, M.MAV_STATE_ACTIVE, 3)
    foreign = heartbeat.pack(M.MAVLink(None, srcSystem=42, srcComponent=1))
    header = bytes([0xFD, 9, 0, 0, 7, 1, 1, 0, 0, 0])
    client_port = int(px4.connection.rsplit(":", 1)[1])
    sent = {"truncated": 0, "heartbeats": 0, "replies": 0}
    done = threading.Event()

    def attack() -> None:
        while "Takeoff detected" not in px4.log():
            if done.wait(0.2):
                return
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
            stranger.bind(("127.0.0.1", 0))
            stranger.setblocking(False)
            start = time.monotonic()
            while time.monotonic() - start < 4.0 and not done.is_set():
                for _ in range(9):
                    stranger.sendto(header, ("127.0.0.1", client_port))
                    sent["truncated"] += 1
                if sent["truncated"] % 450 == 0:
                    stranger.sendto(foreign, ("127.0.0.1", client_port))
                    sent["heartbeats"] += 1
                time.sleep(0.01)
            time.sleep(1.0)
            try:
                while True:
                    stranger.recvfrom(65535)
                    sent["replies"] += 1
            except BlockingIOError:
                pass

    attacker = threading.Thread(target=attack, daemon=True)
    attacker.start()
    scene, mission = small_scene(tmp_path)
    mission.write_text(mission.read_text() + "confirmations = 1\n")
    mission = mission_at_home(mission, tmp_path / "at_home.toml")
    out = tmp_path / "report"
    try:
        rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS,
                   "--connection", px4.connection, "--sim-sensors", "--time-scale", f"{SPEED:g}"])
    finally:
        done.set()
        attacker.join(timeout=10)
    s = json.loads((out / "summary.json").read_text())
    g = json.loads((out / "score.json").read_text())
    assert sent["truncated"] > 2000 and sent["heartbeats"] >= 4  # the attack ran, mid-flight
    assert FAILSAFE_LINE not in px4.log()
    assert rc == 0 and s["status"] == "finished", s["status"]
    assert g["insulators_matched"] == 2 and s["insulators_inspected"] >= 2
    assert len(s["photos"]) == 2 * s["insulators_inspected"]
    assert stats[0]["foreign_address"] >= sent["truncated"] + sent["heartbeats"]
    assert sent["replies"] == 0  # nothing streamed to the stranger
    assert f"foreign_address {stats[0]['foreign_address']}" in capsys.readouterr().out  # reported


# A live flight's camera: the simulator's lens at 320 x 240 (the rig's calibration must match
# the frames the camera delivers), rendered and served at 3 fps by the sensor head.
LIVE_SCALE = 0.25
# localizations before an insulator is registered (see the module docstring)
LIVE_CONFIRMATIONS = 2
LIVE_TIMEOUT = 600.0  # s of wall time for the whole flight (measured: see the test's docstring)


def _live_rig(folder: Path) -> Path:
    """A rig file: the simulator rig's extrinsics, its camera scaled to ``LIVE_SCALE``."""
    from insulator_rs.rig import scaled_camera, simulator_rig

    rig = simulator_rig()
    cam = scaled_camera(rig.camera, LIVE_SCALE)
    k = [cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0]
    (folder / "live_camera.yaml").write_text(
        f"image_width: {cam.width}\nimage_height: {cam.height}\ncamera_name: live\n"
        f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: {k}\n"
        f"distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n"
        f"  data: {[float(d) for d in cam.dist]}\n")
    matrix = lambda T: "[" + ", ".join(str([float(v) for v in row]) for row in T) + "]"  # noqa: E731
    path = folder / "live_rig.toml"
    path.write_text(f'[camera]\ncalibration = "live_camera.yaml"\nT_b_c = {matrix(rig.T_b_c)}\n\n'
                    f"[lidar]\nT_b_l = {matrix(rig.T_b_l)}\n")
    return path


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stop(proc: subprocess.Popen) -> str:
    """SIGTERM (then SIGKILL) one process we started; its output."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
    return proc.stdout.read() if proc.stdout is not None else ""


def test_small_scene_live_sensor_inspection_against_px4_sitl(px4, tmp_path) -> None:
    """The live-sensor path against PX4 itself (see the module docstring). Reference: the small
    scene's ground truth (each insulator found within 0.3 m), the drivers' own counters (no
    LiDAR datagram lost or malformed, every scan mapped to the vehicle clock, camera frames of
    the calibrated size) and PX4's log (no failsafe)."""
    import insulator_rs
    from insulator_rs.sim.towers import load_tower

    scene, mission = small_scene(tmp_path)
    _live_rig(tmp_path)
    text = mission.read_text()
    assert 'rig = "simulator"' in text
    mission.write_text(text.replace('rig = "simulator"', 'rig = "live_rig.toml"') + f"confirmations = {LIVE_CONFIRMATIONS}\n")
    mission = mission_at_home(mission, tmp_path / "at_home.toml")
    env = {**os.environ, "PYTHONPATH": str(Path(insulator_rs.__file__).parents[1])}
    port = _free_udp_port()
    head = subprocess.Popen([sys.executable, "-m", "insulator_rs.sim.sensor_head", "--scene", str(scene),
                             "--mission", str(mission), "--px4", f"udpout:127.0.0.1:{18570 + px4.instance}",
                             "--lidar-to", f"127.0.0.1:{port}"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    out = tmp_path / "report"
    try:
        line = head.stdout.readline() if head.stdout is not None else ""
        assert line.startswith("sensor head ready"), line + _stop(head)
        url = line.split("camera ", 1)[1].strip()
        t0 = time.monotonic()
        flight = subprocess.run([sys.executable, "-m", "insulator_rs.app.cli", "inspect", "--scene", str(scene),
                                 "--mission", str(mission), "--out", str(out), "--connection", px4.connection,
                                 "--lidar", f"mid360://listen:{port}", "--camera", url,
                                 "--detector", "insulator-sim", "--detect-period", "0.5", "--quiet"],
                                capture_output=True, text=True, env=env, timeout=LIVE_TIMEOUT)
        wall = time.monotonic() - t0
    finally:
        head_out = _stop(head)
    s = json.loads((out / "summary.json").read_text())
    truth = [ins.center for ins in load_tower(str(scene)).insulators]
    found = [r["center"] for r in s["insulators"]]
    errors = [min((math.dist(t, f) for f in found), default=math.inf) for t in truth]
    h = s["sensors_health"]
    print(f"live SITL flight: {s['status']}, flight {s['flight_time_s']:.0f} s, wall {wall:.0f} s, "
          f"errors {[round(e, 3) for e in errors]}, found {len(found)}, photos {len(s['photos'])}, "
          f"pairing_short {s['pairing_short']}, health {h}; {head_out.strip()}")
    deadline = time.monotonic() + DISARM_WAIT
    while "Disarmed by landing" not in px4.log() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert FAILSAFE_LINE not in px4.log()
    assert flight.returncode == 0 and s["status"] == "finished", (s["status"], flight.stdout[-2000:],
                                                                  flight.stderr[-2000:])
    assert len(truth) == 2 and max(errors) < 0.3, errors
    assert h["lidar_scans"] > 0 and h["lidar_lost"] == 0 and h["lidar_malformed"] == 0
    assert h["lidar_unmapped_scans"] == 0 and h["lidar_receive_errors"] == 0 and h["lidar_foreign_datagrams"] == 0
    assert h["camera_frames"] > 0 and h["camera_size_mismatch"] == 0 and h["camera_read_failures"] == 0
    assert s["insulators_inspected"] >= 2 and len(s["photos"]) >= 2 * 2
    assert all((out / p["file"]).stat().st_size > 1000 for p in s["photos"])
