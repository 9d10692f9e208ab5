"""The small scene flown once through PX4 v1.16.0 SITL (``--sim-sensors``), read by three tests.

The plain inspection (``test_px4_sitl``), the ground station's view of it (``test_px4_sitl_gcs``)
and PX4's parameters set for the tower and restored (``test_px4_sitl_parameters``) each flew this
same flight on its own PX4: 151 + 161 + 187 s of CI's 90 minutes. One flight, with a ground
station on PX4's GCS link (which the parameter test needs, and which changes nothing the others
check), serves all three: ``reference_flight`` is a session fixture, so the flight happens once,
when the first of them asks, and PX4 is stopped (its process group killed) as soon as the
flight, the disarm and the parameter read-back are over. The fixture is in ``conftest.py``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from helpers.gcs_listener import GcsListener
from helpers.px4_sitl import Px4Sitl, mission_at_home
from helpers.flights import small_scene

GCS_PORT = 18570  # PX4 SITL's GCS link: udp 18570 + instance
# s of wall time to wait for PX4's own disarm after the landing (COM_DISARM_LAND 2 s; loaded box)
DISARM_WAIT = 20.0


@dataclass
class ReferenceFlight:
    """What the flight left: the client's exit code and report, PX4's log, the ground station
    (closed; what it received stays readable), and PX4's parameter values read back after it."""

    rc: int
    out: Path
    mission: Path
    summary: dict[str, Any]
    score: dict[str, Any]
    px4_log: str
    instance: int
    gcs: GcsListener
    parameters_after: dict[str, Any]


def _read_back(connection: str, names: list[str], speed: float) -> dict[str, Any]:
    """PX4's values now, through the client's own parameter protocol (a fresh connection)."""
    from insulator_rs.mavlink.client import connect_vehicle

    with connect_vehicle(connection, time_scale=speed) as vehicle:
        return {name: vehicle.parameters.read(name) for name in names}


def fly(folder: Path, workdir: Path, speed: float, args: list[str]) -> ReferenceFlight:
    from insulator_rs.app.cli import main

    scene, mission = small_scene(workdir)
    mission.write_text(mission.read_text() + "confirmations = 1\n")
    mission = mission_at_home(mission, workdir / "at_home.toml")
    out = workdir / "report"
    with Px4Sitl(folder, speed=speed, workdir=workdir / "px4", first_instance=3) as px4:
        with GcsListener(("127.0.0.1", GCS_PORT + px4.instance), recover_images=True) as gcs:
            assert gcs.wait_for(lambda: gcs.of("HEARTBEAT", 1), 10.0)
            rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *args,
                       "--connection", px4.connection, "--sim-sensors", "--time-scale", f"{speed:g}"])
            # PX4 disarms COM_DISARM_LAND (2 s) after it detects the landing, which may come after
            # the client has returned (CI saw the landing line without the disarm): wait, bounded
            deadline = time.monotonic() + DISARM_WAIT
            while "Disarmed by landing" not in px4.log() and time.monotonic() < deadline:
                time.sleep(0.2)
            time.sleep(1.0)  # the last forwarded frames reach the ground station
        summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else {}
        score = json.loads((out / "score.json").read_text()) if (out / "score.json").exists() else {}
        names = [r["name"] for r in summary.get("px4_parameters", {}).get("parameters", [])]
        after = _read_back(px4.connection, names, speed) if names else {}
        log = px4.log()
    return ReferenceFlight(rc=rc, out=out, mission=mission, summary=summary, score=score, px4_log=log,
                           instance=px4.instance, gcs=gcs, parameters_after=after)


def fly_once_for_the_session(tmp_path_factory: pytest.TempPathFactory) -> ReferenceFlight:
    """The ``reference_flight`` fixture's body (the fixture lives in conftest.py: a session
    fixture imported into several modules is one fixture per module, and would fly once each)."""
    from helpers.flights import ARGS
    from helpers.sitl_suite import FOLDER, SPEED

    if FOLDER is None:
        pytest.skip("PX4 SITL folder absent")
    return fly(FOLDER, tmp_path_factory.mktemp("sitl_reference_flight"), SPEED, ARGS)
