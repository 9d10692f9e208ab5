"""PX4 set for the tower before take-off: the parameter protocol, the tower's values, the flight.

References: PX4 v1.16.0 SITL's answers, measured once by hand and kept true by
``test_px4_sitl_parameters.py`` (the same requests to the real PX4): INT32 values travel bytewise
in PARAM_VALUE's float field (a C-cast 3.0 is taken as 1077936128), a PARAM_SET of another type
or an unknown name gets no answer, ranges are not enforced, and arming is refused while
NAV_DLL_ACT is set with no ground station. Here the client runs against our simulated PX4 over
real UDP on loopback, which answers as that PX4 does; the flights are the small scene's, through
``insulator-rs inspect --vehicle mavlink``.
"""

from __future__ import annotations

import json
import socket
import struct

import numpy as np
import pytest
from helpers.gcs_listener import GcsListener
from helpers.flights import ARGS, small_scene

from insulator_rs.app.cli import main
from insulator_rs.exceptions import ParameterError, PlanningError
from insulator_rs.mavlink.parameters import decode, encode
from insulator_rs.mavlink.wire import mavlink2 as M
from insulator_rs.mission.config import load_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.planning.px4_failsafes import tower_failsafe_parameters
from insulator_rs.sim.px4 import start_simulated_px4
from insulator_rs.sim.px4.parameters import SITL_DEFAULTS

INT32, REAL32 = M.MAV_PARAM_TYPE_INT32, M.MAV_PARAM_TYPE_REAL32
MISSIONS = "python/insulator_rs/missions"


def test_integers_travel_bytewise_and_bad_values_name_the_parameter() -> None:
    """Bytewise: the float field holds the int's own bytes (PX4's PARAM_ENCODE_BYTEWISE)."""
    raw = encode("COM_OBL_RC_ACT", 3, INT32)
    assert struct.pack("<f", raw) == struct.pack("<i", 3) and decode(raw, INT32) == 3
    assert decode(3.0, INT32) == 1077936128  # what PX4 makes of a C-cast 3.0 (measured)
    assert decode(encode("X", -1, INT32), INT32) == -1  # a quiet NaN's bytes survive
    assert encode("RTL_RETURN_ALT", 35.5, REAL32) == 35.5
    for name, value, kind, words in (("COM_OBL_RC_ACT", 2.5, INT32, "integral"),
                                     ("RTL_RETURN_ALT", float("nan"), REAL32, "finite"),
                                     ("RTL_RETURN_ALT", 1e40, REAL32, "32-bit float"),
                                     ("NAV_DLL_ACT", 2**31, INT32, "out of range"),
                                     ("GF_ACTION", 0x7F800001, INT32, "bytewise")):  # a signalling NaN
        with pytest.raises(ParameterError, match=words) as err:
            encode(name, value, kind)
        assert err.value.parameter == name and name in str(err.value)


def test_read_set_verify_against_the_simulated_px4() -> None:
    sim, vehicle = start_simulated_px4(time_scale=4.0, parameter_timeout=0.3)
    with vehicle:
        store = vehicle.parameters
        assert store.read("COM_OBL_RC_ACT") == 0 and isinstance(store.read("COM_OBL_RC_ACT"), int)
        assert store.set("COM_OBL_RC_ACT", 3) == 3
        assert sim.vehicle.params.offboard_loss_mode == "RTL"  # the airframe now returns on offboard loss
        assert store.set("RTL_RETURN_ALT", 35.5) == 35.5 and sim.vehicle.params.return_altitude == 35.5
        assert store.set("GF_MAX_HOR_DIST", 36) == 36.0  # an int for a FLOAT parameter is sent as REAL32
        assert sim.parameters.ignored == 0  # every request had the parameter's own type
        with pytest.raises(ParameterError, match="no PARAM_VALUE") as err:
            store.read("rtl_return_alt")  # PX4's names are case-sensitive: no answer
        assert err.value.parameter == "rtl_return_alt"
        with pytest.raises(ValueError, match="1-16 ASCII"):
            store.read("A_NAME_LONGER_THAN_16")


def test_lost_packets_are_retried_and_a_dead_link_is_a_named_error() -> None:
    sim, vehicle = start_simulated_px4(time_scale=4.0, parameter_timeout=0.2, parameter_retries=15,
                                       sim_options={"seed": 3})
    with vehicle:
        sim.set_packet_loss(0.3)  # both ways
        for value in (1, 2, 3, 4, 5):
            assert vehicle.parameters.set("GF_ACTION", value) == value
        assert sim.stats.dropped > 0
        sim.set_packet_loss(0.0)
        sim.set_link_lost(True)
        with pytest.raises(ParameterError, match="GF_MAX_VER_DIST.*not confirmed|GF_MAX_VER_DIST.*no PARAM_VALUE"):
            vehicle.parameters.set("GF_MAX_VER_DIST", 45.5)


