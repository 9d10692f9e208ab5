"""The operator's abort (flight/operator_abort.py, mavlink/gcs.py): Ctrl-C / SIGTERM in the air
flies the safe route out and lands, a second one hands the vehicle to the autopilot's Return
and exits, on the ground Ctrl-C interrupts as it always did; the ground station's command
(QGroundControl's custom action, data/qgc_mavlink_actions.json) through the simulated PX4's
GCS link is acknowledged, announced and flown like the rest.

The handler's rules are checked on a stand-in flight (an object with the three things the
handler reads); the signals are real (``os.kill`` of this process) and so is the MAVLink path
(the simulated PX4 over UDP, a ground station on its GCS port).
"""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from helpers.flights import ARGS, small_scene
from helpers.gcs_listener import GcsListener, M
from helpers.simulated_px4 import started_simulators

import insulator_rs
from insulator_rs.app.cli import main
from insulator_rs.flight.abort_policy import OPERATOR, operator_reason
from insulator_rs.flight.autopilot_session import AutopilotSession
from insulator_rs.flight.operator_abort import GROUND_STATION, OperatorAbort, ReturnHandover, hand_to_return
from insulator_rs.mavlink.gcs import (ABORT_ANNOUNCEMENT, ABORT_COMMAND, ABORT_PARAM1, ABORT_REFUSED,
                                      COMPANION_COMPONENT, MavlinkGcsObserver)
from insulator_rs.ports.vehicle import FlightMode
from insulator_rs.sim.kinematics import KinematicVehicle

ACTIONS = Path(insulator_rs.__file__).parent / "data" / "qgc_mavlink_actions.json"


class _Flight:
    """What the handler reads of a flight: airborne, the vehicle's landed state, the request."""

    def __init__(self, *, airborne: bool, landed: bool) -> None:
        self.airborne = airborne
        self._landed = landed
        self.vehicle = SimpleNamespace(state=lambda: SimpleNamespace(landed=self._landed))
        self.requests: list[str] = []

    def request_abort(self, reason: str = OPERATOR) -> None:
        self.requests.append(reason)


def test_first_signal_in_the_air_asks_the_abort_the_second_hands_over():
    flight = _Flight(airborne=True, landed=False)
    op = OperatorAbort(flight)
    op.on_signal(signal.SIGINT)
    assert flight.requests == ["operator: Ctrl-C"] == [operator_reason("Ctrl-C")]
    with pytest.raises(ReturnHandover) as exc:
        op.on_signal(signal.SIGINT)
    assert exc.value.how == "Ctrl-C" and isinstance(exc.value, KeyboardInterrupt)
    assert flight.requests == ["operator: Ctrl-C"]  # the second asks nothing more of the loop


def test_sigterm_is_named_and_counts_as_the_first():
    flight = _Flight(airborne=True, landed=False)
    op = OperatorAbort(flight)
    op.on_signal(signal.SIGTERM)
    assert flight.requests == ["operator: SIGTERM"]
    with pytest.raises(ReturnHandover):
        op.on_signal(signal.SIGINT)


@pytest.mark.parametrize("airborne, landed", [(False, True), (True, True)])  # before take-off, after the landing
def test_on_the_ground_a_signal_interrupts_and_the_command_is_refused(airborne, landed):
    flight = _Flight(airborne=airborne, landed=landed)
    op = OperatorAbort(flight)
    with pytest.raises(KeyboardInterrupt) as exc:
        op.on_signal(signal.SIGINT)
    assert not isinstance(exc.value, ReturnHandover)
    assert op.request() is False and flight.requests == [] and op.signals == 0


def test_the_ground_stations_request_is_named():
    flight = _Flight(airborne=True, landed=False)
    assert OperatorAbort(flight).request() is True
    assert flight.requests == [f"operator: {GROUND_STATION}"]


def test_the_handlers_are_installed_for_the_block_and_put_back():
    flight = _Flight(airborne=True, landed=False)
    op = OperatorAbort(flight)
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with op.installed():
        os.kill(os.getpid(), signal.SIGTERM)  # a real signal: without the handler it would end pytest
        deadline = time.monotonic() + 2.0
        while not flight.requests and time.monotonic() < deadline:
            time.sleep(0.01)
        assert flight.requests == ["operator: SIGTERM"]
        with pytest.raises(ReturnHandover):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)  # the handler raises in this thread at the next bytecode
    assert {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)} == before


def test_outside_the_main_thread_nothing_is_installed():
    before = signal.getsignal(signal.SIGINT)
    seen = []

    def worker():
        with OperatorAbort(_Flight(airborne=True, landed=False)).installed():
            seen.append(signal.getsignal(signal.SIGINT))

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert seen == [before]


def test_hand_to_return_puts_the_vehicle_in_rtl_under_a_decorator():
    vehicle = KinematicVehicle()
    vehicle.arm()
    vehicle.takeoff(5.0)
    for _ in range(200):
        vehicle.advance(0.05)
    wrapped = SimpleNamespace(inner=vehicle)  # a decorator of the port offers no Return of its own
    line = hand_to_return(wrapped)
    assert vehicle.state().mode == FlightMode.RTL.value and "Return (RTL)" in line


