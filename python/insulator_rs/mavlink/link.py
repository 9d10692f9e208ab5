"""The link to one autopilot: the connection, what is accepted from it, what is sent to it.

Trust rules (a hostile or merely busy network on the same port must not steer us):

* the autopilot is the sender of the first HEARTBEAT of an autopilot (not
  MAV_AUTOPILOT_INVALID, component MAV_COMP_ID_AUTOPILOT1, the expected system id
  if one was given); from then on only messages of that (system, component) are
  accepted, and on UDP only datagrams from the address that heartbeat came from
  (``udpout``: the address we were told to send to, from the start);
* on UDP each datagram is parsed on its own: the parser is reset after it, so a
  truncated or garbage frame cannot swallow the start of the next datagram;
* everything sent goes to the autopilot's address only (pymavlink's ``udpin`` would
  send to every address that ever wrote to the port);
* nothing received raises: what is dropped is counted in ``LinkStats`` by reason.

Serial and TCP links are byte streams (no datagrams): the source filter applies,
the per-datagram reset does not.
"""

from __future__ import annotations

import re
import select
import socket
import threading
from dataclasses import dataclass, fields
from typing import Any

from insulator_rs.mavlink.wire import mavlink2, mavutil

M = mavlink2
AUTOPILOT_COMPONENT = M.MAV_COMP_ID_AUTOPILOT1
MAX_DATAGRAM = 65535
# Datagrams handled per receive call before the caller gets control back (failsafe
# checks, ACK waits): bounds the time one call can take under a flood.
MAX_DATAGRAMS_PER_POLL = 256
_SERIAL = re.compile(r"^(?P<device>(/|COM|com)[^:]*):(?P<baud>\d+)$")


@dataclass
class LinkStats:
    """What the link received and what it dropped, by reason (counts since connecting)."""

    datagrams: int = 0  # UDP datagrams read (stream links: 0)
    accepted: int = 0  # messages from the autopilot, handed on
    foreign_address: int = 0  # datagrams from an address other than the autopilot's
    foreign_source: int = 0  # messages from another system or component
    before_heartbeat: int = 0  # messages before the autopilot's first HEARTBEAT
    unknown_message: int = 0  # valid frames of a message id the dialect lacks (PX4 sends a few)
    bad_data: int = 0  # bytes that are no valid MAVLink frame (bad CRC, garbage, unknown id)
    truncated: int = 0  # datagrams ending in an incomplete frame
    bad_signature: int = 0  # frames with a missing or wrong MAVLink 2 signature (signing on)

    @property
    def dropped(self) -> int:
        return (self.foreign_address + self.foreign_source + self.before_heartbeat + self.unknown_message
                + self.bad_data + self.truncated + self.bad_signature)

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)} | {"dropped": self.dropped}

    def describe(self) -> str:
        """One line for a log, e.g. '1779 datagrams, 1539 messages accepted, 240 dropped
        (before_heartbeat 228, unknown_message 12)'."""
        reasons = ", ".join(f"{name} {n}" for name, n in self.as_dict().items()
                            if n and name not in ("datagrams", "accepted", "dropped"))
        return (f"{self.datagrams} datagrams, {self.accepted} messages accepted, {self.dropped} dropped"
                + (f" ({reasons})" if reasons else ""))


def open_connection(connection: str, *, source_system: int, source_component: int) -> Any:
    """A pymavlink connection for ``udpin:``/``udpout:``/``udp:``/``tcp:`` strings or ``DEVICE:BAUD``."""
    if not isinstance(connection, str) or not connection:
        raise TypeError(f"connection must be a non-empty string, got {connection!r}")
    serial = _SERIAL.match(connection)
    if serial:
        return mavutil.mavlink_connection(serial["device"], baud=int(serial["baud"]),
                                          source_system=source_system, source_component=source_component)
    if not connection.startswith(("udpin:", "udpout:", "udp:", "tcp:", "tcpin:")):
        raise ValueError("connection must be udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT "
                         f"or DEVICE:BAUD, got {connection!r}")
    return mavutil.mavlink_connection(connection, source_system=source_system,
                                      source_component=source_component)


