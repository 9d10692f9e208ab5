"""A sensor head for SITL flights: the Mid-360 and the camera a real airframe carries, played
by the simulator from the autopilot's own pose estimate, in a process of its own.

Run beside PX4 SITL and ``insulator-rs inspect --connection ... --lidar mid360://listen:PORT
--camera http://127.0.0.1:CPORT/stream.mjpg``; the client's live drivers read it as they
read real sensors, and it reads nothing of the client:

* pose: PX4's GCS MAVLink link (UDP 18570 + instance; PX4 answers the address that talks to
  it): LOCAL_POSITION_NED and ATTITUDE at 50 Hz, and HOME_POSITION, which puts PX4's local
  frame in W (ENU, origin at the tower base, as the client puts it); poses between samples
  are interpolated, past the newest one carried along its velocity and yaw rate;
* clock: PX4's ``time_boot_ms`` (the vehicle clock), carried to "now" from the host clock by
  a :class:`~insulator_rs.timesync.TelemetryClock`;
* LiDAR: a :class:`~insulator_rs.sim.livox_wire.LidarStream` (10 Hz scan windows, encoded as
  Livox SDK2 datagrams on a sensor clock with its own offset and drift) sent on UDP to the
  driver as the stream's arrival times come round on the vehicle clock; the shots are
  rendered in 20 ms slices once each is over, at PX4's pose of those instants (rendered
  ahead, a 100 ms frame carried PX4's pose forward too far: up to 1 m off the tower at 10 m
  while PX4 turned);
* camera: frames rendered at the rig's calibration, at the pose of the instant they will be
  published (the render time is predicted), JPEG-encoded and served as an MJPEG stream
  (``multipart/x-mixed-replace``, what IP cameras serve and OpenCV's FFmpeg backend reads).

The body is rendered at PX4's full attitude (roll, pitch and heading: what a rigidly mounted
sensor sees), always: the flight's pose model is full attitude too (ATTITUDE_QUATERNION).

Not part of the onboard package's dependency graph: nothing onboard imports this.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import socket
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from insulator_rs.exceptions import InsulatorError
from insulator_rs.mavlink.frames import attitude_ned_frd_to_enu_flu, ned_to_enu, yaw_enu_to_ned, yaw_ned_to_enu
from insulator_rs.poses import interpolate_poses
from insulator_rs.rig import MAX_LIDAR_LATENCY_S  # what the rig's [lidar] latency_s may state
from insulator_rs.sim.livox_emitter import SensorClock, send
from insulator_rs.sim.livox_wire import LidarStream
from insulator_rs.sim.sensors import resting_on
from insulator_rs.sim.towers import GROUND_Z
from insulator_rs.timesync import TelemetryClock

#: s: a camera image whose render missed its publication instant by more than this is dropped.
CAMERA_LATE_S = 0.015
#: s: the camera's latency, exposure to publication, held fixed as a real camera's is: an image
#: is rendered at PX4's newest pose (known, not extrapolated) and published this long after it.
#: It is the ``[camera] latency_s`` a calibration of this camera gives (the live SITL rig says so).
#: It covers the render's p90 on a loaded 2-core box (320 x 240: 60-180 ms).
CAMERA_LATENCY_S = 0.25
#: PX4 SITL's GCS link listens on this UDP port + instance.
PX4_GCS_PORT = 18570
#: Pose samples kept (s of 50 Hz telemetry).
HISTORY = 500
#: s of a stall of the head's LiDAR thread rendered and sent late rather than dropped: within
#: the pose feed's HISTORY of PX4 poses (500 at ~50 Hz: 10 s)
LIDAR_CATCH_UP_S = 8.0
#: LiDAR shots are rendered in slices of 1/this s, each once it is over.
LIDAR_SLICE_RATE = 50.0
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MSG_LOCAL_POSITION_NED, MSG_ATTITUDE, MSG_HOME_POSITION = 32, 30, 242


def _body_rotation(yaw_enu: float, roll: float, pitch: float) -> np.ndarray:
    """R_w_b (ENU world, FLU body) from PX4's roll, pitch and heading."""
    return attitude_ned_frd_to_enu_flu(roll, pitch, yaw_enu_to_ned(yaw_enu))