def test_hand_to_return_says_when_there_is_none():
    assert "has no Return" in hand_to_return(SimpleNamespace(inner=None))


# -- the ground station's command, through the simulated PX4's GCS link -------------------------

def _shipped_action() -> dict:
    actions = json.loads(ACTIONS.read_text())
    assert actions["version"] == 1 and actions["fileType"] == "MavlinkActions"
    (action,) = actions["actions"]
    assert action["label"] and action["description"]
    return action


def test_the_shipped_qgc_action_is_the_command_the_companion_takes():
    action = _shipped_action()
    assert (action["mavCmd"], action["compId"], action["param1"]) == (ABORT_COMMAND, COMPANION_COMPONENT,
                                                                      ABORT_PARAM1)
    assert ABORT_COMMAND == 31010  # MAV_CMD_USER_1


def _acks(gcs: GcsListener) -> list[tuple[int, int]]:
    return [(a.command, a.result) for a in gcs.of("COMMAND_ACK", COMPANION_COMPONENT)]


def test_the_command_through_px4s_gcs_link_is_acknowledged_announced_and_asked():
    from insulator_rs.sim.px4 import start_simulated_px4

    action = _shipped_action()
    in_air = [False]
    asked: list[str] = []

    def handler() -> bool:
        if in_air[0]:
            asked.append("abort")
        return in_air[0]

    sim, vehicle = start_simulated_px4(sim_options={"gcs_port": 0})
    obs = MavlinkGcsObserver.on_vehicle(vehicle)
    try:
        with GcsListener(sim.gcs.address, ask_camera=False) as gcs:
            assert gcs.wait_for(lambda: gcs.of("HEARTBEAT", 1), 5.0)
            target = (sim.system_id, action["compId"])
            gcs.command_long(target, action["mavCmd"], action["param1"])  # no flight attached yet
            assert gcs.wait_for(lambda: len(_acks(gcs)) == 1, 5.0)
            obs.on_abort_command(handler)
            gcs.command_long(target, action["mavCmd"], action["param1"])  # on the ground
            assert gcs.wait_for(lambda: len(_acks(gcs)) == 2, 5.0)
            in_air[0] = True
            gcs.command_long(target, action["mavCmd"], 0.0)  # another tool's user command
            gcs.command_long(target, M.MAV_CMD_DO_SET_MODE, 1)  # not ours to take
            assert gcs.wait_for(lambda: len(_acks(gcs)) == 4, 5.0)
            assert asked == []
            gcs.command_long(target, action["mavCmd"], action["param1"])  # in the air
            assert gcs.wait_for(lambda: len(_acks(gcs)) == 5 and any(
                t == ABORT_ANNOUNCEMENT for _, _, t in gcs.statustexts()), 5.0)
            texts = gcs.statustexts()
    finally:
        obs.close()
        vehicle.close()
    assert _acks(gcs) == [(ABORT_COMMAND, M.MAV_RESULT_DENIED), (ABORT_COMMAND, M.MAV_RESULT_TEMPORARILY_REJECTED),
                          (ABORT_COMMAND, M.MAV_RESULT_DENIED), (M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_UNSUPPORTED),
                          (ABORT_COMMAND, M.MAV_RESULT_ACCEPTED)]
    assert asked == ["abort"]
    assert (COMPANION_COMPONENT, M.MAV_SEVERITY_WARNING, ABORT_REFUSED) in texts
    assert (COMPANION_COMPONENT, M.MAV_SEVERITY_CRITICAL, ABORT_ANNOUNCEMENT) in texts
    for ack in gcs.of("COMMAND_ACK", COMPANION_COMPONENT):  # answered to the ground station that asked
        assert (ack.target_system, ack.target_component) == (255, M.MAV_COMP_ID_MISSIONPLANNER)


# -- whole flights on the small scene ------------------------------------------------------------

def _trajectory(out: Path) -> tuple[np.ndarray, list[str]]:
    with (out / "trajectory.csv").open() as f:
        rows = list(csv.reader(f))[1:]
    return np.array([[float(x) for x in r[:4]] for r in rows]), [r[5] for r in rows]


def _flew_the_safe_route_and_landed(out: Path, summary: dict) -> None:
    traj, states = _trajectory(out)
    after = np.array([s == "abort" for s in states])
    assert after.any() and np.all(after[np.argmax(after):]), "the abort comes once and lasts"
    ab = summary["abort"]
    assert ab["route"] is not None and ab["handed_over"] is None and ab["legs"], ab
    last = traj[-1, 1:4]
    assert last[2] < 0.1, "it lands"
    assert np.linalg.norm(np.array(ab["landing_point"])[:2] - last[:2]) < 0.5, "where the route ends"


