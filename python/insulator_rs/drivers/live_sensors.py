"""The live ``Sensors`` adapter: a Livox Mid-360 and a camera (OpenCV or GStreamer) behind one port.

Either may be absent (a LiDAR-only or camera-only rig): its methods then return None.
Where the rig's inspection camera is a MAVLink payload (``[inspection_camera] payload``), ``photo``
is one shot of it (:class:`LiveSensors`); otherwise the camera is fixed to the airframe (no gimbal
is commanded from here), so ``photo`` returns the newest frame with the camera's own ``T_b_c``,
whatever pose was asked for; the flight loop must aim the vehicle (yaw) for an inspection photo.

``lidar_scan(now)`` returns every complete scan the driver finished since the last call, merged
into one (None when there is none): a caller that polls slower than the sensor's 10 Hz (a flight
loop busy with a detection, on a loaded computer) still gets every point, once. The driver keeps
the last ``LIDAR_KEEP_SCANS`` (3 s) for a caller that stalls longer. Measured against PX4 SITL on
a loaded two-core box: with the newest scan alone, 60 of 152 detection frames had no LiDAR
point within their +-100 ms; handing the last 10 scans merged on every call (as this did before)
cost a concatenation of 1 s of points per control tick and recorded every point ten times.
"""

from __future__ import annotations

import math
import socket
from collections.abc import Callable
from concurrent.futures import TimeoutError as FutureTimeout

import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs.drivers.camera_select import open_camera
from insulator_rs.drivers.camera_source import CameraSource
from insulator_rs.drivers.livox import HOST_PORT_IMU, HOST_PORT_POINT, LivoxMid360, TimeMap, parse_url
from insulator_rs.exceptions import SensorError
from insulator_rs.inspection_camera import InspectionCamera, mean_focal
from insulator_rs.poses import yaw_of
from insulator_rs.ports.payload import Payload, ShotRequest, ShotResult
from insulator_rs.ports.sensors import CameraFrame, LidarScan, StreamStatus
from insulator_rs.ports.vehicle import wrap_angle

#: Scans the Mid-360 driver keeps for ``lidar_scan`` (3 s at 10 Hz: perception's PAIRING_WAIT,
#: 2 s, is how late a scan may come and still be paired).
LIDAR_KEEP_SCANS = 30


def merge_scans(scans: list[LidarScan]) -> LidarScan | None:
    """Consecutive scans of one sensor as one (points and times concatenated, in order; the
    window covered up to the newest one's, which an empty scan may hold alone)."""
    if not scans:
        return None
    if len(scans) == 1:
        return scans[0]
    intensity = (None if any(s.intensity is None for s in scans)
                 else np.concatenate([np.asarray(s.intensity) for s in scans]))
    windows = [s.covered_until for s in scans if np.isfinite(s.covered_until)]
    return LidarScan(np.concatenate([np.asarray(s.points_l) for s in scans]),
                     np.concatenate([np.asarray(s.times) for s in scans]), scans[-1].T_b_l, intensity,
                     window_end=max(windows) if windows else None)


#: s the flight loop waits at most for one shot of a payload (every attempt's slew, zoom, capture and
#: download together: the adapter's own bounds end it sooner); the vehicle's setpoints stream from
#: the MAVLink client's thread meanwhile, so the autopilot holds the waypoint
PAYLOAD_SHOT_WAIT_S = 60.0