def test_the_towers_values_clear_the_tower_and_ranges_are_checked() -> None:
    """Reference: the mission's own numbers (tower B: volumes' top 30.5 m, crossing clearance 3 m,
    take-off on the ground at z 0); the path's extent from home."""
    geom = MissionGeometry.from_mission(load_mission(f"{MISSIONS}/tower_b.toml"))
    home = geom.takeoff
    values = {s.name: s.value for s in tower_failsafe_parameters(
        geom.volumes, home, geom.path_points(), crossing_clearance=3.0, ground_station=False)}
    assert values["RTL_RETURN_ALT"] == 35.5 and values["RTL_DESCEND_ALT"] == 35.5
    assert values["RTL_RETURN_ALT"] > geom.volumes.top + 3.0 - home[2]  # over the crossing height
    assert values["RTL_CONE_ANG"] == 0 and values["COM_OBL_RC_ACT"] == 3 and values["GF_ACTION"] == 3
    assert "NAV_DLL_ACT" not in values  # no ground station: PX4 would refuse to arm
    reach = np.max(np.hypot(*(geom.path_points()[:, :2] - home[:2]).T))
    assert reach + 5.0 < values["GF_MAX_HOR_DIST"] <= reach + 11.0
    assert values["GF_MAX_VER_DIST"] >= values["RTL_RETURN_ALT"] + 5.0
    for name, value in values.items():  # PX4's types: INT32 parameters get ints
        assert isinstance(value, int) == (SITL_DEFAULTS[name][0] == INT32), name
    with_gcs = tower_failsafe_parameters(geom.volumes, home, geom.path_points(), crossing_clearance=3.0,
                                         ground_station=True)
    assert {s.name: s.value for s in with_gcs}["NAV_DLL_ACT"] == 2
    higher = {s.name: s.value for s in tower_failsafe_parameters(
        geom.volumes, home, geom.path_points(), crossing_clearance=3.0, ground_station=False, vehicle_return_alt=60.0)}
    assert higher["RTL_RETURN_ALT"] == 60.0 and higher["RTL_DESCEND_ALT"] == 35.5  # the operator's higher value kept
    assert higher["GF_MAX_VER_DIST"] >= 60.0 + 5.0  # and the geofence holds the return
    lower = {s.name: s.value for s in tower_failsafe_parameters(
        geom.volumes, home, geom.path_points(), crossing_clearance=3.0, ground_station=False, vehicle_return_alt=30.0)}
    assert lower["RTL_RETURN_ALT"] == 35.5  # PX4 SITL's 30 m is under tower B's top: raised
    with pytest.raises(PlanningError, match="RTL_DESCEND_ALT"):
        tower_failsafe_parameters(geom.volumes, home - [0, 0, 200], geom.path_points(), crossing_clearance=3.0,
                                  ground_station=False)


def _fly(tmp_path, *extra: str) -> tuple[int, dict]:
    scene, mission = small_scene(tmp_path)
    mission.write_text(mission.read_text() + "confirmations = 1\n")
    out = tmp_path / "report"
    rc = main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *ARGS,
               "--vehicle", "mavlink", "--time-scale", "4", *extra])
    return rc, json.loads((out / "summary.json").read_text())


@pytest.mark.slow
def test_a_flight_sets_verifies_and_restores_the_parameters(tmp_path, monkeypatch) -> None:
    """The small scene through the simulated PX4: every tower value set and verified before
    arming, the old values read first and put back after the landing, all in summary.json; the
    simulated PX4's own table ends as it began."""
    import insulator_rs.sim.px4 as px4

    sims = []
    original = px4.start_simulated_px4

    def keep(*args, **kwargs):
        connection = original(*args, **kwargs)
        sims.append(connection.simulator)
        return connection

    monkeypatch.setattr(px4, "start_simulated_px4", keep)
    rc, s = _fly(tmp_path)
    assert rc == 0 and s["status"] == "finished"
    record = s["px4_parameters"]
    assert record["restore"] == "restored" and record["ground_station"] is False
    names = [r["name"] for r in record["parameters"]]
    assert names[:2] == ["RTL_RETURN_ALT", "RTL_DESCEND_ALT"] and "NAV_DLL_ACT" not in names
    table = sims[0].parameters.values
    for r in record["parameters"]:
        assert r["error"] is None and r["restored"] == r["old"], r
        assert table[r["name"]][1] == r["old"], r  # the autopilot holds its old value again
    by_name = {r["name"]: r for r in record["parameters"]}
    assert by_name["COM_OBL_RC_ACT"] == {**by_name["COM_OBL_RC_ACT"], "old": 0, "set": 3, "restored": 0}
    # small tower: 13.5 m + margin 2 + clearance 3 + 2 = 20.5 m, under the airframe's 60 m: 60 kept
    assert by_name["RTL_DESCEND_ALT"]["set"] == 13.5 + 2.0 + 3.0 + 2.0 and by_name["RTL_RETURN_ALT"]["set"] == 60.0


