"""The payload's MAVLink messages against pymavlink's definitions (dialect common): what the
adapter (mavlink/payload.py) sends, decoded by a fresh pymavlink parser (CRC with each message's
crc_extra, field types), with every command, flag and enum value one MAVLink defines; and what the
simulated payload (sim/payload.py) sends, read the same way by a plain UDP socket."""

from __future__ import annotations

import math
import socket
import time
from typing import Any

import numpy as np
import pytest

from insulator_rs.mavlink.payload import (
    AUTOPILOT_COMPONENT,
    CAMERA_COMPONENT,
    GIMBAL_COMPONENT,
    GimbalRoute,
    MavlinkPayload,
)
from insulator_rs.mavlink.wire import mavlink2 as M
from insulator_rs.ports.payload import ShotRequest
from helpers.payload_rig import FAST, Rig, inspection_camera


def bitmask_ok(value: int, enum: str) -> bool:
    """Every bit of ``value`` is a flag of MAVLink's ``enum``."""
    flags = 0
    for v in M.enums[enum]:
        if M.enums[enum][v].name.endswith("_ENUM_END"):
            continue
        flags |= v
    return value & ~flags == 0


def fresh_parse(datagrams: list[bytes]) -> list[Any]:
    """Every message of ``datagrams``, by a parser of pymavlink's own (no robust parsing: a bad
    CRC or length raises)."""
    out: list[Any] = []
    for data in datagrams:
        mav = M.MAVLink(None)
        out.extend(mav.parse_buffer(data) or [])
    return out


def test_what_the_adapter_sends_is_valid_mavlink() -> None:
    with Rig() as r:
        pitch, yaw = math.radians(-25), math.radians(20)
        assert r.adapter.submit(ShotRequest(pitch, yaw, 500.0)).result(timeout=5.0).photo is not None
        received = list(r.sim.received)
    # the sim's parser is pymavlink's: each message decoded with its CRC; re-packed, it is the same
    for msg in received:
        assert msg.get_type() != "BAD_DATA"
        again = fresh_parse([msg.pack(M.MAVLink(None, srcSystem=msg.get_srcSystem(),
                                                srcComponent=msg.get_srcComponent()))])
        assert [m.get_type() for m in again] == [msg.get_type()]
    by_type: dict[str, list[Any]] = {}
    for msg in received:
        by_type.setdefault(msg.get_type(), []).append(msg)
        assert (msg.get_srcSystem(), msg.get_srcComponent()) == (1, M.MAV_COMP_ID_ONBOARD_COMPUTER)
    hb = by_type["HEARTBEAT"][0]
    assert (hb.type, hb.autopilot) == (M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID)
    aim = by_type["GIMBAL_DEVICE_SET_ATTITUDE"][-1]
    assert aim.target_component == GIMBAL_COMPONENT and bitmask_ok(aim.flags, "GIMBAL_DEVICE_FLAGS")
    assert aim.flags & M.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
    assert np.linalg.norm(aim.q) == pytest.approx(1.0, abs=1e-6)
    commands = by_type["COMMAND_LONG"]
    assert all(c.command in M.enums["MAV_CMD"] for c in commands)
    for c in commands:
        if c.command == M.MAV_CMD_REQUEST_MESSAGE:
            assert int(c.param1) in M.mavlink_map
    zoom = next(c for c in commands if c.command == M.MAV_CMD_SET_CAMERA_ZOOM)
    assert zoom.target_component == CAMERA_COMPONENT
    assert int(zoom.param1) == M.ZOOM_TYPE_FOCAL_LENGTH and zoom.param2 == pytest.approx(500.0 * 2.0e-3)
    capture = next(c for c in commands if c.command == M.MAV_CMD_IMAGE_START_CAPTURE)
    assert (capture.param2, capture.param3, capture.param4) == (0.0, 1.0, 1.0)  # one image, sequence 1
    ftp = by_type["FILE_TRANSFER_PROTOCOL"]
    assert all(f.target_component == CAMERA_COMPONENT and len(f.payload) == 251 for f in ftp)
    assert {f.payload[3] for f in ftp} <= {1, 2, 3, 4, 5, 15}  # opcodes: terminate, reset, list, open, read, burst


