"""Livox Mid-360 driver: UDP receive thread, control commands, scans in the vehicle clock.

Data path: the point-cloud (host port 56301) and IMU (56401) sockets are read by Rust
threads (:class:`~insulator_rs._core.LivoxReceiver`) that hold no GIL: each datagram is
stamped as the kernel hands it over, taken from the LiDAR only, validated (length, version,
type, CRC-32; every fault counted) and assembled into 10 Hz scans with per-point times. One
Python thread takes what is finished a batch at a time: the scans, mapped to the vehicle clock
here and kept (the newest ``keep_scans``) for :meth:`LivoxMid360.lidar_scan`; the IMU samples;
and each packet's (sensor stamp, arrival) pair for the clock fit.

Why the reading is not Python's: a Python thread reading one datagram per ``recvfrom`` gives
the GIL up on every call and waits up to the switch interval (5 ms) to win it back from a
busy flight loop. At the Mid-360's ~2,000 datagrams/s, on a loaded computer, that reader fell
seconds behind and stamped each datagram when it was read: measured against PX4 SITL beside
other jobs, the clock fit read +-1000 ppm and 32-51 of 60-70 camera frames found no LiDAR
points in time to pair (the airframe issue's load finding).

Time: a packet's stamp is the sensor's clock (time since power-on, or PTP/GPS time). The
driver pairs each valid packet's last-point stamp with the time of its arrival on the
``now()`` clock; of every ``PAIR_EVERY`` packets the pair with the least latency goes to a
:class:`~insulator_rs.timesync.OneWaySync` that keeps the least-latency pair of each 0.25 s
(its 2048 of them span 8.5 minutes: measured against PX4 SITL on a loaded box, a 1 s window
put the drift anywhere within +-1000 ppm, a 16 s one still at -692 and +856 ppm for a truth
of -25), and all point times are mapped through it, then through ``to_vehicle``.

With ``arrival_stamps`` (the live path), a datagram's arrival is the reader thread's stamp,
on ``time.monotonic``'s clock carried to ``now``'s (the host clock: the same one); without it
(the simulator and tests, whose clocks are not real time), ``now()`` read when the datagram is
processed.

Two clocks, two maps, as the hardware has them: ``now`` is the host's own clock (a crystal,
as the LiDAR's is, so sensor -> host is the straight line the envelope fits) and
``to_vehicle`` maps host instants to the vehicle clock (MAVLink TIMESYNC, or the
:class:`~insulator_rs.timesync.TelemetryClock`). Fitting the LiDAR straight to the vehicle
clock's estimate instead puts every wobble of that estimate into the LiDAR's map (PX4 SITL
runs in lockstep: its clock slows when a loaded box starves it). Without ``to_vehicle``,
``now`` is the vehicle clock itself (the simulator). A ``time_map`` given by the caller (a
known or externally estimated map, sensor seconds -> vehicle seconds) replaces both.
A datagram that arrives before the vehicle clock exists
(no telemetry yet) cannot be stamped: it is dropped and counted (``unstamped``).

Control (``lidar_ip`` given): discovery broadcast to port 56000 is available through
:func:`discover`; :meth:`LivoxMid360.start` sends the host configuration (where to send
point and IMU data) and "work mode = sampling" to the LiDAR's command port 56100 and
waits for both acks; :meth:`close` sends "work mode = idle".
"""

from __future__ import annotations

import math
import select
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from insulator_rs._core import (
    LivoxReceiver,
    LivoxScan,
    livox_decode_command,
    livox_discovery_request,
    livox_host_config_request,
    livox_parse_config_ack,
    livox_parse_discovery_ack,
    livox_work_mode_request,
)
from insulator_rs.exceptions import InsulatorError, PacketError, SensorError
from insulator_rs.ports.sensors import LidarScan
from insulator_rs.timesync import OneWaySync

