"""The offboard client against the simulated PX4: real MAVLink 2 over UDP on 127.0.0.1.

No mocks: every exchange goes through sockets. The vehicle clock runs
``TIME_SCALE`` times faster than the wall clock (PX4's timeouts scale with it).
"""

from __future__ import annotations

import math
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from helpers.simulated_px4 import DT, TIME_SCALE, connect_new_simulator, sim_of, take_off_into_offboard, wait_until

from insulator_rs.exceptions import VehicleError
from insulator_rs.mavlink import connect_vehicle
from insulator_rs.mavlink.client import CommandRejected, MavlinkVehicle, VehicleFailsafe
from insulator_rs.sim.px4 import SimulatedPx4
from insulator_rs.mavlink.signing import key_from_passphrase
from insulator_rs.mavlink.wire import mavlink2 as M
from insulator_rs.mavlink.wire import mavutil
from insulator_rs.ports.vehicle import Vehicle


@pytest.fixture
def vehicle() -> Iterator[MavlinkVehicle]:
    client = connect_new_simulator(time_scale=TIME_SCALE)
    try:
        yield client
    finally:
        client.close()


def test_client_implements_the_vehicle_protocol(vehicle: MavlinkVehicle) -> None:
    assert isinstance(vehicle, Vehicle)
    state = vehicle.state()
    assert (state.mode, state.armed, state.landed) == ("HOLD", False, True)


@pytest.mark.slow
def test_connect_arm_offboard_fly_a_trajectory_and_land(vehicle: MavlinkVehicle) -> None:
    """Reference: the simulator's true state (read under its lock). MAVLink carries
    positions as float32, so the client's view must match to 1e-3 m."""
    sim = sim_of(vehicle)
    take_off_into_offboard(vehicle, 3.0)
    start = vehicle.state()
    setpoints_before = sim.stats.setpoints
    # A 6 m straight segment east at 2 m/s with velocity feed-forward, yaw north.
    t0 = start.time
    goal = start.position + np.array([6.0, 0.0, 1.0])
    while True:
        s = min(1.0, (vehicle.state().time - t0) / 3.0)
        position = start.position + s * (goal - start.position)
        velocity = (goal - start.position) / 3.0 if s < 1.0 else np.zeros(3)
        vehicle.send_setpoint(position, velocity, yaw=math.pi / 2)
        state = vehicle.advance(DT)
        if state.time - t0 > 6.0:
            break
    assert state.mode == "OFFBOARD" and state.healthy
    np.testing.assert_allclose(state.position, goal, atol=0.03)
    assert state.yaw == pytest.approx(math.pi / 2, abs=1e-3)
    true_position, _yaw, _time = sim.true_pose()
    assert np.linalg.norm(true_position - vehicle.state().position) < 0.05
    # Setpoints arrived at >= 20 Hz of vehicle time while in offboard.
    rate = (sim.stats.setpoints - setpoints_before) / (state.time - t0)
    assert rate >= 19.0
    vehicle.land()
    wait_until(vehicle, lambda s: not s.armed, 20.0)
    final = vehicle.state()
    assert final.landed and final.position[2] == pytest.approx(0.0, abs=1e-3)
    assert sim.stats.last_ack[M.MAV_CMD_NAV_LAND] == M.MAV_RESULT_ACCEPTED


def test_offboard_before_setpoints_is_refused_with_px4s_result(vehicle: MavlinkVehicle) -> None:
    """Reference: PX4 v1.16.0 SITL (tests/test_px4_sitl.py). On the ground, disarmed, PX4
    ACCEPTs DO_SET_MODE OFFBOARD without a setpoint stream and stays in its mode: the client
    believes the HEARTBEAT, not the ACK. In the air it answers TEMPORARILY_REJECTED."""
    with pytest.raises(VehicleError, match="accepted mode OFFBOARD but its heartbeat never showed it"):
        vehicle.start_offboard()
    assert vehicle.state().mode == "HOLD"
    vehicle.arm()
    vehicle.takeoff(2.0)
    wait_until(vehicle, lambda s: s.mode == "HOLD" and abs(s.position[2] - 2.0) < 0.1, 15.0)
    with pytest.raises(CommandRejected) as refusal:
        vehicle.start_offboard()
    assert refusal.value.command == "MAV_CMD_DO_SET_MODE"
    assert refusal.value.reason == "MAV_RESULT_TEMPORARILY_REJECTED"
    assert "OFFBOARD" in str(refusal.value)
    assert vehicle.state().mode == "HOLD"


