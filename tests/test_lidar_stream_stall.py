"""A stalled caller of the simulated Mid-360's stream (the sensor head's LiDAR thread on a loaded
box) gets the missed span late, not a hole (the head's ``silence_s=LIDAR_CATCH_UP_S``); the
default stream (the in-process wire LiDAR, asked only while frames wait) restarts after
SILENCE_S.

Reference: the datagrams' own header stamps (sensor clock, ns), read with ``struct`` from the
Livox SDK2 layout (timestamp at byte 28), not with our parser: a hole is a gap between
consecutive datagrams' stamps far longer than one datagram's span."""

from __future__ import annotations

import struct

import numpy as np
from helpers.lidar_room import body_pose, room

from insulator_rs.sim.lidar import default_T_b_l
from insulator_rs.sim.livox_emitter import SensorClock
from insulator_rs.sim.livox_wire import SILENCE_S, LidarStream
from insulator_rs.sim.sensor_head import LIDAR_CATCH_UP_S


def _largest_stamp_gap_s(stream: LidarStream, calls: list[float]) -> float:
    stamps = []
    for now in calls:
        for _, chunk in stream.due(now):
            stamps += [struct.unpack_from("<Q", d, 28)[0] for d in chunk if len(d) >= 36]
    assert stamps
    return float(np.max(np.diff(np.sort(np.array(stamps, dtype=np.float64))))) * 1e-9


def _stream(**kw) -> LidarStream:
    pose = lambda t: body_pose(np.array([1.0, -2.0, 3.0]), 0.4)  # noqa: E731
    return LidarStream(room(), pose, default_T_b_l(), clock=SensorClock(offset_s=50.0, drift=25e-6),
                       restart_span=0.0, slice_rate=50.0, ahead=False, **kw)


def test_a_stalled_caller_gets_the_missed_span_late_not_a_hole() -> None:
    stall = SILENCE_S + 1.5  # the head's thread stalled 3.5 s (head logs: 1-3 s under load)
    calls = [10.0 + 0.02 * k for k in range(20)] + [10.4 + stall + 0.02 * k for k in range(10)]
    assert stall < LIDAR_CATCH_UP_S
    continuous = _stream(silence_s=LIDAR_CATCH_UP_S)
    gap = _largest_stamp_gap_s(continuous, calls)
    assert continuous.restarts == 1  # the first start only
    assert gap < 0.01  # datagrams tile the sensor clock (~1 ms each, a few dropped to no return)
    # the default (the in-process wire LiDAR): the stall reads as a silent sensor, a hole
    restarting = _stream()
    assert _largest_stamp_gap_s(restarting, calls) > SILENCE_S and restarting.restarts == 2
