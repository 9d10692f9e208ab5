"""Hostile MAVLink traffic on loopback against the client and the simulated PX4 (issue 13, items 1-2).

Each case failed before its fix (pymavlink stores a stream's signing timestamp before it
checks the signature; the client took any HEARTBEAT's sender as its target, any
LOCAL_POSITION_NED as its position, kept a truncated frame's bytes across datagrams, and
pymavlink's ``udpin`` sent to every address that wrote to the port). Reference for every
case: the run without the hostile traffic, i.e. the mission's own commands still work and
the state is the simulated PX4's true one. Floods are bounded loops on 127.0.0.1 only.
"""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from helpers.simulated_px4 import connect_new_simulator, sim_of

from insulator_rs.mavlink.client import MavlinkVehicle
from insulator_rs.mavlink.link import AutopilotLink
from insulator_rs.sim.px4 import SimulatedPx4
from insulator_rs.mavlink.signing import configure_signing, key_from_passphrase
from insulator_rs.mavlink.wire import mavlink2 as M

KEY = key_from_passphrase("insulator_rs hostile tests")
FUTURE = 2**48 - 100  # a signing timestamp near the end of time


def _frame(message, *, system: int, component: int, key: bytes | None = None, link_id: int = 0,
           timestamp: int | None = None) -> bytes:
    """One packed MAVLink 2 frame from (system, component), signed with ``key`` if given."""
    mav = M.MAVLink(None, srcSystem=system, srcComponent=component)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = link_id
        mav.signing.timestamp = timestamp if timestamp is not None else 1
    return message.pack(mav)


def _autopilot_heartbeat(custom_mode: int = 0):
    return M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4,
                                       M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode, M.MAV_STATE_STANDBY, 3)


def _client_address(vehicle: MavlinkVehicle) -> tuple[str, int]:
    return vehicle._link.conn.port.getsockname()[:2]


def _fly_a_little(vehicle: MavlinkVehicle, seconds: float) -> None:
    """Arm, take off to 2 m, switch to OFFBOARD and hold a setpoint for ``seconds`` of vehicle time."""
    vehicle.arm()
    vehicle.takeoff(2.0)
    t0 = vehicle.state().time
    while vehicle.state().mode != "HOLD" or vehicle.state().position[2] < 1.9:
        vehicle.advance(0.05)
        assert vehicle.state().time - t0 < 20.0, "take-off did not finish"
    here = vehicle.state().position
    vehicle.send_setpoint(here)
    vehicle.advance(0.3)
    vehicle.start_offboard()
    t0 = vehicle.state().time
    while vehicle.state().time - t0 < seconds:
        vehicle.send_setpoint(here)
        vehicle.advance(0.05)




@pytest.fixture
def signed():
    vehicle = connect_new_simulator(time_scale=4.0, signing_key=KEY)
    try:
        yield vehicle
    finally:
        vehicle.close()


def test_forged_future_timestamp_towards_the_vehicle_changes_nothing(signed: MavlinkVehicle) -> None:
    """A datagram with the client's stream id (link 1, sys 1, comp 191), timestamp 2^48 - 100
    and a wrong signature, sent to the simulated PX4: rejected and counted, the stream's
    timestamp untouched, and the client's genuine commands are still obeyed."""
    sim = sim_of(signed)
    forged = _frame(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0),
                    system=1, component=191, key=bytes(32), link_id=1, timestamp=FUTURE)
    stream = (1, 1, 191)
    before = sim._mav.signing.stream_timestamps.get(stream)
    assert before is not None and before < FUTURE  # the client's genuine stream is known
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker:
        attacker.sendto(forged, sim.address)
    deadline = time.monotonic() + 2.0
    while sim.stats.rejected_signature == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert sim.stats.rejected_signature == 1
    assert sim._mav.signing.stream_timestamps[stream] < FUTURE
    assert not sim.with_vehicle(lambda v: v.armed)  # the forged ARM did nothing
    _fly_a_little(signed, 2.0)  # genuine, signed commands: arm, take-off, offboard
    assert signed.state().mode == "OFFBOARD" and signed.state().healthy


