"""The ``Payload`` adapter over MAVLink 2: a gimbal (Gimbal Protocol v2) and a zoom camera (Camera
Protocol v2), as a Siyi, a Gremsy with a Sony or the simulated payload (``insulator_rs.sim.payload``)
speak them.

One shot, in a worker thread of its own (the caller's control loop and the vehicle's setpoint
stream never wait on it), each attempt bounded in time:

1. the payload is alive: a HEARTBEAT of the camera and of the gimbal within ``lost_after_s``;
2. the gimbal aimed: through the autopilot's gimbal manager (PX4 with ``MNT_MODE_IN`` = 4,
   ``MNT_MODE_OUT`` = 2: primary control taken with ``MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE``, then
   ``MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW``, which the manager turns into the device's
   ``GIMBAL_DEVICE_SET_ATTITUDE``; refused or unanswered: ``GIMBAL_REFUSED``) or
   ``GIMBAL_DEVICE_SET_ATTITUDE`` straight to the gimbal device where no autopilot manages one;
   yaw in the vehicle frame, pitch from the horizon. An aim past the limits the device reports
   (``GIMBAL_DEVICE_INFORMATION``), or an attitude (``GIMBAL_DEVICE_ATTITUDE_STATUS``) that stops
   short of it within ``slew_timeout_s``, is ``GIMBAL_AT_LIMIT``;
3. the lens zoomed: ``MAV_CMD_SET_CAMERA_ZOOM`` to the focal length (``ZOOM_TYPE_FOCAL_LENGTH``, mm,
   where the rig gives the pixel pitch) or to the zoom range's percentage (``ZOOM_TYPE_RANGE``,
   linear in focal length), then ``CAMERA_SETTINGS`` asked until its ``zoomLevel`` is there;
4. ``MAV_CMD_IMAGE_START_CAPTURE`` (one image), and ``CAMERA_IMAGE_CAPTURED`` waited for
   ``capture_timeout_s``; a lost one is asked for again by its index (``MAV_CMD_REQUEST_MESSAGE``,
   the index from ``CAMERA_CAPTURE_STATUS.image_count``), as the camera protocol recovers it;
5. the file fetched: MAVLink FTP with pymavlink's ``mavftp`` (``mftp://[;comp=N]PATH`` or a bare
   path) or HTTP (``http://``), within ``download_timeout_s``, and decoded;
6. the photo's time, position and attitude from ``CAMERA_IMAGE_CAPTURED`` (not from the request:
   the gimbal may not be where it was asked, the vehicle has moved), its intrinsics from the rig's
   per-zoom table (:meth:`~insulator_rs.inspection_camera.InspectionCamera.at_focal`).

Every failure of an attempt is a :class:`~insulator_rs.exceptions.PayloadError` with its
:class:`~insulator_rs.ports.payload.PayloadFault`, recorded and retried up to ``attempts`` times
(an aim past the gimbal's range is not retried: it would fail the same way).

Trust: only messages of the payload's system (the first camera HEARTBEAT's, or ``target_system``)
are taken, and only from its camera, gimbal and autopilot components.
"""

from __future__ import annotations

import http.client
import math
import queue
import threading
import time
import urllib.request
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from insulator_rs.exceptions import CommandRejected, PayloadError
from insulator_rs.inspection_camera import GimbalRoute as GimbalRoute  # re-exported: the adapter's routes
from insulator_rs.inspection_camera import InspectionCamera
from insulator_rs.mavlink.frames import camera_rotation_w, quaternion_yaw_pitch, yaw_pitch_of_quaternion
from insulator_rs.mavlink.link import open_connection
from insulator_rs.mavlink.wire import command_name, mavlink2, result_name
from insulator_rs.ports.payload import PayloadAttempt, PayloadFault, PayloadPhoto, ShotRequest, ShotResult
from insulator_rs.ports.vehicle import wrap_angle