def test_arming_twice_is_accepted_as_px4_does(vehicle: MavlinkVehicle) -> None:
    """PX4's Commander::arm returns TRANSITION_NOT_CHANGED for an armed vehicle and the
    command handler answers ACCEPTED; the client must not treat that as an error."""
    vehicle.arm()
    vehicle.arm()
    assert vehicle.state().armed
    assert sim_of(vehicle).stats.commands["MAV_CMD_COMPONENT_ARM_DISARM"] == 2


def test_commands_refused_while_disarmed_or_not_ready(vehicle: MavlinkVehicle) -> None:
    with pytest.raises(VehicleError, match="takeoff refused: vehicle is disarmed"):
        vehicle.takeoff(3.0)
    sim = sim_of(vehicle)
    sim.position_loss(True)
    with pytest.raises(CommandRejected, match="arm.*MAV_RESULT_TEMPORARILY_REJECTED"):
        vehicle.arm()
    sim.position_loss(False)
    take_off_into_offboard(vehicle)
    with pytest.raises(CommandRejected, match="disarm.*TEMPORARILY_REJECTED"):
        vehicle.disarm()
    assert vehicle.state().armed


def test_link_loss_mid_flight_vehicle_failsafe_and_client_report(vehicle: MavlinkVehicle) -> None:
    sim = sim_of(vehicle)
    take_off_into_offboard(vehicle)
    for _ in range(10):
        vehicle.send_setpoint(np.array([1.0, 0.0, 3.0]))
        vehicle.advance(DT)
    sim.set_link_lost(True)
    with pytest.raises(VehicleFailsafe) as failsafe:
        for _ in range(400):
            vehicle.send_setpoint(np.array([1.0, 0.0, 3.0]))
            vehicle.advance(DT)
    assert "autopilot heartbeat lost" in failsafe.value.reason
    assert "autopilot flies its own failsafe" in failsafe.value.action
    # The vehicle's own failsafe: setpoints stopped arriving -> Position mode after
    # COM_OF_LOSS_T, as PX4 v1.16.0 SITL does (COM_OBL_RC_ACT = 0).
    mode, fault = sim.with_vehicle(lambda v: (v.mode.value, v.fault))
    assert mode == "POSCTL" and fault == "offboard setpoints lost for more than 1 s"
    assert vehicle.state().fault == failsafe.value.reason


def test_pilot_mode_change_stops_offboard_commanding_at_once(vehicle: MavlinkVehicle) -> None:
    sim = sim_of(vehicle)
    take_off_into_offboard(vehicle)
    vehicle.send_setpoint(np.array([0.0, 0.0, 3.0]))
    vehicle.advance(0.5)
    sim.pilot_mode_change("POSCTL")
    with pytest.raises(VehicleFailsafe, match="mode changed from OFFBOARD to POSCTL"):
        for _ in range(100):
            vehicle.advance(DT)
    # Streaming stopped when the heartbeat arrived: at most a few setpoints were in
    # flight; afterwards none.
    count = sim.stats.setpoints
    time.sleep(0.5)
    assert sim.stats.setpoints - count <= 1
    with pytest.raises(VehicleFailsafe, match="offboard commanding stopped"):
        vehicle.send_setpoint(np.array([5.0, 0.0, 3.0]))
    assert vehicle.state().mode == "POSCTL"


def test_low_battery_returns_home_with_a_reason(vehicle: MavlinkVehicle) -> None:
    sim = sim_of(vehicle)
    take_off_into_offboard(vehicle)
    sim.with_vehicle(lambda v: setattr(v, "battery_fraction", 0.15))
    with pytest.raises(VehicleFailsafe) as failsafe:
        for _ in range(200):
            vehicle.send_setpoint(np.array([0.0, 0.0, 3.0]))
            vehicle.advance(DT)
    assert failsafe.value.reason == "battery low (15% < 20%)"
    assert failsafe.value.action == "return"
    assert vehicle.state().mode == "RTL"


