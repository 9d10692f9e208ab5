"""PX4's GCS connection loss failsafe (NAV_DLL_ACT) in our simulated PX4 (``sim/px4/datalink.py``).

The reference is PX4 v1.16's failsafe code and parameter reference (COM_DL_LOSS_T 10 s, then
Hold for COM_FAIL_ACT_T 5 s, then the action; ignored in Land; Hold clears when the ground station
is heard again, Return and Land do not), not a SITL measurement. The flight test runs against our
simulated PX4 over real UDP, the ground station on its GCS link relayed by the companion.
"""

from __future__ import annotations

import pytest
from helpers.simulated_px4 import wait_until

from insulator_rs.exceptions import VehicleFailsafe
from insulator_rs.ports.vehicle import FlightMode
from insulator_rs.sim.kinematics import KinematicVehicle
from insulator_rs.sim.px4 import start_simulated_px4
from insulator_rs.sim.px4.datalink import DataLinkLoss
from insulator_rs.sim.px4_gcs import RelayedGroundStation

TIMEOUT, DELAY = 10.0, 5.0  # COM_DL_LOSS_T, COM_FAIL_ACT_T: PX4 v1.16's defaults


def _airborne(altitude: float = 20.0) -> KinematicVehicle:
    """Armed and holding ``altitude`` m up after PX4's take-off."""
    vehicle = KinematicVehicle(seed=0)
    vehicle.arm()
    vehicle.takeoff(altitude)
    for _ in range(400):
        vehicle.advance(0.1)
        if vehicle.mode == FlightMode.HOLD:
            break
    assert vehicle.mode == FlightMode.HOLD and vehicle.state().position[2] > altitude - 0.5
    return vehicle


def _step(vehicle: KinematicVehicle, loss: DataLinkLoss, age: float | None, action: int, exceptions: int = 0,
          offboard: bool = False) -> None:
    """0.1 s of flight (a fresh setpoint first when ``offboard``), then the failsafe's look with
    the ground station last heard ``age`` s ago (None: never heard)."""
    if offboard:
        vehicle.send_setpoint(vehicle.state().position, None, 0.0)
    try:
        vehicle.advance(0.1)
    except VehicleFailsafe:
        pass  # raised once by the airframe; the mode tells
    loss.step(vehicle, age, action=action, timeout=TIMEOUT, exceptions=exceptions, delay=DELAY)


def _modes(vehicle: KinematicVehicle, loss: DataLinkLoss, seconds: float, action: int) -> list[tuple[float, str]]:
    """The ground station last heard when this starts: (s since, mode) at each mode change and at
    each new fault."""
    seen, changes = (vehicle.mode.value, vehicle.fault), []
    for k in range(int(round(seconds / 0.1))):
        age = (k + 1) * 0.1
        _step(vehicle, loss, age, action)
        if (vehicle.mode.value, vehicle.fault) != seen:
            seen = (vehicle.mode.value, vehicle.fault)
            changes.append((age, vehicle.mode.value))
    return changes


@pytest.mark.parametrize("action,mode", [(2, "RTL"), (3, "LAND")])
def test_after_com_dl_loss_t_px4_holds_for_com_fail_act_t_then_takes_the_action(action, mode):
    vehicle, loss = _airborne(), DataLinkLoss()
    changes = _modes(vehicle, loss, 20.0, action)
    # already in HOLD: the delay's Hold shows as the fault, then the action
    assert [m for _, m in changes] == ["HOLD", mode]
    assert changes[0][0] == pytest.approx(TIMEOUT, abs=0.15)
    assert changes[1][0] == pytest.approx(TIMEOUT + DELAY, abs=0.25)
    assert "GCS connection lost for more than 10 s" in (vehicle.fault or "")


def test_the_loss_during_the_take_off_climb_returns():
    """The gap it closes: PX4 in TAKEOFF (not offboard: no offboard loss fires) with the link gone."""
    vehicle, loss = KinematicVehicle(seed=0), DataLinkLoss()
    vehicle.arm()
    vehicle.takeoff(40.0)  # a long climb: still climbing when the loss is declared
    changes = _modes(vehicle, loss, 16.0, 2)
    assert [m for _, m in changes] == ["HOLD", "RTL"]
    assert changes[0][0] == pytest.approx(TIMEOUT, abs=0.15)
    assert changes[1][0] == pytest.approx(TIMEOUT + DELAY, abs=0.25)
    assert vehicle.state().position[2] < 40.0 - 5.0  # it had not reached the take-off height


