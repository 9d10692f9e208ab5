"""The simulated Mid-360 through the wire: simulator -> our emitter -> loopback UDP ->
the live driver (:class:`~insulator_rs.drivers.livox.LivoxMid360`).

For flights that exercise the live LiDAR path without a sensor. The sensor streams as a
Mid-360 does, whatever the caller's pattern: when the flight loop asks for a scan at
vehicle time ``now``, every whole 100 ms frame of the sensor's grid that has begun by
``now`` and was not rendered yet is rendered from the pose source (the airframe's
position, yaw and velocity, carried along the velocity to the shots' times), turned into
protocol datagrams on the sensor's own clock, and the datagrams whose arrival time has come
(the vehicle time of the last sample of their chunk of ``CHUNK`` datagrams, plus
``LATENCY_S``: fixed by the data, not by when the caller asks) are sent to the driver on
loopback; the rest wait for a later call. The driver's newest complete scan is returned --
its points and per-point times as the driver parsed and mapped them (the time map is the
driver's own, estimated from those arrival stamps).

Only after a real silence (nobody asked for ``SILENCE_S``: before take-off, after landing)
does the stream restart ``RESTART_SPAN_S`` before ``now``: the driver sees the gap and
counts a resync.

:class:`SplitSensors` pairs this LiDAR with another ``Sensors`` for the cameras.
"""

from __future__ import annotations

import math
import socket
import struct
from collections import deque
from collections.abc import Callable

import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs.drivers.livox import LivoxMid360, wait_for
from insulator_rs.ports.sensors import CameraFrame, LidarScan, Sensors, StreamStatus, sensor_streams
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.livox_emitter import DOTS_PER_PACKET, Faults, LivoxEmitter, SensorClock, send
from insulator_rs.sim.mesh import Mesh
from insulator_rs.sim.sensors import PROBE_SEED_OFFSET, standing

#: The airframe's pose T_w_b (4x4) at a vehicle time (s): the simulator's pose sources.
PoseSource = Callable[[float], np.ndarray]
#: A stream (re)starts this long before the request (s): one whole sensor window + the
#: reorder grace fit in it.
RESTART_SPAN_S = 0.3
#: The caller asked nothing for this long (s): the sensor is taken as silent, and restarts.
SILENCE_S = 2.0
#: Datagrams sent together (7.7 ms of data): the driver's arrival clock advances per chunk.
CHUNK = 16
#: Latency the arrivals are stamped with, past the chunk's last sample (s).
LATENCY_S = 0.0005


class LidarStream:
    """A simulated Mid-360 streaming its datagrams: :meth:`due` renders the shots up to ``now``
    (vehicle clock) and returns the chunks of datagrams whose arrival time has come, each with
    that time (the chunk's last sample + ``LATENCY_S``). ``restart_span``: how far before
    ``now`` the stream starts, at the first call and after ``silence_s`` (default
    :data:`SILENCE_S`) without one; ``silence_s=math.inf``: never restarted, a gap between
    calls is rendered and sent late (a caller that calls continuously, whose gaps are its own
    stalls).

    The shots are rendered in slices of ``1 / slice_rate`` s (the 10 Hz scan windows of the
    datagrams do not depend on it: the shot grid is global). ``ahead``: render a slice once it
    has begun (the pose source knows the future: the in-process simulator), else once it has
    ended (a pose source that extrapolates past its newest sample: render late, not wrong)."""

    def __init__(self, mesh: Mesh, pose: PoseSource, T_b_l: np.ndarray, *, clock: SensorClock | None = None,
                 faults: Faults | None = None, seed: int = 0, data_type: int = 1,
                 restart_span: float = RESTART_SPAN_S, slice_rate: float = 10.0, ahead: bool = True,
                 silence_s: float = SILENCE_S) -> None:
        self.mesh = mesh
        self.pose = pose
        self.ahead = ahead
        self.lidar = Mid360(T_b_l, frame_rate=slice_rate)
        self.emitter = LivoxEmitter(point_rate=self.lidar.point_rate, clock=clock or SensorClock(),
                                    faults=faults or Faults(), data_type=data_type)
        self.seed = seed
        self.restart_span = float(restart_span)
        self.silence_s = float(silence_s)
        self.frames = 0
        self.restarts = 0
        self._rendered_until: float | None = None  # vehicle time where the next frame starts
        self._last_call = -math.inf
        self._datagrams: list[bytes] = []  # rendered, not yet chunked
        self._chunks: deque[tuple[float, list[bytes]]] = deque()  # (arrival, datagrams) not yet due

    def due(self, now: float) -> list[tuple[float, list[bytes]]]:
        self._render(now)
        out = []
        while self._chunks and self._chunks[0][0] <= now:
            out.append(self._chunks.popleft())
        return out

    def _render(self, now: float) -> None:
        period = self.lidar.frame_period
        if self._rendered_until is None or now - self._last_call > self.silence_s:
            # (re)start on the frame grid, dropping what a silent sensor never sent
            self._rendered_until = math.floor((now - self.restart_span) / period + 1e-9) * period
            self.emitter.start_at(self._rendered_until)
            self._datagrams.clear()
            self._chunks.clear()
            self.restarts += 1
        self._last_call = now
        while self._rendered_until + (0.0 if self.ahead else period) <= now + 1e-9:
            frame = self.lidar.scan(self.mesh, self.pose, self._rendered_until, seed=self.seed + self.frames)
            self.frames += 1
            self._rendered_until = round((self._rendered_until + period) / period) * period
            self._datagrams += self.emitter.add_frame(frame)
        span = DOTS_PER_PACKET / self.lidar.point_rate
        while len(self._datagrams) >= CHUNK:
            chunk, self._datagrams = self._datagrams[:CHUNK], self._datagrams[CHUNK:]
            self._chunks.append((self._vehicle_start(chunk) + span + LATENCY_S, chunk))

    def _vehicle_start(self, chunk: list[bytes]) -> float:
        """Vehicle time of the newest first sample among ``chunk``'s datagrams (their header
        timestamps, on the sensor clock; the map to the vehicle clock is monotonic, so the newest
        stamp is mapped alone: one clock call a chunk, not one a datagram)."""
        stamps = [struct.unpack_from("<Q", d, 28)[0] for d in chunk if len(d) >= 36]
        if not stamps:
            return -math.inf
        return float(self.emitter.clock.to_vehicle(max(stamps) * 1e-9))