def test_stale_position_holds_with_a_reason(vehicle: MavlinkVehicle) -> None:
    sim = sim_of(vehicle)
    take_off_into_offboard(vehicle)
    sim.set_rate("LOCAL_POSITION_NED", 0.0)
    with pytest.raises(VehicleFailsafe) as failsafe:
        for _ in range(400):
            vehicle.send_setpoint(np.array([0.0, 0.0, 3.0]))
            vehicle.advance(DT)
    assert failsafe.value.reason == "local position stale for more than 1 s"
    assert failsafe.value.action == "hold"
    assert sim.with_vehicle(lambda v: v.mode.value) == "HOLD"


def test_link_loss_just_after_a_heartbeat_is_reported_as_link_loss(vehicle: MavlinkVehicle) -> None:
    """A silent link whose last message was a heartbeat is a link loss, not a stale position.

    The position stream stops first, a heartbeat still arrives (well inside the 1 s stale
    timeout), then the link goes: only the heartbeat failsafe may fire (CI once saw the
    stale-position hold win this race)."""
    sim = sim_of(vehicle)
    take_off_into_offboard(vehicle)
    sim.set_rate("LOCAL_POSITION_NED", 0.0)
    time.sleep(0.5)  # 2 vehicle s at 4x: heartbeats arrive, positions do not
    sim.set_link_lost(True)
    with pytest.raises(VehicleFailsafe) as failsafe:
        for _ in range(400):
            vehicle.send_setpoint(np.array([0.0, 0.0, 3.0]))
            vehicle.advance(DT)
    assert failsafe.value.reason == "autopilot heartbeat lost for more than 3 s"


def test_commands_survive_packet_loss_and_delay() -> None:
    """20 % loss each way and 30 ms latency: retransmission gets every command through."""
    client = connect_new_simulator(time_scale=TIME_SCALE, command_timeout=0.3, command_retries=10)
    try:
        sim = sim_of(client)
        sim.set_packet_loss(0.2)
        sim.set_delay(0.03)
        take_off_into_offboard(client)
        assert client.state().mode == "OFFBOARD"
        assert sim.stats.dropped > 0
    finally:
        client.close()


def test_telemetry_snapshot_global_position_home_attitude(vehicle: MavlinkVehicle) -> None:
    """Reference: pymap3d.enu2geodetic of the reported position from the sim's origin;
    tolerance 2e-7 deg and 2 mm (GLOBAL_POSITION_INT carries 1e-7 deg and mm)."""
    import pymap3d

    take_off_into_offboard(vehicle, 4.0)
    for _ in range(140):  # 7 s: settled, so the two messages' sample instants agree
        vehicle.send_setpoint(np.array([3.0, -2.0, 4.0]), yaw=0.5)
        vehicle.advance(DT)
    snapshot = vehicle.telemetry()
    origin = sim_of(vehicle).origin
    lat, lon, alt = pymap3d.enu2geodetic(*snapshot.state.position, *origin)
    assert snapshot.global_position is not None and snapshot.home_global is not None
    assert snapshot.global_position[:2] == pytest.approx((lat, lon), abs=2e-7)
    assert snapshot.global_position[2] == pytest.approx(alt, abs=2e-3)  # mm quantisation
    assert snapshot.home_global[:2] == pytest.approx(origin[:2], abs=2e-7)
    assert snapshot.home_global[2] == pytest.approx(origin[2], abs=2e-3)
    np.testing.assert_allclose(snapshot.home, [0.0, 0.0, 0.0], atol=1e-6)
    assert snapshot.landed_state == "MAV_LANDED_STATE_IN_AIR"
    yaw = snapshot.state.yaw
    # settled in still air: the airframe hovers level (to its last micro-corrections) at its heading
    np.testing.assert_allclose(snapshot.attitude @ [1.0, 0.0, 0.0], [math.cos(yaw), math.sin(yaw), 0.0],
                               atol=1e-4)
    np.testing.assert_allclose(snapshot.attitude, snapshot.state.T_w_b[:3, :3], atol=1e-6)