@pytest.mark.parametrize("action,mode,heard,exceptions", [
    (0, FlightMode.OFFBOARD, True, 0),  # NAV_DLL_ACT 0: disabled
    (2, FlightMode.HOLD, False, 0),  # no ground station was ever heard: nothing to lose
    (1, FlightMode.HOLD, True, 0),  # Hold while holding: nothing changes
    (2, FlightMode.LAND, True, 0),  # PX4 ignores the loss in Land
    (2, FlightMode.HOLD, True, 2),  # COM_DLL_EXCEPT bit 1: Hold excepted
    (2, FlightMode.OFFBOARD, True, 4),  # COM_DLL_EXCEPT bit 2: Offboard excepted
], ids=["disabled", "never heard", "hold in hold", "in land", "hold excepted", "offboard excepted"])
def test_no_action(action, mode, heard, exceptions):
    vehicle, loss = _airborne(), DataLinkLoss()
    offboard = mode == FlightMode.OFFBOARD
    if offboard:
        vehicle.send_setpoint(vehicle.state().position, None, 0.0)
    vehicle.set_mode(mode)
    for k in range(160):
        _step(vehicle, loss, (k + 1) * 0.1 if heard else None, action, exceptions, offboard)
    assert vehicle.mode == mode and vehicle.fault is None


def test_hold_clears_when_the_ground_station_is_back_return_does_not():
    vehicle, loss = _airborne(), DataLinkLoss()
    vehicle.send_setpoint(vehicle.state().position, None, 0.0)
    vehicle.start_offboard()
    for _ in range(20):  # the setpoints stopped: PX4's offboard loss, Position mode (COM_OBL_RC_ACT 0)
        try:
            vehicle.advance(0.1)
        except VehicleFailsafe:
            pass
    assert vehicle.mode == FlightMode.POSCTL
    loss.step(vehicle, 11.0, action=1, timeout=TIMEOUT, exceptions=0, delay=DELAY)
    assert vehicle.mode == FlightMode.HOLD and "GCS" in vehicle.fault
    loss.step(vehicle, 0.0, action=1, timeout=TIMEOUT, exceptions=0, delay=DELAY)
    assert vehicle.mode == FlightMode.POSCTL and vehicle.fault is None  # back to where it was
    vehicle, loss = _airborne(), DataLinkLoss()
    _modes(vehicle, loss, 16.0, 2)
    assert vehicle.mode == FlightMode.RTL
    loss.step(vehicle, 0.0, action=2, timeout=TIMEOUT, exceptions=0, delay=DELAY)
    assert vehicle.mode == FlightMode.RTL  # Return stays until another mode is chosen


@pytest.mark.slow  # a climb and the failsafe's 15 s over UDP: about 10 s
def test_over_udp_the_relayed_ground_station_cut_in_the_climb_makes_px4_return():
    """Our simulated PX4 with a ground station on its GCS link: NAV_DLL_ACT 2 set over MAVLink, the
    vehicle climbing in TAKEOFF, the ground station cut: HOLD COM_DL_LOSS_T s later, RTL
    COM_FAIL_ACT_T s after that (vehicle time), and PX4 lands at home."""
    sim, client = start_simulated_px4(time_scale=4.0, sim_options={"gcs_port": 0})
    gcs = RelayedGroundStation(sim.gcs.address).start()
    with client:
        try:
            assert client.parameters.ground_station(5.0)  # PX4 forwards the GCS's HEARTBEAT (measured)
            client.parameters.set("NAV_DLL_ACT", 2)
            client.parameters.set("RTL_RETURN_ALT", 8.0)
            client.arm()
            client.takeoff(40.0)
            wait_until(client, lambda s: s.position[2] > 2.0, 10.0)
            gcs.cut()
            cut_at = client.state().time
            wait_until(client, lambda s: s.mode == "HOLD", TIMEOUT + 5.0)
            hold_at = client.state().time
            wait_until(client, lambda s: s.mode == "RTL", DELAY + 3.0)
            rtl_at = client.state().time
            # the last HEARTBEAT came up to 4 vehicle s (1 wall s) before the cut
            assert TIMEOUT - 4.0 - 1.0 <= hold_at - cut_at <= TIMEOUT + 1.0
            assert DELAY - 0.5 <= rtl_at - hold_at <= DELAY + 0.5
            assert client.state().position[2] < 40.0 - 1.0  # the climb was cut short
            wait_until(client, lambda s: not s.armed, 120.0)
            end = sim.with_vehicle(lambda v: v.model.position.copy())
            assert abs(end[0]) < 0.5 and abs(end[1]) < 0.5  # landed at home
        finally:
            gcs.close()