class LiveSensors:
    """``Sensors`` over live drivers (already started), and the inspection photos through a payload.

    ``payload`` (a :class:`~insulator_rs.ports.payload.Payload`: the rig's MAVLink gimbal-and-zoom
    camera), with the rig's ``inspection`` camera and ``pose()`` (the vehicle's T_w_b now): each
    :meth:`photo` is one shot of the payload, aimed where the asked ``T_b_c`` looks (pitch from the
    horizon, yaw from the heading: the mount looks along the body's x at zero gimbal angles, the
    rig's default), zoomed to the asked intrinsics' focal length. The photo's attitude and time are
    the capture message's; its position the mount's on the body. Every shot's attempts and faults
    are kept (``shots``) for the report. Without a payload the photo is the detection frame."""

    def __init__(self, lidar: LivoxMid360 | None, camera: CameraSource | None, *, payload: Payload | None = None,
                 inspection: InspectionCamera | None = None, pose: Callable[[], np.ndarray] | None = None,
                 shot_wait_s: float = PAYLOAD_SHOT_WAIT_S) -> None:
        if lidar is None and camera is None and payload is None:
            raise ValueError("LiveSensors: need a LiDAR, a camera, a payload, or more")
        if payload is not None and (inspection is None or pose is None):
            raise ValueError("LiveSensors: payload: needs the rig's inspection camera and the vehicle's pose")
        self.lidar = lidar
        self.camera = camera
        self.payload = payload
        self.inspection = inspection
        self.pose = pose
        self.shot_wait_s = shot_wait_s
        self.shots: list[ShotResult] = []
        self.shots_late = 0  # shots not ended within shot_wait_s (their photo is dropped)
        self._failure: str | None = None  # why the newest photo() gave no frame
        self._handed_until = -np.inf  # vehicle time: the end of the newest scan handed over

    @property
    def name(self) -> str:
        """The drivers in words (the report's sensors row): ``live: Livox Mid-360, camera <source>``."""
        parts = ([] if self.lidar is None else ["Livox Mid-360"]) + \
                ([] if self.camera is None else [f"camera {self.camera.source}"])
        return "live: " + ", ".join(parts)

    def detection_frame(self, now: float) -> CameraFrame | None:
        return None if self.camera is None else self.camera.latest(now)

    def lidar_scan(self, now: float) -> LidarScan | None:
        if self.lidar is None:
            return None
        new = [scan for scan in self.lidar.scans_until(now) if scan.covered_until > self._handed_until]
        if new:
            self._handed_until = new[-1].covered_until
        return merge_scans(new)

    def photo(self, now: float, T_b_c: np.ndarray, camera: CameraModel | None = None) -> CameraFrame | None:
        if self.payload is None or self.inspection is None or self.pose is None:
            return self.detection_frame(now)  # no payload: the detection camera's frame (its own intrinsics)
        T_w_b = np.asarray(self.pose(), dtype=np.float64)
        axis = T_w_b[:3, :3] @ np.asarray(T_b_c, dtype=np.float64)[:3, 2]  # the asked optical axis in W
        pitch = math.asin(max(-1.0, min(1.0, float(axis[2]) / float(np.linalg.norm(axis)))))
        yaw = wrap_angle(math.atan2(axis[1], axis[0]) - yaw_of(T_w_b))
        focal = self.inspection.focal_px[0] if camera is None else mean_focal(camera)
        future = self.payload.submit(ShotRequest(pitch, yaw, focal))
        try:
            result = future.result(timeout=self.shot_wait_s)
        except FutureTimeout:
            self.shots_late += 1
            self._failure = f"payload: the shot did not end within {self.shot_wait_s:g} s"
            return None
        self.shots.append(result)
        photo = result.photo
        self._failure = None if photo is not None else shot_failure(result)
        if photo is None:
            return None
        T_w_c = np.eye(4)
        T_w_c[:3, :3] = photo.R_w_c
        T_w_c[:3, 3] = (T_w_b @ self.inspection.T_b_c)[:3, 3]
        return CameraFrame(photo.time, photo.image, photo.camera, np.linalg.inv(T_w_b) @ T_w_c)

    def photo_failure(self) -> str | None:
        """Why the newest :meth:`photo` of the payload gave no frame (each attempt's fault), None
        when it gave one."""
        return self._failure

    def streams(self, now: float) -> list[StreamStatus]:
        """What each driver has received and stamped up to ``now`` (nothing is consumed); the
        payload's: the photos it gave, and whether it answers now (its heartbeats)."""
        out = []
        if self.camera is not None:
            out.append(camera_stream(self.camera, now))
        if self.lidar is not None:
            out.append(lidar_stream(self.lidar, now))
        if self.payload is not None:
            alive = self.payload.alive()
            photos = sum(1 for shot in self.shots if shot.photo is not None)
            out.append(StreamStatus("payload", photos, now if alive else None,
                                    error=None if alive else "no HEARTBEAT of its camera and gimbal"))
        return out

    def health(self) -> dict[str, object]:
        out: dict[str, object] = {}
        if self.payload is not None:
            out.update({f"payload_{k}": v for k, v in self.payload.health().items()})
            out["payload_shots_late"] = self.shots_late
        if self.lidar is not None:
            out.update({f"lidar_{k}": v for k, v in self.lidar.health().items()})
        if self.camera is not None:
            out.update(self.camera.health())
        return out

    def close(self) -> None:
        if self.lidar is not None:
            self.lidar.close()
        if self.camera is not None:
            self.camera.close()
        if self.payload is not None:
            self.payload.close()