def _around(samples: deque[Any], t: float) -> list[Any]:
    """The two samples (time first) around ``t``, or the one to carry: the newest when ``t`` is
    past it, the oldest when before it."""
    if t >= samples[-1][0]:
        return [samples[-1]]
    if t < samples[0][0]:
        return [samples[0]]
    i = len(samples) - 2
    while samples[i][0] > t:
        i -= 1
    return [samples[i], samples[i + 1]]


def _between(ta: float, tb: float, pa: np.ndarray, pb: np.ndarray, Ra: np.ndarray, Rb: np.ndarray,
             t: float) -> np.ndarray:
    """The pose at ``t`` between two samples, as poses.py interpolates every pose."""
    Ta, Tb = np.eye(4), np.eye(4)
    Ta[:3, :3], Ta[:3, 3] = Ra, pa
    Tb[:3, :3], Tb[:3, 3] = Rb, pb
    return interpolate_poses(np.array([ta, tb]), np.stack([Ta, Tb]), np.array([t]))[0]


#: A crystal's stamps are continuous: the head's map of PX4 time to host time is refitted as
#: telemetry comes, and its corrections are slewed in at most this rate (s per s). Applied at
#: once, a refit's step of a millisecond read as two lost datagrams per ms (the driver counts a
#: gap in the stamps as loss): 2 and 7 in two SITL flights.
CRYSTAL_SLEW = 1e-3


@dataclass(frozen=True)
class HostCrystalClock(SensorClock):
    """The LiDAR's clock as a real one runs: its own crystal against the host's (``sensor =
    (1 + drift) * host + offset``), not against PX4's clock, which in SITL's lockstep stops
    whenever a loaded box starves it. Shots are rendered at PX4's times and stamped at the
    host instants the head's clock map gives them (``telemetry``), carried along the map's
    rate and corrected at most :data:`CRYSTAL_SLEW` s per s (continuous stamps)."""

    telemetry: TelemetryClock | None = None
    _last: list[float] = field(default_factory=list)  # the newest (vehicle, host) stamped

    def _clock(self) -> TelemetryClock:
        if self.telemetry is None:
            raise InsulatorError("HostCrystalClock: no telemetry clock")
        return self.telemetry

    def _host(self, t_vehicle: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t_vehicle, np.float64)
        target = self._clock().to_host(t)
        if not self._last:
            self._last[:] = [float(np.max(t)), float(np.max(target))]
            return target
        tv0, h0 = self._last
        rate = 1.0 + self._clock().sync.fit.drift  # host s per vehicle s
        predicted = h0 + (t - tv0) * rate
        room = CRYSTAL_SLEW * np.abs(t - tv0)
        host = predicted + np.clip(target - predicted, -room, room)
        k = int(np.argmax(t))
        if float(np.ravel(t)[k]) > tv0:
            self._last[:] = [float(np.ravel(t)[k]), float(np.ravel(host)[k])]
        return host

    def sensor_ns(self, t_vehicle: float | np.ndarray) -> np.ndarray:
        return super().sensor_ns(self._host(t_vehicle))

    def to_vehicle(self, sensor_s: float | np.ndarray) -> np.ndarray:
        return self._clock().to_vehicle(super().to_vehicle(sensor_s))