M = mavlink2
CAMERA_COMPONENT = M.MAV_COMP_ID_CAMERA  # 100
GIMBAL_COMPONENT = M.MAV_COMP_ID_GIMBAL  # 154
AUTOPILOT_COMPONENT = M.MAV_COMP_ID_AUTOPILOT1
COMPANION_COMPONENT = M.MAV_COMP_ID_ONBOARD_COMPUTER
# the MAVLink FTP URL scheme of the camera protocol: mftp://[;comp=<id>]<path>
FTP_SCHEME = "mftp://"
# s between two polls of a wait (an ACK, the gimbal's attitude, the zoom): also how soon a lost
# payload is noticed inside a wait
POLL_S = 0.02
#: Faults an attempt does not retry: the next attempt would fail the same way.
FINAL_FAULTS = frozenset({PayloadFault.GIMBAL_AT_LIMIT})


@dataclass(frozen=True)
class PayloadSettings:
    """The adapter's bounds (s, rad): tries per shot and the time each step may take."""

    attempts: int = 3
    command_timeout_s: float = 0.5  # one COMMAND_ACK
    command_tries: int = 3  # sends of one command (MAVLink's retransmission)
    lost_after_s: float = 3.0  # a payload silent this long is gone (PAYLOAD_LOST)
    slew_timeout_s: float = 6.0
    aim_tolerance_rad: float = math.radians(1.0)
    zoom_timeout_s: float = 8.0
    zoom_tolerance_pct: float = 1.0  # CAMERA_SETTINGS.zoomLevel within this of the asked
    capture_timeout_s: float = 3.0  # for CAMERA_IMAGE_CAPTURED, then as long again once asked
    download_timeout_s: float = 20.0
    ftp_retry_s: float = 0.5  # a stalled burst read asked again after this
    ftp_idle_s: float = 3.7  # mavftp's idle detection (must exceed ftp_retry_s)
    heartbeat_period_s: float = 1.0  # our own HEARTBEAT (the payload learns our address from it)

    def __post_init__(self) -> None:
        for name in ("command_timeout_s", "lost_after_s", "slew_timeout_s", "aim_tolerance_rad", "zoom_timeout_s",
                     "zoom_tolerance_pct", "capture_timeout_s", "download_timeout_s", "ftp_retry_s", "ftp_idle_s",
                     "heartbeat_period_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"PayloadSettings.{name}: expected a finite number > 0, got {value!r}")
        for name in ("attempts", "command_tries"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"PayloadSettings.{name}: expected an int >= 1, got {value!r}")
        if not self.ftp_idle_s > self.ftp_retry_s:
            raise ValueError(f"PayloadSettings.ftp_idle_s: must exceed ftp_retry_s ({self.ftp_retry_s:g} s), "
                             f"got {self.ftp_idle_s!r}")


def gimbal_device_quaternion(pitch: float, yaw: float) -> list[float]:
    """GIMBAL_DEVICE_SET_ATTITUDE's q for our aim: ``pitch`` rad from the horizon (negative looks
    down, as MAVLink's), ``yaw`` rad from the body heading counter-clockwise (MAVLink's yaw is
    clockwise: negated), in the vehicle frame (GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME)."""
    return quaternion_yaw_pitch(-yaw, pitch)


def gimbal_aim_of_quaternion(q: object) -> tuple[float, float]:
    """(pitch, yaw) rad, ours (yaw counter-clockwise), of a gimbal quaternion in the vehicle frame."""
    yaw_cw, pitch = yaw_pitch_of_quaternion(q)
    return pitch, -yaw_cw


def zoom_percent(inspection: InspectionCamera, focal_px: float) -> float:
    """The zoom range's percentage (0 widest, 100 longest) of ``focal_px``, linear in focal length
    (MAVLink's ZOOM_TYPE_RANGE and CAMERA_SETTINGS.zoomLevel); 0 for a fixed lens."""
    lo, hi = inspection.focal_px
    return 0.0 if hi <= lo else 100.0 * (inspection.clamp_focal(focal_px) - lo) / (hi - lo)


def ftp_path(file_url: str) -> tuple[str, int | None]:
    """(path, component) of a camera's MAVLink FTP URL: ``mftp://[;comp=N]PATH`` or a bare path
    (component None: the camera's)."""
    if not file_url.startswith(FTP_SCHEME):
        return file_url, None
    rest = file_url[len(FTP_SCHEME):]
    if rest.startswith("[;comp="):  # the bracketed form some cameras send
        end = rest.index("]")
        return rest[end + 1:], int(rest[len("[;comp="):end])
    if rest.startswith(";comp="):
        digits = rest[len(";comp="):]
        n = len(digits) - len(digits.lstrip("0123456789"))
        return digits[n:], int(digits[:n])
    return rest, None


class _FtpMaster:
    """What pymavlink's ``MAVFTP`` reads and writes through (its ``master``): our sender, our ids,
    and the FILE_TRANSFER_PROTOCOL messages our receiver hands over (MAVFTP's own ``recv_match``
    on the connection would drop every other message while a file comes: the heartbeats with it)."""

    def __init__(self, payload: MavlinkPayload) -> None:
        self._payload = payload
        self.source_system = payload.source_system
        self.source_component = payload.source_component
        self.mav = self

    def file_transfer_protocol_send(self, network: int, system: int, component: int, data: Any) -> None:
        self._payload._send("file_transfer_protocol", network, system, component, data)

    def recv_match(self, type: Any = None, timeout: float | None = None, blocking: bool = True) -> Any:  # noqa: A002
        try:
            return self._payload._ftp_queue.get(timeout=timeout if blocking else 0.0)
        except queue.Empty:
            return None


@dataclass
class _State:
    """What the receiver keeps of the payload's messages (under the adapter's condition)."""

    heartbeats: dict[int, float] = field(default_factory=dict)  # component -> monotonic s
    gimbal_aim: tuple[float, float] | None = None  # (pitch, yaw) rad, ours
    gimbal_limits: tuple[float, float, float, float] | None = None  # pitch min/max, yaw min/max
    camera_information: Any = None
    zoom_level: float | None = None
    settings_seen: int = 0
    image_count: int | None = None
    capture_status_seen: int = 0
    captured: dict[int, Any] = field(default_factory=dict)  # image_index -> CAMERA_IMAGE_CAPTURED
    acks: dict[tuple[int, int], Any] = field(default_factory=dict)  # (component, command) -> ack


class MavlinkPayload:
    """The :class:`~insulator_rs.ports.payload.Payload` port on a MAVLink gimbal and camera.

    ``connection``: how to reach them (``udpout:HOST:PORT`` to the payload or to a router,
    ``udpin:...``, ``DEVICE:BAUD``). ``inspection``: the rig's inspection camera (zoom range,
    per-zoom intrinsics, gimbal limits, pixel pitch). ``gimbal_route``: :class:`GimbalRoute`.
    ``target_system``: the payload's system id (None: the first camera HEARTBEAT's).
    ``vehicle_clock``: the vehicle clock now (s); given, the camera's clock (every ``time_boot_ms``
    of the camera component, s) is mapped to it by the least offset seen (vehicle time at arrival minus the
    message's stamp: the least-delayed message, as the LiDAR driver's clock fit); None: the
    camera's clock is the vehicle's (the simulated payload, a camera synchronised to the
    autopilot's boot time)."""

    def __init__(self, connection: str, inspection: InspectionCamera, *, gimbal_route: str = GimbalRoute.MANAGER,
                 target_system: int | None = None, settings: PayloadSettings | None = None,
                 vehicle_clock: Callable[[], float] | None = None,
                 source_system: int = 1, source_component: int = COMPANION_COMPONENT) -> None:
        if gimbal_route not in GimbalRoute.ALL:
            raise ValueError(f"gimbal_route: expected one of {GimbalRoute.ALL}, got {gimbal_route!r}")
        if target_system is not None and not (isinstance(target_system, int) and 1 <= target_system <= 255):
            raise ValueError(f"target_system: a MAVLink system id in [1, 255], got {target_system!r}")
        self.inspection = inspection
        self.gimbal_route = gimbal_route
        self.settings = settings or PayloadSettings()
        self.vehicle_clock = vehicle_clock
        self._clock_offset = math.inf  # vehicle time minus the camera's, the least seen (s)
        self.source_system = source_system
        self.source_component = source_component
        self.target_system = target_system
        self.conn = open_connection(connection, source_system=source_system, source_component=source_component)
        self.conn.mav.robust_parsing = True
        self._send_lock = threading.Lock()
        self._cond = threading.Condition()
        self._state = _State()
        self._ftp_queue: queue.Queue[Any] = queue.Queue()
        self._in_control = False  # primary control of the autopilot's gimbal manager taken
        self._stop = threading.Event()
        self.counts: dict[str, int] = {"shots": 0, "photos": 0, "attempts": 0, "foreign": 0}
        self._threads = [threading.Thread(target=self._receive_loop, name="payload-rx", daemon=True),
                         threading.Thread(target=self._heartbeat_loop, name="payload-hb", daemon=True)]
        for thread in self._threads:
            thread.start()
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="payload-shot")

    # -- the port ------------------------------------------------------------------------------
    def submit(self, request: ShotRequest) -> Future[ShotResult]:
        self.counts["shots"] += 1
        return self._worker.submit(self._shoot, request)

    def health(self) -> dict[str, object]:
        return dict(self.counts)

    def alive(self) -> bool:
        """Whether the camera's and the gimbal's HEARTBEAT came within ``lost_after_s`` (what a
        pre-flight check asks before the payload is flown)."""
        try:
            self._require_alive()
        except PayloadError:
            return False
        return True

    def close(self) -> None:
        self._stop.set()
        self._worker.shutdown(wait=True, cancel_futures=True)
        for thread in self._threads:
            thread.join(timeout=2.0)
        try:
            self.conn.close()
        except OSError:
            pass

    # -- one shot ------------------------------------------------------------------------------
    def _shoot(self, request: ShotRequest) -> ShotResult:
        attempts: list[PayloadAttempt] = []
        for n in range(1, self.settings.attempts + 1):
            self.counts["attempts"] += 1
            try:
                photo = self._attempt(request)
            except PayloadError as err:
                fault = err.fault if isinstance(err.fault, PayloadFault) else PayloadFault.CAPTURE_FAILED
                attempts.append(PayloadAttempt(n, fault, err.detail))
                self.counts[fault.value] = self.counts.get(fault.value, 0) + 1
                if fault in FINAL_FAULTS:
                    break
                continue
            attempts.append(PayloadAttempt(n, None, photo.file_url))
            self.counts["photos"] += 1
            return ShotResult(photo, tuple(attempts))
        return ShotResult(None, tuple(attempts))

    def _attempt(self, request: ShotRequest) -> PayloadPhoto:
        self._require_alive()
        focal = self.inspection.clamp_focal(request.focal_px)
        self._aim(request.pitch, request.yaw)
        self._zoom(focal)
        msg = self._capture()
        if msg.capture_result != 1:
            raise PayloadError(PayloadFault.CAPTURE_FAILED, f"image {msg.image_index}: capture_result "
                                                            f"{msg.capture_result}")
        url = _text(msg.file_url)
        data = self._download(url)
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise PayloadError(PayloadFault.DOWNLOAD_FAILED, f"{url}: {len(data)} bytes fetched are no image")
        camera = self.inspection.at_focal(focal)
        if image.shape[:2] != (camera.height, camera.width):
            raise PayloadError(PayloadFault.DOWNLOAD_FAILED,
                               f"{url}: image {image.shape[1]}x{image.shape[0]}, the rig's inspection camera "
                               f"{camera.width}x{camera.height}")
        return PayloadPhoto(time=self._to_vehicle(msg.time_boot_ms / 1000.0), image=image, camera=camera,
                            R_w_c=camera_rotation_w(msg.q),
                            wgs84=(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3), focal_px=focal,
                            file_url=url, image_index=int(msg.image_index))

    # -- gimbal ----------------------------------------------------------------------------------
    def _aim(self, pitch: float, yaw: float) -> None:
        limits = self._gimbal_limits()
        pitch_lo, pitch_hi, yaw_lo, yaw_hi = limits
        tol = self.settings.aim_tolerance_rad
        if not (pitch_lo - tol <= pitch <= pitch_hi + tol and yaw_lo - tol <= yaw <= yaw_hi + tol):
            raise PayloadError(PayloadFault.GIMBAL_AT_LIMIT,
                               f"aim pitch {math.degrees(pitch):.1f} deg, yaw {math.degrees(yaw):.1f} deg is past "
                               f"the gimbal's range (pitch {math.degrees(pitch_lo):.0f}..{math.degrees(pitch_hi):.0f}, "
                               f"yaw {math.degrees(yaw_lo):.0f}..{math.degrees(yaw_hi):.0f} deg)")
        if self.gimbal_route == GimbalRoute.MANAGER:
            self._command_manager(pitch, yaw)
        deadline = time.monotonic() + self.settings.slew_timeout_s
        resend = 0.0
        while True:
            now = time.monotonic()
            if self.gimbal_route == GimbalRoute.DEVICE and now >= resend:
                # a message without an answer, and MAVLink is lossy: sent again until it is reached
                self._send_device_aim(pitch, yaw)
                resend = now + 0.5
            with self._cond:
                aim = self._state.gimbal_aim
            if aim is not None and abs(aim[0] - pitch) <= tol and abs(wrap_angle(aim[1] - yaw)) <= tol:
                return
            if now >= deadline:
                seen = "no GIMBAL_DEVICE_ATTITUDE_STATUS" if aim is None else (
                    f"stopped at pitch {math.degrees(aim[0]):.1f} deg, yaw {math.degrees(aim[1]):.1f} deg")
                raise PayloadError(PayloadFault.GIMBAL_AT_LIMIT,
                                   f"aim pitch {math.degrees(pitch):.1f} deg, yaw {math.degrees(yaw):.1f} deg not "
                                   f"reached in {self.settings.slew_timeout_s:g} s: {seen}")
            self._wait(POLL_S)

    def _command_manager(self, pitch: float, yaw: float) -> None:
        """The aim through the autopilot's gimbal manager: primary control taken once
        (MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE: our system and component), then
        MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (degrees; yaw clockwise, in the vehicle frame).

        Why the command and not the GIMBAL_MANAGER_SET_PITCHYAW message: PX4 v1.16 has no handler
        for that message (its binary carries the command's and GIMBAL_MANAGER_SET_ATTITUDE's only),
        and the command is acknowledged: a manager that gives control to someone else says DENIED,
        which a message would leave unsaid. ArduPilot takes the command too."""
        flags = M.GIMBAL_MANAGER_FLAGS_ROLL_LOCK | M.GIMBAL_MANAGER_FLAGS_PITCH_LOCK \
            | M.GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME
        for _ in range(2):  # control taken by another (a GCS) since: taken back once
            if not self._in_control:
                # param1/2: the primary control's system/component (us), param3/4 -1: the secondary
                # unchanged, param7 0: the manager's gimbal
                self._command(AUTOPILOT_COMPONENT, M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, self.source_system,
                              self.source_component, -1, -1, 0, 0, 0, fault=PayloadFault.GIMBAL_REFUSED)
                self._in_control = True
            try:
                self._command(AUTOPILOT_COMPONENT, M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, math.degrees(pitch),
                              math.degrees(-yaw), math.nan, math.nan, flags, 0, 0, fault=PayloadFault.GIMBAL_REFUSED)
                return
            except PayloadError as err:
                if err.fault is not PayloadFault.GIMBAL_REFUSED or "DENIED" not in err.detail:
                    raise
                self._in_control = False
        raise PayloadError(PayloadFault.GIMBAL_REFUSED, "MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW: DENIED with primary "
                                                         "control taken")

    def _send_device_aim(self, pitch: float, yaw: float) -> None:
        """GIMBAL_DEVICE_SET_ATTITUDE straight to the gimbal device (no manager in between)."""
        flags = M.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | M.GIMBAL_DEVICE_FLAGS_PITCH_LOCK \
            | M.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
        self._send("gimbal_device_set_attitude", self._system(), GIMBAL_COMPONENT, flags,
                   gimbal_device_quaternion(pitch, yaw), math.nan, math.nan, math.nan)

    def _gimbal_limits(self) -> tuple[float, float, float, float]:
        """The gimbal device's range (GIMBAL_DEVICE_INFORMATION, asked once), else the rig's."""
        with self._cond:
            known = self._state.gimbal_limits
        if known is None:
            try:
                self._request_message(M.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION, GIMBAL_COMPONENT,
                                      fault=PayloadFault.GIMBAL_AT_LIMIT)
            except PayloadError as err:
                if err.fault is PayloadFault.PAYLOAD_LOST:
                    raise
                # a device that does not say: the rig's limits
            self._wait_for(lambda s: s.gimbal_limits is not None, self.settings.command_timeout_s)
            with self._cond:
                known = self._state.gimbal_limits
        if known is None:
            g = self.inspection.gimbal
            return g.pitch[0], g.pitch[1], g.yaw[0], g.yaw[1]
        return known

    # -- camera ----------------------------------------------------------------------------------
    def _zoom(self, focal_px: float) -> None:
        if not self.inspection.zoom:
            return
        percent = zoom_percent(self.inspection, focal_px)
        focal_mm = self.inspection.focal_length_mm(focal_px)
        if focal_mm is not None:
            self._command(CAMERA_COMPONENT, M.MAV_CMD_SET_CAMERA_ZOOM, M.ZOOM_TYPE_FOCAL_LENGTH, focal_mm,
                          fault=PayloadFault.ZOOM_REFUSED)
        else:
            self._command(CAMERA_COMPONENT, M.MAV_CMD_SET_CAMERA_ZOOM, M.ZOOM_TYPE_RANGE, percent,
                          fault=PayloadFault.ZOOM_REFUSED)
        deadline = time.monotonic() + self.settings.zoom_timeout_s
        while True:
            with self._cond:
                seen = self._state.settings_seen
            self._request_message(M.MAVLINK_MSG_ID_CAMERA_SETTINGS, CAMERA_COMPONENT, fault=PayloadFault.ZOOM_REFUSED)
            self._wait_for(lambda s: s.settings_seen > seen, self.settings.command_timeout_s)
            with self._cond:
                level = self._state.zoom_level
            if level is not None and abs(level - percent) <= self.settings.zoom_tolerance_pct:
                return
            if time.monotonic() >= deadline:
                raise PayloadError(PayloadFault.ZOOM_REFUSED,
                                   f"zoom {percent:.1f} % ({focal_px:.0f} px) not reached in "
                                   f"{self.settings.zoom_timeout_s:g} s: CAMERA_SETTINGS.zoomLevel {level}")
            self._wait(0.1)

    def _image_count(self, fault: PayloadFault) -> int:
        """The camera's image count (CAMERA_CAPTURE_STATUS); PayloadError(``fault``) without it."""
        with self._cond:
            seen = self._state.capture_status_seen
        self._request_message(M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS, CAMERA_COMPONENT, fault=fault)
        if not self._wait_for(lambda s: s.capture_status_seen > seen, self.settings.command_timeout_s):
            raise PayloadError(fault, "no CAMERA_CAPTURE_STATUS")
        with self._cond:
            return self._state.image_count or 0

    def _capture(self) -> Any:
        index = self._image_count(PayloadFault.CAPTURE_REFUSED)
        # param3 1 image, param4 its capture sequence number (a retransmitted command is not a
        # second capture): the camera's image count, from 1
        self._command(CAMERA_COMPONENT, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, index + 1,
                      fault=PayloadFault.CAPTURE_REFUSED)
        timeout = self.settings.capture_timeout_s
        if self._wait_for(lambda s: index in s.captured, timeout):
            return self._state.captured[index]
        # lost on the way, or never taken: the camera says how many it took, and a taken one is
        # asked for again by its index
        count = self._image_count(PayloadFault.NO_CAPTURE_ANSWER)
        if count > index:
            self._request_message(M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, CAMERA_COMPONENT, index,
                                  fault=PayloadFault.NO_CAPTURE_ANSWER)
        if count > index and self._wait_for(lambda s: index in s.captured, timeout):
            return self._state.captured[index]
        raise PayloadError(PayloadFault.NO_CAPTURE_ANSWER,
                           f"image {index}: no CAMERA_IMAGE_CAPTURED in {timeout:g} s (the camera counts {count} "
                           f"images{', asked for it again' if count > index else ''})")

    # -- download ---------------------------------------------------------------------------------
    def _download(self, url: str) -> bytes:
        if url.startswith(("http://", "https://")):
            try:
                with urllib.request.urlopen(url, timeout=self.settings.download_timeout_s) as response:  # noqa: S310
                    data = bytes(response.read())
            except (OSError, http.client.HTTPException) as err:  # a body cut short: IncompleteRead
                raise PayloadError(PayloadFault.DOWNLOAD_FAILED, f"{url}: {err!r}") from err
            return data
        try:
            return self._ftp_get(url)
        except PayloadError:
            raise
        # A camera's FTP replies are bytes from the network: pymavlink's mavftp raises on some it
        # cannot parse (struct.error, IndexError, an assertion). None may end the shot otherwise
        # than as a named fault, nor reach the flight loop.
        except Exception as err:  # noqa: BLE001
            raise PayloadError(PayloadFault.DOWNLOAD_FAILED, f"{url}: MAVLink FTP failed: {err!r}") from err

    def _ftp_get(self, url: str) -> bytes:
        from pymavlink import mavftp

        try:
            path, component = ftp_path(url)
        except ValueError as err:
            raise PayloadError(PayloadFault.DOWNLOAD_FAILED, f"{url}: not a MAVLink FTP URL") from err
        s = self.settings
        ftp_settings = mavftp.MAVFTPSettings([
            ("debug", int, 0), ("pkt_loss_tx", int, 0), ("pkt_loss_rx", int, 0), ("max_backlog", int, 5),
            ("burst_read_size", int, mavftp.MAX_Payload), ("write_size", int, 80), ("write_qsize", int, 5),
            ("idle_detection_time", float, s.ftp_idle_s), ("read_retry_time", float, s.ftp_retry_s),
            ("retry_time", float, s.ftp_retry_s)])
        while not self._ftp_queue.empty():  # a stale transfer's replies
            self._ftp_queue.get_nowait()
        got: list[bytes] = []

        def keep(fh: Any) -> None:
            got.append(bytes(fh.read()))

        ftp = mavftp.MAVFTP(_FtpMaster(self), self._system(),
                            CAMERA_COMPONENT if component is None else component, settings=ftp_settings)
        ftp.cmd_get([path], callback=keep)
        ret = ftp.process_ftp_reply("OpenFileRO", timeout=max(s.download_timeout_s, s.ftp_idle_s * 1.01))
        if not got:
            raise PayloadError(PayloadFault.DOWNLOAD_FAILED,
                               f"{url}: MAVLink FTP {ret.operation_name} {ret.error_code.name} "
                               f"({ftp.read_total} of {ftp.remote_file_size or '?'} bytes)")
        return got[0]

    # -- commands ----------------------------------------------------------------------------------
    def _command(self, component: int, command: int, *params: float, fault: PayloadFault) -> None:
        """COMMAND_LONG to ``component``, retransmitted; PayloadError(``fault``) unless ACCEPTED
        (PAYLOAD_LOST when the payload falls silent meanwhile)."""
        padded = [float(p) for p in params] + [0.0] * (7 - len(params))
        name = command_name(command)
        key = (component, command)
        for confirmation in range(self.settings.command_tries):
            self._require_alive()
            with self._cond:
                self._state.acks.pop(key, None)
            self._send("command_long", self._system(), component, command, confirmation, *padded)
            ok = self._wait_for(lambda s: key in s.acks and s.acks[key].result != M.MAV_RESULT_IN_PROGRESS,
                                self.settings.command_timeout_s)
            if ok:
                ack = self._state.acks[key]
                if ack.result != M.MAV_RESULT_ACCEPTED:
                    raise PayloadError(fault, str(CommandRejected(name, result_name(ack.result))))
                return
        raise PayloadError(fault, f"{name}: no COMMAND_ACK after {self.settings.command_tries} tries of "
                                  f"{self.settings.command_timeout_s:g} s")

    def _request_message(self, message_id: int, component: int, *params: float, fault: PayloadFault) -> None:
        self._command(component, M.MAV_CMD_REQUEST_MESSAGE, message_id, *params, fault=fault)

    # -- liveness and waiting ---------------------------------------------------------------------
    def _require_alive(self) -> None:
        now = time.monotonic()
        with self._cond:
            beats = dict(self._state.heartbeats)
        for component, what in ((CAMERA_COMPONENT, "camera"), (GIMBAL_COMPONENT, "gimbal")):
            seen = beats.get(component)
            if seen is None or now - seen > self.settings.lost_after_s:
                ago = "never" if seen is None else f"{now - seen:.1f} s ago"
                raise PayloadError(PayloadFault.PAYLOAD_LOST, f"the {what}'s last HEARTBEAT: {ago}")

    def _wait(self, seconds: float) -> None:
        self._stop.wait(seconds)

    def _wait_for(self, done: Callable[[_State], bool], timeout: float) -> bool:
        """Wait until ``done(state)`` or ``timeout`` s; whether it came. PAYLOAD_LOST if the payload
        falls silent meanwhile."""
        deadline = time.monotonic() + timeout
        while True:
            with self._cond:
                if done(self._state):
                    return True
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._stop.is_set():
                    return False
                self._cond.wait(timeout=min(remaining, POLL_S * 5))
            self._require_alive()

    def _to_vehicle(self, camera_s: float) -> float:
        """A payload stamp (s of its boot clock) in the vehicle clock (see ``vehicle_clock``)."""
        if self.vehicle_clock is None or not math.isfinite(self._clock_offset):
            return camera_s
        return camera_s + self._clock_offset

    def _system(self) -> int:
        return self.target_system if self.target_system is not None else 1

    # -- the link ------------------------------------------------------------------------------------
    def _send(self, name: str, *args: Any) -> None:
        with self._send_lock:
            try:
                getattr(self.conn.mav, f"{name}_send")(*args)
            except OSError:
                pass  # MAVLink is lossy: a send that fails is a message lost

    def _heartbeat_loop(self) -> None:
        while True:
            self._send("heartbeat", M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
            if self._stop.wait(self.settings.heartbeat_period_s):
                return

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.05)
            except Exception:  # noqa: BLE001  (bytes from the network are hostile input)
                continue
            if msg is not None:
                self._handle(msg)

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        system, component = msg.get_srcSystem(), msg.get_srcComponent()
        if self.target_system is None and kind == "HEARTBEAT" and component == CAMERA_COMPONENT:
            self.target_system = system
        if system != self.target_system or component not in (CAMERA_COMPONENT, GIMBAL_COMPONENT, AUTOPILOT_COMPONENT):
            self.counts["foreign"] += 1
            return
        if kind == "FILE_TRANSFER_PROTOCOL":
            self._ftp_queue.put(msg)
            return
        stamp = getattr(msg, "time_boot_ms", None)
        # the camera's own clock (a gimbal of another make boots on a clock of its own)
        if self.vehicle_clock is not None and stamp is not None and component == CAMERA_COMPONENT:
            self._clock_offset = min(self._clock_offset, self.vehicle_clock() - stamp / 1000.0)
        with self._cond:
            s = self._state
            if kind == "HEARTBEAT":
                s.heartbeats[component] = time.monotonic()
            elif kind == "COMMAND_ACK":
                s.acks[(component, msg.command)] = msg
            elif kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
                pitch, yaw = gimbal_aim_of_quaternion(msg.q)
                if not msg.flags & M.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME and math.isfinite(msg.delta_yaw):
                    yaw = wrap_angle(yaw + msg.delta_yaw)  # earth frame: the vehicle's heading taken out
                s.gimbal_aim = (pitch, yaw)
            elif kind == "GIMBAL_DEVICE_INFORMATION":
                # MAVLink's yaw is clockwise: our counter-clockwise range is its range negated
                s.gimbal_limits = (msg.pitch_min, msg.pitch_max, -msg.yaw_max, -msg.yaw_min)
            elif kind == "CAMERA_INFORMATION":
                s.camera_information = msg
            elif kind == "CAMERA_SETTINGS":
                s.zoom_level = float(msg.zoomLevel) if math.isfinite(msg.zoomLevel) else None
                s.settings_seen += 1
            elif kind == "CAMERA_CAPTURE_STATUS":
                s.image_count = int(msg.image_count)
                s.capture_status_seen += 1
            elif kind == "CAMERA_IMAGE_CAPTURED":
                s.captured[int(msg.image_index)] = msg
            else:
                return
            self._cond.notify_all()


def _text(value: Any) -> str:
    """A MAVLink char[] field as text (pymavlink gives str or bytes, NUL-padded)."""
    if isinstance(value, (bytes, bytearray)):
        value = value.decode("utf-8", errors="replace")
    return str(value).split("\0", 1)[0]