def test_world_origin_from_geodetic_tower_position() -> None:
    """The sim's PX4 started 30 m east and 40 m north of the tower (its local origin is
    there); after set_world_origin(tower), positions are in the tower's ENU frame.
    Reference: pymap3d.enu2geodetic places the PX4 origin; tolerance 1 cm."""
    import pymap3d

    tower = (47.3977, 8.5456, 500.0)
    px4_origin = pymap3d.enu2geodetic(30.0, 40.0, 0.0, *tower)
    client = connect_new_simulator(time_scale=TIME_SCALE, sim_options={"origin": px4_origin})
    try:
        np.testing.assert_allclose(client.state().position, [0.0, 0.0, 0.0], atol=1e-6)
        offset = client.set_world_origin(*tower)
        np.testing.assert_allclose(offset, [30.0, 40.0, 0.0], atol=0.01)
        np.testing.assert_allclose(client.state().position, [30.0, 40.0, 0.0], atol=0.01)
        take_off_into_offboard(client)
        for _ in range(60):
            client.send_setpoint(np.array([32.0, 40.0, 3.0]))  # W: 2 m east of where we took off
            client.advance(DT)
        truth = sim_of(client).with_vehicle(lambda v: v.model.position.copy())
        np.testing.assert_allclose(truth, [2.0, 0.0, 3.0], atol=0.05)  # PX4 local frame
    finally:
        client.close()


def test_gps_glitch_is_seen_by_the_client(vehicle: MavlinkVehicle) -> None:
    sim = sim_of(vehicle)
    sim.gps_glitch((4.0, -2.0, 0.0))
    vehicle.advance(0.2)
    np.testing.assert_allclose(vehicle.state().position, [4.0, -2.0, 0.0], atol=1e-3)


def test_signing_rejects_unsigned_and_wrongly_signed_commands(tmp_path) -> None:
    key = key_from_passphrase("insulator tower 42")
    key_file = tmp_path / "mavlink.key"
    key_file.write_text(key.hex())
    client = connect_new_simulator(time_scale=TIME_SCALE, signing_key=str(key_file))
    try:
        sim = sim_of(client)
        host, port = sim.address
        for intruder_key in (None, key_from_passphrase("not the key")):
            intruder = mavutil.mavlink_connection(f"udpout:{host}:{port}", source_system=255,
                                                  source_component=190)
            if intruder_key is not None:
                intruder.setup_signing(intruder_key, sign_outgoing=True)
            before = sim.stats.rejected_signature
            for _ in range(3):
                intruder.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
                time.sleep(0.05)
            ack = intruder.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
            intruder.close()
            assert ack is None
            assert sim.stats.rejected_signature - before == 3
            assert not client.state().armed
        client.arm()  # the key holder is obeyed
        assert client.state().armed
    finally:
        client.close()


