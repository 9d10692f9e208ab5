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


CAPTURE_STATUS_PERIOD_S = 2.0  # how often a camera's image count is asked (recover_images)
RCVBUF_BYTES = 4 << 20  # a GCS drains its socket in its own process; this one shares a GIL


class GcsListener:
    """``with GcsListener(("127.0.0.1", port)) as gcs: ... gcs.messages``. Like QGroundControl,
    it asks a camera component (100-105) for its CAMERA_INFORMATION when it first hears its
    HEARTBEAT (``ask_camera``). With ``recover_images`` it also keeps each camera's photo list
    whole as the camera protocol provides: it asks for CAMERA_CAPTURE_STATUS every
    :data:`CAPTURE_STATUS_PERIOD_S`, and asks again (MAV_CMD_REQUEST_MESSAGE, param2 = the index)
    for every CAMERA_IMAGE_CAPTURED below the image count that has not arrived
    (``images_requested``)."""

    def __init__(self, autopilot_gcs_port: tuple[str, int] | None = None, *, bind_port: int = 0,
                 ask_camera: bool = True, recover_images: bool = False) -> None:
        self.ask_camera = ask_camera
        self.recover_images = recover_images
        self.cameras_asked: set[tuple[int, int]] = set()
        self.images_requested: list[tuple[tuple[int, int], int]] = []
        self.drops_at_close: int | None = None
        self._images: dict[tuple[int, int], set[int]] = {}
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
        except OSError:
            pass
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

    def socket_drops(self) -> int | None:
        """Datagrams the kernel dropped at this socket (its receive buffer was full: the listener
        fell behind), from /proc/net/udp; None where that cannot be read."""
        try:
            port = self.port
            for line in open("/proc/net/udp").read().splitlines()[1:]:
                f = line.split()
                if int(f[1].split(":")[1], 16) == port:
                    return int(f[-1])
        except (OSError, ValueError, IndexError):
            return None
        return None

    def _ask_missing_images(self, camera: tuple[int, int], count: int, *, again: bool) -> None:
        """Ask for each image below ``count`` not received: once, and ``again`` (at a capture
        status) up to 3 times, since the answer can be lost too."""
        have = self._images.setdefault(camera, set())
        for index in range(count):
            tries = self.images_requested.count((camera, index))
            if index not in have and (tries == 0 or (again and tries < 3)):
                self.images_requested.append((camera, index))
                self.command_long(camera, M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, index)

    def _run(self) -> None:
        next_hb = next_status = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_hb:
                self._out.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
                next_hb = time.monotonic() + 0.5
            if self.recover_images and self.dest is not None and time.monotonic() >= next_status:
                next_status = time.monotonic() + CAPTURE_STATUS_PERIOD_S
                for camera in list(self.cameras_asked):
                    self.command_long(camera, M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS)
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
                if self.recover_images and self.dest is not None:
                    if m.get_type() == "CAMERA_IMAGE_CAPTURED":
                        self._images.setdefault(src, set()).add(int(m.image_index))
                        self._ask_missing_images(src, int(m.image_index), again=False)  # the ones before it
                    elif m.get_type() == "CAMERA_CAPTURE_STATUS":
                        self._ask_missing_images(src, int(m.image_count), again=True)

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
        self.drops_at_close = self.socket_drops()  # the socket leaves /proc/net/udp when closed
        self.sock.close()

    def __enter__(self) -> GcsListener:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
