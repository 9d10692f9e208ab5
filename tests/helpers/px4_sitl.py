"""The packaged PX4 v1.16.0 SITL (``../shared/px4_sitl``, SIH, no Gazebo) for tests and manual runs.

* ``sitl_folder()``: where ``run.sh`` is: ``$INSULATOR_RS_PX4_SITL`` if set, else
  ``<repo root>/../shared/px4_sitl`` (the CI layout); None when absent.
* ``Px4Sitl``: starts one PX4 instance with ``run.sh -i N -d DIR -s SPEED`` on a free
  instance number (its offboard port 14540+N must be free), waits for "Ready for takeoff!"
  in ``px4.log`` and kills the whole process group on ``stop()``, always.
* The SIH battery is a flight's pack (``SITL_BATTERY``, PX4's ``PX4_PARAM_<name>`` start-up
  overrides): SIH's own default drains to 50 % in 60 s, which the battery reserve rightly reads
  as a plan that cannot be flown (every SITL flight returned at 52-55 %).
* ``mission_at_home()``: a mission file whose take-off point is PX4's home: the tower (and
  its neighbours) are moved so the mission's own take-off point (the file's ``[takeoff]`` or
  its default on the "+" side at the standoff) lands on home, keeping the geometry in the
  tower's ENU frame exactly (pymap3d both ways).

Run by hand::

    PYTHONPATH=python:tests python tests/px4_sitl.py tower_b --speed 2 --out /tmp/tower_b_sitl
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

#: PX4 and the sensor head stand for hardware of their own (the flight controller's MCU, the
#: LiDAR and the camera), which a loaded companion computer cannot slow down. On one shared
#: two-core box they run at a higher priority than the client, so that the load a test puts on
#: the machine lands on the software under test, not on the simulated hardware: measured beside
#: a CI build at normal priority, the head's LiDAR left 0.39 s late at the median (1.76 s at
#: p99), which no Mid-360 does. Without the privilege to raise a priority (not root) they run at
#: the normal one (``nice`` would warn on the output the head's readiness line is read from).
HARDWARE_PRIORITY = ["nice", "-n", "-10"] if os.geteuid() == 0 else []

REPO = Path(__file__).resolve().parents[2]
ENV_VAR = "INSULATOR_RS_PX4_SITL"
# PX4 SITL's home as its HOME_POSITION says before arming (measured twice on v1.16.0 SIH:
# 47.3977434, 8.5455942, 489.382-489.397 m): SIH starts at SIH_LOC_LAT0/LON0/H0 (47.397742,
# 8.545594, 488.0, its README), and the estimator's home lies 0.16 m north and 1.4 m above it.
# The pre-flight's home check (flight/preflight.py) allows 1 m in height: a mission put on the
# SIH start would be refused.
PX4_HOME = (47.3977434, 8.5455942, 489.39)
OFFBOARD_PORT = 14540  # PX4's onboard link sends to udp 127.0.0.1:14540 + instance
READY_LINE = "Ready for takeoff!"
FAILSAFE_LINE = "Failsafe activated"


def _main_checkout(repo: Path) -> Path:
    """The main checkout of a git worktree (``.git`` is then a file naming its gitdir)."""
    git = repo / ".git"
    try:
        if git.is_file():
            gitdir = Path(git.read_text().split("gitdir:", 1)[1].strip())
            common = (gitdir / (gitdir / "commondir").read_text().strip()).resolve()
            return common.parent
    except (OSError, IndexError):
        pass
    return repo


def sitl_folder() -> Path | None:
    """The folder holding ``run.sh`` and the PX4 tarball, or None when it is not there:
    ``$INSULATOR_RS_PX4_SITL``, else ``../shared/px4_sitl`` beside the repository (or beside
    its main checkout, for a git worktree)."""
    env = os.environ.get(ENV_VAR)
    candidates = [Path(env)] if env else [root.parent / "shared" / "px4_sitl"
                                          for root in (REPO, _main_checkout(REPO))]
    return next((c for c in candidates if (c / "run.sh").is_file()), None)


def _port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _lock_free(instance: int) -> bool:
    """Whether PX4's per-instance lock (``/tmp/px4_lock-N``, a POSIX lockf its server holds) is free."""
    path = f"/tmp/px4_lock-{instance}"
    if not os.path.exists(path):
        return True
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return False
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fcntl.lockf(fd, fcntl.LOCK_UN)
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