def test_forged_future_timestamp_towards_the_client_changes_nothing(signed: MavlinkVehicle) -> None:
    """The same forgery the other way (link 0, sys 1, comp 1: the simulated PX4's stream id),
    injected from the autopilot's own address: the client drops it, counts it, keeps the
    stream's timestamp and keeps hearing the autopilot (no heartbeat-loss failsafe)."""
    sim = sim_of(signed)
    forged = _frame(_autopilot_heartbeat(), system=1, component=1, key=bytes(32), link_id=0, timestamp=FUTURE)
    signing = signed._link.mav.signing
    before = signing.stream_timestamps.get((0, 1, 1))
    assert before is not None and before < FUTURE
    sim._sock.sendto(forged, _client_address(signed))  # a man in the middle on the autopilot's path
    _fly_a_little(signed, 5.0)  # longer than the 3 s heartbeat-loss timeout
    assert signed.link_stats.bad_signature == 1
    assert signing.stream_timestamps[(0, 1, 1)] < FUTURE
    assert signed.state().healthy and signed.state().mode == "OFFBOARD"


def test_signature_is_checked_before_the_stream_timestamp() -> None:
    """Unit level, both orders: a valid frame then a forged future one, and the forged one first."""
    mav = M.MAVLink(None, srcSystem=1, srcComponent=191)
    mav.robust_parsing = True
    configure_signing(mav, KEY, link_id=1, allow_unsigned=frozenset())
    now = mav.signing.timestamp
    genuine = _frame(_autopilot_heartbeat(), system=1, component=1, key=KEY, timestamp=now + 10)
    forged = _frame(_autopilot_heartbeat(), system=1, component=1, key=bytes(32), timestamp=FUTURE)
    later = _frame(_autopilot_heartbeat(), system=1, component=1, key=KEY, timestamp=now + 20)
    kinds = [m.get_type() for data in (forged, genuine, forged, later) for m in (mav.parse_buffer(data) or [])]
    assert kinds == ["BAD_DATA", "HEARTBEAT", "BAD_DATA", "HEARTBEAT"]
    assert mav.signing.stream_timestamps[(0, 1, 1)] == now + 20
    assert mav.signing.timestamp == now + 20
    replay = mav.parse_buffer(genuine)  # a genuine frame replayed: its timestamp is old now
    assert [m.get_type() for m in replay] == ["BAD_DATA"]


@pytest.fixture
def vehicle():
    client = connect_new_simulator(time_scale=4.0)
    try:
        yield client
    finally:
        client.close()


def test_a_foreign_heartbeat_neither_retargets_nor_fires_a_failsafe(vehicle: MavlinkVehicle) -> None:
    """HEARTBEAT of an autopilot with system id 42 in mode POSCTL, from a foreign address and
    from the autopilot's own address, while flying OFFBOARD: dropped and counted."""
    sim = sim_of(vehicle)
    _fly_a_little(vehicle, 0.5)
    foreign = _frame(_autopilot_heartbeat(custom_mode=3 << 16), system=42, component=1)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
        for _ in range(3):
            stranger.sendto(foreign, _client_address(vehicle))
            sim._sock.sendto(foreign, _client_address(vehicle))
            vehicle.send_setpoint(vehicle.state().position)
            vehicle.advance(0.5)
    assert vehicle.autopilot == (1, 1)
    assert vehicle.link_stats.foreign_address == 3 and vehicle.link_stats.foreign_source == 3
    state = vehicle.state()
    assert state.mode == "OFFBOARD" and state.healthy and state.fault is None


def test_a_foreign_local_position_does_not_move_the_client(vehicle: MavlinkVehicle) -> None:
    """LOCAL_POSITION_NED (1000, 1000, -50) from system 42 via the autopilot's address: the
    client's position stays the simulated PX4's true one (tolerance 0.05 m)."""
    sim = sim_of(vehicle)
    _fly_a_little(vehicle, 0.5)
    forged = _frame(M.MAVLink_local_position_ned_message(10**6, 1000.0, 1000.0, -50.0, 0, 0, 0),
                    system=42, component=1)
    for _ in range(5):
        sim._sock.sendto(forged, _client_address(vehicle))
        vehicle.send_setpoint(vehicle.state().position)
        state = vehicle.advance(0.1)
        true_position, _yaw, _t = sim.true_pose()
        assert np.linalg.norm(state.position - true_position) < 0.05
    assert vehicle.link_stats.foreign_source == 5


