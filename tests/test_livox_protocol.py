"""The Livox bindings against independent references: the protocol tables encoded with
``struct``, CRC-32 by ``zlib.crc32`` and CRC-16/CCITT-FALSE by ``binascii.crc_hqx(.., 0xFFFF)``
(exact equality); arbitrary bytes never raise; bad arguments name themselves."""

from __future__ import annotations

import binascii
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from insulator_rs._core import (
    LivoxScanAssembler,
    livox_decode_command,
    livox_discovery_request,
    livox_encode_command,
    livox_host_config_request,
    livox_parse_config_ack,
    livox_parse_discovery_ack,
    livox_parse_header,
    livox_work_mode_request,
)
from insulator_rs.exceptions import PacketError, SensorError
from insulator_rs.sim.livox_emitter import encode_datagram


def packet(k: int, n: int = 96) -> bytes:
    samples = b"".join(struct.pack("<iiiBB", 1000 + i, -i, 7, i % 256, 0) for i in range(n))
    return encode_datagram(data_type=1, samples=samples, dot_num=n, time_interval=4800, udp_cnt=k,
                           frame_cnt=0, timestamp_ns=10**9 + k * 480_000)


def test_header_fields_match_the_table() -> None:
    d = packet(5)
    h = livox_parse_header(d)
    assert h == {"version": 0, "length": 1380, "time_interval": 4800, "dot_num": 96, "udp_cnt": 5, "frame_cnt": 0,
                 "data_type": 1, "time_type": 0, "crc32": zlib.crc32(d[28:]), "timestamp_ns": 10**9 + 5 * 480_000}


def test_header_errors_name_the_field() -> None:
    d = packet(0)
    with pytest.raises(PacketError, match=r"^packet: truncated datagram, 10 bytes"):
        livox_parse_header(d[:10])
    with pytest.raises(PacketError, match=r"^packet\.crc32"):
        livox_parse_header(d[:-1] + bytes([d[-1] ^ 1]))
    with pytest.raises(PacketError, match=r"^packet\.version"):
        livox_parse_header(b"\x05" + d[1:])
    with pytest.raises(PacketError, match=r"^packet\.data_type"):
        livox_parse_header(d[:10] + b"\x09" + d[11:])


def test_scan_arrays_are_numpy_without_copies_and_read_only() -> None:
    asm = LivoxScanAssembler()
    for k in range(300):  # 0.144 s: one full window [1.0, 1.1)
        assert asm.push(packet(k)) == "points"
    scan = asm.pop_scan()
    assert scan is not None and asm.pop_scan() is None
    assert scan.points.dtype == np.float32 and scan.points.shape == (len(scan), 3)
    assert scan.points.flags.c_contiguous and scan.points.flags.owndata is False or scan.points.base is not None
    assert not scan.points.flags.writeable
    assert scan.times_ns.dtype == np.uint64 and scan.reflectivity.dtype == np.uint8
    assert (scan.start_ns, scan.end_ns) == (10**9, 11 * 10**8)
    assert np.all(np.diff(scan.times_ns.astype(np.int64)) == 5000)
    assert scan.points[1].tolist() == pytest.approx([1.001, -0.001, 0.007])
    assert "LivoxScan(points=" in repr(scan)


def test_push_reports_each_outcome() -> None:
    asm = LivoxScanAssembler()
    d = packet(0)
    assert asm.push(d) == "points"
    assert asm.push(d) == "duplicate"
    assert asm.push(d[:20]) == "truncated"
    assert asm.push(d + b"\0") == "length_mismatch"
    bad = bytearray(d)
    bad[40] ^= 1
    assert asm.push(bytes(bad)) == "bad_crc"
    s = asm.stats()
    assert (s["datagrams"], s["duplicates"], s["truncated"], s["length_mismatch"], s["bad_crc"], s["malformed"]) == \
        (5, 1, 1, 1, 1, 3)