class Px4PoseFeed:
    """PX4's pose estimate in W from its GCS link (see the module docstring).

    ``origin``: W's origin (lat, lon deg, alt m AMSL): the mission's tower base."""

    def __init__(self, connection: str, origin: tuple[float, float, float]) -> None:
        from pymavlink import mavutil

        self.origin = origin
        # component id of a camera (100): a payload, not a second ground station
        self.link = mavutil.mavlink_connection(connection, source_system=1, source_component=100)
        self._lock = threading.Lock()
        self._pos: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=HISTORY)  # t, p_w, v_w
        self._att: deque[tuple[float, float, float, float, float]] = deque(maxlen=HISTORY)  # t, yaw_enu, roll, pitch, rate
        self.local_origin_w: np.ndarray | None = None
        self.messages = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="px4-pose-feed", daemon=True)

    def start(self) -> Px4PoseFeed:
        self._thread.start()
        return self

    def _request(self) -> None:
        """Targeted commands (PX4 does not forward them to its other links): the streams, home."""
        mav = self.link.mav
        for msg_id in (MSG_LOCAL_POSITION_NED, MSG_ATTITUDE):
            mav.command_long_send(1, 1, MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 20_000, 0, 0, 0, 0, 0)
        mav.command_long_send(1, 1, MAV_CMD_REQUEST_MESSAGE, 0, MSG_HOME_POSITION, 0, 0, 0, 0, 0, 0)

    def _run(self) -> None:
        next_request = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_request and (self.local_origin_w is None or not self._pos):
                self._request()
                next_request = time.monotonic() + 1.0
            msg = self.link.recv_match(type=["LOCAL_POSITION_NED", "ATTITUDE", "HOME_POSITION"], blocking=True,
                                       timeout=0.1)
            if msg is None:
                continue
            self.messages += 1
            kind = msg.get_type()
            if kind == "HOME_POSITION":
                self._home(msg)
            elif kind == "LOCAL_POSITION_NED":
                p = ned_to_enu([msg.x, msg.y, msg.z])
                v = ned_to_enu([msg.vx, msg.vy, msg.vz])
                with self._lock:
                    if not self._pos or msg.time_boot_ms / 1e3 > self._pos[-1][0]:
                        self._pos.append((msg.time_boot_ms / 1e3, p, v))
            else:
                with self._lock:
                    if not self._att or msg.time_boot_ms / 1e3 > self._att[-1][0]:
                        self._att.append((msg.time_boot_ms / 1e3, yaw_ned_to_enu(msg.yaw), msg.roll, msg.pitch,
                                          -msg.yawspeed))

    def _home(self, msg: Any) -> None:
        import pymap3d

        home_w = np.array(pymap3d.geodetic2enu(msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3,
                                               *self.origin))
        self.local_origin_w = home_w - ned_to_enu([msg.x, msg.y, msg.z])

    def ready(self) -> bool:
        return self.local_origin_w is not None and bool(self._pos) and bool(self._att)

    def newest_time(self) -> float:
        """PX4's time of the newest position sample (s): the vehicle clock."""
        with self._lock:
            if not self._pos:
                raise InsulatorError("no LOCAL_POSITION_NED from PX4 yet")
            return self._pos[-1][0]

    def pose(self, t: float) -> np.ndarray:
        """T_w_b at vehicle time ``t`` (called for every LiDAR slice and camera image: the
        samples around ``t`` are found from the newest end, where ``t`` almost always is)."""
        with self._lock:
            origin = self.local_origin_w
            if origin is None or not self._pos or not self._att:
                raise InsulatorError("no pose from PX4 yet")
            pos = _around(self._pos, t)
            att = _around(self._att, t)
        T = np.eye(4)
        T[:3, 3] = origin + self._position(pos, t)
        T[:3, :3] = self._rotation(att, t)
        return T

    @staticmethod
    def _position(pos: list[Any], t: float) -> np.ndarray:
        if len(pos) == 1:  # before the first sample or past the newest: along its velocity
            t0, p0, v0 = pos[0]
            return p0 + v0 * (t - t0)
        (ta, pa, _), (tb, pb, _) = pos
        return _between(ta, tb, pa, pb, np.eye(3), np.eye(3), t)[:3, 3]

    def _rotation(self, att: list[Any], t: float) -> np.ndarray:
        if len(att) == 1:  # past the newest sample: carried along its yaw rate
            ta, yaw, roll, pitch, rate = att[0]
            return _body_rotation(yaw + rate * (t - ta), roll, pitch)
        (ta, ya, ra, pa, _), (tb, yb, rb, pb, _) = att
        Ra = _body_rotation(ya, ra, pa)
        Rb = _body_rotation(yb, rb, pb)
        return _between(ta, tb, np.zeros(3), np.zeros(3), Ra, Rb, t)[:3, :3]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.link.close()


