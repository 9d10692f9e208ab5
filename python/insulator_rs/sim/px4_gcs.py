"""The simulated PX4's GCS link: a second UDP port, and PX4's MAVLink forwarding between links.

Measured on PX4 v1.16.0 SITL (``tests/test_px4_sitl_gcs.py``): its onboard (offboard/API) link
and its GCS link both forward (``mavlink start ... -f``). What a companion sends on the onboard
link reaches the GCS unchanged (source system/component kept): HEARTBEATs of its components
(camera 100, onboard computer 191), STATUSTEXT with its severity, CAMERA_INFORMATION,
CAMERA_IMAGE_CAPTURED, and commands addressed to the GCS. The other way, a GCS's HEARTBEAT and
its commands addressed to the companion's components (100, 191) reach the onboard link, while a
command addressed to the autopilot itself (component 1) is answered by PX4 and not forwarded.
PX4 streams its own telemetry (HEARTBEAT...) on the GCS link too; a GCS is learnt from its first
datagram (as PX4's UDP links learn their partner).

PX4 forwards through a small buffer drained by the receiving link's loop: of 10 frames of
~230 bytes (CAMERA_IMAGE_CAPTURED) sent back to back 2 reached the GCS, 7 at 2 ms apart, all at
5 ms and more; 10 small STATUSTEXTs back to back all got through. Modelled here as
:data:`FORWARD_BUFFER_BYTES` (two of MAVLink's largest frames) emptied every
:data:`FORWARD_DRAIN_S`; what does not fit is dropped (``forward_dropped``).

This is what :class:`GcsLink` does for :class:`~insulator_rs.sim.px4.SimulatedPx4` (its
``gcs_port`` option). Limitations: the GCS's own commands to the autopilot are not handled
(PX4 answers them; the simulated PX4 serves its one client), no signing on this link.
"""

from __future__ import annotations

import socket
import threading
import time
from typing import Any

from insulator_rs.mavlink.wire import mavlink2

M = mavlink2
MAX_DATAGRAM = 65535
FORWARD_BUFFER_BYTES = 2 * 280  # two MAVLINK_MAX_PACKET_LEN frames
FORWARD_DRAIN_S = 0.004  # s between two drains of the forwarding buffer


def forwarded(msg: Any, system_id: int, component_id: int) -> bool:
    """PX4's forwarding rule: every message except those addressed to the autopilot itself."""
    return not (getattr(msg, "target_system", None) == system_id
                and getattr(msg, "target_component", None) == component_id)


class GcsLink:
    """PX4's GCS link of the simulated PX4: a UDP socket on 127.0.0.1 (``port`` 0: any free one)."""

    def __init__(self, port: int = 0, *, remote: tuple[str, int] | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.peers: list[tuple[str, int]] = [remote] if remote else []
        self._parser = M.MAVLink(None)
        self._parser.robust_parsing = True
        self.forwarded_to_gcs = 0
        self.forwarded_to_onboard = 0
        self.forward_dropped = 0
        self.last_heartbeat: float | None = None  # wall time of a ground station's last HEARTBEAT
        self._buffered = 0
        self._last_drain = time.monotonic()

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()[:2]
        return host, port

    def send(self, data: bytes) -> None:
        """The autopilot's own telemetry (or a forwarded frame) to every GCS."""
        for peer in self.peers:
            try:
                self.sock.sendto(data, peer)
            except OSError:
                pass

    def forward_to_gcs(self, msg: Any) -> None:
        frame = bytes(msg.get_msgbuf())
        now = time.monotonic()
        if now - self._last_drain >= FORWARD_DRAIN_S:
            self._buffered, self._last_drain = 0, now
        if self._buffered + len(frame) > FORWARD_BUFFER_BYTES:
            self.forward_dropped += 1  # as PX4 drops what its forwarding buffer cannot hold
            return
        self._buffered += len(frame)
        self.forwarded_to_gcs += 1
        self.send(frame)

    def receive(self, system_id: int, component_id: int) -> list[bytes]:
        """Datagrams from GCSs: the frames to forward to the onboard link."""
        out: list[bytes] = []
        while True:
            try:
                data, addr = self.sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError, OSError):
                return out
            if addr not in self.peers:
                self.peers.append(addr)
            try:
                messages = self._parser.parse_buffer(data) or []
            except M.MAVError:
                messages = []
            self._parser.buf = bytearray()
            self._parser.buf_index = 0
            self._parser.expected_length = M.HEADER_LEN_V1 + 2
            for msg in messages:
                if msg.get_type() == "HEARTBEAT" and msg.type == M.MAV_TYPE_GCS:
                    self.last_heartbeat = time.monotonic()  # PX4's data link: a GCS is there
                if msg.get_type() != "BAD_DATA" and forwarded(msg, system_id, component_id):
                    self.forwarded_to_onboard += 1
                    out.append(bytes(msg.get_msgbuf()))

    def close(self) -> None:
        self.sock.close()


GCS_SYSTEM_ID = 255  # QGroundControl's system id
HEARTBEAT_PERIOD_S = 1.0  # a ground station's HEARTBEAT rate (QGroundControl's)


class RelayedGroundStation:
    """A ground station whose link runs through the companion computer (its radio or modem on the
    companion, relayed to PX4's GCS link): a HEARTBEAT (MAV_TYPE_GCS) every
    :data:`HEARTBEAT_PERIOD_S` wall s to ``address`` (the simulated PX4's GCS port) from a thread,
    until ``cut()``: the companion died or its link to PX4 went, and the ground station's with it.
    What PX4's GCS connection loss (NAV_DLL_ACT) then sees."""

    def __init__(self, address: tuple[str, int]) -> None:
        self.address = address
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self._mav = M.MAVLink(None, srcSystem=GCS_SYSTEM_ID, srcComponent=M.MAV_COMP_ID_MISSIONPLANNER)
        self._cut = threading.Event()
        self._thread = threading.Thread(target=self._run, name="relayed-gcs", daemon=True)

    def start(self) -> RelayedGroundStation:
        self._thread.start()
        return self

    def cut(self) -> None:
        """No HEARTBEAT from now on (the relay is gone)."""
        self._cut.set()

    def close(self) -> None:
        self.cut()
        self._thread.join(timeout=2.0)
        self.sock.close()

    def _run(self) -> None:
        while not self._cut.is_set():
            frame = self._mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
            try:
                self.sock.sendto(bytes(frame.pack(self._mav)), self.address)
            except OSError:
                return
            self._cut.wait(HEARTBEAT_PERIOD_S)