@pytest.mark.slow
def test_a_flood_of_truncated_headers_starves_nothing() -> None:
    """~900 datagrams/s of truncated 10-byte MAVLink 2 headers for 4 s, from the autopilot's own
    address and from a stranger, against a ``udpin`` client (PX4 SITL's layout: the autopilot
    streams to the client's port). The client keeps hearing the autopilot (no heartbeat
    loss), counts every truncated datagram, and sends nothing to the stranger."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with SimulatedPx4(time_scale=4.0, remote=("127.0.0.1", port)) as sim:
        client = MavlinkVehicle(f"udpin:127.0.0.1:{port}", time_scale=4.0)
        try:
            header = bytes([0xFD, 9, 0, 0, 7, 1, 1, 0, 0, 0])  # a HEARTBEAT header, no payload/CRC
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
                stranger.bind(("127.0.0.1", 0))
                stranger.setblocking(False)
                sent, start = 0, time.monotonic()
                while time.monotonic() - start < 4.0:
                    for _ in range(9):
                        sim._sock.sendto(header, ("127.0.0.1", port))
                        stranger.sendto(header, ("127.0.0.1", port))
                        sent += 1
                    time.sleep(0.01)
                    client.state()
                received_by_stranger = 0
                try:
                    while True:
                        stranger.recvfrom(65535)
                        received_by_stranger += 1
                except BlockingIOError:
                    pass
            _fly_a_little(client, 1.0)
            stats = client.link_stats
            assert sent / 4.0 > 600  # the flood really was one (~900/s on an idle machine)
            assert stats.truncated >= sent * 0.95 and stats.foreign_address >= sent * 0.95
            assert received_by_stranger == 0
            assert client.state().healthy and client.state().mode == "OFFBOARD"
            assert client.telemetry().link["dropped"] >= 2 * sent * 0.95
            line = stats.describe()
            assert f"{stats.datagrams} datagrams" in line and f"truncated {stats.truncated}" in line
        finally:
            client.close()


# -- fuzzing the datagram handler ----------------------------------------------------------

PEER = ("127.0.0.1", 9)  # the link's udpout address (nothing listens: nothing is sent in these tests)


def _fresh_link() -> AutopilotLink:
    link = AutopilotLink(f"udpout:{PEER[0]}:{PEER[1]}", source_system=1, source_component=191)
    assert link.handle_datagram(_frame(_autopilot_heartbeat(), system=1, component=1), PEER)
    return link


VALID = _frame(M.MAVLink_local_position_ned_message(1234, 1.0, 2.0, -3.0, 0, 0, 0), system=1, component=1)


@given(st.lists(st.binary(max_size=300) | st.builds(lambda n, tail: VALID[:n] + tail,
                                                    st.integers(0, len(VALID)), st.binary(max_size=20)),
                max_size=8))
def test_fuzz_any_bytes_are_counted_never_raised_and_a_valid_packet_still_gets_through(datagrams) -> None:
    """Arbitrary datagrams (random bytes, a valid frame cut anywhere plus junk) from the
    autopilot's address: never an exception, each one counted, and a valid LOCAL_POSITION_NED
    datagram right after them is accepted with its values (float32 exact)."""
    link = _fresh_link()
    try:
        for data in datagrams:
            before = link.stats.datagrams
            out = link.handle_datagram(data, PEER)
            assert link.stats.datagrams == before + 1
            assert all(m.get_srcSystem() == 1 and m.get_srcComponent() == 1 for m in out)
        accepted = link.handle_datagram(VALID, PEER)
        assert [m.get_type() for m in accepted] == ["LOCAL_POSITION_NED"]
        assert (accepted[0].x, accepted[0].y, accepted[0].z) == (1.0, 2.0, -3.0)
    finally:
        link.close()


def test_link_counts_each_kind_of_drop() -> None:
    """One datagram of each kind, with the counter it must land in."""
    link = _fresh_link()
    try:
        stranger = ("127.0.0.1", 10)
        assert link.handle_datagram(VALID, stranger) == [] and link.stats.foreign_address == 1
        other = _frame(M.MAVLink_local_position_ned_message(1, 0, 0, 0, 0, 0, 0), system=1, component=100)
        assert link.handle_datagram(other, PEER) == [] and link.stats.foreign_source == 1
        assert link.handle_datagram(VALID[:10], PEER) == [] and link.stats.truncated == 1
        broken = bytearray(VALID)
        broken[-1] ^= 0xFF  # CRC
        assert link.handle_datagram(bytes(broken), PEER) == [] and link.stats.bad_data >= 1
        assert len(link.handle_datagram(VALID + VALID, PEER)) == 2  # two whole frames in one datagram
        unknown = bytearray(VALID)
        unknown[7:10] = (4242).to_bytes(3, "little")  # a message id the dialect lacks (CRC unchecked then)
        assert link.handle_datagram(bytes(unknown), PEER) == [] and link.stats.unknown_message == 1
        assert link.stats.dropped == (link.stats.foreign_address + link.stats.foreign_source
                                      + link.stats.truncated + link.stats.bad_data + link.stats.unknown_message)
        assert math.isfinite(link.stats.dropped)
    finally:
        link.close()