def test_type_mask_velocity_only_and_yaw_rate_setpoints() -> None:
    """A raw pymavlink peer sends velocity-only (positions ignored) with a yaw rate:
    the simulated PX4 flies that velocity and turns at that rate."""
    with SimulatedPx4(time_scale=TIME_SCALE) as sim:
        sim.with_vehicle(lambda v: (v.arm(), v.request_takeoff(3.0)))
        deadline = time.monotonic() + 10
        while sim.with_vehicle(lambda v: v.mode.value) != "HOLD" and time.monotonic() < deadline:
            time.sleep(0.05)
        host, port = sim.address
        peer = mavutil.mavlink_connection(f"udpout:{host}:{port}", source_system=255, source_component=190)
        mask = (M.POSITION_TARGET_TYPEMASK_X_IGNORE | M.POSITION_TARGET_TYPEMASK_Y_IGNORE
                | M.POSITION_TARGET_TYPEMASK_Z_IGNORE | M.POSITION_TARGET_TYPEMASK_AX_IGNORE
                | M.POSITION_TARGET_TYPEMASK_AY_IGNORE | M.POSITION_TARGET_TYPEMASK_AZ_IGNORE
                | M.POSITION_TARGET_TYPEMASK_YAW_IGNORE)
        try:
            def stream(seconds: float) -> None:
                end = time.monotonic() + seconds / TIME_SCALE
                while time.monotonic() < end:
                    # NED: 1 m/s north, 0.5 m/s up; yaw rate 0.2 rad/s clockwise seen from above
                    peer.mav.set_position_target_local_ned_send(0, 1, 1, M.MAV_FRAME_LOCAL_NED, mask,
                                                                0, 0, 0, 1.0, 0.0, -0.5, 0, 0, 0, 0, 0.2)
                    time.sleep(0.05 / TIME_SCALE)
            stream(1.0)
            peer.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MODE, 0, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                       6, 0, 0, 0, 0, 0)
            stream(3.0)
            velocity, mode, yaw_before, t_before = sim.with_vehicle(
                lambda v: (v.model.velocity.copy(), v.mode.value, v.model.yaw, v.clock.now))
            stream(1.0)
            yaw_after, t_after = sim.with_vehicle(lambda v: (v.model.yaw, v.clock.now))
        finally:
            peer.close()
        assert mode == "OFFBOARD"
        np.testing.assert_allclose(velocity, [0.0, 1.0, 0.5], atol=0.02)  # ENU
        turn = math.remainder(yaw_after - yaw_before, 2 * math.pi)
        assert turn < 0  # clockwise in NED = negative (clockwise) in ENU
        # the rate on the simulator's own clock: how much simulated time a wall-clock second of
        # streaming covers depends on the machine's load, the rate flown does not
        elapsed = t_after - t_before
        assert elapsed > 0.2, elapsed
        print(f"yaw rate {abs(turn) / elapsed:.4f} rad/s over {elapsed:.2f} s")
        assert abs(turn) / elapsed == pytest.approx(0.2, rel=0.1)


def test_no_heartbeat_times_out_with_a_clear_error() -> None:
    with SimulatedPx4() as silent:
        port = silent.address[1]
    start = time.monotonic()
    with pytest.raises(VehicleError, match="no autopilot heartbeat on udpout:127.0.0.1:.* within 0.5 s"):
        MavlinkVehicle(f"udpout:127.0.0.1:{port}", heartbeat_timeout=0.5)
    assert time.monotonic() - start < 3.0


@pytest.mark.parametrize(
    ("connection", "error", "match"),
    [("bogus", ValueError, "connection must be udpin"), ("", TypeError, "connection must be a non-empty"),
     (None, TypeError, "connection must be a non-empty")],
)
def test_bad_connection_strings(connection, error, match) -> None:
    with pytest.raises(error, match=match):
        MavlinkVehicle(connection)  # type: ignore[arg-type]


def test_the_mavlink_package_starts_no_simulator() -> None:
    """The simulated PX4 is the simulator's adapter: ``mavlink.connect_vehicle`` needs a real
    connection and says where the simulated one is."""
    with pytest.raises(TypeError, match="insulator_rs.sim.px4.connect_simulated_px4"):
        connect_vehicle(None)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="sim_options"):
        connect_vehicle("udpin:127.0.0.1:14540", sim_options={"time_scale": 2.0})


def test_bad_setpoints_name_the_argument(vehicle: MavlinkVehicle) -> None:
    with pytest.raises(ValueError, match="position must have shape"):
        vehicle.send_setpoint(np.zeros(2))
    with pytest.raises(ValueError, match="yaw must be finite"):
        vehicle.send_setpoint(np.zeros(3), yaw=math.nan)
    with pytest.raises(ValueError, match="dt must be > 0"):
        vehicle.advance(-1.0)


def test_standalone_simulator_entry_point(capsys) -> None:
    """``python -m insulator_rs.sim.px4`` runs, listens, reports and stops."""
    from insulator_rs.sim.px4 import main

    assert main(["--port", "0", "--remote", "", "--duration", "0.3"]) == 0
    out = capsys.readouterr().out
    assert "simulated PX4 listening on udp 127.0.0.1:" in out
    assert "stopped: mode HOLD, armed False" in out


