"""Record a flight as ROS 2 messages (cdr) in one MCAP file, as ``ros2 bag record -s mcap`` would.

:class:`McapRecorder` writes the messages (schemas are the ROS 2 ``.msg`` definitions that
rosbags generates, so Foxglove, ``ros2 bag play`` and rosbags open the file);
:class:`RecordingSensors` wraps any :class:`~insulator_rs.ports.sensors.Sensors` adapter and
records what it hands out (detection frames, LiDAR scans); :class:`RecordingVehicle` wraps
any :class:`~insulator_rs.ports.vehicle.Vehicle` and records its pose stream (every ``state()``
and ``advance()``, deduplicated by time). Inspection photos are not recorded (full-size
images the replay does not need). Extrinsics go on ``/tf_static`` once (the LiDAR's and the
first detection frame's camera); a camera pose that changes later (a gimbal) goes on ``/tf``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.exceptions import BagError
from insulator_rs.recording import convert as C
from insulator_rs.recording import types as T
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped, ScanIntake, Sensors, SensorsDecorator
from insulator_rs.ports.vehicle import Vehicle, VehicleDecorator, VehicleState

# Topic the recorder writes nav_msgs/Odometry on (the replay finds it by default).
RECORDED_ODOMETRY = "/odom"
FLUSH_PERIOD = 1.0  # s of log time between flushes of the chunk in progress (McapRecorder)
# rosbag2's QoS of /tf_static (transient local) so `ros2 bag play` latches it.
_TF_STATIC_QOS = ("- history: 3\n  depth: 0\n  reliability: 1\n  durability: 1\n  deadline:\n    sec: 2147483647\n"
                  "    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n  liveliness: 1\n"
                  "  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n"
                  "  avoid_ros_namespace_conventions: false")


class McapRecorder:
    """Writes one MCAP file of ROS 2 messages; ``image_format`` "jpeg" (CompressedImage,
    default: what camera drivers' image_transport publishes) or "raw" (Image bgr8, lossless).

    The chunk in progress is finished and handed to the operating system every FLUSH_PERIOD s of
    log time: a process killed mid-flight (``kill -9``, a crash) leaves a file whose messages up
    to the last flush a replay reads (``durable``: how many); before, up to a 1 MiB chunk was lost
    (the fault matrix's client killed read 0 of 109 messages)."""

    def __init__(self, path: Path, topics: T.Topics = T.Topics(), *, image_format: str = "jpeg") -> None:
        from mcap.writer import CompressionType, Writer

        if image_format not in ("jpeg", "raw"):
            raise ValueError(f"image_format: must be 'jpeg' or 'raw', got {image_format!r}")
        self.path = Path(path)
        self.topics = topics
        self.image_format = image_format
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("wb")
        # LZ4 when available (what rosbag2 uses), else uncompressed chunks; zstd is optional too.
        try:
            import lz4  # noqa: F401

            compression = CompressionType.LZ4
        except ImportError:
            compression = CompressionType.NONE
        self._writer = Writer(self._file, compression=compression)
        self._writer.start(profile="ros2", library="insulator_rs")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._store = T.typestore()
        self._static_written = False
        self._T_b_c: np.ndarray | None = None
        self._T_b_l: np.ndarray | None = None  # the LiDAR's extrinsics, from its first scan
        self._last_pose_time = -math.inf
        self.counts: dict[str, int] = {}
        self.durable = 0  # messages flushed to the file so far
        self._flushed_at = -math.inf  # log time (s) of the last flush
        self.closed = False

    def _channel(self, topic: str, msgtype: str) -> int:
        if topic not in self._channels:
            if msgtype not in self._schemas:
                text, _ = self._store.generate_msgdef(msgtype, ros_version=2)
                self._schemas[msgtype] = self._writer.register_schema(msgtype, "ros2msg", text.encode())
            meta = {"offered_qos_profiles": _TF_STATIC_QOS} if topic == self.topics.tf_static else {}
            self._channels[topic] = self._writer.register_channel(topic, "cdr", self._schemas[msgtype], meta)
        return self._channels[topic]

    def write(self, topic: str, msgtype: str, t: float, msg: Any) -> None:
        self.write_stamped(topic, msgtype, log_time=t, msg=msg)

    def write_stamped(self, topic: str, msgtype: str, *, log_time: float, msg: Any) -> None:
        """``msg`` on ``topic``, logged at ``log_time`` (s, vehicle clock)."""
        if self.closed:
            raise BagError(f"{self.path}: recorder already closed")
        data = self._store.serialize_cdr(msg, msgtype)
        ns = int(round(log_time * 1e9))
        seq = self.counts.get(topic, 0)
        self._writer.add_message(self._channel(topic, msgtype), log_time=ns, data=bytes(data), publish_time=ns,
                                 sequence=seq)
        self.counts[topic] = seq + 1
        if log_time - self._flushed_at >= FLUSH_PERIOD:
            self._writer.flush()  # type: ignore[no-untyped-call]  # mcap's Writer is untyped
            self._flushed_at = log_time
            self.durable = sum(self.counts.values())

    def _extrinsics(self, t: float, T_b_l: np.ndarray | None, T_b_c: np.ndarray | None) -> None:
        tp = self.topics
        if not self._static_written and T_b_l is not None and T_b_c is not None:
            tfs = [C.transform_stamped(np.asarray(T_b_l), t, tp.body_frame, tp.lidar_frame),
                   C.transform_stamped(np.asarray(T_b_c), t, tp.body_frame, tp.camera_frame)]
            self.write(tp.tf_static, T.TF_MESSAGE, t, C.tf_message(tfs))
            self._static_written = True
            self._T_b_c = np.asarray(T_b_c, dtype=np.float64)
        elif (self._static_written and T_b_c is not None and self._T_b_c is not None
              and not np.allclose(T_b_c, self._T_b_c, atol=1e-9)):
            tf = C.transform_stamped(np.asarray(T_b_c), t, tp.body_frame, tp.camera_frame)
            self.write("/tf", T.TF_MESSAGE, t, C.tf_message([tf]))

    def scan(self, scan: LidarScan, T_b_c: np.ndarray | None = None) -> None:
        """One scan, logged at the instant the flight had all of it (``covered_until``: the
        window's end, see ``FlightBag(scan_windows=True)``); a scan with no return is recorded
        too when it knows its window (it says the LiDAR saw nothing there)."""
        done = scan.covered_until
        if not np.isfinite(done):
            return  # no point and no window: nothing it covers
        self._T_b_l = np.asarray(scan.T_b_l, dtype=np.float64)
        t0, msg = C.scan_to_pointcloud2(scan, self.topics.lidar_frame)
        if not self._static_written and T_b_c is not None:
            self._extrinsics(t0, scan.T_b_l, T_b_c)
        self.write_stamped(self.topics.lidar, T.POINTCLOUD2, log_time=done, msg=msg)

    def frame(self, frame: CameraFrame, T_b_l: np.ndarray | None = None) -> None:
        T_b_l = T_b_l if T_b_l is not None else self._T_b_l
        self._extrinsics(frame.time, T_b_l, frame.T_b_c)
        tp = self.topics
        self.write(tp.camera_info, T.CAMERA_INFO, frame.time, C.camera_info(frame.camera, frame.time, tp.camera_frame))
        if self.image_format == "jpeg":
            self.write(tp.image, T.COMPRESSED_IMAGE, frame.time, C.image_to_compressed(frame, tp.camera_frame))
        else:
            self.write(tp.image.removesuffix("/compressed"), T.IMAGE, frame.time,
                       C.image_raw(frame, tp.camera_frame))

    def pose(self, pose: PoseStamped, velocity_w: np.ndarray | None = None) -> None:
        """One pose of the vehicle's stream; a time at or before the last one is skipped."""
        if not pose.time > self._last_pose_time:
            return
        self._last_pose_time = pose.time
        self.write(RECORDED_ODOMETRY, T.ODOMETRY, pose.time,
                   C.odometry(pose, velocity_w, self.topics.world_frame, self.topics.body_frame))

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """An MCAP metadata record (the flight's mission and scene: see :mod:`.metadata`)."""
        self._writer.add_metadata(name, values)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer is untyped
            self.durable = sum(self.counts.values())
        finally:
            self._file.close()


class RecordingSensors(SensorsDecorator):
    """A :class:`~insulator_rs.ports.sensors.Sensors` decorator that records what ``inner``
    delivers (every detection frame and every scan the flight asks for), wired by the
    composition root: the flight does not know it is recorded. ``T_b_l``: the rig's LiDAR
    extrinsics, recorded with the frames until a scan brings its own.

    Of each scan, the part not delivered before is recorded (:class:`ScanIntake`, the rule
    perception takes scans by): a live driver's scans never overlap, but the simulator's do
    (each ask renders the last 100 ms), and two asks within 100 ms (the obstacle map's survey
    and the pairing in one tick) gave two scans of one window whose first returns, drawn anew,
    went back in time: the replay refused the recording as out of order. Perception takes the
    same part of each scan, so the replay sees what the flight saw."""

    def __init__(self, inner: Sensors, recorder: McapRecorder, *, T_b_l: np.ndarray | None = None) -> None:
        super().__init__(inner)
        self.recorder = recorder
        self._T_b_c: np.ndarray | None = None
        self._T_b_l = None if T_b_l is None else np.asarray(T_b_l, dtype=np.float64)
        self._intake = ScanIntake()

    def detection_frame(self, now: float) -> CameraFrame | None:
        frame = self.inner.detection_frame(now)
        if frame is not None:
            self._T_b_c = frame.T_b_c
            self.recorder.frame(frame, self._T_b_l)
        return frame

    def lidar_scan(self, now: float) -> LidarScan | None:
        scan = self.inner.lidar_scan(now)
        if scan is not None:
            self._T_b_l = scan.T_b_l
            new = self._intake.take(scan)
            if new is not None:
                self.recorder.scan(new, self._T_b_c)
        return scan

    def health(self) -> dict[str, object]:
        return {**self.inner.health(), "recorded_messages": dict(self.recorder.counts)}


class RecordingVehicle(VehicleDecorator):
    """A :class:`~insulator_rs.ports.vehicle.Vehicle` decorator that records the pose stream
    ``inner`` reports (``VehicleState.T_w_b``, what the flight's perception is fed), wired by
    the composition root; every other call passes on."""

    def __init__(self, inner: Vehicle, recorder: McapRecorder) -> None:
        super().__init__(inner)
        self.recorder = recorder

    def _record(self, st: VehicleState) -> VehicleState:
        T_w_b = st.T_w_b
        if self.recorder.closed:  # the flight is over and its recording closed (inspect's report after it)
            return st
        if math.isfinite(st.time) and st.time >= 0 and np.all(np.isfinite(T_w_b)):
            self.recorder.pose(PoseStamped(float(st.time), T_w_b), st.velocity)
        return st

    def state(self) -> VehicleState:
        return self._record(self.inner.state())

    def advance(self, dt: float) -> VehicleState:
        return self._record(self.inner.advance(dt))
