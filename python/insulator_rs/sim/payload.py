"""The simulated payload: a MAVLink gimbal device and zoom camera on UDP, behaving as a real one.

Two MAVLink components of one system, each with its own HEARTBEAT: the gimbal device
(``MAV_COMP_ID_GIMBAL``, ``MAV_TYPE_GIMBAL``) and the camera (``MAV_COMP_ID_CAMERA``,
``MAV_TYPE_CAMERA``). What it does, as a Siyi- or Gremsy-class payload does:

* **gimbal** (Gimbal Protocol v2, device side): takes ``GIMBAL_DEVICE_SET_ATTITUDE`` (from PX4's
  gimbal manager with ``MNT_MODE_OUT`` = 2, or from the companion directly), slews towards it at
  ``slew_rate`` and stops at its mechanical limits, stabilises roll and pitch (the camera stays
  level whatever the airframe's tilt), reports ``GIMBAL_DEVICE_ATTITUDE_STATUS`` (yaw in the vehicle
  frame) and, when asked, ``GIMBAL_DEVICE_INFORMATION`` with the range it advertises;
* **camera** (Camera Protocol v2): ``CAMERA_INFORMATION``, ``CAMERA_SETTINGS`` (its ``zoomLevel``:
  the zoom range's percentage now), ``CAMERA_CAPTURE_STATUS`` and a lost ``CAMERA_IMAGE_CAPTURED``
  again when asked by index (``MAV_CMD_REQUEST_MESSAGE``); ``MAV_CMD_SET_CAMERA_ZOOM`` to a range
  percentage or a focal length, travelling there in ``zoom_time_s`` for the whole range;
  ``MAV_CMD_IMAGE_START_CAPTURE`` taken ``capture_latency_s`` later, the image rendered at the
  gimbal's true attitude and zoom from the airframe's true pose at that instant, then
  ``CAMERA_IMAGE_CAPTURED`` with that instant, the camera's position and attitude and the
  ``file_url`` (a seeded fraction of them lost on the way);
* **MAVLink FTP server** for the images (OpenFileRO, ReadFile, BurstReadFile, ListDirectory,
  TerminateSession, ResetSessions). pymavlink ships the client side only (``mavftp``), and no
  Python library implements the server; PX4 and ArduPilot have theirs in C++ inside the
  autopilot. So the server side of the sub-protocol (https://mavlink.io/en/services/ftp.html) is
  written here, over pymavlink's message definitions.

Faults (:class:`PayloadFaults`): a capture never taken (``capture_silent``), lost
CAMERA_IMAGE_CAPTURED (``lost_capture_rate``, seeded), a zoom refused, a mechanical stop short of
the advertised range, downloads that stop halfway, and :meth:`SimulatedPayload.vanish` (the
payload falls silent mid-flight).
"""

from __future__ import annotations

import math
import select
import socket
import struct
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from collections import deque
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import cv2
import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs.flight.gimbal import stabilised_T_b_c
from insulator_rs.geodesy import GeoPoint, enu_to_gps
from insulator_rs.inspection_camera import InspectionCamera
from insulator_rs.mavlink.frames import camera_quaternion_ned
from insulator_rs.mavlink.gcs import name32
from insulator_rs.mavlink.payload import (
    CAMERA_COMPONENT,
    FTP_SCHEME,
    GIMBAL_COMPONENT,
    gimbal_aim_of_quaternion,
    gimbal_device_quaternion,
    zoom_percent,
)
from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.poses import yaw_of
from insulator_rs.ports.vehicle import wrap_angle

M = mavlink2
# the FTP sub-protocol's header (seq, session, opcode, size, req_opcode, burst_complete, padding,
# offset) and its data bytes per message
FTP_HEADER = struct.Struct("<HBBBBBBI")
FTP_DATA = 239
OP_TERMINATE, OP_RESET, OP_LIST, OP_OPEN_RO, OP_READ, OP_BURST = 1, 2, 3, 4, 5, 15
OP_ACK, OP_NACK = 128, 129
ERR_EOF, ERR_UNKNOWN_COMMAND, ERR_NOT_FOUND, ERR_INVALID_SESSION, ERR_NO_SESSIONS = 6, 7, 10, 4, 5
#: Data messages of one burst before the server waits for the client's next BurstReadFile.
BURST_PACKETS = 64
#: s of the server loop's one wait: the gimbal and the zoom move in steps this long.
TICK_S = 0.01
IMAGE_DIR = "/DCIM"
JPEG_QUALITY = 92