def test_the_manager_route_takes_control_then_commands_pitch_and_yaw_of_the_autopilot() -> None:
    """Through the autopilot's gimbal manager: MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE (primary control:
    our system and component), then MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (degrees, yaw clockwise, in
    the vehicle frame), both to component 1; read off the wire by a plain socket standing in for
    PX4 (acknowledging) and a live camera and gimbal."""
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    peer.settimeout(0.02)
    adapter = MavlinkPayload(f"udpout:127.0.0.1:{peer.getsockname()[1]}", inspection_camera(),
                             gimbal_route=GimbalRoute.MANAGER, settings=FAST, target_system=1)
    camera = M.MAVLink(None, srcSystem=1, srcComponent=CAMERA_COMPONENT)
    gimbal = M.MAVLink(None, srcSystem=1, srcComponent=GIMBAL_COMPONENT)
    autopilot = M.MAVLink(None, srcSystem=1, srcComponent=AUTOPILOT_COMPONENT)
    commands: list[Any] = []
    try:
        addr = None
        future = None
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and not any(c.command == M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
                                                      for c in commands):
            try:
                data, addr = peer.recvfrom(65535)
            except socket.timeout:
                data = b""
            for m in fresh_parse([data]) if data else []:
                if m.get_type() == "COMMAND_LONG" and m.target_component == AUTOPILOT_COMPONENT:
                    commands.append(m)
                    peer.sendto(autopilot.command_ack_encode(m.command, M.MAV_RESULT_ACCEPTED, 0, 0, 1,
                                                             M.MAV_COMP_ID_ONBOARD_COMPUTER).pack(autopilot), addr)
            if addr is not None:
                for mav, kind in ((camera, M.MAV_TYPE_CAMERA), (gimbal, M.MAV_TYPE_GIMBAL)):
                    peer.sendto(mav.heartbeat_encode(kind, M.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(mav), addr)
                if future is None:
                    time.sleep(0.1)  # the heartbeats received before the shot starts
                    future = adapter.submit(ShotRequest(math.radians(-30), math.radians(15), 300.0))
        assert [c.command for c in commands] == [M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
                                                 M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW]
        configure, pitchyaw = commands
        assert (configure.param1, configure.param2, configure.param3, configure.param4) == (
            1, M.MAV_COMP_ID_ONBOARD_COMPUTER, -1, -1)
        assert (pitchyaw.param1, pitchyaw.param2) == pytest.approx((-30.0, -15.0))
        assert math.isnan(pitchyaw.param3) and math.isnan(pitchyaw.param4)
        flags = int(pitchyaw.param5)
        assert bitmask_ok(flags, "GIMBAL_MANAGER_FLAGS") and flags & M.GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME
        assert pitchyaw.param7 == 0  # the manager's gimbal
    finally:
        adapter.close()
        peer.close()


def test_what_the_simulated_payload_sends_is_valid_mavlink() -> None:
    r = Rig()
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listener.bind(("127.0.0.1", 0))
    listener.settimeout(0.05)
    try:
        r.adapter.close()  # a plain socket is the payload's peer now
        r.sim.peer = listener.getsockname()
        me = M.MAVLink(None, srcSystem=1, srcComponent=M.MAV_COMP_ID_ONBOARD_COMPUTER)
        listener.sendto(me.command_long_encode(1, CAMERA_COMPONENT, M.MAV_CMD_REQUEST_MESSAGE, 0,
                                               M.MAVLINK_MSG_ID_CAMERA_INFORMATION, 0, 0, 0, 0, 0, 0).pack(me),
                        r.sim.address)
        listener.sendto(me.command_long_encode(1, GIMBAL_COMPONENT, M.MAV_CMD_REQUEST_MESSAGE, 0,
                                               M.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION, 0, 0, 0, 0, 0, 0).pack(me),
                        r.sim.address)
        datagrams = []
        deadline = time.monotonic() + 0.6
        while time.monotonic() < deadline:
            try:
                datagrams.append(listener.recvfrom(65535)[0])
            except socket.timeout:
                pass
    finally:
        listener.close()
        r.close()
    messages = fresh_parse(datagrams)
    kinds = {(m.get_srcComponent(), m.get_type()) for m in messages}
    assert {(GIMBAL_COMPONENT, "HEARTBEAT"), (CAMERA_COMPONENT, "HEARTBEAT"),
            (GIMBAL_COMPONENT, "GIMBAL_DEVICE_ATTITUDE_STATUS"), (GIMBAL_COMPONENT, "GIMBAL_DEVICE_INFORMATION"),
            (CAMERA_COMPONENT, "CAMERA_INFORMATION"), (CAMERA_COMPONENT, "COMMAND_ACK")} <= kinds
    for m in messages:
        if m.get_type() == "HEARTBEAT":
            assert m.type == {GIMBAL_COMPONENT: M.MAV_TYPE_GIMBAL, CAMERA_COMPONENT: M.MAV_TYPE_CAMERA}[m.get_srcComponent()]
            assert m.autopilot == M.MAV_AUTOPILOT_INVALID
        elif m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS":
            assert bitmask_ok(m.flags, "GIMBAL_DEVICE_FLAGS") and m.flags & M.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
        elif m.get_type() == "GIMBAL_DEVICE_INFORMATION":
            assert bitmask_ok(m.cap_flags, "GIMBAL_DEVICE_CAP_FLAGS")
            assert m.pitch_min < m.pitch_max and m.yaw_min <= m.yaw_max
        elif m.get_type() == "CAMERA_INFORMATION":
            assert bitmask_ok(m.flags, "CAMERA_CAP_FLAGS") and m.flags & M.CAMERA_CAP_FLAGS_HAS_BASIC_ZOOM
            assert (m.resolution_h, m.resolution_v) == (160, 120)
        elif m.get_type() == "COMMAND_ACK":
            assert m.result == M.MAV_RESULT_ACCEPTED and m.command == M.MAV_CMD_REQUEST_MESSAGE
