"""A ground station for tests: a UDP socket that says HEARTBEAT (as QGroundControl does) to an
autopilot's GCS port and keeps every MAVLink message it gets, parsed by pymavlink."""

from __future__ import annotations

import os
import socket
import threading
import time
from collections import Counter
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as M  # type: ignore[import-untyped]  # noqa: E402

GCS_SYSTEM, GCS_COMPONENT = 255, M.MAV_COMP_ID_MISSIONPLANNER  # QGroundControl's ids


class GcsListener:
    """``with GcsListener(("127.0.0.1", port)) as gcs: ... gcs.messages``. Like QGroundControl,
    it asks a camera component (100-105) for its CAMERA_INFORMATION when it first hears its
    HEARTBEAT (``ask_camera``)."""

    def __init__(self, autopilot_gcs_port: tuple[str, int] | None = None, *, bind_port: int = 0,
                 ask_camera: bool = True) -> None:
        self.ask_camera = ask_camera
        self.cameras_asked: set[tuple[int, int]] = set()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", bind_port))
        self.sock.settimeout(0.05)
        self.dest = autopilot_gcs_port
        self._out = M.MAVLink(self, srcSystem=GCS_SYSTEM, srcComponent=GCS_COMPONENT)
        self._in = M.MAVLink(None)
        self._in.robust_parsing = True
        self.messages: list[Any] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @property
    def port(self) -> int:
        return self.sock.getsockname()[1]

    def write(self, buf: bytes) -> None:  # pymavlink's send path
        if self.dest is not None:
            self.sock.sendto(buf, self.dest)

    def _run(self) -> None:
        next_hb = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_hb:
                self._out.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
                next_hb = time.monotonic() + 0.5
            try:
                data, _ = self.sock.recvfrom(65535)
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            msgs = self._in.parse_buffer(data) or []
            with self._lock:
                self.messages.extend(m for m in msgs if m.get_type() != "BAD_DATA")
            for m in msgs:
                src = (m.get_srcSystem(), m.get_srcComponent())
                if (self.ask_camera and self.dest is not None and m.get_type() == "HEARTBEAT"
                        and m.type == M.MAV_TYPE_CAMERA and src not in self.cameras_asked):
                    self.cameras_asked.add(src)
                    self.command_long(src, M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_INFORMATION)

    def command_long(self, target: tuple[int, int], command: int, *params: float) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self._out.command_long_send(target[0], target[1], command, 0, *p)

    def of(self, kind: str, component: int | None = None) -> list[Any]:
        with self._lock:
            return [m for m in self.messages if m.get_type() == kind
                    and (component is None or m.get_srcComponent() == component)]

    def count(self) -> Counter:
        with self._lock:
            return Counter((m.get_srcSystem(), m.get_srcComponent(), m.get_type()) for m in self.messages)

    def wait_for(self, predicate: Any, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.05)
        return predicate()

    def statustexts(self) -> list[tuple[int, int, str]]:
        """(component, severity, text) of every STATUSTEXT, chunks (MAVLink 2 id/chunk_seq) joined."""
        out: list[tuple[int, int, str]] = []
        pending: dict[tuple[int, int], list[str]] = {}
        for m in self.of("STATUSTEXT"):
            text = m.text if isinstance(m.text, str) else m.text.decode("ascii", "replace")
            text = text.split("\0")[0]
            if m.id == 0:
                out.append((m.get_srcComponent(), m.severity, text))
                continue
            key = (m.get_srcComponent(), m.id)
            pending.setdefault(key, []).append(text)
            if len(text) < 50:
                out.append((m.get_srcComponent(), m.severity, "".join(pending.pop(key))))
        return out

    def start(self) -> GcsListener:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.sock.close()

    def __enter__(self) -> GcsListener:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