@pytest.mark.slow
def test_the_ground_stations_abort_mid_flight_flies_the_safe_route_and_lands(tmp_path, monkeypatch):
    """The pilot presses QGroundControl's custom action (the shipped file's command) on the GCS link
    of the simulated PX4, in the exploration: the companion acknowledges and announces it, the
    mission flies the safe route out and lands, and the report says ``aborted: operator``."""
    action = _shipped_action()
    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    sims = started_simulators(monkeypatch)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with GcsListener(("127.0.0.1", port), ask_camera=False) as gcs:
        def press_when_exploring() -> None:
            if gcs.wait_for(lambda: any("-> explore" in t for _, _, t in gcs.statustexts()), 120.0):
                time.sleep(3.0)  # a few seconds into the first pass
                gcs.command_long((1, action["compId"]), action["mavCmd"], action["param1"])

        presser = threading.Thread(target=press_when_exploring, daemon=True)
        presser.start()
        rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out),
                   "--vehicle", "mavlink", "--gcs-port", str(port), "--time-scale", "2", *ARGS])
        presser.join(timeout=5.0)
        gcs.wait_for(lambda: gcs.of("COMMAND_ACK", COMPANION_COMPONENT), 2.0)
    summary = json.loads((out / "summary.json").read_text())
    assert rc == 1  # aborted: the mission did not do its job
    assert summary["status"] == f"aborted: {OPERATOR}: {GROUND_STATION}"
    _flew_the_safe_route_and_landed(out, summary)
    assert _acks(gcs) == [(ABORT_COMMAND, M.MAV_RESULT_ACCEPTED)]
    texts = [t for _, _, t in gcs.statustexts()]
    assert ABORT_ANNOUNCEMENT in texts and f"Inspection aborted: {OPERATOR}: {GROUND_STATION}" in texts
    assert sims and sims[0].with_vehicle(lambda v: v.state().landed)  # the simulated PX4 says so too


def _signal_when_flying(out: Path, signals: list[signal.Signals], *, after_s: float,
                        gap_s: float = 0.0) -> threading.Thread:
    """A thread that sends ``signals`` to this process once summary.json says the flight has
    flown ``after_s`` s (``gap_s`` wall s between them)."""

    def run() -> None:
        deadline = time.monotonic() + 300.0
        while time.monotonic() < deadline:
            try:
                s = json.loads((out / "summary.json").read_text())
            except (OSError, ValueError):
                s = {}
            if s.get("status") == "running" and (s.get("flight_time_s") or 0.0) >= after_s:
                for k, sig in enumerate(signals):
                    if k:
                        time.sleep(gap_s)
                    os.kill(os.getpid(), sig)
                return
            time.sleep(0.05)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


@pytest.mark.slow
def test_ctrl_c_in_the_air_flies_the_safe_route_and_lands(tmp_path):
    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    before = signal.getsignal(signal.SIGINT)
    sender = _signal_when_flying(out, [signal.SIGINT], after_s=20.0)
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS])
    sender.join(timeout=5.0)
    summary = json.loads((out / "summary.json").read_text())
    assert rc == 1
    assert summary["status"] == "aborted: operator: Ctrl-C"
    _flew_the_safe_route_and_landed(out, summary)
    assert signal.getsignal(signal.SIGINT) is before  # the command line put the old handler back


@pytest.mark.slow
def test_a_second_ctrl_c_hands_over_to_the_return_and_exits(tmp_path, monkeypatch, capsys):
    from insulator_rs.app import inspect_command

    vehicles: list[KinematicVehicle] = []
    original = inspect_command.kinematic_vehicle

    def recorded(*a, **k):
        vehicles.append(original(*a, **k))
        return vehicles[-1]

    monkeypatch.setattr(inspect_command, "kinematic_vehicle", recorded)
    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    sender = _signal_when_flying(out, [signal.SIGINT, signal.SIGINT], after_s=20.0, gap_s=0.5)
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS])
    sender.join(timeout=5.0)
    summary = json.loads((out / "summary.json").read_text())
    assert rc == 130
    assert summary["status"].startswith("aborted: operator: Ctrl-C; Ctrl-C again: handed over to PX4's Return")
    (vehicle,) = vehicles  # closed by the command: its mode and landed state read directly
    assert vehicle.mode == FlightMode.RTL and not vehicle.landed  # the autopilot's Return flies it now
    assert "Ctrl-C again: handed over to PX4's Return (RTL)" in capsys.readouterr().err
    assert not (out / "score.json").exists()  # out at once: nothing scored


def test_ctrl_c_before_take_off_interrupts_as_before(tmp_path, monkeypatch):
    """A real SIGINT during the pre-flight gate (on the ground): the program stops, ``interrupted``."""
    def preflight_then_ctrl_c(self):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(1.0)  # the handler raises here

    monkeypatch.setattr(AutopilotSession, "preflight", preflight_then_ctrl_c)
    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS])
    summary = json.loads((out / "summary.json").read_text())
    assert rc == 130 and summary["status"] == "interrupted"
    assert summary["abort"] is None