def _instance_free(instance: int) -> bool:
    # The ports PX4 binds (its UDP links, see px4.log "udp port ...") and the one we listen on,
    # and PX4's own lock: a server starting beside us holds it before it binds the ports.
    ports = (OFFBOARD_PORT + instance, 14580 + instance, 18570 + instance, 14280 + instance,
             13030 + instance, 19450 + instance)
    return _lock_free(instance) and all(_port_free(p) for p in ports)


ALREADY_RUNNING = "PX4 server already running for instance"


#: SIH's battery as a 25-minute pack: 95 % in 1500 s (SIM_BAT_DRAIN: the time to drain from
#: full to SIM_BAT_MIN_PCT). A test of the reserve sets its own over PARAM_SET.
SITL_BATTERY = {"SIM_BAT_DRAIN": "1500", "SIM_BAT_MIN_PCT": "5"}


class Px4Sitl:
    """One PX4 SITL process (see the module docstring); a context manager."""

    def __init__(self, folder: Path, *, speed: float = 1.0, workdir: Path | None = None,
                 first_instance: int = 1) -> None:
        self.folder = folder
        self.speed = speed
        self.workdir = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="px4-sitl-"))
        self.instance = next((i for i in range(first_instance, first_instance + 40) if _instance_free(i)), None)
        if self.instance is None:
            raise RuntimeError("no free PX4 SITL instance (UDP ports 14540+N all taken)")
        self.pid: int | None = None

    @property
    def connection(self) -> str:
        return f"udpin:127.0.0.1:{OFFBOARD_PORT + self.instance}"

    @property
    def log_path(self) -> Path:
        return self.workdir / "px4.log"

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def start(self, ready_timeout: float = 90.0, tries: int = 5) -> Px4Sitl:
        """Start PX4 and wait for its ready line; an instance another PX4 took between our check
        and its start (two test runs side by side) is given up for the next free one."""
        for _ in range(tries - 1):
            self._start_once(ready_timeout)
            if self.pid is not None:
                return self
            taken = self.instance
            self.instance = next((i for i in range(taken + 1, taken + 40) if _instance_free(i)), None)
            if self.instance is None:
                raise RuntimeError("no free PX4 SITL instance (UDP ports 14540+N all taken)")
        self._start_once(ready_timeout)
        if self.pid is None:
            raise RuntimeError(f"PX4 SITL: instance {self.instance} taken by another PX4 each of {tries} tries")
        return self

    def _start_once(self, ready_timeout: float) -> None:
        """One start; ``pid`` None if the instance turned out to be another PX4's."""
        env = {**os.environ, **{f"PX4_PARAM_{k}": v for k, v in SITL_BATTERY.items()}}
        out = subprocess.run([*HARDWARE_PRIORITY, str(self.folder / "run.sh"), "-i", str(self.instance), "-d",
                              str(self.workdir), "-s", f"{self.speed:g}"], capture_output=True, text=True, timeout=60,
                             check=True, env=env)
        self.pid = int(out.stdout.strip().splitlines()[-1])
        deadline = time.monotonic() + ready_timeout
        while READY_LINE not in self.log():
            if ALREADY_RUNNING in self.log():
                self.stop()
                self.pid = None
                self.log_path.unlink(missing_ok=True)
                return
            if time.monotonic() > deadline or not self._alive():
                tail = "\n".join(self.log().splitlines()[-20:])
                self.stop()
                raise RuntimeError(f"PX4 SITL not ready within {ready_timeout:g} s; px4.log ends:\n{tail}")
            time.sleep(0.2)

    def _alive(self) -> bool:
        if self.pid is None:
            return False
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return False
        return True

    def stop(self) -> None:
        """Kill PX4's process group (run.sh starts it with setsid: pid == pgid) and reap it."""
        if self.pid is None:
            return
        pid, self.pid = self.pid, None
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(pid, sig)
            except ProcessLookupError:
                return
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline:
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    return
                time.sleep(0.1)

    def __enter__(self) -> Px4Sitl:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