class WireLidar:
    """The LiDAR half of a ``Sensors``: a :class:`LidarStream` sent to the live driver in process,
    each chunk when the caller's ``now`` reaches its arrival time, stamped with that time."""

    def __init__(self, mesh: Mesh, pose: PoseSource, T_b_l: np.ndarray, *,
                 clock: SensorClock | None = None, faults: Faults | None = None, seed: int = 0,
                 data_type: int = 1) -> None:
        self.stream = LidarStream(mesh, pose, T_b_l, clock=clock, faults=faults, seed=seed, data_type=data_type)
        self._arrival = 0.0  # the vehicle time the driver stamps the datagrams being sent with
        self.driver = LivoxMid360(now=lambda: self._arrival, T_b_l=T_b_l, host_ip="127.0.0.1", point_port=0, imu_port=None,
                                  resync_gap_s=0.2).start()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sent = 0

    def lidar_scan(self, now: float) -> LidarScan | None:
        target = self.driver.point_address
        for self._arrival, chunk in self.stream.due(now):
            self._sent += send(chunk, self._sock, target)
            wait_for(lambda: self.driver.received() >= self._sent, 5.0, poll=0.0002)
        return self.driver.lidar_scan(now)

    def streams(self, now: float) -> list[StreamStatus]:
        """The LiDAR at ``now`` for the pre-flight gate. This simulated sensor streams only as the
        caller's ``now`` advances: sending its datagrams for a probe would start the stream and the
        driver's clock map early, and the flight would differ (measured: one frame more short of
        points on the small scene). As :class:`~insulator_rs.sim.sensors.SimulatedSensors` does,
        a probe scan rendered at ``now`` on its landing gear, outside the stream's frames and
        seeds, stands for it; the driver behind the wire is not probed."""
        try:
            self.stream.lidar.scan(self.stream.mesh, standing(self.stream.pose), now - self.stream.lidar.frame_period,
                                   seed=self.stream.seed + PROBE_SEED_OFFSET)
        except ValueError as exc:
            return [StreamStatus("lidar", self.stream.frames, None, error=str(exc))]
        return [StreamStatus("lidar", self.stream.frames + 1, now)]

    def health(self) -> dict[str, object]:
        return {f"lidar_{k}": v for k, v in self.driver.health().items()}

    def close(self) -> None:
        self._sock.close()
        self.driver.close()


class SplitSensors:
    """``Sensors`` with the cameras of one source and the LiDAR of another."""

    def __init__(self, cameras: Sensors, lidar: WireLidar) -> None:
        self.cameras = cameras
        self.lidar = lidar

    def detection_frame(self, now: float) -> CameraFrame | None:
        return self.cameras.detection_frame(now)

    def lidar_scan(self, now: float) -> LidarScan | None:
        return self.lidar.lidar_scan(now)

    def photo(self, now: float, T_b_c: np.ndarray, camera: CameraModel | None = None) -> CameraFrame | None:
        return self.cameras.photo(now, T_b_c, camera)

    def streams(self, now: float) -> list[StreamStatus]:
        cameras = sensor_streams(self.cameras, now) or []
        return [s for s in cameras if s.name != "lidar"] + self.lidar.streams(now)

    def health(self) -> dict[str, object]:
        return {**self.cameras.health(), **self.lidar.health()}

    def close(self) -> None:
        self.lidar.close()
        self.cameras.close()
