"""The simulated PX4's link: a UDP socket on 127.0.0.1, MAVLink 2 framing and signing,
injected link faults (loss, delay, a lost link) in both directions, and the peers telemetry
goes to (``remote``, and every address a valid message came from).

A mixin of :class:`insulator_rs.sim.px4.autopilot.SimulatedPx4`, which owns the state
(one lock, one thread); this module holds the transport half of its methods.
"""

from __future__ import annotations

import heapq
import random
import socket
from dataclasses import dataclass, field
from typing import Any
import math
import time

from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.sim.px4_gcs import GcsLink, forwarded

M = mavlink2
# Wall-clock period of the simulation loop (s): physics, inbound, telemetry.
LOOP_PERIOD_S = 0.005
MAX_DATAGRAM = 65535
# Most vehicle time one loop iteration may simulate (s).
MAX_STEP_VEHICLE_S = 0.05
UNSIGNED_ALLOWED = frozenset({M.MAVLINK_MSG_ID_RADIO_STATUS})


@dataclass
class LinkFaults:
    """Injected link faults, applied to every datagram in both directions."""

    drop_probability: float = 0.0  # each datagram is lost with this probability
    delay_s: float = 0.0  # extra one-way latency, wall seconds
    link_lost: bool = False  # nothing gets through


@dataclass
class SimStats:
    """Counters the tests and the CLI read (updated by the sim thread)."""

    received: int = 0
    dropped: int = 0
    rejected_signature: int = 0
    bad_data: int = 0
    setpoints: int = 0
    timesync_answers: int = 0  # answers to the simulated PX4's own TIMESYNC requests
    commands: dict[str, int] = field(default_factory=dict)
    last_ack: dict[int, int] = field(default_factory=dict)


class Px4Transport:
    """The link half of the simulated PX4 (see the module docstring)."""

    faults: LinkFaults
    stats: SimStats
    _sock: socket.socket
    _rng: random.Random
    _peers: list[tuple[str, int]]
    _mav: Any
    _delayed: list[tuple[float, int, str, bytes, tuple[str, int] | None]]
    _sequence: int
    gcs: GcsLink | None  # PX4's GCS link and its forwarding (sim/px4_gcs.py), when a port is given
    system_id: int
    component_id: int

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the vehicle listens on."""
        host, port = self._sock.getsockname()[:2]
        return host, port

    def set_link_lost(self, lost: bool = True) -> None:
        with self._lock:
            self.faults.link_lost = lost

    def set_packet_loss(self, probability: float) -> None:
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability!r}")
        with self._lock:
            self.faults.drop_probability = probability

    def set_delay(self, seconds: float) -> None:
        if not (math.isfinite(seconds) and seconds >= 0.0):
            raise ValueError(f"seconds must be finite and >= 0, got {seconds!r}")
        with self._lock:
            self.faults.delay_s = seconds

    def _receive(self, now: float) -> None:
        while True:
            try:
                data, addr = self._sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            if self._lost():
                continue
            if self.faults.delay_s > 0.0:
                self._queue(now + self.faults.delay_s, "in", data, addr)
            else:
                self._handle_datagram(data, addr)

    def _lost(self) -> bool:
        if self.faults.link_lost or (self.faults.drop_probability > 0.0
                                     and self._rng.random() < self.faults.drop_probability):
            self.stats.dropped += 1
            return True
        return False

    def _queue(self, due: float, kind: str, data: bytes, addr: tuple[str, int] | None) -> None:
        self._sequence += 1
        heapq.heappush(self._delayed, (due, self._sequence, kind, data, addr))

    def _deliver_due(self, now: float) -> None:
        while self._delayed and self._delayed[0][0] <= now:
            _due, _seq, kind, data, addr = heapq.heappop(self._delayed)
            if kind == "in" and addr is not None:
                self._handle_datagram(data, addr)
            else:
                self._sendto_peers(data)

    def _handle_datagram(self, data: bytes, addr: tuple[str, int]) -> None:
        try:
            messages = self._mav.parse_buffer(data) or []
        except M.MAVError:
            self.stats.bad_data += 1
            messages = []
        if self._mav.buf_len() > 0:
            # A UDP datagram carries whole frames: a leftover is a truncated or
            # garbage frame, and must not swallow the start of the next datagram.
            self.stats.bad_data += 1
            self._mav.buf = bytearray()
            self._mav.buf_index = 0
            self._mav.expected_length = M.HEADER_LEN_V1 + 2
        for msg in messages:
            if msg.get_type() == "BAD_DATA":
                if "signature" in str(getattr(msg, "reason", "")).lower():
                    self.stats.rejected_signature += 1
                else:
                    self.stats.bad_data += 1
                continue
            self.stats.received += 1
            if addr not in self._peers:
                self._peers.append(addr)
            if self.gcs is not None and forwarded(msg, self.system_id, self.component_id):
                self.gcs.forward_to_gcs(msg)  # as PX4 forwards the companion's messages
            self._handle_message(msg)

    def _send(self, msg: Any) -> None:
        data = msg.pack(self._mav)
        now = time.monotonic()
        if self._lost():
            return
        if self.faults.delay_s > 0.0:
            self._queue(now + self.faults.delay_s, "out", data, None)
        else:
            self._sendto_peers(data)

    def _sendto_peers(self, data: bytes, *, gcs: bool = True) -> None:
        if gcs and self.gcs is not None:
            self.gcs.send(data)
        for peer in self._peers:
            try:
                self._sock.sendto(data, peer)
            except OSError:
                pass  # a peer that went away: UDP has nobody to tell

    # provided by SimulatedPx4
    _lock: Any

    def _handle_message(self, msg: Any) -> None:
        raise NotImplementedError
