"""One live-sensor flight against PX4 SITL, shared by the CI test and the soak script.

``fly_live(px4, folder, scene, mission)``: the sensor head (``insulator_rs.sim.sensor_head``, a
process of its own) reads PX4's pose from PX4's GCS link and plays a Mid-360 (Livox SDK2
datagrams on UDP, its own clock) and an MJPEG camera; ``insulator-rs inspect --lidar
mid360://listen:PORT --camera http://...`` flies the mission with the LIVE drivers in a
subprocess, at the mission's defaults unless ``extra`` says otherwise. The result is scored
against the scene's ground truth and PX4's log.

Soak (item 5 of issue 18; not a CI test)::

    PYTHONPATH=python:tests python tests/live_sitl.py --small 10 --tower-b 3 --out /tmp/soak
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import socket
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from helpers.px4_sitl import FAILSAFE_LINE, HARDWARE_PRIORITY, Px4Sitl, mission_at_home, sitl_folder

REPO = Path(__file__).resolve().parents[2]
# A live flight's camera: the simulator's lens at 320 x 240 (the rig's calibration must match
# the frames the camera delivers), rendered and served at 3 fps by the sensor head.
LIVE_SCALE = 0.25
# The payload's camera in a live flight: the simulator's 12 MP zoom at 400 x 300 (a ray-cast 12 MP
# photo takes seconds of the sensor head's CPU beside PX4, and its MAVLink FTP download minutes).
PAYLOAD_SCALE = 0.1
LIVE_TIMEOUT = 900.0  # s of wall time for the whole flight
DISARM_WAIT = 20.0  # s of wall time to wait for PX4's own disarm after the landing (COM_DISARM_LAND 2 s)


def live_rig(folder: Path, lidar_latency_s: float = 0.0, payload_port: int | None = None) -> Path:
    """A rig file: the simulator rig's extrinsics, its camera scaled to ``LIVE_SCALE``, the
    sensor head camera's fixed latency as its calibration states it (``latency_s``), and the
    head's LiDAR latency (``--lidar-latency``) where it holds its packets to one. With
    ``payload_port``: the simulator's inspection camera scaled to ``PAYLOAD_SCALE`` as a MAVLink
    payload on that port (the sensor head's ``--payload-port``), its gimbal aimed directly."""
    from insulator_rs.rig import scaled_camera, simulator_rig
    from insulator_rs.sim.sensor_head import CAMERA_LATENCY_S

    rig = simulator_rig()
    write_camera_info(folder / "live_camera.yaml", scaled_camera(rig.camera, LIVE_SCALE), "live")
    matrix = lambda T: "[" + ", ".join(str([float(v) for v in row]) for row in T) + "]"  # noqa: E731
    path = folder / "live_rig.toml"
    inspection = ""
    if payload_port is not None:
        wide = rig.inspection_camera()
        zoom = scaled_camera(wide.camera, PAYLOAD_SCALE)
        write_camera_info(folder / "payload_camera.yaml", zoom, "payload")
        long_end = wide.focal_px[1] * PAYLOAD_SCALE
        limits = [[math.degrees(a) for a in pair] for pair in (wide.gimbal.pitch, wide.gimbal.yaw)]
        inspection = (f'\n[inspection_camera]\ncalibration = "payload_camera.yaml"\n'
                      f"focal_length_px = [{0.5 * (zoom.fx + zoom.fy)!r}, {long_end!r}]\n"
                      f"T_b_c = {matrix(wide.T_b_c)}\ngimbal_pitch_deg = {limits[0]}\ngimbal_yaw_deg = {limits[1]}\n"
                      f'payload = "udpout:127.0.0.1:{payload_port}"\npayload_gimbal = "device"\n')
    path.write_text(f'[camera]\ncalibration = "live_camera.yaml"\nT_b_c = {matrix(rig.T_b_c)}\n'
                    f"latency_s = {CAMERA_LATENCY_S}\n\n[lidar]\nT_b_l = {matrix(rig.T_b_l)}\n"
                    + (f"latency_s = {lidar_latency_s}\n" if lidar_latency_s else "") + inspection)
    return path


def write_camera_info(path: Path, cam: Any, name: str) -> None:
    """``cam``'s intrinsics as a ROS camera_info YAML file."""
    k = [cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0]
    path.write_text(f"image_width: {cam.width}\nimage_height: {cam.height}\ncamera_name: {name}\n"
                    f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: {k}\n"
                    f"distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n"
                    f"  data: {[float(d) for d in cam.dist]}\n")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def stop_process(proc: subprocess.Popen) -> str:
    """SIGTERM (then SIGKILL) one process we started; its output."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
    return proc.stdout.read() if proc.stdout is not None else ""


@dataclass
class LiveFlight:
    """What one live flight did, scored against the scene's ground truth."""

    returncode: int
    status: str
    errors: list[float]  # m: each true insulator to the nearest found one
    false_finds: int  # found insulators farther than the match distance from every true one
    failsafe: bool
    wall_s: float
    summary: dict[str, Any] = field(repr=False)
    head_output: str = field(repr=False, default="")
    stdout: str = field(repr=False, default="")
    stderr: str = field(repr=False, default="")

    def line(self) -> str:
        s = self.summary
        h = s.get("sensors_health", {})
        return (f"{self.status}, flight {s.get('flight_time_s', math.nan):.0f} s, wall {self.wall_s:.0f} s, "
                f"errors {[round(e, 3) for e in self.errors]}, false {self.false_finds}, failsafe {self.failsafe}, "
                f"localizations {s.get('localizations')}, pairing_short {s.get('pairing_short')}, "
                f"pairing timing {s.get('pairing_timing')}, "
                f"perception {s.get('perception')}, lidar drift_ppm {h.get('lidar_clock_drift_ppm')}, "
                f"timesync {s.get('timesync')}, companion stalls {_stalls(s)}, candidates "
                f"{[(c['observations'], [round(x, 1) for x in c['center']]) for c in s.get('candidates', [])]}")


def gstreamer_available() -> bool:
    """Whether PyGObject and GStreamer's HTTP, multipart and JPEG elements are here."""
    try:
        import gi

        gi.require_version("Gst", "1.0")
        from gi.repository import Gst
    except (ImportError, ValueError):
        return False
    Gst.init(None)
    return all(Gst.ElementFactory.find(e) is not None for e in ("souphttpsrc", "multipartdemux", "jpegdec"))


def camera_source(url: str) -> str:
    """The ``--camera`` for the sensor head's MJPEG stream: through GStreamer where it is here (the
    frames stamped by GStreamer's own thread as they arrive, ``do-timestamp``), else OpenCV's
    reader (stamped by a Python thread: measured 0.1-0.4 s late on a loaded box, the pose the
    frame goes with then off by up to a metre at 3 m/s)."""
    if gstreamer_available():
        return f"souphttpsrc location={url} is-live=true do-timestamp=true ! multipartdemux ! jpegdec"
    return url


def _stalls(summary: dict[str, Any]) -> str:
    """The companion's stalls of a summary (flight/stall_watch.py): count, longest, total."""
    st = summary.get("companion_stalls")
    if not st:
        return "not watched"
    return f"{st['count']} (max {st['max_s']} s, total {st['total_s']} s)"


def fly_live(px4: Px4Sitl, folder: Path, scene: Path, mission: Path, *, extra: list[str] = (),
             head_args: list[str] = (), confirmations: int | None = None,
             inspection_extra: str = "", lidar_latency_s: float = 0.0, payload: bool = False) -> LiveFlight:
    """Fly ``mission`` over ``scene`` against ``px4`` with the live drivers (module docstring);
    ``confirmations`` replaces the mission's (None: its own, the default 4); ``inspection_extra``:
    TOML lines appended to the mission's ``[inspection]`` (its last table), for an experiment;
    ``lidar_latency_s``: the head holds each LiDAR packet to this delay after its samples
    (``--lidar-latency``) and the rig states it (0: sent as soon as rendered); ``payload``: the
    sensor head plays the inspection camera as a MAVLink payload the flight photographs through."""
    import insulator_rs
    from insulator_rs.evaluation.scoring import MATCH_DISTANCE
    from insulator_rs.sim.towers import load_tower

    folder.mkdir(parents=True, exist_ok=True)
    payload_port = free_udp_port() if payload else None
    live_rig(folder, lidar_latency_s, payload_port)
    if payload_port is not None:
        head_args = [*head_args, "--payload-port", str(payload_port)]
    text = mission.read_text()
    assert 'rig = "simulator"' in text, mission
    live_mission = folder / "live_mission.toml"
    text = text.replace('rig = "simulator"', 'rig = "live_rig.toml"')
    if confirmations is not None:
        text += f"confirmations = {confirmations}\n"
    live_mission.write_text(text + (inspection_extra.strip() + "\n" if inspection_extra.strip() else ""))
    live_mission = mission_at_home(live_mission, folder / "at_home.toml")
    env = {**os.environ, "PYTHONPATH": str(Path(insulator_rs.__file__).parents[1])}
    port = free_udp_port()
    head = subprocess.Popen([*HARDWARE_PRIORITY, sys.executable, "-m", "insulator_rs.sim.sensor_head", "--scene", str(scene),
                             "--mission", str(live_mission), "--px4", f"udpout:127.0.0.1:{18570 + px4.instance}",
                             "--lidar-to", f"127.0.0.1:{port}", "--lidar-latency", str(lidar_latency_s), *head_args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    out = folder / "report"
    stdout = stderr = ""
    rc = -1
    try:
        line = head.stdout.readline() if head.stdout is not None else ""
        if not line.startswith("sensor head ready"):
            raise RuntimeError(line + stop_process(head))
        url = line.split("camera ", 1)[1].split(",", 1)[0].strip()
        t0 = time.monotonic()
        try:
            flight = subprocess.run([sys.executable, "-m", "insulator_rs.app.cli", "inspect", "--scene", str(scene),
                                     "--mission", str(live_mission), "--out", str(out), "--connection", px4.connection,
                                     "--lidar", f"mid360://listen:{port}", "--camera", camera_source(url),
                                     "--detector", "insulator-sim", "--quiet", *extra],
                                    capture_output=True, text=True, env=env, timeout=LIVE_TIMEOUT)
            rc, stdout, stderr = flight.returncode, flight.stdout, flight.stderr
        except subprocess.TimeoutExpired as exc:
            stdout, stderr = str(exc.stdout or ""), str(exc.stderr or "")
        wall = time.monotonic() - t0
    finally:
        head_out = stop_process(head)
    try:
        s = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        s = {"status": "no summary"}
    truth = [ins.center for ins in load_tower(str(scene)).insulators]
    found = [r["center"] for r in s.get("insulators", [])]
    errors = [min((math.dist(t, f) for f in found), default=math.inf) for t in truth]
    false = sum(1 for f in found if min(math.dist(t, f) for t in truth) > MATCH_DISTANCE)
    deadline = time.monotonic() + DISARM_WAIT
    while "Disarmed by landing" not in px4.log() and time.monotonic() < deadline:
        time.sleep(0.2)
    return LiveFlight(rc, str(s.get("status")), errors, false, FAILSAFE_LINE in px4.log(), wall, s,
                      head_out, stdout, stderr)


def main(argv: list[str] | None = None) -> int:
    """Soak the live path: consecutive live-sensor flights against fresh PX4 SITLs, at the defaults."""
    from helpers.flights import small_scene

    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("--small", type=int, default=10, help="small-scene flights")
    p.add_argument("--tower-b", type=int, default=3, help="tower B flights")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--head", default="", help="sensor head arguments, one string (e.g. '--log head.jsonl')")
    p.add_argument("--head-log", action="store_true",
                   help="the sensor head's timing log (head.jsonl: each LiDAR send, camera image, clock sample) in each flight's folder")
    p.add_argument("--lidar-latency", type=float, default=0.0,
                   help="s: the head sends each LiDAR packet this long after its samples, the rig says so (0: as rendered)")
    p.add_argument("--record", action="store_true",
                   help="record each flight (flight.mcap in its folder: a miss can then be replayed)")
    p.add_argument("--inspection", default="",
                   help="TOML lines appended to the mission's [inspection] (an experiment, e.g. 'photo_retakes = 0')")
    p.add_argument("extra", nargs="*", help="more inspect arguments (after --)")
    args = p.parse_args(argv)
    folder = sitl_folder()
    if folder is None:
        print("no PX4 SITL folder", file=sys.stderr)
        return 2
    runs: list[tuple[str, int]] = [("small", i) for i in range(args.small)] + [("tower_b", i) for i in range(args.tower_b)]
    rows = []
    for kind, i in runs:
        work = args.out / f"{kind}_{i}"
        work.mkdir(parents=True, exist_ok=True)
        if kind == "small":
            scene, mission = small_scene(work)
        else:
            scene = REPO / "python" / "insulator_rs" / "scenes" / "tower_b.toml"
            mission = REPO / "python" / "insulator_rs" / "missions" / "tower_b.toml"
        with Px4Sitl(folder, workdir=work / "px4") as px4:
            extra = [*args.extra, *(["--record", str(work / "flight.mcap")] if args.record else [])]
            head_args = [*shlex.split(args.head), *(["--log", str(work / "head.jsonl")] if args.head_log else [])]
            result = fly_live(px4, work, Path(scene), mission, extra=extra, head_args=head_args,
                              inspection_extra=args.inspection, lidar_latency_s=args.lidar_latency)
        ok = (result.returncode == 0 and result.status == "finished" and max(result.errors) < 0.30
              and result.false_finds == 0 and not result.failsafe)
        print(f"{kind} {i}: {'PASS' if ok else 'FAIL'} {result.line()}", flush=True)
        # what the sensor head and the client said, beside the flight's report, and the load
        (work / "head.txt").write_text(result.head_output)
        (work / "client_stderr.txt").write_text(result.stderr)
        (work / "client_stdout.txt").write_text(result.stdout)
        load = os.getloadavg()[0]
        if result.status == "no summary" or result.returncode != 0:
            print(f"  stderr: {result.stderr[-1500:]}\n  head: {result.head_output[-800:]}", flush=True)
        rows.append({"kind": kind, "run": i, "ok": ok, **{k: v for k, v in asdict(result).items()
                                                        if k not in ("summary", "head_output", "stdout", "stderr")},
                     "localizations": result.summary.get("localizations"),
                     "pairing_short": result.summary.get("pairing_short"), "load_1min_after": round(load, 1)})
        (args.out / "soak.json").write_text(json.dumps(rows, indent=1))
    passed = sum(r["ok"] for r in rows)
    print(f"soak: {passed} of {len(rows)} passed")
    return 0 if passed == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