@dataclass(frozen=True)
class PayloadDynamics:
    """How the payload moves: ``slew_rate`` (rad/s per axis), ``zoom_time_s`` (s over the whole
    range), ``capture_latency_s`` (s from the command to the exposure), the HEARTBEAT and the
    gimbal status periods (s)."""

    slew_rate: float = math.radians(90.0)
    zoom_time_s: float = 2.0
    capture_latency_s: float = 0.3
    heartbeat_period_s: float = 1.0
    status_period_s: float = 0.05


@dataclass(frozen=True)
class PayloadFaults:
    """The payload's faults: ``lost_capture_rate`` (fraction of CAMERA_IMAGE_CAPTURED lost on the
    way, seeded; sent again when asked), ``capture_silent`` (captures acknowledged, never taken),
    ``refuse_zoom`` (MAV_CMD_SET_CAMERA_ZOOM DENIED), ``pitch_stop`` (rad: a mechanical stop the
    gimbal halts at, above the advertised lower pitch limit), ``downloads_cut`` (the first this
    many downloads stop halfway through the file: MAVLink FTP answers no more, HTTP closes)."""

    lost_capture_rate: float = 0.0
    capture_silent: bool = False
    refuse_zoom: bool = False
    pitch_stop: float | None = None
    downloads_cut: int = 0


def scene_photo_renderer(mesh: Any, *, seed: int = 0) -> Callable[[np.ndarray, CameraModel, float], np.ndarray]:
    """A renderer for the payload: the scene ``mesh`` seen from the camera pose ``T_w_c`` through
    ``camera`` at vehicle time ``t``, BGR uint8 (the simulator's ray caster, as its photos)."""
    from insulator_rs.sim.camera_render import Camera

    count = [0]

    def render(T_w_c: np.ndarray, camera: CameraModel, t: float) -> np.ndarray:
        count[0] += 1
        frame = Camera(camera, np.eye(4)).render(mesh, T_w_c, seed=seed + 300_000 + count[0], time=t)
        return np.ascontiguousarray(frame.rgb[:, :, ::-1])

    return render


@dataclass
class _Session:
    path: str
    cut_at: int | None  # bytes served before the download stops answering (a fault), None: all


@dataclass
class _Capture:
    due: float  # vehicle time of the exposure
    index: int


@dataclass
class _Image:
    index: int
    message: list[Any] = field(default_factory=list)  # CAMERA_IMAGE_CAPTURED's arguments


