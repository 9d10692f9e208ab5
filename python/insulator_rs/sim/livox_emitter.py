"""A Livox Mid-360 of our own: the simulator's LiDAR frames as SDK2 protocol datagrams.

The simulated Mid-360 (:mod:`insulator_rs.sim.lidar`) fires shot ``k`` at
``t_k = k / point_rate`` (vehicle clock) and keeps only the shots that returned. A
real Mid-360 sends every shot: 96 consecutive shots per point-cloud datagram, a shot
without a return as an all-zero sample. This module does the same, written from the
protocol tables ("Livox LiDAR Communication Protocol -- Mid360") with ``struct`` and
``zlib.crc32``, independently of the Rust parser it tests:

* header (36 bytes, little-endian): version 0, length, time_interval (0.1 us: the
  span of the packet's 96 shots), dot_num 96, udp_cnt, frame_cnt, data_type,
  time_type 0, 12 reserved, crc32 (zlib) of timestamp + data, timestamp (ns, first shot);
* counters: ``frame_cnt`` advances when a packet's timestamp enters a new frame
  period of the sensor clock, and ``udp_cnt`` restarts at 0 there (as documented);
* data types 1 (int32 mm), 2 (int16 cm) and 3 (depth mm, zenith and azimuth in
  0.01 deg); IMU datagrams (type 0) with gyro (rad/s) and acc (g);
* the sensor's clock: ``sensor_ns = round(((1 + drift) * t + offset) * 1e9)`` for a
  vehicle time ``t`` (s), so tests can check the time sync;
* faults, seeded, at most one per packet: loss, duplication, reordering (a packet
  held back ``reorder_depth`` packets), a corrupted CRC-covered byte, a truncated
  datagram. :class:`FaultLog` records what was injected: the truth the driver's
  counters are checked against.

Not part of the onboard package's dependency graph: nothing onboard imports this.
"""

from __future__ import annotations

import itertools
import math
import socket
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from insulator_rs.sim.lidar import LidarFrame