@contextmanager
def companion_link(connection: str) -> Iterator[tuple[Any, tuple[int, int]]]:
    """A bare pymavlink link to an autopilot as the companion computer (system 1, component
    191), once the autopilot's HEARTBEAT came: (the link, the autopilot's (system, 1)). Closed
    on exit."""
    from insulator_rs.mavlink.wire import mavlink2 as M
    from insulator_rs.mavlink.wire import mavutil

    link = mavutil.mavlink_connection(connection, source_system=1, source_component=191)
    try:
        link.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
        heartbeat = link.recv_match(type="HEARTBEAT", blocking=True, timeout=30)
        assert heartbeat is not None, f"no HEARTBEAT on {connection}"
        yield link, (heartbeat.get_srcSystem(), 1)
    finally:
        link.close()


def mission_at_home(mission_file: Path, out_file: Path, home: tuple[float, float, float] = PX4_HOME) -> Path:
    """Write ``mission_file`` moved so that its take-off point is ``home`` (lat, lon, alt AMSL).

    The tower goes where home minus the take-off point's ENU offset from the tower is
    (pymap3d.enu2geodetic about home); the neighbours keep their ENU offsets from the
    tower; ``[takeoff]`` is set to home itself. Altitudes: the tower base at home's
    altitude minus the take-off point's height above it.
    """
    import numpy as np
    import pymap3d  # type: ignore[import-untyped]

    from insulator_rs._toml import tomllib
    from insulator_rs.mission.config import load_mission

    mission = load_mission(mission_file)
    takeoff = mission.takeoff_enu()
    neighbours = mission.neighbours_enu()
    tower = pymap3d.enu2geodetic(*(-np.asarray(takeoff, dtype=float)), *home)
    data = tomllib.loads(mission_file.read_text())
    lines = ["[tower]", f"lat = {float(tower[0])!r}", f"lon = {float(tower[1])!r}", f"alt = {float(tower[2])!r}",
             f"max_height = {data['tower']['max_height']!r}", f"max_width = {data['tower']['max_width']!r}", ""]
    for n in neighbours:
        lat, lon, alt = pymap3d.enu2geodetic(*n, *tower)
        lines += ["[[neighbours]]", f"lat = {float(lat)!r}", f"lon = {float(lon)!r}", f"alt = {float(alt)!r}", ""]
    lines += ["[takeoff]", f"lat = {home[0]!r}", f"lon = {home[1]!r}", f"alt = {home[2]!r}", ""]
    for table in ("vehicle", "inspection"):
        if table in data:
            lines.append(f"[{table}]")
            # JSON's scalars and arrays are TOML's (a bool is true/false, not Python's True)
            lines += [f"{k} = {json.dumps(v)}" for k, v in data[table].items()]
            lines.append("")
    out_file.write_text("\n".join(lines))
    return out_file


def main(argv: list[str] | None = None) -> int:
    """Fly a built-in scene's inspection against a fresh PX4 SITL; print PX4's failsafes."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("scene", help="tower_a or tower_b (its example mission is moved to PX4's home)")
    parser.add_argument("--speed", type=float, default=1.0, help="PX4 speed factor (run.sh -s)")
    parser.add_argument("--out", type=Path, required=True, help="report folder")
    parser.add_argument("extra", nargs="*", help="more insulator-rs inspect arguments (after --)")
    args = parser.parse_args(argv)
    folder = sitl_folder()
    if folder is None:
        print(f"no PX4 SITL folder (set {ENV_VAR} or put it at {REPO.parent / 'shared' / 'px4_sitl'})",
              file=sys.stderr)
        return 2
    from insulator_rs.app.cli import main as cli

    args.out.mkdir(parents=True, exist_ok=True)
    mission = mission_at_home(REPO / "python" / "insulator_rs" / "missions" / f"{args.scene}.toml",
                              args.out.parent / f"{args.out.name}_mission.toml")
    with Px4Sitl(folder, speed=args.speed, workdir=args.out.parent / f"{args.out.name}_px4") as px4:
        print(f"PX4 SITL instance {px4.instance} (x{args.speed:g}), log {px4.log_path}", flush=True)
        t0 = time.monotonic()
        rc = cli(["inspect", "--scene", args.scene, "--mission", str(mission), "--out", str(args.out),
                  "--connection", px4.connection, "--sim-sensors", "--time-scale", f"{args.speed:g}",
                  *args.extra])
        wall = time.monotonic() - t0
        failsafes = [line for line in px4.log().splitlines() if FAILSAFE_LINE in line]
    print(f"inspect exit code {rc}, wall {wall:.0f} s, PX4 failsafes: {failsafes or 'none'}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