def test_control_frames_carry_independent_crcs() -> None:
    for frame in (livox_discovery_request(7), livox_work_mode_request(8, True),
                  livox_host_config_request(9, "192.168.1.50", 56301, 56401),
                  livox_encode_command(0x0101, 10, b"\x01\x00\x00\x00\x06\x80")):
        sof, version, length, seq, cmd_id, cmd_type, sender, crc16, crc32 = struct.unpack_from("<BBHIHBB6xHI", frame)
        assert (sof, version, length, cmd_type, sender) == (0xAA, 0, len(frame), 0, 0)
        assert crc16 == binascii.crc_hqx(frame[:18], 0xFFFF)
        assert crc32 == (zlib.crc32(frame[24:]) if len(frame) > 24 else 0)
        assert livox_decode_command(frame)[:2] == (cmd_id, seq)
    assert livox_discovery_request(7)[8:10] == b"\x00\x00"
    assert livox_work_mode_request(8, False)[24:] == struct.pack("<HHHHB", 1, 0, 0x001A, 1, 2)


def test_acks_parse_and_bad_frames_name_the_field() -> None:
    body = bytes([0, 9]) + b"SN123".ljust(16, b"\0") + bytes([10, 0, 0, 2]) + struct.pack("<H", 56100)
    ack = livox_encode_command(0, 1, body, cmd_type=1, sender_type=1)
    assert livox_parse_discovery_ack(ack) == {"ret_code": 0, "dev_type": 9, "serial_number": "SN123",
                                              "lidar_ip": "10.0.0.2", "cmd_port": 56100}
    cfg = livox_encode_command(0x0100, 2, b"\x21\x1a\x00", cmd_type=1, sender_type=1)
    assert livox_parse_config_ack(cfg) == (0x21, 0x001A)
    with pytest.raises(PacketError, match=r"^command\.cmd_id"):
        livox_parse_config_ack(ack)
    with pytest.raises(PacketError, match=r"^command\.sof"):
        livox_decode_command(b"\x55" + ack[1:])
    with pytest.raises(PacketError, match=r"^command\.crc16"):
        livox_decode_command(ack[:4] + b"\xff" + ack[5:])
    with pytest.raises(PacketError, match=r"^command\.data"):
        livox_parse_discovery_ack(livox_encode_command(0, 1, b"\x00", cmd_type=1))
    with pytest.raises(ValueError, match=r"^host_ip"):
        livox_host_config_request(1, "not-an-ip", 1, 2)
    with pytest.raises(PacketError, match=r"^command\.length"):
        livox_encode_command(0x0100, 1, bytes(1400))


def test_assembler_arguments_are_validated() -> None:
    with pytest.raises(ValueError, match=r"^frame_period_s"):
        LivoxScanAssembler(frame_period_s=0.0)
    with pytest.raises(ValueError, match=r"^reorder_grace_s"):
        LivoxScanAssembler(reorder_grace_s=float("nan"))
    with pytest.raises(ValueError, match=r"^max_queued_scans"):
        LivoxScanAssembler(max_queued_scans=0)


@given(st.lists(st.binary(max_size=1500), max_size=30))
def test_arbitrary_datagrams_never_raise(datagrams: list[bytes]) -> None:
    asm = LivoxScanAssembler()
    for d in datagrams:
        assert isinstance(asm.push(d), str)
    asm.flush()
    while asm.pop_scan() is not None:
        pass
    assert asm.stats()["datagrams"] == len(datagrams)


@given(st.binary(max_size=1500))
def test_arbitrary_frames_raise_only_packet_error(frame: bytes) -> None:
    for parse in (livox_decode_command, livox_parse_discovery_ack, livox_parse_config_ack, livox_parse_header):
        try:
            parse(frame)
        except PacketError as exc:
            assert str(exc).startswith(("packet", "command")), exc  # names the packet or frame field


def test_protocol_errors_are_the_declared_packet_error() -> None:
    """The bindings raise the class declared in exceptions.py (looked up, not created in Rust):
    a SensorError, not a bare ValueError, so a caller cannot mistake it for a bad argument."""
    assert issubclass(PacketError, SensorError) and not issubclass(PacketError, ValueError)
    with pytest.raises(PacketError) as info:
        livox_decode_command(b"\x55" * 30)
    assert type(info.value) is PacketError
