"""Receive-path cost of one second of Mid-360 data (200,000 points, 2084 type-1 datagrams
of 96 points) from Python, side by side:

    pytest benches/bench_livox.py --benchmark-enable

* ``insulator_rs``: every datagram through ``LivoxScanAssembler.push`` (validation,
  CRC-32, decoding, sequence accounting, 10 Hz assembly in Rust; one Python call per
  datagram, as the driver's receive thread makes them) and the scans popped as numpy.
* ``numpy``: what a user would otherwise write: ``zlib.crc32`` per datagram and a
  structured-dtype ``np.frombuffer`` decode to float32 metres (no sequence accounting,
  no assembly).

Target (issue 11): keep up with 200k points/s at <= 5 % of one core, i.e. one round
(one second of data) in <= 50 ms.
"""

from __future__ import annotations

import struct
import zlib
from typing import Any

import numpy as np
import pytest

from insulator_rs._core import LivoxScanAssembler
from insulator_rs.sim.livox_emitter import encode_datagram

GROUP = "Mid-360 receive, 1 s of data (200k points)"
POINTS_PER_S = 200_000
DOTS = 96
_HIGH = np.dtype([("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("r", "u1"), ("tag", "u1")])


def one_second() -> list[bytes]:
    rng = np.random.default_rng(0)
    out = []
    for k in range(-(-POINTS_PER_S // DOTS)):
        s = np.zeros(DOTS, _HIGH)
        s["x"], s["y"], s["z"] = rng.integers(-20_000, 20_000, (3, DOTS))
        out.append(encode_datagram(data_type=1, samples=s.tobytes(), dot_num=DOTS, time_interval=4800,
                                   udp_cnt=k, frame_cnt=0, timestamp_ns=10**9 + k * 480_000))
    return out


DATAGRAMS = one_second()


def rust_receive() -> int:
    asm = LivoxScanAssembler()
    push = asm.push
    for d in DATAGRAMS:
        push(d)
    asm.flush()
    n = 0
    while (scan := asm.pop_scan()) is not None:
        n += len(scan.points)
    return n


def numpy_receive() -> int:
    n = 0
    for d in DATAGRAMS:
        (crc,) = struct.unpack_from("<I", d, 24)
        if zlib.crc32(memoryview(d)[28:]) != crc:
            continue
        s = np.frombuffer(d, _HIGH, offset=36)
        xyz = np.stack([s["x"], s["y"], s["z"]], axis=1).astype(np.float32) * np.float32(1e-3)
        n += len(xyz)
    return n


@pytest.mark.benchmark(group=GROUP)
def test_receive_one_second_rust(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="insulator_rs", target="<= 50 ms")
    assert benchmark(rust_receive) == len(DATAGRAMS) * DOTS


@pytest.mark.benchmark(group=GROUP)
def test_receive_one_second_numpy(benchmark: Any) -> None:
    benchmark.extra_info.update(impl="numpy + zlib")
    assert benchmark(numpy_receive) == len(DATAGRAMS) * DOTS
