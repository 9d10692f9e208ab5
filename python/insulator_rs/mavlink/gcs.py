"""The pilot's view: the flight's events as the ground station (QGroundControl) expects them.

An adapter of the :class:`~insulator_rs.ports.observer.FlightObserver` port that speaks MAVLink 2
as PX4 companion software does, through the autopilot, which forwards it to its GCS link
(measured on PX4 v1.16.0 SITL, ``tests/test_px4_sitl_gcs.py``):

* **STATUSTEXT** from the companion computer (``MAV_COMP_ID_ONBOARD_COMPUTER``, 191) for each
  phase change (INFO; NOTICE when the mission finishes, WARNING for a hold), each insulator
  found (NOTICE), each photo (INFO) and an abort (CRITICAL), a hand-over to the pilot (ALERT), each failed pre-flight check (CRITICAL, ``Preflight Fail: ...``); the flight's other progress lines
  (``message``: the console's lines) at DEBUG, below what a GCS shows by default; texts longer than STATUSTEXT's 50
  characters go in chunks (MAVLink 2 ``id`` / ``chunk_seq``), as PX4 does.
* A **MAVLink camera** (``MAV_COMP_ID_CAMERA``, 100, camera protocol v2): its own HEARTBEAT
  (``MAV_TYPE_CAMERA``) at 1 Hz, CAMERA_INFORMATION at start and when asked
  (``MAV_CMD_REQUEST_MESSAGE`` or the older ``MAV_CMD_REQUEST_CAMERA_INFORMATION``, with a
  COMMAND_ACK), CAMERA_SETTINGS / CAMERA_CAPTURE_STATUS / STORAGE_INFORMATION when asked, and
  **CAMERA_IMAGE_CAPTURED** for each photo: position (lat/lon degE7, alt mm, relative alt mm),
  UTC time, ``image_index`` (0-based), ``file_url`` and the camera's attitude as a quaternion
  (w, x, y, z; NED earth frame, zero = looking north, level), from which QGroundControl draws
  its photo markers. A lost CAMERA_IMAGE_CAPTURED is sent again when asked by index.

* The **operator's abort** from the ground station: a COMMAND_LONG ``MAV_CMD_USER_1``
  (:data:`ABORT_COMMAND`, param1 :data:`ABORT_PARAM1`) addressed to the companion (component 191; QGroundControl sends it from
  the Fly View's custom action, ``data/qgc_mavlink_actions.json``) asks the flight for the abort
  (the handler given to :meth:`MavlinkGcsObserver.on_abort_command`). Accepted in the air: a
  COMMAND_ACK ACCEPTED and the STATUSTEXT :data:`ABORT_ANNOUNCEMENT` (CRITICAL); on the ground
  TEMPORARILY_REJECTED with the reason in a STATUSTEXT. Any other command to the companion is
  answered UNSUPPORTED.

Frames go out paced, at least :data:`SEND_INTERVAL_S` apart (a queue and a sender thread): PX4
forwards a burst of large frames only in part (measured on v1.16.0 SITL: of 10
CAMERA_IMAGE_CAPTURED sent back to back 2 reached the GCS, 7 at 2 ms apart, all 10 at 5 ms and
more; small STATUSTEXTs all got through even back to back), so a photo's messages are spaced.

Both components use the autopilot's system id, so the ground station shows them as parts of
the vehicle. Bytes go out through a ``send(bytes)`` callable (the companion's own link to the
autopilot, :meth:`MavlinkGcsObserver.on_vehicle`, or any UDP socket) and commands come in
through :meth:`handle_message`. An observer never raises: a failed send is counted
(``send_errors``) and the flight goes on.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from insulator_rs.mavlink.frames import quaternion_yaw_pitch, yaw_enu_to_ned
from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.ports.observer import InsulatorFound, PhaseChange, PhotoTaken

M = mavlink2
CAMERA_COMPONENT = M.MAV_COMP_ID_CAMERA  # 100
COMPANION_COMPONENT = M.MAV_COMP_ID_ONBOARD_COMPUTER  # 191
STATUSTEXT_LEN = 50  # characters of one STATUSTEXT
# The ground station's abort: MAVLink's first user-defined command, addressed to the companion (no
# standard command means "companion, abort your mission"; PX4 forwards commands to component 191)
ABORT_COMMAND = M.MAV_CMD_USER_1  # 31010
# its param1: 1 asks for the abort; any other value is refused (DENIED), so that another tool's use
# of MAVLink's user command never aborts a flight by accident
ABORT_PARAM1 = 1.0
ABORT_ANNOUNCEMENT = "insulator-rs: operator abort, flying the safe route"
ABORT_REFUSED = "insulator-rs: abort refused: not in the air"
HEARTBEAT_PERIOD_S = 1.0
# s between two frames sent. PX4 forwards through a buffer of about two frames, drained by its
# GCS link's loop: on a quiet machine every large frame got through from 5 ms apart, but on a
# loaded one that loop runs late, and at 10 ms a flight's GCS lost one STATUSTEXT in about 100
# frames (CI, tests/test_px4_sitl_gcs.py). Six times the quiet spacing: a photo's few frames
# still reach the pilot within a tenth of a second.
SEND_INTERVAL_S = 0.03
FILE_URL_LEN = 205  # CAMERA_IMAGE_CAPTURED.file_url
# Severity of a phase change by the phase entered (the rest INFO).
PHASE_SEVERITY = {"hold": M.MAV_SEVERITY_WARNING, "finish": M.MAV_SEVERITY_NOTICE,
                  "abort": M.MAV_SEVERITY_CRITICAL}


@dataclass(frozen=True)
class CameraDescription:
    """What CAMERA_INFORMATION says of the inspection camera: vendor and model (at most 32
    bytes each), focal length and sensor size (mm), resolution (px)."""

    vendor: str = "insulator_rs"
    model: str = "inspection camera"
    focal_length_mm: float = 0.0
    sensor_width_mm: float = 0.0
    sensor_height_mm: float = 0.0
    width_px: int = 0
    height_px: int = 0
    firmware_version: int = 0

    @classmethod
    def from_camera_model(cls, camera: Any, *, pixel_pitch_um: float | None = None, vendor: str | None = None,
                          model: str | None = None) -> CameraDescription:
        """From an ``ir.CameraModel`` and the rig's lens (:class:`~insulator_rs.rig.CameraLens`
        fields): the focal length and sensor size follow from the pixel pitch (default 3.45 um,
        a Sony IMX 12 MP class sensor)."""
        vendor = vendor or "insulator_rs"
        model = model or "inspection camera"
        pitch_mm = (pixel_pitch_um or 3.45) * 1e-3
        return cls(vendor=vendor, model=model, focal_length_mm=0.5 * (camera.fx + camera.fy) * pitch_mm,
                   sensor_width_mm=camera.width * pitch_mm, sensor_height_mm=camera.height * pitch_mm,
                   width_px=int(camera.width), height_px=int(camera.height))


def name32(text: str) -> list[int]:
    raw = text.encode("utf-8")[:32]
    return list(raw.ljust(32, b"\0"))


def _ascii(text: str) -> str:
    """STATUSTEXT is char[]: keep to printable ASCII (a degree sign or an arrow would be mangled)."""
    return "".join(c if 32 <= ord(c) < 127 else "?" for c in text.replace("\u2192", "->").replace("\u00b0", " deg"))


def camera_quaternion(yaw_enu: float, gimbal_pitch: float) -> list[float]:
    """(w, x, y, z) of the camera in NED: yaw from north (clockwise) = 90 deg - yaw in W (ENU),
    then the gimbal pitch (negative looks down, as MAVLink's pitch), no roll."""
    return quaternion_yaw_pitch(yaw_ned=yaw_enu_to_ned(yaw_enu), pitch=gimbal_pitch)


class MavlinkGcsObserver:
    """The FlightObserver that tells the ground station (see the module docstring).

    ``send``: writes one MAVLink datagram (bytes) towards the autopilot / GCS. ``system_id``:
    the vehicle's (the autopilot's) system id. ``camera``: what CAMERA_INFORMATION says.
    ``heartbeat``: run the camera's 1 Hz HEARTBEAT thread (:meth:`start` / :meth:`close`)."""

    def __init__(self, send: Callable[[bytes], None], *, system_id: int, camera: CameraDescription | None = None,
                 file_url_prefix: str = "") -> None:
        if not (isinstance(system_id, int) and 1 <= system_id <= 255):
            raise ValueError(f"system_id must be a MAVLink system id in [1, 255], got {system_id!r}")
        self._send_bytes = send
        self.system_id = system_id
        self.camera = camera or CameraDescription()
        self.file_url_prefix = file_url_prefix
        self._lock = threading.Lock()
        # the flight's abort (flight/operator_abort.py OperatorAbort.request): True when taken
        self._abort_handler: Callable[[], bool] | None = None

        class _Writer:
            def write(_self, buf: bytes) -> None:  # noqa: N805
                self._write(buf)

        self._companion = M.MAVLink(_Writer(), srcSystem=system_id, srcComponent=COMPANION_COMPONENT)
        self._camera = M.MAVLink(_Writer(), srcSystem=system_id, srcComponent=CAMERA_COMPONENT)
        self._t0 = time.monotonic()
        self._text_id = 0
        self.images: list[PhotoTaken] = []
        self.sent: dict[str, int] = {}
        self.send_errors = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._queue: queue.Queue[bytes | None] = queue.Queue()
        self._sender = threading.Thread(target=self._send_loop, name="mavlink-gcs-tx", daemon=True)
        self._sender.start()

    # -- construction on the companion's link to the autopilot ------------------------------
    @classmethod
    def on_vehicle(cls, vehicle: Any, *, camera: CameraDescription | None = None,
                   file_url_prefix: str = "") -> MavlinkGcsObserver:
        """On a :class:`~insulator_rs.mavlink.client.MavlinkVehicle`'s own link: the same socket
        (or serial port) the offboard client uses, the autopilot's system id, and the commands
        PX4 forwards to our components handed to :meth:`handle_message`. Started."""
        link = vehicle.link
        system_id = link.autopilot[0] if link.autopilot is not None else 1
        obs = cls(link.send_raw, system_id=system_id, camera=camera, file_url_prefix=file_url_prefix)
        link.add_listener(obs.handle_message)
        return obs.start()

    def start(self) -> MavlinkGcsObserver:
        """Camera HEARTBEAT now and every second, CAMERA_INFORMATION once (at start, as cameras do)."""
        self._heartbeat()
        self.send_camera_information()
        if self._thread is None:
            self._thread = threading.Thread(target=self._heartbeat_loop, name="mavlink-camera", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop the heartbeat; what is queued is still sent (at most a few seconds' worth)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._queue.put(None)
        self._sender.join(timeout=5.0)

    # -- FlightObserver -----------------------------------------------------------------------
    def phase(self, event: PhaseChange) -> None:
        text = f"Inspection: {event.source} -> {event.target}"
        if event.reason:
            text += f" ({event.reason})"
        self.statustext(text, PHASE_SEVERITY.get(event.target, M.MAV_SEVERITY_INFO))

    def insulator_found(self, event: InsulatorFound) -> None:
        lat, lon, alt = event.wgs84
        self.statustext(f"Insulator {event.insulator_id} found ({event.outcome}): {lat:.6f} {lon:.6f} "
                        f"{alt:.1f} m", M.MAV_SEVERITY_NOTICE)

    def photo_taken(self, event: PhotoTaken) -> None:
        self.images.append(event)
        self._image_captured(event)
        self.statustext(f"Photo {event.index}: insulator {event.insulator_id}, {event.file}", M.MAV_SEVERITY_INFO)

    def aborted(self, time_s: float, reason: str) -> None:
        self.statustext(f"Inspection aborted: {reason}", M.MAV_SEVERITY_CRITICAL)

    def handed_over(self, time_s: float, reason: str) -> None:
        self.statustext(f"HOLD, take over: {reason}", M.MAV_SEVERITY_ALERT)

    def preflight_failed(self, time_s: float, failed: list[tuple[str, str]]) -> None:
        for name, reason in failed:  # one each, as PX4's own "Preflight Fail: ..."
            self.statustext(f"Preflight Fail: {name}: {reason}", M.MAV_SEVERITY_CRITICAL)

    def message(self, time_s: float, text: str) -> None:
        # the console's progress lines (the events above come as their own STATUSTEXT too)
        self.statustext(text, M.MAV_SEVERITY_DEBUG)

    # -- sending --------------------------------------------------------------------------------
    def _write(self, buf: bytes) -> None:
        self._queue.put(bytes(buf))  # the flight never waits for the link

    def _send_loop(self) -> None:
        while True:
            buf = self._queue.get()
            if buf is None:
                return
            try:
                self._send_bytes(buf)
            except Exception:  # noqa: BLE001  (an observer must not raise: the flight does not wait)
                self.send_errors += 1
            time.sleep(SEND_INTERVAL_S)

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until everything queued has been sent (True) or ``timeout`` s passed."""
        deadline = time.monotonic() + timeout
        while not self._queue.empty() and time.monotonic() < deadline:
            time.sleep(SEND_INTERVAL_S)
        time.sleep(SEND_INTERVAL_S)
        return self._queue.empty()

    def _emit(self, mav: Any, name: str, *args: Any) -> None:
        with self._lock:
            try:
                getattr(mav, f"{name}_send")(*args)
            except Exception:  # noqa: BLE001  (a bad value must not stop the flight either)
                self.send_errors += 1
                return
            key = name.upper()
            self.sent[key] = self.sent.get(key, 0) + 1

    def _boot_ms(self) -> int:
        return int((time.monotonic() - self._t0) * 1000) & 0xFFFFFFFF

    def statustext(self, text: str, severity: int = M.MAV_SEVERITY_INFO) -> None:
        """One STATUSTEXT, or several chunks of 50 characters sharing an ``id`` (MAVLink 2)."""
        raw = _ascii(text).encode("ascii")
        if len(raw) <= STATUSTEXT_LEN:
            self._emit(self._companion, "statustext", severity, raw, 0, 0)
            return
        self._text_id = self._text_id % 0xFFFF + 1
        chunks = [raw[i:i + STATUSTEXT_LEN] for i in range(0, len(raw), STATUSTEXT_LEN)]
        if len(chunks[-1]) == STATUSTEXT_LEN:
            chunks.append(b"")  # the end is a chunk shorter than 50 (here: empty)
        for seq, chunk in enumerate(chunks):
            self._emit(self._companion, "statustext", severity, chunk, self._text_id, seq)

    def _heartbeat(self) -> None:
        self._emit(self._camera, "heartbeat", M.MAV_TYPE_CAMERA, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)

    def _heartbeat_loop(self) -> None:
        while not self._stop.wait(HEARTBEAT_PERIOD_S):
            self._heartbeat()

    def send_camera_information(self) -> None:
        c = self.camera
        self._emit(self._camera, "camera_information", self._boot_ms(), name32(c.vendor), name32(c.model),
                   c.firmware_version, float(c.focal_length_mm), float(c.sensor_width_mm),
                   float(c.sensor_height_mm), int(c.width_px), int(c.height_px), 0,
                   M.CAMERA_CAP_FLAGS_CAPTURE_IMAGE, 0, b"")

    def _image_captured(self, event: PhotoTaken) -> None:
        lat, lon, alt = event.wgs84
        url = (self.file_url_prefix + event.file).encode("utf-8")
        if len(url) > FILE_URL_LEN:  # a cut URL names nothing: the path in the report folder then
            url = event.file.encode("utf-8")[:FILE_URL_LEN]
        rel_alt = float(event.position[2]) if len(event.position) > 2 else 0.0
        self._emit(self._camera, "camera_image_captured", self._boot_ms(), int(event.time_utc * 1e6), 0,
                   int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
                   int(round(rel_alt * 1000)), camera_quaternion(event.yaw, event.gimbal_pitch),
                   event.index - 1, 1, url)

    # -- receiving (commands PX4 forwards to our components) ------------------------------------
    def on_abort_command(self, handler: Callable[[], bool] | None) -> None:
        """Who takes the ground station's abort: ``handler()`` asks the flight for it and says
        whether it was taken (None: nobody; the command is then refused)."""
        self._abort_handler = handler

    def handle_message(self, msg: Any) -> None:
        """A message from the ground station (forwarded by the autopilot): answer the camera
        requests addressed to our camera and the abort addressed to the companion; everything
        else is ignored. Never raises."""
        try:
            if msg.get_type() not in ("COMMAND_LONG", "COMMAND_INT") or msg.target_system != self.system_id:
                return
            if msg.target_component == CAMERA_COMPONENT:
                self._command(msg)
            elif msg.target_component == COMPANION_COMPONENT:
                self._companion_command(msg)
        except Exception:  # noqa: BLE001
            self.send_errors += 1

    def _companion_command(self, msg: Any) -> None:
        """A command to the companion: the operator's abort, or UNSUPPORTED."""
        if msg.command != ABORT_COMMAND:
            self._ack(msg, M.MAV_RESULT_UNSUPPORTED, self._companion)
            return
        handler = self._abort_handler
        # not the abort's param1 (another tool's user command), or no flight to abort: refused
        if msg.param1 != ABORT_PARAM1 or handler is None:
            self._ack(msg, M.MAV_RESULT_DENIED, self._companion)
            return
        if handler():
            self._ack(msg, M.MAV_RESULT_ACCEPTED, self._companion)
            self.statustext(ABORT_ANNOUNCEMENT, M.MAV_SEVERITY_CRITICAL)
        else:
            self._ack(msg, M.MAV_RESULT_TEMPORARILY_REJECTED, self._companion)
            self.statustext(ABORT_REFUSED, M.MAV_SEVERITY_WARNING)

    def _requested_images(self, first: float, last: float) -> range:
        """The image indices a MAV_CMD_REQUEST_MESSAGE(CAMERA_IMAGE_CAPTURED) asks for, as the
        message's definition says: param2 the first (-1: every image), param3 0 that one only,
        -1 it and all after it, else the last of the range. Empty when none of them exists."""
        n = len(self.images)
        if not (math.isfinite(first) and math.isfinite(last)):
            return range(0)
        first_i, last_i = int(first), int(last)
        if first_i == -1:
            return range(n)
        if first_i < 0 or first_i >= n:
            return range(0)
        if last_i == 0:
            return range(first_i, first_i + 1)
        if last_i == -1:
            return range(first_i, n)
        return range(first_i, min(last_i, n - 1) + 1) if last_i >= first_i else range(0)

    def _ack(self, msg: Any, result: int, component: Any = None) -> None:
        """COMMAND_ACK from ``component`` (our camera's MAVLink by default) to the command's sender."""
        self._emit(self._camera if component is None else component, "command_ack", msg.command, result, 0, 0, msg.get_srcSystem(),
                   msg.get_srcComponent())

    def _command(self, msg: Any) -> None:
        cmd = msg.command
        if cmd == M.MAV_CMD_REQUEST_CAMERA_INFORMATION:
            self._ack(msg, M.MAV_RESULT_ACCEPTED)
            self.send_camera_information()
            return
        if cmd != M.MAV_CMD_REQUEST_MESSAGE:
            self._ack(msg, M.MAV_RESULT_UNSUPPORTED)
            return
        wanted = int(msg.param1)
        if wanted == M.MAVLINK_MSG_ID_CAMERA_INFORMATION:
            self._ack(msg, M.MAV_RESULT_ACCEPTED)
            self.send_camera_information()
        elif wanted == M.MAVLINK_MSG_ID_CAMERA_SETTINGS:
            self._ack(msg, M.MAV_RESULT_ACCEPTED)
            self._emit(self._camera, "camera_settings", self._boot_ms(), M.CAMERA_MODE_IMAGE, math.nan, math.nan)
        elif wanted == M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS:
            self._ack(msg, M.MAV_RESULT_ACCEPTED)
            self._emit(self._camera, "camera_capture_status", self._boot_ms(), 0, 0, 0.0, 0, math.nan,
                       len(self.images))
        elif wanted == M.MAVLINK_MSG_ID_STORAGE_INFORMATION:
            self._ack(msg, M.MAV_RESULT_ACCEPTED)
            self._emit(self._camera, "storage_information", self._boot_ms(), 1, 1, M.STORAGE_STATUS_NOT_SUPPORTED,
                       0.0, 0.0, 0.0, 0.0, 0.0)
        elif wanted == M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED:
            indices = self._requested_images(msg.param2, msg.param3)
            if indices:
                self._ack(msg, M.MAV_RESULT_ACCEPTED)
                for index in indices:
                    self._image_captured(self.images[index])
            else:
                self._ack(msg, M.MAV_RESULT_DENIED)
        else:
            self._ack(msg, M.MAV_RESULT_UNSUPPORTED)