def test_udpin_as_px4_sitl_streams_to_the_offboard_port() -> None:
    """PX4 SITL streams to a fixed offboard port; the client listens there (udpin)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        listen_port = probe.getsockname()[1]
    with SimulatedPx4(time_scale=TIME_SCALE, remote=("127.0.0.1", listen_port)) as sim:
        client = MavlinkVehicle(f"udpin:127.0.0.1:{listen_port}", heartbeat_timeout=5.0, time_scale=TIME_SCALE)
        try:
            client.arm()
            assert sim.with_vehicle(lambda v: v.armed)
        finally:
            client.close()


def test_serial_link_through_a_pseudo_terminal() -> None:
    """A serial device (``DEVICE:BAUD``, pyserial under pymavlink) bridged byte for byte
    to the simulated PX4's UDP port, as a flight controller's UART would carry it."""
    master, slave = os.openpty()
    tty.setraw(slave)
    device = os.ttyname(slave)
    stop = threading.Event()
    with SimulatedPx4(time_scale=TIME_SCALE) as sim:
        bridge = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        bridge.bind(("127.0.0.1", 0))
        bridge.setblocking(False)

        def pump() -> None:
            while not stop.is_set():
                readable, _, _ = select.select([master, bridge], [], [], 0.02)
                if master in readable:
                    bridge.sendto(os.read(master, 4096), sim.address)
                if bridge in readable:
                    os.write(master, bridge.recv(65535))

        thread = threading.Thread(target=pump, daemon=True)
        thread.start()
        client = None
        try:
            client = MavlinkVehicle(f"{device}:921600", heartbeat_timeout=5.0, time_scale=TIME_SCALE)
            client.arm()
            assert sim.with_vehicle(lambda v: v.armed)
            assert client.state().armed
        finally:
            if client is not None:
                client.close()
            stop.set()
            thread.join(timeout=2.0)
            bridge.close()
            os.close(master)
            os.close(slave)


@pytest.mark.parametrize("leave", ["land", "return_to_launch", "hold"])
def test_leaving_offboard_with_a_lost_command_never_trips_px4s_offboard_loss(leave: str) -> None:
    """The first LAND / RTL / HOLD command is lost on the link (the simulated PX4 never sees it):
    the client sends it again after its 1 s ACK wait, 4 s of vehicle time at this time scale,
    past PX4's COM_OF_LOSS_T (1 s). Reference: the simulated PX4's own mode, polled under its
    lock all along: it must go from OFFBOARD straight to the mode asked for, never through the
    offboard-loss fallback (PX4's default POSCTL), because the setpoint stream holds the last
    position until the heartbeat shows the new mode. The client before this kept that stream
    stopped from the first try on: PX4 SITL logged "Failsafe activated" and began its Return."""
    client = connect_new_simulator(time_scale=TIME_SCALE)
    try:
        sim = sim_of(client)
        take_off_into_offboard(client, 3.0)
        for _ in range(10):
            client.send_setpoint(client.state().position)
            client.advance(DT)
        wanted = {"land": (M.MAV_CMD_NAV_LAND, "LAND"), "return_to_launch": (M.MAV_CMD_NAV_RETURN_TO_LAUNCH, "RTL"),
                  "hold": (M.MAV_CMD_DO_SET_MODE, "HOLD")}[leave]
        handle = sim._handle_command
        lost: list[int] = []

        def lose_the_first(msg: Any, command: int, params: list[float]) -> None:
            if command == wanted[0] and not lost:
                lost.append(command)
                return
            handle(msg, command, params)

        sim._handle_command = lose_the_first  # type: ignore[method-assign]
        modes: list[str] = []
        done = threading.Event()

        def watch() -> None:
            while not done.is_set():
                mode = sim.with_vehicle(lambda v: v.mode.value)
                if not modes or modes[-1] != mode:
                    modes.append(mode)
                time.sleep(0.005)

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        try:
            getattr(client, leave)()
        finally:
            done.set()
            watcher.join()
        assert lost == [wanted[0]]
        assert modes == ["OFFBOARD", wanted[1]], modes
        assert client.state().mode == wanted[1]
    finally:
        client.close()