@pytest.mark.slow
def test_with_a_ground_station_the_datalink_loss_returns_too(tmp_path) -> None:
    """A ground station on the simulated PX4's GCS link: its HEARTBEAT reaches the companion
    through the autopilot (as PX4 forwards it: measured), so NAV_DLL_ACT is set to Return; PX4
    arms because the GCS is there, and NAV_DLL_ACT is put back after the landing."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with GcsListener(("127.0.0.1", port)):
        rc, s = _fly(tmp_path, "--gcs-port", str(port))
    assert rc == 0 and s["status"] == "finished"
    record = s["px4_parameters"]
    assert record["ground_station"] is True and record["restore"] == "restored"
    dll = next(r for r in record["parameters"] if r["name"] == "NAV_DLL_ACT")
    assert (dll["old"], dll["set"], dll["restored"]) == (0, 2, 0)


def test_the_simulated_px4_refuses_to_arm_with_a_datalink_action_and_no_ground_station() -> None:
    """PX4 v1.16.0 SITL: 'Preflight Fail: No connection to the ground control station' and
    TEMPORARILY_REJECTED (measured); ACCEPTED again once NAV_DLL_ACT is 0."""
    from insulator_rs.exceptions import CommandRejected

    _, vehicle = start_simulated_px4(time_scale=4.0)
    with vehicle:
        vehicle.parameters.set("NAV_DLL_ACT", 2)
        with pytest.raises(CommandRejected, match="TEMPORARILY_REJECTED"):
            vehicle.arm()
        vehicle.parameters.set("NAV_DLL_ACT", 0)
        vehicle.arm()
        assert vehicle.state().armed


@pytest.mark.slow
def test_a_parameter_px4_lacks_stops_the_mission_before_arming(tmp_path, monkeypatch) -> None:
    """An old value that cannot be read: nothing is set, nothing arms, the report names the
    parameter (status aborted, exit code 1, no traceback)."""
    import insulator_rs.sim.px4.parameters as table

    monkeypatch.setattr(table, "SITL_DEFAULTS", {k: v for k, v in table.SITL_DEFAULTS.items() if k != "GF_ACTION"})
    rc, s = _fly(tmp_path)
    assert rc == 1 and s["status"].startswith("aborted: autopilot parameters not set")
    assert "parameter GF_ACTION: no PARAM_VALUE" in s["status"]
    record = s["px4_parameters"]
    assert all(r["set"] is None for r in record["parameters"]) and s["distance_m"] == 0.0
    assert s["abort"]["route"] is None  # never took off: no way out to fly


def test_a_set_that_fails_puts_back_what_was_set_before_it() -> None:
    """Three values set, the fourth cannot be (not an integer for an INT32): the three are put
    back (verified on the simulated PX4's own table) and the error names the fourth."""
    from insulator_rs.flight.autopilot_setup import AutopilotSetup
    from insulator_rs.planning.px4_failsafes import ParameterSetting

    sim, vehicle = start_simulated_px4(time_scale=4.0)
    with vehicle:
        before = dict(sim.parameters.values)
        settings = [ParameterSetting("RTL_RETURN_ALT", 25.0, ""), ParameterSetting("GF_ACTION", 3, ""),
                    ParameterSetting("RTL_CONE_ANG", 0, ""), ParameterSetting("COM_OBL_RC_ACT", 2.5, "")]
        setup = AutopilotSetup(vehicle.parameters, settings, ground_station=False)
        with pytest.raises(ParameterError, match="COM_OBL_RC_ACT.*integral") as err:
            setup.apply()
        assert err.value.parameter == "COM_OBL_RC_ACT"
        assert sim.parameters.values == before and sim.parameters.sets == 6  # 3 set, 3 put back
        record = setup.record()
        assert record["restore"].startswith("set failed at COM_OBL_RC_ACT; restored")
        assert [r["restored"] for r in record["parameters"]] == [60.0, 2, 45, None]
        assert not setup.pending