def shot_failure(result: ShotResult) -> str:
    """A failed shot in words for the report: ``payload: <fault> (attempt 1), ...``, each attempt's
    fault by its :class:`~insulator_rs.ports.payload.PayloadFault` name."""
    faults = ", ".join(f"{a.fault.value} (attempt {a.attempt})" for a in result.attempts if a.fault is not None)
    return f"payload: {faults or 'no photo'}"


def camera_stream(camera: CameraSource, now: float) -> StreamStatus:
    """A camera driver's stream at ``now``: frames kept, the newest stamp, frames left unstamped."""
    frame = camera.latest(now)
    return StreamStatus("camera", camera.frames, None if frame is None else frame.time, camera.unstamped,
                        "the camera source ended" if camera.ended else None)


def lidar_stream(lidar: LivoxMid360, now: float) -> StreamStatus:
    """A Mid-360 driver's stream at ``now``: complete scans kept, the newest scan's end, scans
    left without a vehicle-clock stamp."""
    scans = lidar.scans_until(now)
    return StreamStatus("lidar", len(scans), scans[-1].covered_until if scans else None,
                        lidar.unstamped + lidar.unmapped_scans)


def local_address_towards(host: str, port: int = 56100) -> str:
    """The local IP the kernel would use to reach ``host`` (no packet is sent)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect((host, port))
        except OSError as err:
            raise SensorError(f"--lidar: no route to {host}: {err}") from err
        return str(s.getsockname()[0])


def open_live_sensors(lidar: str | None, camera: str | None, *, now: Callable[[], float],
                      T_b_l: np.ndarray, T_b_c: np.ndarray, camera_model: CameraModel | None,
                      time_map: TimeMap | None = None, camera_latency_s: float = 0.0,
                      lidar_latency_s: float = 0.0, host_clock: Callable[[], float] | None = None,
                      host_to_vehicle: TimeMap | None = None) -> LiveSensors:
    """Opens and starts the live drivers named on the command line.

    ``lidar``: ``mid360://HOST[:PORT]`` (HOST = the Mid-360's IP: it is configured to send
    to us and started; ``mid360://listen[:PORT]``: only listen on PORT, default 56301).
    ``camera``: a V4L2 index, a GStreamer pipeline (``gst:PIPELINE``, or any string with ``!``),
    a URL or a video file (see :mod:`insulator_rs.drivers.camera_select`); needs
    ``camera_model``. ``now``: the vehicle clock. ``camera_latency_s``: the rig's measured
    camera latency, subtracted where a frame's exposure time is not known. ``lidar_latency_s``:
    the rig's ``[lidar] latency_s`` (a packet's least delay after its last sample). ``host_clock``
    with ``host_to_vehicle``: the LiDAR's arrivals are stamped on the host's clock (a clock at
    real time, ``time.monotonic``'s or offset from it) as they arrive, and mapped to the vehicle
    clock afterwards (see :mod:`insulator_rs.drivers.livox`).
    """
    livox: LivoxMid360 | None = None
    cam: CameraSource | None = None
    try:
        if lidar:
            host, port = parse_url(lidar)
            listen_only = host in ("", "listen")
            livox = LivoxMid360(
                now=now if host_clock is None else host_clock, to_vehicle=host_to_vehicle, T_b_l=T_b_l,
                point_port=HOST_PORT_POINT if port is None else port,
                # port 0 (any free one) for the points: the IMU's too, not the fixed 56401 another
                # listener may hold (a LiDAR told where to send asks for both)
                imu_port=0 if port == 0 else HOST_PORT_IMU,
                lidar_ip=None if listen_only else host,
                announce_ip=None if listen_only else local_address_towards(host),
                time_map=time_map, keep_scans=LIDAR_KEEP_SCANS,
                # the host's clock runs at real time: each datagram keeps its arrival instant
                arrival_stamps=host_clock is not None, latency_s=lidar_latency_s,
            ).start()
        if camera is not None:
            if camera_model is None:
                raise SensorError("--camera: the camera's intrinsics (camera model) are needed")
            cam = open_camera(camera, camera=camera_model, T_b_c=T_b_c, now=now, latency_s=camera_latency_s)
        return LiveSensors(livox, cam)
    except BaseException:
        if livox is not None:
            livox.close()
        if cam is not None:
            cam.close()
        raise