HEADER = struct.Struct("<BHHHHBBB12sIQ")
assert HEADER.size == 36
DOTS_PER_PACKET = 96
PROTOCOL_VERSION = 0
DATA_TYPE_IMU = 0
DATA_TYPE_CARTESIAN_HIGH = 1
DATA_TYPE_CARTESIAN_LOW = 2
DATA_TYPE_SPHERICAL = 3
_CRC_START = 28
_HIGH = np.dtype([("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("r", "u1"), ("tag", "u1")])
_LOW = np.dtype([("x", "<i2"), ("y", "<i2"), ("z", "<i2"), ("r", "u1"), ("tag", "u1")])
_SPH = np.dtype([("depth", "<u4"), ("theta", "<u2"), ("phi", "<u2"), ("r", "u1"), ("tag", "u1")])
_SAMPLE = {DATA_TYPE_CARTESIAN_HIGH: _HIGH, DATA_TYPE_CARTESIAN_LOW: _LOW, DATA_TYPE_SPHERICAL: _SPH}
assert (_HIGH.itemsize, _LOW.itemsize, _SPH.itemsize) == (14, 8, 10)


@dataclass(frozen=True)
class SensorClock:
    """The LiDAR's clock against the vehicle's: ``sensor = (1 + drift) * vehicle + offset`` (s)."""

    offset_s: float = 0.0
    drift: float = 0.0

    def sensor_ns(self, t_vehicle: float | np.ndarray) -> np.ndarray:
        return np.round(((1.0 + self.drift) * np.asarray(t_vehicle, np.float64) + self.offset_s) * 1e9).astype(
            np.uint64)

    def to_vehicle(self, sensor_s: float | np.ndarray) -> np.ndarray:
        """The exact inverse (what a perfect time sync would give)."""
        return (np.asarray(sensor_s, np.float64) - self.offset_s) / (1.0 + self.drift)


@dataclass(frozen=True)
class Faults:
    """Probabilities per point packet (at most one fault each); seeded."""

    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    bad_crc: float = 0.0
    truncate: float = 0.0
    reorder_depth: int = 3
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate", "reorder", "bad_crc", "truncate"):
            p = getattr(self, name)
            if not (0.0 <= p <= 1.0):
                raise ValueError(f"faults.{name}: must be a probability in [0, 1], got {p}")
        if self.loss + self.duplicate + self.reorder + self.bad_crc + self.truncate > 1.0:
            raise ValueError("faults: the probabilities must sum to at most 1 (one fault per packet)")
        if self.reorder_depth < 1:
            raise ValueError(f"faults.reorder_depth: must be >= 1, got {self.reorder_depth}")


@dataclass
class FaultLog:
    """What the emitter did: packets built, and each fault injected."""

    packets: int = 0
    sent: int = 0
    lost: int = 0
    duplicated: int = 0
    reordered: int = 0
    #: Held back, but nothing valid overtook it (arrives in order).
    held_in_place: int = 0
    bad_crc: int = 0
    truncated: int = 0
    #: Indices (first shot // 96) of the packets the receiver cannot have: lost, bad CRC, truncated.
    dropped: list[int] = field(default_factory=list)


def _samples(points_l: np.ndarray, reflectivity: np.ndarray, data_type: int) -> np.ndarray:
    out = np.zeros(len(points_l), dtype=_SAMPLE[data_type])
    if data_type == DATA_TYPE_CARTESIAN_HIGH:
        mm = np.round(points_l * 1000.0).astype(np.int64)
        out["x"], out["y"], out["z"] = mm[:, 0], mm[:, 1], mm[:, 2]
    elif data_type == DATA_TYPE_CARTESIAN_LOW:
        cm = np.clip(np.round(points_l * 100.0), -32768, 32767).astype(np.int64)
        out["x"], out["y"], out["z"] = cm[:, 0], cm[:, 1], cm[:, 2]
    else:
        r = np.linalg.norm(points_l, axis=1)
        zenith = np.degrees(np.arccos(np.clip(points_l[:, 2] / np.where(r > 0, r, 1.0), -1.0, 1.0)))
        azimuth = np.degrees(np.arctan2(points_l[:, 1], points_l[:, 0])) % 360.0
        out["depth"] = np.round(r * 1000.0).astype(np.int64)
        out["theta"] = np.round(zenith * 100.0).astype(np.int64)
        out["phi"] = np.round(azimuth * 100.0).astype(np.int64) % 36000
    out["r"] = reflectivity
    return out


def encode_datagram(*, data_type: int, samples: bytes, dot_num: int, time_interval: int, udp_cnt: int,
                    frame_cnt: int, timestamp_ns: int, time_type: int = 0) -> bytes:
    """One datagram from the protocol table (CRC-32 = zlib's, over timestamp + data)."""
    length = HEADER.size + len(samples)
    tail = struct.pack("<Q", timestamp_ns) + samples
    return HEADER.pack(PROTOCOL_VERSION, length, time_interval, dot_num, udp_cnt & 0xFFFF, frame_cnt & 0xFF,
                       data_type, time_type, bytes(12), zlib.crc32(tail), timestamp_ns) + samples


def imu_datagram(t_vehicle: float, gyro: Iterable[float], acc: Iterable[float], *, clock: SensorClock,
                 udp_cnt: int = 0) -> bytes:
    """An IMU datagram (type 0): gyro rad/s, acc in g, stamped on the sensor clock."""
    sample = struct.pack("<6f", *gyro, *acc)
    return encode_datagram(data_type=DATA_TYPE_IMU, samples=sample, dot_num=1, time_interval=0,
                           udp_cnt=udp_cnt, frame_cnt=0, timestamp_ns=int(clock.sensor_ns(t_vehicle)))


@dataclass
class LivoxEmitter:
    """Turns consecutive simulator frames into Mid-360 datagrams.

    ``point_rate``: shots per second (the :class:`~insulator_rs.sim.lidar.Mid360`'s).
    Packets span 96 consecutive shots of the global grid, so a packet may straddle two
    frames: it is emitted once the frame holding its last shot has been added.
    """

    point_rate: float = 200_000.0
    clock: SensorClock = field(default_factory=SensorClock)
    data_type: int = DATA_TYPE_CARTESIAN_HIGH
    faults: Faults = field(default_factory=Faults)
    frame_period_s: float = 0.1
    log: FaultLog = field(default_factory=FaultLog)

    def __post_init__(self) -> None:
        if self.data_type not in _SAMPLE:
            raise ValueError(f"data_type: must be 1, 2 or 3, got {self.data_type}")
        if not (math.isfinite(self.point_rate) and self.point_rate > 0):
            raise ValueError(f"point_rate: must be a finite number > 0, got {self.point_rate}")
        self._rng = np.random.default_rng(self.faults.seed)
        self._next_packet = 0  # packet index (global shot k // 96) not yet emitted
        # the shots not sent yet: global shot index k, xyz (L), reflectivity
        self._pending_k = np.zeros(0, np.int64)
        self._pending_xyz = np.zeros((0, 3))
        self._pending_refl = np.zeros(0, np.uint8)
        self._udp_cnt = -1
        self._frame_cnt = 0
        self._frame_index: int | None = None
        self._held: list[list[Any]] = []  # [packets left to wait, overtaken?, datagram]
        #: Faults are injected only while this is True (keep the stream's ends clean).
        self.faults_enabled = True
        f = self.faults
        self._edges = list(itertools.accumulate((f.loss, f.duplicate, f.reorder, f.bad_crc, f.truncate)))
        span_s = DOTS_PER_PACKET / self.point_rate * (1.0 + self.clock.drift)
        self._time_interval = int(round(span_s * 1e7))

    def add_frame(self, frame: LidarFrame, reflectivity: np.ndarray | None = None) -> list[bytes]:
        """The datagrams (faults applied) completed by ``frame``, in send order."""
        k = np.round(frame.timestamps * self.point_rate).astype(np.int64)
        refl = (np.full(len(k), 100, np.uint8) if reflectivity is None
                else np.asarray(reflectivity, np.uint8))
        keep = k >= self._next_packet * DOTS_PER_PACKET  # shots of packets already sent are dropped
        self._pending_k = np.concatenate([self._pending_k, k[keep]])
        self._pending_xyz = np.concatenate([self._pending_xyz, np.asarray(frame.points_l, np.float64)[keep]])
        self._pending_refl = np.concatenate([self._pending_refl, refl[keep]])
        # The frame covers shots up to the one before the next frame's first.
        k_end = math.ceil(frame.t_end * self.point_rate - 1e-9)
        n_packets = k_end // DOTS_PER_PACKET - self._next_packet
        out: list[bytes] = []
        if n_packets <= 0:
            return out
        # every completed packet's shots at once (numpy), then one header each: a Python loop
        # per shot (200,000 a second) kept a third of a core busy, and a loaded sensor head
        # falls behind the flight (frames paired short)
        k0 = self._next_packet * DOTS_PER_PACKET
        k1 = k0 + n_packets * DOTS_PER_PACKET
        done = self._pending_k < k1
        take = done & (self._pending_k >= k0)
        xyz = np.zeros((n_packets * DOTS_PER_PACKET, 3))
        refl_all = np.zeros(n_packets * DOTS_PER_PACKET, np.uint8)
        slots = self._pending_k[take] - k0
        xyz[slots] = self._pending_xyz[take]  # a shot given twice: the later one, as it came
        refl_all[slots] = self._pending_refl[take]
        self._pending_k, self._pending_xyz, self._pending_refl = (
            self._pending_k[~done], self._pending_xyz[~done], self._pending_refl[~done])
        samples = _samples(xyz, refl_all, self.data_type).tobytes()
        size = len(samples) // n_packets
        # every packet's stamp in one call: the sensor head's crystal clock costs tens of
        # microseconds a call, and a call per packet (2,083 a second) was a fifth of a core
        first_shots = (self._next_packet + np.arange(n_packets)) * DOTS_PER_PACKET
        stamps = np.atleast_1d(self.clock.sensor_ns(first_shots / self.point_rate))
        for j in range(n_packets):
            out.extend(self._inject(self._build(int(stamps[j]), samples[j * size:(j + 1) * size]),
                                    self._next_packet))
            self._next_packet += 1
        return out

    def start_at(self, t_vehicle: float) -> None:
        """Start the packet grid at the first packet at or after ``t_vehicle``."""
        self._next_packet = math.ceil(t_vehicle * self.point_rate / DOTS_PER_PACKET - 1e-9)

    def finish(self) -> list[bytes]:
        """Releases packets still held back for reordering."""
        out = [entry[2] for entry in self._held]
        self.log.reordered += sum(1 for entry in self._held if entry[1])
        self.log.held_in_place += sum(1 for entry in self._held if not entry[1])
        self._held.clear()
        self.log.sent += len(out)
        return out

    def _build(self, ts: int, samples: bytes) -> bytes:
        """The datagram stamped ``ts`` (ns, sensor clock: its first shot) around its encoded ``samples``."""
        frame_index = ts // int(round(self.frame_period_s * 1e9))
        if self._frame_index is None or frame_index != self._frame_index:
            if self._frame_index is not None:
                self._frame_cnt = (self._frame_cnt + 1) & 0xFF
            self._frame_index = frame_index
            self._udp_cnt = 0
        else:
            self._udp_cnt = (self._udp_cnt + 1) & 0xFFFF
        self.log.packets += 1
        return encode_datagram(data_type=self.data_type, samples=samples, dot_num=DOTS_PER_PACKET,
                               time_interval=self._time_interval, udp_cnt=self._udp_cnt,
                               frame_cnt=self._frame_cnt, timestamp_ns=ts)

    def _inject(self, datagram: bytes, index: int) -> list[bytes]:
        f = self.faults
        out: list[bytes] = []
        held: bytes | None = None
        u = float(self._rng.random()) if self.faults_enabled else 2.0
        edges = self._edges
        if u < edges[0] or edges[2] <= u < edges[4]:
            self.log.dropped.append(index)
        if u < edges[0]:
            self.log.lost += 1
        elif u < edges[1]:
            self.log.duplicated += 1
            out += [datagram, datagram]
        elif u < edges[2]:
            held = datagram
        elif u < edges[3]:
            self.log.bad_crc += 1
            bad = bytearray(datagram)
            bad[int(self._rng.integers(_CRC_START, len(bad)))] ^= 0x5A
            out.append(bytes(bad))
        elif u < edges[4]:
            self.log.truncated += 1
            out.append(datagram[: int(self._rng.integers(0, len(datagram)))])
        else:
            out.append(datagram)
        # A valid newer datagram went out: every held one has now been overtaken.
        overtaking = (edges[0] <= u < edges[1]) or u >= edges[4]
        out.extend(self._release(overtaking))
        if held is not None:
            self._held.append([f.reorder_depth, False, held])
        self.log.sent += len(out)
        return out

    def _release(self, overtaking: bool) -> list[bytes]:
        """Held datagrams whose delay is over; counts those that were really overtaken."""
        out: list[bytes] = []
        still: list[list[Any]] = []
        for entry in self._held:
            entry[0] -= 1
            entry[1] = entry[1] or overtaking
            if entry[0] <= 0:
                out.append(entry[2])
                if entry[1]:
                    self.log.reordered += 1
                else:
                    self.log.held_in_place += 1
            else:
                still.append(entry)
        self._held = still
        return out


def send(datagrams: Iterable[bytes], sock: socket.socket, address: tuple[str, int]) -> int:
    """Sends each datagram to ``address``; returns how many were sent."""
    n = 0
    for d in datagrams:
        sock.sendto(d, address)
        n += 1
    return n


def frames_to_datagrams(frames: Iterable[LidarFrame], emitter: LivoxEmitter) -> Iterator[bytes]:
    """All datagrams of a sequence of frames, the held-back ones released at the end."""
    for frame in frames:
        yield from emitter.add_frame(frame)
    yield from emitter.finish()
