"""The simulated Mid-360 through the wire: simulator -> our emitter -> loopback UDP ->
the live driver (:class:`~insulator_rs.drivers.livox.LivoxMid360`).

For flights that exercise the live LiDAR path without a sensor: when the flight loop
asks for a scan at vehicle time ``now``, the last 0.3 s of shots are rendered from the
pose source (position, yaw, velocity of the airframe, now; the trajectory before it is
extrapolated back at that velocity), turned into protocol datagrams on the sensor's own
clock, sent to the driver on loopback, and the driver's newest complete scan is returned
-- its points and per-point times as the driver parsed and mapped them (the time map is
the driver's own, estimated from arrivals, which are stamped as if the shots had
streamed in real time: chunk by chunk, the vehicle time of the chunk's last sample). 0.3 s always holds one whole 100 ms window
of the sensor clock ending at least the reorder grace before ``now``.

Between requests the sensor is silent (only the requested windows are rendered): the
driver is told so with a short resync gap, and counts each pause as a resync.

:class:`SplitSensors` pairs this LiDAR with another ``Sensors`` for the cameras.
"""

from __future__ import annotations

import math
import socket
import struct
from collections.abc import Callable

import numpy as np

from insulator_rs.drivers.livox import LivoxMid360, wait_for
from insulator_rs.sensors import CameraFrame, LidarScan, Sensors
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.livox_emitter import DOTS_PER_PACKET, Faults, LivoxEmitter, SensorClock, send
from insulator_rs.sim.mesh import Mesh

#: The airframe's pose T_w_b (4x4) at a vehicle time (s): the simulator's pose sources.
PoseSource = Callable[[float], np.ndarray]
#: Rendered before each request (s): one whole sensor window + the reorder grace fit in it.
RENDER_SPAN_S = 0.3
#: Datagrams sent together (7.7 ms of data): the driver's arrival clock advances per chunk.
CHUNK = 16
#: Latency the arrivals are stamped with, past the chunk's last sample (s).
LATENCY_S = 0.0005


class WireLidar:
    """The LiDAR half of a ``Sensors``: rendered, encoded, sent and parsed back."""

    def __init__(self, mesh: Mesh, pose: PoseSource, T_b_l: np.ndarray, *,
                 clock: SensorClock | None = None, faults: Faults | None = None, seed: int = 0,
                 data_type: int = 1) -> None:
        self.mesh = mesh
        self.pose = pose
        self.lidar = Mid360(T_b_l)
        self.emitter = LivoxEmitter(point_rate=self.lidar.point_rate, clock=clock or SensorClock(),
                                    faults=faults or Faults(), data_type=data_type)
        # Arrivals are stamped as if the shots had streamed in real time (a real Mid-360
        # sends as it scans): the vehicle time of each chunk's last sample + LATENCY_S.
        self._arrival = 0.0
        self.driver = LivoxMid360(now=lambda: self._arrival, T_b_l=T_b_l, host_ip="127.0.0.1", point_port=0, imu_port=None,
                                  resync_gap_s=0.2).start()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sent = 0
        self._frames = 0
        self.seed = seed

    def _render(self, now: float) -> list[bytes]:
        start = now - RENDER_SPAN_S
        first = math.ceil(start * self.lidar.point_rate / DOTS_PER_PACKET - 1e-9)
        if self.emitter._next_packet < first:  # the sensor was silent since the last request
            self.emitter.start_at(start)
        out: list[bytes] = []
        n = round(RENDER_SPAN_S * self.lidar.frame_rate)
        for k in range(n):
            t0 = start + k * self.lidar.frame_period
            frame = self.lidar.scan(self.mesh, self.pose, t0, seed=self.seed + self._frames)
            self._frames += 1
            out += self.emitter.add_frame(frame)
        return out

    def lidar_scan(self, now: float) -> LidarScan | None:
        datagrams = self._render(now)
        target = self.driver.point_address
        span = DOTS_PER_PACKET / self.lidar.point_rate
        for i in range(0, len(datagrams), CHUNK):
            chunk = datagrams[i:i + CHUNK]
            last_start = max(self._vehicle_start(d) for d in chunk)
            self._arrival = min(now, last_start + span + LATENCY_S)
            self._sent += send(chunk, self._sock, target)
            wait_for(lambda: self.driver.received() >= self._sent, 5.0, poll=0.0002)
        return self.driver.lidar_scan(now)

    def _vehicle_start(self, datagram: bytes) -> float:
        """Vehicle time of a datagram's first sample (its header timestamp, on the sensor clock)."""
        if len(datagram) < 36:
            return -math.inf
        (ts,) = struct.unpack_from("<Q", datagram, 28)
        return float(self.emitter.clock.to_vehicle(ts * 1e-9))

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

    def photo(self, now: float, T_b_c: np.ndarray) -> CameraFrame | None:
        return self.cameras.photo(now, T_b_c)

    def health(self) -> dict[str, object]:
        return {**self.cameras.health(), **self.lidar.health()}

    def close(self) -> None:
        self.lidar.close()
        self.cameras.close()