class AutopilotLink:
    """One MAVLink connection narrowed to one autopilot (see the module docstring).

    ``receive(timeout)`` returns the accepted messages of one poll; ``send(name, *args)``
    calls pymavlink's ``<name>_send`` under the send lock. ``autopilot`` is the
    (system, component) once its HEARTBEAT came, ``peer`` its address (UDP).
    """

    def __init__(self, connection: str, *, source_system: int, source_component: int,
                 target_system: int | None = None) -> None:
        if target_system is not None and not (isinstance(target_system, int) and 1 <= target_system <= 255):
            raise ValueError(f"target_system must be a MAVLink system id in [1, 255], got {target_system!r}")
        self.target_system = target_system
        self.conn = open_connection(connection, source_system=source_system, source_component=source_component)
        self.mav = self.conn.mav
        self.mav.robust_parsing = True
        self.stats = LinkStats()
        self.autopilot: tuple[int, int] | None = None
        self.peer: tuple[str, int] | None = None
        self._send_lock = threading.Lock()
        self._socket: socket.socket | None = None
        # Components of ours besides the client (the MAVLink camera, mavlink/gcs.py): they get the
        # messages of other systems the autopilot forwards to us (a GCS's commands), from its address.
        self._listeners: list[Any] = []
        if isinstance(self.conn, mavutil.mavudp):
            self._socket = self.conn.port
            if not self.conn.udp_server:  # udpout: the address is given, and the only one trusted
                host, port = self.conn.destination_addr
                self.peer = (socket.gethostbyname(host), int(port))
            self.mav.file = _DatagramWriter(self)  # pymavlink's send path ends in our write()

    @property
    def datagrams(self) -> bool:
        """True on UDP (per-datagram parsing and the address check apply)."""
        return self._socket is not None

    # -- sending ---------------------------------------------------------------------

    def send(self, name: str, *args: Any) -> None:
        """``mav.<name>_send(*args)``; a link that cannot send yet (udpin before the
        autopilot spoke, a serial device gone) drops the message: MAVLink is lossy."""
        with self._send_lock:
            try:
                getattr(self.mav, f"{name}_send")(*args)
            except OSError:
                pass

    def send_raw(self, buf: bytes) -> None:
        """One packed MAVLink frame of another of our components (its own system/component ids
        and sequence), to the autopilot's address; dropped like :meth:`send`'s."""
        with self._send_lock:
            try:
                self._write(buf)
            except OSError:
                pass

    def add_listener(self, listener: Any) -> None:
        """``listener(msg)`` gets each message from another system or component that came over
        the autopilot's link (what the autopilot forwards, e.g. a GCS's commands to our camera)."""
        self._listeners.append(listener)

    def _write(self, buf: bytes) -> None:
        if self._socket is not None and self.peer is not None:
            self._socket.sendto(buf, self.peer)

    # -- receiving -------------------------------------------------------------------

    def receive(self, timeout: float) -> list[Any]:
        """Wait up to ``timeout`` s for input; return the messages accepted from the autopilot."""
        if self._socket is None:
            return self._receive_stream(timeout)
        try:
            readable, _, _ = select.select([self._socket], [], [], timeout)
        except (OSError, ValueError):  # closed under us
            return []
        accepted: list[Any] = []
        for _ in range(MAX_DATAGRAMS_PER_POLL if readable else 0):
            try:
                data, addr = self._socket.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # ICMP port unreachable of an earlier send, a closed socket
                break
            accepted.extend(self.handle_datagram(data, addr))
        return accepted

    def handle_datagram(self, data: bytes, addr: tuple[str, int]) -> list[Any]:
        """Parse one UDP datagram from ``addr``; the autopilot's messages in it (never raises)."""
        self.stats.datagrams += 1
        if self.peer is not None and tuple(addr[:2]) != self.peer:
            self.stats.foreign_address += 1
            return []
        try:
            messages = self.mav.parse_buffer(data) or []
        # Bytes from the network are hostile input: pymavlink raises MAVError, struct.error,
        # IndexError... on frames it cannot decode. None of them may stop the receiver.
        except Exception:  # noqa: BLE001
            self.stats.bad_data += 1
            messages = []
        if self.mav.buf_len() > 0:
            self.stats.truncated += 1
        self._reset_parser()
        return [msg for msg in messages if self._accept(msg, addr)]

    def _receive_stream(self, timeout: float) -> list[Any]:
        try:
            msg = self.conn.recv_match(blocking=True, timeout=timeout)
        except Exception:  # noqa: BLE001  (a stream's bytes are as hostile as a datagram's)
            self.stats.bad_data += 1
            return []
        if msg is None or not self._accept(msg, None):
            return []
        return [msg]

    def _reset_parser(self) -> None:
        mav = self.mav
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = M.HEADER_LEN_V1 + 2
        mav.have_prefix_error = False

    def _accept(self, msg: Any, addr: tuple[str, int] | None) -> bool:
        if msg.get_type() == "BAD_DATA":
            if "signature" in str(getattr(msg, "reason", "")).lower():
                self.stats.bad_signature += 1
            else:
                self.stats.bad_data += 1
            return False
        if isinstance(msg, M.MAVLink_unknown):  # pymavlink keeps no header for these: source unknown
            self.stats.unknown_message += 1
            return False
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.autopilot is None:
            if not self._is_autopilot_heartbeat(msg):
                self.stats.before_heartbeat += 1
                return False
            self.autopilot = source
            if self.datagrams and self.peer is None and addr is not None:
                self.peer = (str(addr[0]), int(addr[1]))
        elif source != self.autopilot:
            self.stats.foreign_source += 1
            for listener in self._listeners:
                listener(msg)
            return False
        self.stats.accepted += 1
        return True

    def _is_autopilot_heartbeat(self, msg: Any) -> bool:
        return (msg.get_type() == "HEARTBEAT" and msg.autopilot != M.MAV_AUTOPILOT_INVALID
                and msg.get_srcComponent() == AUTOPILOT_COMPONENT
                and (self.target_system is None or msg.get_srcSystem() == self.target_system))

    def close(self) -> None:
        try:
            self.conn.close()
        except (OSError, AttributeError):
            pass


class _DatagramWriter:
    """What pymavlink's ``MAVLink.send`` writes to (``mav.file``): the link's own sendto."""

    def __init__(self, link: AutopilotLink) -> None:
        self._link = link

    def write(self, buf: bytes) -> None:
        self._link._write(buf)