class MjpegServer:
    """Serves the newest JPEG as ``multipart/x-mixed-replace`` on every path, to every client."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0) -> None:
        self._cond = threading.Condition()
        self._jpeg: bytes | None = None
        self._seq = 0
        self._stop = threading.Event()
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 (http.server's name)
                self.send_response(200)
                self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
                self.send_header("Cache-Control", "no-cache")
                self.end_headers()
                seen = 0
                try:
                    while not server._stop.is_set():
                        with server._cond:
                            server._cond.wait_for(lambda: server._seq != seen or server._stop.is_set(), timeout=1.0)
                            seen, jpeg = server._seq, server._jpeg
                        if jpeg is None or server._stop.is_set():
                            continue
                        self.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: %d\r\n\r\n"
                                         % len(jpeg) + jpeg + b"\r\n")
                        self.wfile.flush()
                except (BrokenPipeError, ConnectionResetError):
                    return

            def log_message(self, *args: object) -> None:
                return

        self.httpd = ThreadingHTTPServer((host, port), Handler)
        self.httpd.daemon_threads = True
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="mjpeg-server", daemon=True)

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host!s}:{port}/stream.mjpg"  # an IPv4 server: host is a str

    def start(self) -> MjpegServer:
        self._thread.start()
        return self

    def publish(self, jpeg: bytes) -> None:
        with self._cond:
            self._jpeg, self._seq = jpeg, self._seq + 1
            self._cond.notify_all()

    def close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self.httpd.shutdown()
        self.httpd.server_close()


class LatencyQueue:
    """Chunks of datagrams held until ``latency_s`` past their arrival time (vehicle clock, the
    chunk's last sample + the stream's own latency), as a sensor whose packets leave at a fixed
    delay after their samples sends them.

    Why: the head can render a slice of shots only once PX4 has reported the poses of its
    instants, so its packets cannot leave as a real Mid-360's do, within a millisecond of the
    samples. Sent as soon as rendered, they left a render time late, and that time follows the
    load (the LiDAR driver's clock fit reads the least delay of each quarter second as its floor,
    so a floor that moves by 20 ms in a 150 s flight reads as 130 ppm of drift). Held to a fixed
    delay longer than a render, they leave on time whatever the render took, and the rig states
    the delay (``[lidar] latency_s``) for the driver to take off."""

    def __init__(self, latency_s: float) -> None:
        if not (math.isfinite(latency_s) and 0.0 <= latency_s <= MAX_LIDAR_LATENCY_S):
            raise ValueError(f"latency_s: must be in [0, {MAX_LIDAR_LATENCY_S:g}] s, got {latency_s}")
        self.latency_s = float(latency_s)
        self._chunks: deque[tuple[float, list[bytes]]] = deque()

    def add(self, chunks: list[tuple[float, list[bytes]]]) -> None:
        """Queues ``(arrival, datagrams)`` chunks, in arrival order (as the stream hands them)."""
        self._chunks.extend(chunks)

    def due(self, now: float) -> list[tuple[float, list[bytes]]]:
        """The chunks whose time to leave (arrival + latency) has come by ``now``, oldest first."""
        out = []
        while self._chunks and self._chunks[0][0] + self.latency_s <= now:
            out.append(self._chunks.popleft())
        return out

    def next_due(self) -> float | None:
        """When the oldest queued chunk is to leave (vehicle clock); None when none waits."""
        return self._chunks[0][0] + self.latency_s if self._chunks else None

    def __len__(self) -> int:
        return len(self._chunks)


class SensorHead:
    """The LiDAR and camera threads over one pose feed and clock (see the module docstring)."""

    def __init__(self, mesh: Any, rig: Any, feed: Px4PoseFeed, *, lidar_to: tuple[str, int],
                 camera_port: int = 0, fps: float = 3.0, sensor_clock: SensorClock | None = None,
                 seed: int = 0, log: Any = None, lidar_latency_s: float = 0.0) -> None:
        from insulator_rs.sim.camera_render import Camera

        self.feed = feed
        self.clock = TelemetryClock(feed.newest_time)
        sensor_clock = sensor_clock or SensorClock()
        sensor_clock = HostCrystalClock(offset_s=sensor_clock.offset_s, drift=sensor_clock.drift, telemetry=self.clock)
        # 20 ms slices rendered once over: PX4's pose of the past, interpolated (at most a
        # telemetry period carried forward), sent a render time late. This thread calls
        # continuously, so a gap between its calls is the head's own stall on a loaded box
        # (head logs of three soak flights: 1-3 s, 3-18 times a flight), not a silent sensor.
        # Restarted after 2 s, as the in-process stream is, the stall left a hole of 2-3 s in
        # the scans (the receiver's resyncs: 5-58 a flight where frames went unpaired, 0 where
        # none did); a real Mid-360 sends on through the host's stalls, so the span is rendered
        # and sent late, up to LIDAR_CATCH_UP_S (past it the stream restarts, so a head that
        # cannot keep up falls behind by a bounded span, not for ever)
        self.pose = resting_on(feed.pose, GROUND_Z)  # the airframe stands on its gear
        self.stream = LidarStream(mesh, self.pose, rig.T_b_l, clock=sensor_clock, seed=seed, restart_span=0.0,
                                  slice_rate=LIDAR_SLICE_RATE, ahead=False, silence_s=LIDAR_CATCH_UP_S)
        # each chunk leaves lidar_latency_s after its arrival time (0: as soon as rendered)
        self.lidar_queue = LatencyQueue(lidar_latency_s)
        self.camera = Camera(rig.camera, rig.T_b_c)
        self.mesh = mesh
        self.lidar_to = lidar_to
        self.period = 1.0 / fps
        self.seed = seed
        self.server = MjpegServer(port=camera_port)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._lidar, name="head-lidar", daemon=True),
                         threading.Thread(target=self._camera, name="head-camera", daemon=True)]
        self.datagrams = 0
        self.images = 0
        self.camera_late = 0  # images dropped: their render missed the exposure instant
        self._log_lock = threading.Lock()  # the LiDAR and camera threads both log
        self.render_ms: deque[float] = deque(maxlen=50)
        self.errors: list[str] = []
        self.log = log  # a text file: one JSON line per camera image and per LiDAR send (timing)
        self.lidar_late_s: deque[float] = deque(maxlen=2000)  # how late each chunk went out (s)

    def _log(self, **record: object) -> None:
        if self.log is not None:
            with self._log_lock:
                self.log.write(json.dumps(record) + "\n")

    def start(self) -> SensorHead:
        self.clock.start()
        self.server.start()
        for t in self._threads:
            t.start()
        return self

    def _now(self) -> float | None:
        try:
            return self.clock.now()
        except InsulatorError:
            return None

    def _lidar(self) -> None:
        next_clock_log = 0.0
        while not self._stop.is_set():
            now = self._now()
            if now is None or not self.feed.ready():
                time.sleep(0.01)
                continue
            if self.log is not None and time.monotonic() >= next_clock_log:
                # PX4's clock against the host's: where lockstep under load stops PX4
                next_clock_log = time.monotonic() + 0.2
                self._log(kind="clock", host=time.monotonic(), px4=self.feed.newest_time(), estimate=now)
            try:
                self.lidar_queue.add(self.stream.due(now))  # renders the slices that have ended
                sent = self._now()  # after the render: what leaves now leaves this late
                for arrival, chunk in self.lidar_queue.due(sent if sent is not None else now):
                    self.datagrams += send(chunk, self._sock, self.lidar_to)
                    late = (sent if sent is not None else now) - arrival - self.lidar_queue.latency_s
                    self.lidar_late_s.append(late)
                    self._log(kind="lidar", arrival=arrival, sent=sent, host=time.monotonic())
            except (OSError, ValueError, InsulatorError) as exc:
                self._error(f"lidar: {exc}")
            wait = 0.002
            if (next_due := self.lidar_queue.next_due()) is not None and (now := self._now()) is not None:
                wait = min(wait, max(0.0, next_due - now))
            time.sleep(wait)

    def _camera(self) -> None:
        # An image is exposed at PX4's newest pose and published CAMERA_LATENCY_S later, as a real
        # camera's frames leave at a steady latency after exposure. Rendered (as before) at the
        # pose predicted for its publication instant, the image of a vehicle braking at a
        # waypoint was extrapolated along the velocity by the render time (0.1-0.5 s on a loaded
        # box): the string beside the climb came out 0.24-0.29 m low in the live soak.
        while not self._stop.is_set():
            now = self._now()
            if now is None or not self.feed.ready():
                time.sleep(0.01)
                continue
            t0 = time.monotonic()
            try:
                exposure = min(now, self.feed.newest_time())
                frame = self.camera.render(self.mesh, self.pose(exposure), seed=self.seed + self.images,
                                           time=exposure)
                ok, jpeg = cv2.imencode(".jpg", np.ascontiguousarray(frame.rgb[:, :, ::-1]),
                                        [cv2.IMWRITE_JPEG_QUALITY, 92])
            except (ValueError, InsulatorError, cv2.error) as exc:
                self._error(f"camera: {exc}")
                time.sleep(self.period)
                continue
            self.render_ms.append((time.monotonic() - t0) * 1e3)
            publish_at = exposure + CAMERA_LATENCY_S
            while (now := self._now()) is not None and now < publish_at and not self._stop.is_set():
                time.sleep(0.001)
            if now is not None and now - publish_at > CAMERA_LATE_S:
                # the render outlasted the camera's latency: dropped, not served late (served, its
                # arrival stamp would be off by the miss: measured up to 125 ms at p99 under load)
                self.camera_late += 1
                self._log(kind="camera_late", exposure=exposure, now=now)
            elif ok:
                self.server.publish(jpeg.tobytes())
                self.images += 1
                self._log(kind="camera", exposure=exposure, published=now, host=time.monotonic(),
                          mean=float(frame.rgb.mean()))
            self._stop.wait(max(0.0, self.period - (time.monotonic() - t0)))

    def _error(self, text: str) -> None:
        if len(self.errors) < 20:
            self.errors.append(text)
            print(f"sensor head: {text}", file=sys.stderr, flush=True)

    def stats(self) -> dict[str, object]:
        return {"lidar_frames": self.stream.frames, "lidar_stream_starts": self.stream.restarts,
                "datagrams": self.datagrams, "camera_images": self.images, "camera_late_dropped": self.camera_late,
                "camera_render_ms": round(float(np.mean(self.render_ms)), 1) if self.render_ms else None,
                "camera_render_p90_ms": round(float(np.percentile(self.render_ms, 90)), 1) if self.render_ms else None,
                "lidar_late_ms_p50_p99": [round(float(np.percentile(self.lidar_late_s, q)) * 1e3, 1) for q in (50, 99)]
                if self.lidar_late_s else None,
                "pose_messages": self.feed.messages, "errors": len(self.errors)}

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        self.server.close()
        self._sock.close()
        self.clock.close()


def main(argv: list[str] | None = None) -> int:
    """Play a Mid-360 and a camera for a SITL flight until SIGTERM/SIGINT (module docstring)."""
    from insulator_rs.mission.config import load_mission
    from insulator_rs.sim.towers import load_tower

    parser = argparse.ArgumentParser(prog="python -m insulator_rs.sim.sensor_head", description=main.__doc__)
    parser.add_argument("--scene", required=True, help="built-in scene name or scene TOML file")
    parser.add_argument("--mission", type=Path, required=True,
                        help="the mission file the client flies (its tower base is W's origin; its rig is worn)")
    parser.add_argument("--px4", required=True, help="PX4's GCS link, e.g. udpout:127.0.0.1:18571")
    parser.add_argument("--lidar-to", default="127.0.0.1:56301", help="HOST:PORT the driver listens on")
    parser.add_argument("--camera-port", type=int, default=0, help="MJPEG HTTP port (0: a free one, printed)")
    parser.add_argument("--fps", type=float, default=3.0, help="camera frames per second")
    parser.add_argument("--clock-offset", type=float, default=1234.5, help="LiDAR clock offset (s)")
    parser.add_argument("--clock-drift-ppm", type=float, default=25.0, help="LiDAR clock drift (ppm)")
    parser.add_argument("--lidar-latency", type=float, default=0.0,
                        help="s: each LiDAR packet leaves this long after its last sample (0: as soon as "
                             "rendered, a render time late); the client's rig states it as [lidar] latency_s")
    parser.add_argument("--log", type=Path, default=None, help="timing log (JSON lines) of every image and send")
    parser.add_argument("--ready-timeout", type=float, default=60.0, help="s to wait for PX4's pose")
    parser.add_argument("--payload-port", type=int, default=None,
                        help="also play the rig's inspection camera as a MAVLink gimbal-and-zoom payload "
                             "(insulator_rs.sim.payload) on this UDP port, at PX4's pose")
    args = parser.parse_args(argv)
    host, _, port = args.lidar_to.rpartition(":")
    if not host or not port.isdigit():
        parser.error(f"--lidar-to: expected HOST:PORT, got {args.lidar_to!r}")
    if not (math.isfinite(args.fps) and 0 < args.fps <= 30):
        parser.error(f"--fps: must be in (0, 30], got {args.fps}")
    if not (math.isfinite(args.lidar_latency) and 0.0 <= args.lidar_latency <= MAX_LIDAR_LATENCY_S):
        parser.error(f"--lidar-latency: must be in [0, {MAX_LIDAR_LATENCY_S:g}] s, got {args.lidar_latency}")
    tower = load_tower(args.scene)
    mission = load_mission(args.mission)
    rig = mission.sensor_rig()
    if args.payload_port is not None and rig.inspection is None:
        parser.error("--payload-port: the mission's rig has no [inspection_camera] to play")
    feed = Px4PoseFeed(args.px4, (mission.tower.lat, mission.tower.lon, mission.tower.alt)).start()
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    deadline = time.monotonic() + args.ready_timeout
    while not feed.ready():
        if stop.is_set() or time.monotonic() > deadline:
            feed.close()
            print(f"sensor head: no pose from PX4 on {args.px4} within {args.ready_timeout:g} s", file=sys.stderr)
            return 2
        time.sleep(0.05)
    log = args.log.open("w") if args.log is not None else None
    head = SensorHead(tower.mesh, rig, feed, lidar_to=(host, int(port)), camera_port=args.camera_port,
                      fps=args.fps, sensor_clock=SensorClock(offset_s=args.clock_offset,
                                                             drift=args.clock_drift_ppm * 1e-6), log=log,
                      lidar_latency_s=args.lidar_latency).start()
    payload = None
    if args.payload_port is not None:
        from insulator_rs.sim.payload import SimulatedPayload, scene_photo_renderer

        assert rig.inspection is not None
        payload = SimulatedPayload(rig.inspection, pose=feed.pose, clock=feed.newest_time,
                                   render=scene_photo_renderer(tower.mesh),
                                   origin=mission.tower, port=args.payload_port).start()
    print(f"sensor head ready: lidar -> {host}:{port}, camera {head.server.url}"
          + ("" if payload is None else f", payload {payload.url}"), flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        if payload is not None:
            payload.close()
        head.close()
        feed.close()
        if log is not None:
            log.close()
        print(f"sensor head stats: {head.stats()}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
