"""Independent MAVLink peer: MAVSDK (the `mavsdk` wheel, its C++ core in-process, offline).

Both directions, so neither side of the project is only tested against itself:
* MAVSDK as the ground station drives the simulated PX4 through arm, offboard
  and a position setpoint (MAVSDK's own PX4 mode encoding and setpoint stream);
* the project's client flies against MAVSDK's autopilot-side server plugins
  (ActionServer, TelemetryServer): refusal and acceptance of arming, the
  OFFBOARD switch, telemetry in NED converted to ENU.
MAVSDK's ActionServer answered NAV_LAND with no COMMAND_ACK in our probing, so
landing is not exercised against it.
"""

from __future__ import annotations

import math
import socket
import threading
import time

import numpy as np
import pytest

from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.plugins.action import Action
from mavsdk.plugins.action_server import ActionServer, AllowableFlightModes
from mavsdk.plugins.offboard import Offboard, PositionNedYaw
from mavsdk.plugins.telemetry import Telemetry
from mavsdk.plugins import telemetry_server as ts

from insulator_rs.mavlink.client import CommandRejected, MavlinkVehicle
from insulator_rs.sim.px4 import SimulatedPx4

TIME_SCALE = 2.0


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def wait_for(predicate, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def test_mavsdk_drives_the_simulated_px4_through_arm_offboard_and_a_setpoint() -> None:
    """Reference: the simulator's true state. MAVSDK's NED setpoint (2, 1, -3) is ENU
    (1, 2, 3); its telemetry must read back what it commanded."""
    with SimulatedPx4(time_scale=TIME_SCALE) as sim:
        host, port = sim.address
        sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            assert int(sdk.add_any_connection(f"udpout://{host}:{port}")) == 0
            system = sdk.first_autopilot(5.0)
            assert system is not None
            assert system.autopilot_type().name == "PX4"
            action, offboard, telemetry = Action(system), Offboard(system), Telemetry(system)
            action.arm()
            assert sim.with_vehicle(lambda v: v.armed)
            offboard.set_position_ned(PositionNedYaw(2.0, 1.0, -3.0, 90.0))
            time.sleep(0.3)
            offboard.start()
            assert sim.with_vehicle(lambda v: v.mode.value) == "OFFBOARD"
            assert wait_for(lambda: np.linalg.norm(sim.with_vehicle(lambda v: v.model.position)
                                                   - [1.0, 2.0, 3.0]) < 0.02, 10.0)
            yaw_enu = sim.with_vehicle(lambda v: v.model.yaw)
            assert yaw_enu == pytest.approx(0.0, abs=1e-3)  # 90 deg from north = east
            assert wait_for(lambda: abs(telemetry.position_velocity_ned().position.down_m + 3.0) < 0.02, 3.0)
            reading = telemetry.position_velocity_ned().position
            assert (reading.north_m, reading.east_m) == pytest.approx((2.0, 1.0), abs=0.02)
            assert sim.stats.setpoints > 20
        finally:
            sdk.destroy()


def test_client_against_mavsdk_server_plugins() -> None:
    """The project's client against MAVSDK's autopilot server plugins (the inspection photo is the
    companion computer's own camera, not a MAVLink camera: no camera plugin)."""
    port = free_udp_port()
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.AUTOPILOT))
    stop = threading.Event()
    client: MavlinkVehicle | None = None
    try:
        assert int(sdk.add_any_connection(f"udpin://127.0.0.1:{port}")) == 0
        autopilot = sdk.server_component()
        action_server = ActionServer(autopilot)
        telemetry_server = ts.TelemetryServer(autopilot)

        def publish() -> None:
            while not stop.is_set():
                telemetry_server.publish_position_velocity_ned(ts.PositionVelocityNed(
                    ts.PositionNed(1.0, 2.0, -3.0), ts.VelocityNed(0.5, 0.0, 0.0)))
                telemetry_server.publish_home(ts.Position(47.4, 8.5, 488.0, 0.0))
                telemetry_server.publish_extended_sys_state(ts.VtolState.UNDEFINED, ts.LandedState.IN_AIR)
                telemetry_server.publish_attitude(ts.EulerAngle(0.0, 0.0, 30.0, 0),
                                                  ts.AngularVelocityBody(0.0, 0.0, 0.0))
                time.sleep(0.05)

        threading.Thread(target=publish, daemon=True).start()
        # MAVSDK answers from its own threads: allow more than PX4's usual ACK time.
        client = MavlinkVehicle(f"udpout:127.0.0.1:{port}", heartbeat_timeout=5.0, command_timeout=3.0)
        # the client is up once it has a position; ATTITUDE may come a few samples later on a
        # loaded machine (CI saw yaw 0.0 read before the first one): wait for it, bounded
        deadline = time.monotonic() + 5.0
        while abs(client.state().yaw - math.radians(60.0)) > 1e-5 and time.monotonic() < deadline:
            time.sleep(0.02)
        state = client.state()
        np.testing.assert_allclose(state.position, [2.0, 1.0, 3.0])  # NED (1, 2, -3) in ENU
        np.testing.assert_allclose(state.velocity, [0.0, 0.5, 0.0])
        assert state.yaw == pytest.approx(math.radians(60.0), abs=1e-5)  # 30 deg from north
        # MAVSDK's ActionServer refuses arming until told the vehicle is armable.
        with pytest.raises(CommandRejected, match="MAV_RESULT_TEMPORARILY_REJECTED"):
            client.arm()
        action_server.set_armable(True, True)
        client.arm()
        assert client.state().armed
        action_server.set_allowable_flight_modes(AllowableFlightModes(True, True, True, True, True, True, True))
        client.send_setpoint(np.array([2.0, 1.0, 3.0]), yaw=math.radians(60.0))
        time.sleep(0.3)
        client.start_offboard()
        assert client.state().mode == "OFFBOARD"  # MAVSDK's heartbeat, PX4 custom_mode decoded
    finally:
        stop.set()
        if client is not None:
            client.close()
        sdk.destroy()