class SimulatedPayload:
    """The gimbal and camera on a UDP port of their own (see the module docstring).

    ``inspection``: the rig's inspection camera (zoom range, per-zoom intrinsics, gimbal range and
    mount). ``pose(t)``: the airframe's true T_w_b at vehicle time ``t``; ``clock()``: vehicle time
    now. ``render(T_w_c, camera, t)``: the image (BGR) the camera sees (:func:`scene_photo_renderer`).
    ``origin``: W's origin in WGS-84 (the capture message's position). ``peer``: where to send
    (None: whoever sent to us first, as a payload on a MAVLink router). ``port``: ours (0: any).
    ``http``: serve the images over HTTP too, and name them by their ``http://`` URL in
    CAMERA_IMAGE_CAPTURED (as cameras with a web server do) instead of MAVLink FTP's.
    ``received``: the newest messages it took (their types and fields, for protocol checks)."""

    def __init__(self, inspection: InspectionCamera, *, pose: Callable[[float], np.ndarray],
                 clock: Callable[[], float], render: Callable[[np.ndarray, CameraModel, float], np.ndarray],
                 origin: GeoPoint, system_id: int = 1, host: str = "127.0.0.1", port: int = 0,
                 peer: tuple[str, int] | None = None, dynamics: PayloadDynamics | None = None,
                 faults: PayloadFaults | None = None, seed: int = 0, http: bool = False) -> None:
        self.inspection = inspection
        self.pose = pose
        self.clock = clock
        self.render = render
        self.origin = origin
        self.system_id = system_id
        self.dynamics = dynamics or PayloadDynamics()
        self.faults = faults or PayloadFaults()
        self.rng = np.random.default_rng(seed)
        self.peer = peer
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((host, port))
        self._sock.setblocking(False)
        self._send_lock = threading.Lock()

        class _Writer:
            def write(_self, buf: bytes) -> None:  # noqa: N805
                self._write(buf)

        self._gimbal_mav = M.MAVLink(_Writer(), srcSystem=system_id, srcComponent=GIMBAL_COMPONENT)
        self._camera_mav = M.MAVLink(_Writer(), srcSystem=system_id, srcComponent=CAMERA_COMPONENT)
        self._parser = M.MAVLink(None)
        self._parser.robust_parsing = True
        self.pitch_range = self._pitch_range(self.faults)
        self.pitch = 0.0  # rad: the gimbal's true aim (ours: yaw counter-clockwise from the heading)
        self.yaw = 0.0
        self._target = (0.0, 0.0)
        self.focal_px = inspection.focal_px[0]  # the lens's true focal length now
        self._focal_target = self.focal_px
        self._captures: list[_Capture] = []
        self._last_sequence = 0  # MAV_CMD_IMAGE_START_CAPTURE's param4 of the newest capture taken
        self.images: list[_Image] = []
        self.files: dict[str, bytes] = {}
        self._sessions: dict[int, _Session] = {}
        self._downloads_cut = self.faults.downloads_cut
        self.counts: dict[str, int] = {"captures": 0, "captured_lost": 0, "ftp_requests": 0, "set_attitude": 0}
        self._gone = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()  # the state the loop and the render thread share
        self._renderer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="payload-render")
        self._thread = threading.Thread(target=self._run, name="sim-payload", daemon=True)
        self.received: deque[Any] = deque(maxlen=2000)
        self._http = _FileServer(self.files, host, self._cut_download) if http else None

    @property
    def address(self) -> tuple[str, int]:
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    @property
    def url(self) -> str:
        """The adapter's connection string to this payload (``udpout:HOST:PORT``)."""
        host, port = self.address
        return f"udpout:{host}:{port}"

    def start(self) -> SimulatedPayload:
        self._thread.start()
        if self._http is not None:
            self._http.start()
        return self

    def inject(self, faults: PayloadFaults) -> None:
        """The payload's faults from now on (a fault that begins mid-flight): ``downloads_cut``
        counts from now, a ``pitch_stop`` holds the gimbal's next aims."""
        with self._lock:
            self.faults = faults
            self.pitch_range = self._pitch_range(faults)
            self._downloads_cut = faults.downloads_cut

    def _pitch_range(self, faults: PayloadFaults) -> tuple[float, float]:
        """The pitch the gimbal can reach (rad): the advertised range, its lower end raised to a
        mechanical stop's."""
        lo, hi = self.inspection.gimbal.pitch
        return (lo if faults.pitch_stop is None else max(lo, faults.pitch_stop), hi)

    def vanish(self) -> None:
        """The payload falls silent (a cable shaken loose, its power gone): nothing more is sent
        or answered."""
        self._gone.set()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self._renderer.shutdown(wait=True, cancel_futures=True)
        if self._http is not None:
            self._http.close()
        self._sock.close()

    # -- sending -------------------------------------------------------------------------------
    def _write(self, buf: bytes) -> None:
        if self.peer is None or self._gone.is_set():
            return
        try:
            self._sock.sendto(bytes(buf), self.peer)
        except OSError:
            pass

    def _emit(self, mav: Any, name: str, *args: Any) -> None:
        with self._send_lock:
            getattr(mav, f"{name}_send")(*args)

    def _boot_ms(self) -> int:
        return int(self.clock() * 1000) & 0xFFFFFFFF

    # -- the loop ------------------------------------------------------------------------------
    def _run(self) -> None:
        last = time.monotonic()
        next_beat = next_status = last
        while not self._stop.is_set():
            try:
                readable, _, _ = select.select([self._sock], [], [], TICK_S)
            except (OSError, ValueError):
                return
            if readable:
                self._receive()
            now = time.monotonic()
            self._move(now - last)
            last = now
            if self._gone.is_set():
                continue
            if now >= next_beat:
                next_beat = now + self.dynamics.heartbeat_period_s
                self._emit(self._gimbal_mav, "heartbeat", M.MAV_TYPE_GIMBAL, M.MAV_AUTOPILOT_INVALID, 0, 0,
                           M.MAV_STATE_ACTIVE)
                self._emit(self._camera_mav, "heartbeat", M.MAV_TYPE_CAMERA, M.MAV_AUTOPILOT_INVALID, 0, 0,
                           M.MAV_STATE_ACTIVE)
            if now >= next_status:
                next_status = now + self.dynamics.status_period_s
                self._gimbal_status()
            self._take_due()

    def _receive(self) -> None:
        for _ in range(256):  # datagrams per wake-up: the gimbal moves on under a flood
            try:
                data, addr = self._sock.recvfrom(65535)
            except OSError:  # nothing more to read (non-blocking), or closed
                return
            if self._gone.is_set():
                continue
            if self.peer is None:
                self.peer = (str(addr[0]), int(addr[1]))
            try:
                messages = self._parser.parse_buffer(data) or []
            except Exception:  # noqa: BLE001  (hostile bytes are dropped, as the link drops them)
                messages = []
            self._parser.buf = bytearray()
            self._parser.buf_index = 0
            for msg in messages:
                self._handle(msg)

    def _move(self, dt: float) -> None:
        """The gimbal and the zoom ``dt`` s further towards their targets."""
        step = self.dynamics.slew_rate * dt
        with self._lock:
            self.pitch += float(np.clip(self._target[0] - self.pitch, -step, step))
            self.yaw += float(np.clip(wrap_angle(self._target[1] - self.yaw), -step, step))
            lo, hi = self.inspection.focal_px
            zoom_step = (hi - lo) * dt / self.dynamics.zoom_time_s
            self.focal_px += float(np.clip(self._focal_target - self.focal_px, -zoom_step, zoom_step))

    # -- messages ----------------------------------------------------------------------------
    def _handle(self, msg: Any) -> None:
        self.received.append(msg)
        kind = msg.get_type()
        target_system = getattr(msg, "target_system", None)
        if target_system not in (None, 0, self.system_id):
            return
        component = getattr(msg, "target_component", None)
        if kind == "GIMBAL_DEVICE_SET_ATTITUDE" and component in (0, GIMBAL_COMPONENT):
            self._set_attitude(msg)
        elif kind == "COMMAND_LONG" and component in (CAMERA_COMPONENT, GIMBAL_COMPONENT):
            self._command(msg)
        elif kind == "FILE_TRANSFER_PROTOCOL" and component == CAMERA_COMPONENT:
            self.counts["ftp_requests"] += 1
            self._ftp(msg)

    def _set_attitude(self, msg: Any) -> None:
        if not all(math.isfinite(v) for v in msg.q):
            return  # rates only: this gimbal is aimed by angle
        self.counts["set_attitude"] += 1
        pitch, yaw = gimbal_aim_of_quaternion(msg.q)
        # the yaw's frame: the earth's when the flags say so, or (neither frame flag set, as older
        # managers send) when the yaw is locked; the vehicle's otherwise
        earth = bool(msg.flags & M.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME) or (
            not msg.flags & M.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME and bool(msg.flags & M.GIMBAL_DEVICE_FLAGS_YAW_LOCK))
        if earth:
            yaw = wrap_angle(yaw - yaw_of(self.pose(self.clock())) + math.pi / 2)  # heading out (NED yaw -> ours)
        g = self.inspection.gimbal
        with self._lock:
            self._target = (min(max(pitch, self.pitch_range[0]), self.pitch_range[1]),
                            min(max(yaw, g.yaw[0]), g.yaw[1]))

    def _gimbal_status(self) -> None:
        flags = (M.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | M.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
                 | M.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME)
        with self._lock:
            q = gimbal_device_quaternion(self.pitch, self.yaw)
        self._emit(self._gimbal_mav, "gimbal_device_attitude_status", 0, 0, self._boot_ms(), flags, q,
                   math.nan, math.nan, math.nan, 0, math.nan, math.nan, 0)

    def _ack(self, msg: Any, result: int) -> None:
        mav = self._gimbal_mav if msg.target_component == GIMBAL_COMPONENT else self._camera_mav
        self._emit(mav, "command_ack", msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def _command(self, msg: Any) -> None:
        if msg.command == M.MAV_CMD_REQUEST_MESSAGE:
            self._ack(msg, self._send_requested(int(msg.param1), msg.target_component, msg.param2))
        elif msg.command == M.MAV_CMD_SET_CAMERA_ZOOM and msg.target_component == CAMERA_COMPONENT:
            self._ack(msg, self._zoom(int(msg.param1), float(msg.param2)))
        elif msg.command == M.MAV_CMD_IMAGE_START_CAPTURE and msg.target_component == CAMERA_COMPONENT:
            self._ack(msg, M.MAV_RESULT_ACCEPTED)
            # param4: the capture's sequence number; the same one again is a retransmission (its
            # first COMMAND_ACK lost), not a second shot
            sequence = int(msg.param4) if math.isfinite(msg.param4) else 0
            if not self.faults.capture_silent and (sequence == 0 or sequence != self._last_sequence):
                self._last_sequence = sequence
                with self._lock:
                    index = len(self.images) + len(self._captures)
                    self._captures.append(_Capture(self.clock() + self.dynamics.capture_latency_s, index))
        else:
            self._ack(msg, M.MAV_RESULT_UNSUPPORTED)

    def _send_requested(self, message_id: int, component: int, index: float) -> int:
        """Sends the message MAV_CMD_REQUEST_MESSAGE asks for; its MAV_RESULT."""
        if component == GIMBAL_COMPONENT:
            if message_id != M.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION:
                return int(M.MAV_RESULT_UNSUPPORTED)
            g = self.inspection.gimbal
            caps = (M.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS | M.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_LOCK
                    | M.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_LOCK | M.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS
                    | M.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_FOLLOW)
            # the advertised range (a mechanical stop is a fault it does not know of); MAVLink's yaw
            # is clockwise: our counter-clockwise range negated
            self._emit(self._gimbal_mav, "gimbal_device_information", self._boot_ms(), b"insulator_rs",
                       b"simulated gimbal", b"", 0, 0, 0, caps, 0, 0.0, 0.0, g.pitch[0], g.pitch[1],
                       -g.yaw[1], -g.yaw[0], 0, 0)
            return int(M.MAV_RESULT_ACCEPTED)
        if message_id == M.MAVLINK_MSG_ID_CAMERA_INFORMATION:
            self._camera_information()
        elif message_id == M.MAVLINK_MSG_ID_CAMERA_SETTINGS:
            with self._lock:
                level = zoom_percent(self.inspection, self.focal_px)
            self._emit(self._camera_mav, "camera_settings", self._boot_ms(), M.CAMERA_MODE_IMAGE, level, math.nan, 0)
        elif message_id == M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS:
            self._emit(self._camera_mav, "camera_capture_status", self._boot_ms(), 0, 0, 0.0, 0, math.nan,
                       len(self.images), 0)
        elif message_id == M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED:
            i = int(index) if math.isfinite(index) else -2
            if not 0 <= i < len(self.images):
                return int(M.MAV_RESULT_DENIED)
            self._emit(self._camera_mav, "camera_image_captured", *self.images[i].message)
        else:
            return int(M.MAV_RESULT_UNSUPPORTED)
        return int(M.MAV_RESULT_ACCEPTED)

    def _camera_information(self) -> None:
        cam = self.inspection.camera
        pitch_mm = (self.inspection.pixel_pitch_um or 0.0) * 1e-3
        flags = M.CAMERA_CAP_FLAGS_CAPTURE_IMAGE | (M.CAMERA_CAP_FLAGS_HAS_BASIC_ZOOM if self.inspection.zoom else 0)
        self._emit(self._camera_mav, "camera_information", self._boot_ms(), name32("insulator_rs"),
                   name32("simulated zoom camera"), 0, float(self.focal_px * pitch_mm), float(cam.width * pitch_mm),
                   float(cam.height * pitch_mm), int(cam.width), int(cam.height), 0, flags, 0, b"", GIMBAL_COMPONENT, 0)

    def _zoom(self, zoom_type: int, value: float) -> int:
        """A zoom's MAV_RESULT; the lens starts travelling to an accepted one."""
        if self.faults.refuse_zoom or not self.inspection.zoom or not math.isfinite(value):
            return int(M.MAV_RESULT_DENIED)
        lo, hi = self.inspection.focal_px
        if zoom_type == M.ZOOM_TYPE_RANGE and 0.0 <= value <= 100.0:
            focal = lo + (hi - lo) * value / 100.0
        elif zoom_type == M.ZOOM_TYPE_FOCAL_LENGTH and self.inspection.pixel_pitch_um:
            focal = value / (self.inspection.pixel_pitch_um * 1e-3)
            if not lo * (1 - 1e-6) <= focal <= hi * (1 + 1e-6):
                return int(M.MAV_RESULT_DENIED)
        else:
            return int(M.MAV_RESULT_UNSUPPORTED if zoom_type not in (M.ZOOM_TYPE_RANGE, M.ZOOM_TYPE_FOCAL_LENGTH)
                       else M.MAV_RESULT_DENIED)
        with self._lock:
            self._focal_target = self.inspection.clamp_focal(focal)
        return int(M.MAV_RESULT_ACCEPTED)

    # -- captures ------------------------------------------------------------------------------
    def _take_due(self) -> None:
        now = self.clock()
        with self._lock:
            due = [c for c in self._captures if c.due <= now]
            self._captures = [c for c in self._captures if c.due > now]
            shots = [(c, now, self.pitch, self.yaw, self.focal_px) for c in due]
        for shot in shots:
            self._renderer.submit(self._take, *shot)

    def _take(self, capture: _Capture, t: float, pitch: float, yaw: float, focal_px: float) -> None:
        """Renders the image of ``capture`` at the instant ``t`` with the gimbal and lens as they
        were then, stores the file and sends CAMERA_IMAGE_CAPTURED (unless lost)."""
        T_w_b = np.asarray(self.pose(t), dtype=np.float64)
        T_w_c = T_w_b @ stabilised_T_b_c(T_w_b, self.inspection.T_b_c, pitch, yaw)
        camera = self.inspection.at_focal(focal_px)
        image = self.render(T_w_c, camera, t)
        ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        path = f"{IMAGE_DIR}/IMG_{capture.index:04d}.jpg"
        if ok:
            self.files[path] = jpeg.tobytes()
        gps = enu_to_gps(T_w_c[:3, 3], self.origin)
        url = ((FTP_SCHEME + path) if self._http is None else self._http.url + path).encode()
        message = [int(t * 1000) & 0xFFFFFFFF, int(time.time() * 1e6), 0, int(round(gps.lat * 1e7)),
                   int(round(gps.lon * 1e7)), int(round(gps.alt * 1000)), int(round(T_w_c[2, 3] * 1000)),
                   [float(v) for v in camera_quaternion_ned(T_w_c[:3, :3])], capture.index, 1 if ok else 0, url]
        with self._lock:
            self.images.append(_Image(capture.index, message))
        self.counts["captures"] += 1
        if self.rng.random() < self.faults.lost_capture_rate:
            self.counts["captured_lost"] += 1
            return
        self._emit(self._camera_mav, "camera_image_captured", *message)

    # -- MAVLink FTP server ---------------------------------------------------------------------
    def _ftp(self, msg: Any) -> None:
        raw = bytes(msg.payload)
        seq, session, opcode, size, _, _, _, offset = FTP_HEADER.unpack_from(raw)
        data = raw[FTP_HEADER.size:FTP_HEADER.size + size]
        reply = _FtpReply(self, msg, seq, session, opcode)
        if opcode == OP_RESET:
            self._sessions.clear()
            reply.ack()
        elif opcode == OP_TERMINATE:
            self._sessions.pop(session, None)
            reply.ack()
        elif opcode == OP_OPEN_RO:
            path = data.split(b"\0", 1)[0].decode("utf-8", errors="replace")
            if path not in self.files:
                reply.nack(ERR_NOT_FOUND)
                return
            sid = next((i for i in range(256) if i not in self._sessions), None)
            if sid is None:
                reply.nack(ERR_NO_SESSIONS)
                return
            cut = len(self.files[path]) // 2 if self._cut_download() else None
            self._sessions[sid] = _Session(path, cut)
            reply.session = sid
            reply.ack(struct.pack("<I", len(self.files[path])))
        elif opcode in (OP_READ, OP_BURST):
            s = self._sessions.get(session)
            if s is None:
                reply.nack(ERR_INVALID_SESSION)
                return
            self._read(reply, s, offset, min(max(size, 1), FTP_DATA), burst=opcode == OP_BURST)
        elif opcode == OP_LIST:
            self._list(reply, data.split(b"\0", 1)[0].decode("utf-8", errors="replace"), offset)
        else:
            reply.nack(ERR_UNKNOWN_COMMAND)

    def _cut_download(self) -> bool:
        """Whether the download starting now stops halfway (one of ``downloads_cut``)."""
        with self._lock:
            if self._downloads_cut <= 0:
                return False
            self._downloads_cut -= 1
            return True

    def _read(self, reply: _FtpReply, s: _Session, offset: int, size: int, *, burst: bool) -> None:
        content = self.files[s.path]
        end = len(content) if s.cut_at is None else s.cut_at
        if s.cut_at is not None and offset >= end:
            return  # the fault: the download stops answering halfway
        if offset >= len(content):
            reply.offset = offset
            reply.nack(ERR_EOF, burst_complete=burst)
            return
        for packet in range(BURST_PACKETS if burst else 1):
            chunk = content[offset:min(offset + size, end)]
            last = (not burst or packet == BURST_PACKETS - 1 or offset + len(chunk) >= end
                    or len(chunk) < size)
            reply.offset = offset
            reply.ack(chunk, burst_complete=burst and last)
            offset += len(chunk)
            if last:
                if burst and offset >= len(content) and len(chunk) == size:  # EOF on a packet's edge
                    reply.offset = offset
                    reply.nack(ERR_EOF, burst_complete=True)
                return

    def _list(self, reply: _FtpReply, path: str, offset: int) -> None:
        entries = sorted((p.rsplit("/", 1)[1], len(b)) for p, b in self.files.items()
                         if p.rsplit("/", 1)[0] == path.rstrip("/"))
        if offset >= len(entries):
            reply.nack(ERR_EOF)
            return
        out = b""
        for name, n in entries[offset:]:
            entry = f"F{name}\t{n}".encode() + b"\0"
            if len(out) + len(entry) > FTP_DATA:
                break
            out += entry
        reply.offset = offset
        reply.ack(out)


class _FtpReply:
    """The replies to one FTP request: seq = the request's + 1 (then one more per burst message)."""

    def __init__(self, server: SimulatedPayload, request: Any, seq: int, session: int, opcode: int) -> None:
        self.server = server
        self.request = request
        self.seq = (seq + 1) & 0xFFFF
        self.session = session
        self.opcode = opcode
        self.offset = 0

    def ack(self, data: bytes = b"", *, burst_complete: bool = False) -> None:
        self._send(OP_ACK, data, burst_complete)

    def nack(self, error: int, *, burst_complete: bool = False) -> None:
        self._send(OP_NACK, bytes([error]), burst_complete)

    def _send(self, opcode: int, data: bytes, burst_complete: bool) -> None:
        header = FTP_HEADER.pack(self.seq, self.session, opcode, len(data), self.opcode, int(burst_complete), 0,
                                 self.offset)
        payload = list((header + data).ljust(251, b"\0"))
        self.server._emit(self.server._camera_mav, "file_transfer_protocol", 0, self.request.get_srcSystem(),
                          self.request.get_srcComponent(), payload)
        self.seq = (self.seq + 1) & 0xFFFF


class _FileServer:
    """The payload's images over HTTP (GET of a path in ``files``; 404 otherwise); a download
    ``cut()`` says to cut sends its whole length in the header and half the file, then closes."""

    def __init__(self, files: dict[str, bytes], host: str, cut: Callable[[], bool]) -> None:
        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 (http.server's name)
                data = files.get(self.path)
                if data is None:
                    self.send_error(404)
                    return
                self.send_response(200)
                self.send_header("Content-Type", "image/jpeg")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data[:len(data) // 2] if cut() else data)

            def log_message(self, *args: object) -> None:
                return

        self.httpd = ThreadingHTTPServer((host, 0), Handler)
        self.httpd.daemon_threads = True
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="payload-http", daemon=True)

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host!s}:{port}"

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