PORT_DISCOVERY = 56000
PORT_COMMAND = 56100
HOST_PORT_COMMAND = 56101
HOST_PORT_POINT = 56301
HOST_PORT_IMU = 56401
MAX_DATAGRAM = 2048
#: Finished scans the reader threads hold for the Python thread (6.4 s: a thread starved that
#: long still finds them; the oldest is dropped and counted beyond it).
RECEIVE_QUEUED_SCANS = 64
#: Kernel receive buffer asked for (a second of Mid-360 data is 2.9 MB): 32 MB, 11 s. A receive
#: thread starved on a loaded computer must find the datagrams still there; measured against
#: PX4 SITL in CI, 2 datagrams were lost with 8 MB asked (the kernel caps SO_RCVBUF at
#: net.core.rmem_max, 4 MB there). SO_RCVBUFFORCE (CAP_NET_ADMIN) passes the cap; without it
#: the cap holds, and the effective size is in ``health()`` (raise rmem_max on the Jetson).
RECEIVE_BUFFER_BYTES = 32 << 20
#: Linux's SO_RCVBUFFORCE (Python's socket module does not name it everywhere).
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
#: How long a read waits before checking for shutdown (s).
POLL_S = 0.05
#: s: the least time between two batches taken from the reader threads (live sensors only; a
#: simulated one is stepped datagram by datagram by its caller and must not wait)
BATCH_S = 0.01
#: s of sensor time per clock pair kept: the least-latency pair of each (timesync.OneWaySync).
CLOCK_BIN_S = 0.25
#: Valid packets per clock pair (the one with the least latency is kept: see the module docstring).
PAIR_EVERY = 16

TimeMap = Callable[[np.ndarray], np.ndarray]


def parse_url(url: str) -> tuple[str, int | None]:
    """``mid360://HOST[:POINT_PORT]`` -> (HOST, port or None); HOST is the LiDAR's IP, or
    ``listen`` / an empty host to only listen (no control commands)."""
    prefix = "mid360://"
    if not url.startswith(prefix):
        raise SensorError(f"--lidar: expected mid360://HOST[:PORT], got {url!r}")
    rest = url[len(prefix):].rstrip("/")
    host, _, port = rest.partition(":")
    if port:
        if not port.isdigit() or not (0 <= int(port) < 65536):
            raise SensorError(f"--lidar: port must be 0..65535 (0: any free port), got {port!r} in {url!r}")
        return host, int(port)
    return host, None


@dataclass(frozen=True)
class ImuBatch:
    """IMU samples: ``times`` (M,) vehicle clock (s), ``gyro`` (M, 3) rad/s, ``acc`` (M, 3) g."""

    times: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray


def datagrams_until(sock: socket.socket, deadline: float) -> Iterator[bytes]:
    """The datagrams ``sock`` receives until ``deadline`` (``time.monotonic()`` s), as they come."""
    while (left := deadline - time.monotonic()) > 0:
        ready, _, _ = select.select([sock], [], [], left)
        if not ready:
            return
        data, _ = sock.recvfrom(MAX_DATAGRAM)
        yield data


def discover(*, timeout: float = 1.0, broadcast: str = "255.255.255.255",
             bind_ip: str = "0.0.0.0", port: int = PORT_DISCOVERY) -> list[dict[str, object]]:
    """Broadcasts a discovery request (cmd 0x0000) to port 56000; returns every ack."""
    acks: list[dict[str, object]] = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        sock.bind((bind_ip, 0))
        sock.sendto(livox_discovery_request(1), (broadcast, port))
        for data in datagrams_until(sock, time.monotonic() + timeout):
            try:
                acks.append(livox_parse_discovery_ack(data))
            except PacketError:
                continue  # not a discovery ack (the message names the frame field): ignore
    return acks


class LivoxMid360:
    """A live Mid-360 (or our emitter) as a LiDAR source in the vehicle clock.

    ``now``: the time (s) of "now", called on each datagram's arrival: the host clock with
    ``to_vehicle`` (host s -> vehicle s), else the vehicle clock itself (module docstring).
    ``T_b_l``: the LiDAR's extrinsics (4x4). ``lidar_ip``: the sensor's address for
    control commands (None: only listen). ``time_map``: sensor s -> vehicle s, replacing
    the arrival-based estimate. ``arrival_stamps``: stamp datagrams when they arrive (the
    reader threads' stamps; ``now`` must run at real time, as the host clock does) rather
    than when they are processed (module docstring). ``latency_s``: the least delay from a
    packet's last sample to its arrival (the rig's ``[lidar] latency_s``): the clock fit maps a
    stamp to the earliest arrivals, so this much is taken off (0: a Mid-360 on Ethernet).
    """

    def __init__(self, *, now: Callable[[], float], T_b_l: np.ndarray, host_ip: str = "0.0.0.0",
                 point_port: int = HOST_PORT_POINT, imu_port: int | None = HOST_PORT_IMU,
                 lidar_ip: str | None = None, lidar_command_port: int = PORT_COMMAND,
                 announce_ip: str | None = None,
                 time_map: TimeMap | None = None, to_vehicle: TimeMap | None = None, keep_scans: int = 4, frame_period_s: float = 0.1,
                 reorder_grace_s: float = 0.005, resync_gap_s: float = 1.0, command_timeout: float = 1.0,
                 arrival_stamps: bool = False, latency_s: float = 0.0) -> None:
        T = np.asarray(T_b_l, np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_b_l: expected a finite 4x4 matrix, got shape {T.shape}")
        if keep_scans < 1:
            raise ValueError(f"keep_scans: must be >= 1, got {keep_scans}")
        if not (math.isfinite(latency_s) and latency_s >= 0.0):
            raise ValueError(f"latency_s: must be a finite number >= 0, got {latency_s}")
        self.latency_s = float(latency_s)
        self.T_b_l = T
        self._now = now
        self.arrival_stamps = bool(arrival_stamps)
        self.host_ip = host_ip
        self.lidar_ip = lidar_ip or None
        self.lidar_command_port = int(lidar_command_port)
        self.announce_ip = announce_ip
        self.command_timeout = float(command_timeout)
        self._time_map = time_map
        self._to_vehicle = to_vehicle
        self.clock = OneWaySync(bin_s=CLOCK_BIN_S)
        self._windows = (frame_period_s, reorder_grace_s, resync_gap_s)  # the assembler's scan windows
        self._receiver: LivoxReceiver | None = None  # made by start(), or by the first _on_datagram
        self._process_lock = threading.Lock()  # one taker at a time: the thread, flush(), _on_datagram
        self._received = 0  # datagrams read, as of the last batch processed
        self._scans: deque[LidarScan] = deque(maxlen=keep_scans)
        self._imu: deque[ImuBatch] = deque(maxlen=64)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._seq = 0
        self.unmapped_scans = 0
        self.receive_errors = 0
        self.receive_buffer_bytes = 0  # the kernel's effective receive buffer (the last socket bound)
        self._pair: tuple[float, float] | None = None  # the least-latency (stamp, arrival) of this group
        self._pair_count = 0
        self.sockets: list[socket.socket] = []
        self._point_sock = self._bind(point_port, "point data")
        self._imu_sock = self._bind(imu_port, "IMU data") if imu_port is not None else None
        self._cmd_sock: socket.socket | None = None
        self.batches = 0  # batches taken from the reader threads
        self.largest_batch = 0  # packet stamps in the largest one (how far the Python thread fell behind)

    @property
    def point_address(self) -> tuple[str, int]:
        return self._point_sock.getsockname()

    @property
    def imu_address(self) -> tuple[str, int] | None:
        return None if self._imu_sock is None else self._imu_sock.getsockname()

    def _bind(self, port: int, what: str) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            try:
                sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, RECEIVE_BUFFER_BYTES)
            except OSError:  # not permitted (no CAP_NET_ADMIN): as much as rmem_max allows
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
            self.receive_buffer_bytes = int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
            sock.bind((self.host_ip, port))
        except OSError as err:
            sock.close()
            for s in self.sockets:
                s.close()
            raise SensorError(f"Mid-360: cannot bind the {what} port {self.host_ip}:{port}: {err}") from err
        self.sockets.append(sock)
        return sock

    # -- control -----------------------------------------------------------------

    def _command(self, frame: bytes, what: str) -> None:
        assert self.lidar_ip is not None
        if self._cmd_sock is None:
            # Any host port will do (the LiDAR answers to the sender); 56101 is only a suggestion.
            self._cmd_sock = self._bind(0, "command")
        sock = self._cmd_sock
        seq = self._seq
        sock.sendto(frame, (self.lidar_ip, self.lidar_command_port))
        for data in datagrams_until(sock, time.monotonic() + self.command_timeout):
            try:
                cmd_id, ack_seq, _, _, _ = livox_decode_command(data)
                if cmd_id != 0x0100 or ack_seq != seq:
                    continue
                ret, key = livox_parse_config_ack(data)
            except PacketError:
                continue  # not a well-formed ack (the message names the frame field): ignore
            if ret != 0:
                raise SensorError(f"Mid-360 {self.lidar_ip}: {what} refused (ret_code {ret:#04x}, key {key:#06x})")
            return
        raise SensorError(f"Mid-360 {self.lidar_ip}:{self.lidar_command_port}: no ack to {what} within {self.command_timeout} s")

    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFFFFFFFF
        return self._seq

    def configure(self) -> None:
        """Point the LiDAR's data at our sockets and start sampling."""
        if self.lidar_ip is None:
            return
        host = self.announce_ip or self.host_ip
        if host in ("0.0.0.0", ""):
            raise SensorError("Mid-360: announce_ip is needed to tell the LiDAR where to send data")
        imu_port = self.imu_address[1] if self.imu_address else HOST_PORT_IMU
        self._command(livox_host_config_request(self._next_seq(), host, self.point_address[1], imu_port),
                      "host configuration")
        self._command(livox_work_mode_request(self._next_seq(), True), "start sampling")

    # -- receive -----------------------------------------------------------------

    def start(self) -> LivoxMid360:
        self.configure()
        socks = [s for s in (self._point_sock, self._imu_sock) if s is not None]
        # datagrams are taken only once they can be stamped (the vehicle clock answers)
        accepting = self._clock_ready()
        self._receiver = self._new_receiver([s.fileno() for s in socks], accepting=accepting)
        self._thread = threading.Thread(target=self._run, args=(self._receiver, accepting), name="livox-mid360",
                                        daemon=True)
        self._thread.start()
        return self

    def _new_receiver(self, fds: list[int], *, accepting: bool) -> LivoxReceiver:
        frame_period_s, reorder_grace_s, resync_gap_s = self._windows
        return LivoxReceiver(fds, lidar_ip=self.lidar_ip, accepting=accepting, frame_period_s=frame_period_s,
                             reorder_grace_s=reorder_grace_s, resync_gap_s=resync_gap_s,
                             max_queued_scans=RECEIVE_QUEUED_SCANS)

    def _clock_ready(self) -> bool:
        """Whether a datagram arriving now can be stamped in the vehicle clock."""
        try:
            now = self._now()
            if self._to_vehicle is not None:
                self._to_vehicle(np.array([now]))
        except InsulatorError:
            return False
        return True

    def _run(self, receiver: LivoxReceiver, accepting: bool) -> None:
        """``accepting``: what the receiver was made with (the clock may have become ready since:
        it is asked again here, and the receiver told)."""
        while not self._stop.is_set():
            try:
                if not accepting and (accepting := self._clock_ready()):
                    receiver.accept()
                with self._process_lock:
                    # waits with the GIL released until datagrams came
                    self._process(receiver.take(POLL_S), None)
                if self.arrival_stamps:
                    # a live sensor: its datagrams keep their arrival stamps while they wait, so
                    # batches of BATCH_S at most take the GIL 1/BATCH_S times a second, not 2,000
                    self._stop.wait(BATCH_S)
            except (OSError, ValueError, InsulatorError):
                # a vehicle clock that failed mid-batch: that batch's stamps are lost, counted;
                # the thread keeps going
                if self._stop.is_set():
                    return
                self.receive_errors += 1

    def _process(self, taken: tuple[list[LivoxScan], tuple[np.ndarray, np.ndarray, np.ndarray], np.ndarray,
                                    np.ndarray, int], arrival: float | None) -> None:
        """One batch of the reader threads: packet stamps to the clock fit, then the scans and
        IMU samples mapped through it. ``arrival``: every packet's arrival on ``now``'s clock
        (None: the readers' stamps with ``arrival_stamps``, else ``now()``)."""
        scans, (imu_t, gyro, acc), stamps_ns, arrivals_s, datagrams = taken
        if len(stamps_ns):
            if arrival is not None:
                arrivals = np.full(len(stamps_ns), arrival)
            elif self.arrival_stamps:
                # time.monotonic -> now's clock, once a batch (the host clock's own: offset ~0)
                arrivals = np.asarray(arrivals_s) + (self._now() - time.monotonic())
            else:
                arrivals = np.full(len(stamps_ns), self._now())
            self.batches += 1
            self.largest_batch = max(self.largest_batch, len(stamps_ns))
            for stamp, at in zip((np.asarray(stamps_ns, np.float64) * 1e-9).tolist(), arrivals.tolist()):
                self._add_pair(stamp, at)
        for scan in scans:
            self._take(scan)
        if len(imu_t):
            self._take_imu(imu_t, gyro, acc)
        self._received = datagrams

    def _on_datagram(self, data: bytes, arrival: float) -> None:
        """Processes one datagram now, as arrived at ``arrival`` (tests; the driver's thread is
        not running)."""
        if self._receiver is None:
            self._receiver = self._new_receiver([], accepting=True)
        self._receiver.push(0, self.lidar_ip or "127.0.0.1", 0, data)
        with self._process_lock:
            self._process(self._receiver.take(0.0), arrival)

    def _add_pair(self, stamp: float, arrival: float) -> None:
        if self._pair is None or arrival - stamp < self._pair[1] - self._pair[0]:
            self._pair = (stamp, arrival)
        self._pair_count += 1
        if self._pair_count >= PAIR_EVERY or not self.clock.ready():
            self.clock.add(*self._pair)
            self._pair, self._pair_count = None, 0

    def _map(self, sensor_s: np.ndarray) -> np.ndarray | None:
        if self._time_map is not None:
            return np.asarray(self._time_map(sensor_s), np.float64)
        if not self.clock.ready():
            return None
        arrival = self.clock.to_target(sensor_s) - self.latency_s
        if self._to_vehicle is None:
            return arrival
        try:
            return np.asarray(self._to_vehicle(arrival), np.float64)
        except InsulatorError:  # no vehicle time yet: the scan cannot be stamped
            return None

    def _take(self, scan: LivoxScan) -> None:
        times = self._map(scan.times_ns.astype(np.float64) * 1e-9)
        if times is None:
            self.unmapped_scans += 1
            return
        # the window a whole scan covers, even one with no return: a LiDAR that sees only sky (above
        # the tower during a crossing) still says time has passed, and a frame waiting for points
        # there is due with none, not left waiting for a scan that will never hold any
        window = None if scan.partial else self._map(np.array([scan.end_ns * 1e-9]))
        lidar = LidarScan(points_l=scan.points, times=times, T_b_l=self.T_b_l,
                          intensity=scan.reflectivity, window_end=None if window is None else float(window[0]))
        with self._lock:
            self._scans.append(lidar)

    def _take_imu(self, t: np.ndarray, gyro: np.ndarray, acc: np.ndarray) -> None:
        times = self._map(t.astype(np.float64) * 1e-9)
        if times is not None:
            with self._lock:
                self._imu.append(ImuBatch(times=times, gyro=gyro, acc=acc))

    # -- the Sensors side --------------------------------------------------------

    def lidar_scan(self, now: float) -> LidarScan | None:
        """The newest complete scan ending at or before ``now`` (vehicle clock); one with no
        return counts when it knows its window (the sensor saw nothing in range there)."""
        with self._lock:
            for scan in reversed(self._scans):
                if scan.covered_until <= now:  # nan (no point, no window) compares false
                    return scan
        return None

    def scans_until(self, now: float) -> list[LidarScan]:
        """The kept scans (the newest ``keep_scans``) ending at or before ``now``, oldest first."""
        with self._lock:
            return [scan for scan in self._scans if scan.covered_until <= now]

    def imu(self) -> list[ImuBatch]:
        """IMU batches received since the last call."""
        with self._lock:
            out = list(self._imu)
            self._imu.clear()
        return out

    def received(self) -> int:
        """Datagrams read and processed so far, from the LiDAR or not."""
        return self._received

    def _counters(self) -> dict[str, int]:
        return {} if self._receiver is None else dict(self._receiver.stats())

    @property
    def unstamped(self) -> int:
        """Datagrams dropped because they arrived before the vehicle clock could stamp them."""
        return int(self._counters().get("unstamped", 0))

    @property
    def foreign_datagrams(self) -> int:
        """Datagrams from another address than the LiDAR's (never parsed)."""
        return int(self._counters().get("foreign", 0))

    def health(self) -> dict[str, object]:
        counters = self._counters()
        read_errors = counters.pop("read_errors", 0)
        stats: dict[str, object] = {k: v for k, v in counters.items() if k not in ("read", "foreign")}
        stats["receive_errors"] = self.receive_errors + read_errors
        stats["receive_largest_batch"] = self.largest_batch
        stats["receive_buffer_bytes"] = self.receive_buffer_bytes
        stats["unmapped_scans"] = self.unmapped_scans
        stats["foreign_datagrams"] = counters.get("foreign", 0)
        if self.clock.ready() and self._time_map is None:
            fit = self.clock.fit
            stats["clock_drift_ppm"] = fit.drift * 1e6
            stats["clock_offset_s"] = fit.offset
        return stats

    def flush(self) -> None:
        """Closes the scan being assembled (end of a recording or test)."""
        if self._receiver is None:
            return
        with self._process_lock:
            self._receiver.flush()
            self._process(self._receiver.take(0.0), None)

    def close(self) -> None:
        if self.lidar_ip is not None and self._cmd_sock is not None:
            try:
                self._command(livox_work_mode_request(self._next_seq(), False), "stop sampling")
            except (SensorError, OSError):
                pass  # closing anyway: the sensor may already be gone
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._receiver is not None:
            self._receiver.stop()
        for s in self.sockets:
            s.close()
        self.sockets.clear()

    def __enter__(self) -> LivoxMid360:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def wait_for(predicate: Callable[[], bool], timeout: float, poll: float = 0.005) -> bool:
    """Polls ``predicate`` until it holds or ``timeout`` (s) passes."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll)
    return bool(predicate())


__all__ = ["ImuBatch", "LivoxMid360", "discover", "parse_url", "wait_for"]
