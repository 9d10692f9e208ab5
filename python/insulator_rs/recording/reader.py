"""A recorded flight as a checked, time-ordered stream of sensor data (vehicle clock).

Opens an MCAP file, a rosbag2 folder (sqlite3 or MCAP storage) or ROS 1 ``.bag`` file(s)
with rosbags' :class:`~rosbags.highlevel.AnyReader` (no ROS install), checks that the topics
a replay needs are there with a type it reads, and yields :class:`Item` s in log-time order:
poses (``nav_msgs/Odometry`` or ``px4_msgs/VehicleOdometry``), LiDAR scans
(``PointCloud2`` or livox ``CustomMsg``) and camera frames (``CompressedImage``/``Image``
with the latest ``CameraInfo``); extrinsics come from ``/tf_static``.

Everything wrong is a :class:`~insulator_rs.exceptions.BagError` that names the file or the
topic and the time: a missing or unreadable file, a missing topic (the topics present are
listed), a wrong message type, a message that does not deserialise (a truncated file), a
stamp earlier than the previous one on its topic (out of order) or one that drifts more than
``max_gap`` from the pace of the recorder's clock (a jump; a gap in the recording is fine).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import insulator_rs as ir
from insulator_rs.exceptions import BagError
from insulator_rs.recording import convert as C
from insulator_rs.recording import types as T
from insulator_rs.recording.writer import RECORDED_ODOMETRY
from insulator_rs.ports.sensors import CameraFrame, LidarScan

# s: a stamp this far off the pace of the recorder's clock (log time) is a jump.
MAX_GAP = 2.0
# s of slack for stamps going back (rounding of ns stamps).
BACKWARDS_SLACK = 1e-6

_LIDAR_TYPES = (T.POINTCLOUD2, T.LIVOX_CUSTOM, "livox_ros_driver/msg/CustomMsg")
_IMAGE_TYPES = (T.COMPRESSED_IMAGE, T.IMAGE)
_ODOMETRY_TYPES = (T.ODOMETRY, T.PX4_ODOMETRY)


@dataclass(frozen=True)
class Item:
    """One datum of the flight: ``kind`` is "pose", "scan" or "frame"; ``value`` a
    :class:`PoseStamped`, :class:`LidarScan` or :class:`CameraFrame`."""

    kind: str
    time: float
    topic: str
    value: Any


def bag_paths(path: Path) -> list[Path]:
    """The paths AnyReader takes for one flight: a ``.bag`` file, an ``.mcap`` file or a rosbag2
    folder (a folder of ``.bag`` files is a split ROS 1 recording)."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such file or folder")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        bags = sorted(path.glob("*.bag"))
        if bags:
            return bags
        raise BagError(f"{path}: a folder without metadata.yaml (not a rosbag2 folder) and no .bag files")
    if path.is_file() and path.suffix not in (".bag", ".mcap", ".db3"):
        raise BagError(f"{path}: not a recorded flight (expected .mcap, .bag, or a rosbag2 folder)")
    return [path]


def _tf_lookup(edges: dict[tuple[str, str], np.ndarray], parent: str, child: str) -> np.ndarray | None:
    """T_parent_child through the tf tree (edges parent->child, walked both ways)."""
    adj: dict[str, list[tuple[str, np.ndarray]]] = {}
    for (p, c), T_pc in edges.items():
        adj.setdefault(p, []).append((c, T_pc))
        adj.setdefault(c, []).append((p, np.linalg.inv(T_pc)))
    stack: list[tuple[str, np.ndarray]] = [(parent, np.eye(4))]
    seen = {parent}
    while stack:
        frame, T_pf = stack.pop()
        if frame == child:
            return T_pf
        for nxt, T_fn in adj.get(frame, []):
            if nxt not in seen:
                seen.add(nxt)
                stack.append((nxt, T_pf @ T_fn))
    return None


class FlightBag:
    """One recorded flight opened for reading (see the module docstring). Use as a context
    manager or call :meth:`close`."""

    def __init__(self, path: Path, topics: T.Topics = T.Topics(), *, max_gap: float = MAX_GAP,
                 scan_windows: bool = False) -> None:
        from rosbags.highlevel import AnyReader

        if not (math.isfinite(max_gap) and max_gap > 0):
            raise ValueError(f"max_gap: must be > 0, got {max_gap}")
        self.path = Path(path)
        self.topics = topics
        self.max_gap = max_gap
        # insulator_rs logs each scan at the instant the flight had all of it (its window's end):
        # a scan's log time is then its window_end (a scan whose last returns were lost, or one
        # with none, still covers its whole window). Other recorders' log times are receive times.
        self.scan_windows = scan_windows
        paths = bag_paths(self.path)
        self._store = T.typestore()
        self.truncated = False
        try:
            self._reader: Any = AnyReader(paths, default_typestore=self._store)
            self._reader.open()
        except Exception as exc:  # rosbags raises several kinds for a damaged file
            self._reader = self._salvage(paths, exc)
        try:
            self._select()
            self.T_b_l, self.T_b_c = self._extrinsics()
        except BaseException:
            self.close()
            raise

    # -- opening ------------------------------------------------------------------------------
    def _salvage(self, paths: list[Path], exc: Exception) -> Any:
        """A single MCAP file rosbags refuses (no summary: cut short) is read up to the cut."""
        f = paths[0]
        if len(paths) == 1 and f.is_file() and f.suffix == ".mcap":
            try:
                reader = TruncatedMcap(f, self._store)
            except Exception:
                reader = None
            if reader is not None and reader.break_error is not None and reader.connections:
                self.truncated = True
                return reader
        raise BagError(f"{self.path}: cannot open the recording: {type(exc).__name__}: {exc}") from exc

    def _conn(self, topic: str, accepted: tuple[str, ...], role: str) -> Any:
        conns = [c for c in self._reader.connections if c.topic == topic]
        if not conns:
            present = sorted({f"{c.topic} ({c.msgtype})" for c in self._reader.connections})
            raise BagError(f"{self.path}: topic {topic} ({role}) is not in the recording; topics present: "
                           f"{', '.join(present) or 'none'}")
        types = {c.msgtype for c in conns}
        bad = types - set(accepted)
        if bad:
            raise BagError(f"{self.path}: topic {topic} ({role}) has message type {', '.join(sorted(bad))}; "
                           f"expected {' or '.join(accepted)}")
        return conns

    def _select(self) -> None:
        tp = self.topics
        present = {c.topic for c in self._reader.connections}
        odom = tp.odometry
        if odom not in present and odom == T.Topics().odometry and RECORDED_ODOMETRY in present:
            odom = RECORDED_ODOMETRY  # our own recordings carry nav_msgs/Odometry there
        image = tp.image
        if image not in present and image.endswith("/compressed") and image.removesuffix("/compressed") in present:
            image = image.removesuffix("/compressed")
        self.lidar_topic, self.image_topic, self.odometry_topic = tp.lidar, image, odom
        self._roles = {}
        for topic, accepted, role in ((tp.lidar, _LIDAR_TYPES, "LiDAR"), (image, _IMAGE_TYPES, "camera"),
                                      (tp.camera_info, (T.CAMERA_INFO,), "camera intrinsics"),
                                      (odom, _ODOMETRY_TYPES, "vehicle pose"),
                                      (tp.tf_static, (T.TF_MESSAGE,), "extrinsics")):
            for c in self._conn(topic, accepted, role):
                self._roles[c.id] = topic
        self._conns = [c for c in self._reader.connections if c.id in self._roles]
        self.start = self._reader.start_time * 1e-9
        self.end = self._reader.end_time * 1e-9
        self.counts = {t: sum(c.msgcount for c in self._conns if c.topic == t)
                       for t in (tp.lidar, image, odom, tp.camera_info)}

    def _deserialize(self, raw: bytes, conn: Any, t: float) -> Any:
        try:
            return self._reader.deserialize(raw, conn.msgtype)
        except Exception as first:
            try:  # a connection without a definition in the file: our own store has the type
                if self._reader.is2:
                    return self._store.deserialize_cdr(raw, conn.msgtype)
                return self._store.deserialize_ros1(raw, conn.msgtype)
            except Exception:
                raise BagError(f"{self.path}: {conn.topic} at t={t:.3f} s: message does not deserialise as "
                               f"{conn.msgtype} ({type(first).__name__}: {first}); truncated or corrupt?") from first

    def _extrinsics(self) -> tuple[np.ndarray, np.ndarray]:
        tp = self.topics
        edges: dict[tuple[str, str], np.ndarray] = {}
        try:
            for conn, ns, raw in self._messages([c for c in self._conns if c.topic == tp.tf_static]):
                edges.update(C.transforms_from(self._deserialize(raw, conn, ns * 1e-9), tp.tf_static))
        except BagError:
            if not self.truncated:
                raise  # a cut file's break is named once, by the stream (items)
        out = []
        for child in (tp.lidar_frame, tp.camera_frame):
            T_bc = _tf_lookup(edges, tp.body_frame, child)
            if T_bc is None:
                have = ", ".join(f"{p}->{c}" for p, c in edges) or "none"
                raise BagError(f"{self.path}: {tp.tf_static} has no transform from {tp.body_frame} to {child} "
                               f"(transforms: {have}); give the frame names with --body-frame/--lidar-frame/"
                               f"--camera-frame")
            out.append(T_bc)
        return out[0], out[1]

    def _messages(self, conns: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
        """The reader's messages, with its low-level failures (a truncated chunk, a bad
        record) turned into BagError naming the last good message."""
        last = "the start"
        it = self._reader.messages(connections=conns)
        while True:
            try:
                conn, ns, raw = next(it)
            except StopIteration:
                return
            except Exception as exc:
                raise BagError(f"{self.path}: the recording breaks off after {last}: {type(exc).__name__}: {exc} "
                               f"(truncated or corrupt file)") from exc
            last = f"{conn.topic} at t={ns * 1e-9:.3f} s"
            yield conn, ns, raw

    # -- the stream ---------------------------------------------------------------------------
    def items(self) -> Iterator[Item]:
        """Poses, scans and frames in log-time order, checked (module docstring)."""
        tp = self.topics
        camera: ir.CameraModel | None = None
        previous: dict[str, float] = {}
        offsets: dict[str, float] = {}
        conns = [c for c in self._conns if c.topic != tp.tf_static]
        for conn, ns, raw in self._messages(conns):
            topic = conn.topic
            msg = self._deserialize(raw, conn, ns * 1e-9)
            if conn.msgtype == T.PX4_ODOMETRY:
                value: Any = C.pose_from_px4(msg, topic)
                t = value.time
            else:
                t = C.from_stamp(msg.header.stamp)
            if topic != self.lidar_topic:  # a scan is checked by its newest point, below
                self._check_stamp(topic, t, ns * 1e-9, previous, offsets)
            if topic == tp.camera_info:
                camera = C.camera_from_info(msg, topic)
                continue
            if topic == self.odometry_topic:
                if conn.msgtype == T.ODOMETRY:
                    value = C.pose_from_odometry(msg, topic)
                yield Item("pose", t, topic, value)
            elif topic == self.lidar_topic:
                if conn.msgtype == T.POINTCLOUD2:
                    pts, times, inten = C.pointcloud2_points(msg, topic)
                else:
                    pts, times, inten = C.custom_msg_points(msg, topic)
                if len(times) and not np.all(np.isfinite(times)):
                    raise BagError(f"{self.path}: {topic} at t={t:.3f} s: non-finite per-point times")
                # A scan's pace is its newest point: its header stamp is its first, and a live
                # flight's scan may hold every scan since the last one it asked for (seconds)
                self._check_stamp(topic, float(times.max()) if len(times) else t, ns * 1e-9, previous, offsets)
                window_end = None
                if self.scan_windows:
                    window_end = max(ns * 1e-9, float(times.max())) if len(times) else ns * 1e-9
                yield Item("scan", t, topic, LidarScan(points_l=pts, times=times, T_b_l=self.T_b_l, intensity=inten,
                                                       window_end=window_end))
            elif topic == self.image_topic:
                if camera is None:
                    raise BagError(f"{self.path}: {topic} at t={t:.3f} s: an image before any CameraInfo on "
                                   f"{tp.camera_info}")
                img = C.image_from(msg, conn.msgtype, topic)
                if img.shape[1] != camera.width or img.shape[0] != camera.height:
                    raise BagError(f"{self.path}: {topic} at t={t:.3f} s: image {img.shape[1]}x{img.shape[0]} "
                                   f"but CameraInfo says {camera.width}x{camera.height}")
                yield Item("frame", t, topic, CameraFrame(time=t, image=img, camera=camera, T_b_c=self.T_b_c))

    def _check_stamp(self, topic: str, t: float, log_t: float, previous: dict[str, float],
                     offsets: dict[str, float]) -> None:
        """Stamps on a topic never go back; and they keep pace with the recorder's clock (log
        time): a sensor clock at a constant offset is fine, a gap in the recording is fine,
        a stamp that moves more than ``max_gap`` away from that pace is a jump."""
        if not math.isfinite(t):
            raise BagError(f"{self.path}: {topic}: non-finite stamp")
        prev = previous.get(topic)
        if prev is not None and t < prev - BACKWARDS_SLACK:
            raise BagError(f"{self.path}: {topic} at t={t:.3f} s: stamp is earlier than the previous one "
                           f"({prev:.3f} s): messages out of order")
        offset = log_t - t
        first = offsets.setdefault(topic, offset)
        if abs(offset - first) > self.max_gap:
            raise BagError(f"{self.path}: {topic} at t={t:.3f} s: stamp jumps {first - offset:+.3f} s against the "
                           f"recording's clock (log time {log_t:.3f} s), more than {self.max_gap:g} s: a clock "
                           f"reset or a bad stamp")
        previous[topic] = t

    def close(self) -> None:
        reader = getattr(self, "_reader", None)
        if reader is not None and reader.stack is not None:
            reader.close()

    def __enter__(self) -> FlightBag:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()



class _Conn:
    """What the reader needs of a connection (rosbags' Connection has these fields too)."""

    def __init__(self, id: int, topic: str, msgtype: str) -> None:
        self.id, self.topic, self.msgtype, self.msgcount = id, topic, msgtype, 0


class TruncatedMcap:
    """A ROS 2 MCAP file cut short (a crash or power loss mid-recording: no summary, no end
    magic), read record by record up to the break with the ``mcap`` library. It offers the
    part of rosbags' AnyReader the flight stream uses; after the last whole message it raises
    the break, so a replay processes everything recorded before it and then names it."""

    is2 = True

    def __init__(self, path: Path, store: Any) -> None:
        from rosbags.typesys import get_types_from_msg

        self.path = path
        self.store = store
        self.stack: Any = object()  # "open", as AnyReader's
        self.connections: list[_Conn] = []
        self.break_error: str | None = None
        schemas: dict[int, tuple[str, str]] = {}
        by_id: dict[int, _Conn] = {}
        times: list[int] = []
        self._count = 0
        for rec in self._records():
            kind = type(rec).__name__
            if kind == "Schema":
                schemas[rec.id] = (rec.name, rec.data.decode("utf-8", "replace"))
            elif kind == "Channel" and rec.id not in by_id:
                name, text = schemas.get(rec.schema_id, ("", ""))
                if name and name not in store.fielddefs and text:
                    try:
                        store.register(get_types_from_msg(text.split("=" * 80)[0], name))
                    except Exception:  # an unreadable definition: that topic fails to deserialise, named
                        pass
                by_id[rec.id] = _Conn(rec.id, rec.topic, name)
                self.connections.append(by_id[rec.id])
            elif kind == "Message" and rec.channel_id in by_id:
                by_id[rec.channel_id].msgcount += 1
                times.append(rec.log_time)
        self._by_id = by_id
        self.start_time = min(times) if times else 0
        self.end_time = max(times) if times else 0

    def _records(self) -> Iterator[Any]:
        from mcap.stream_reader import StreamReader

        with self.path.open("rb") as f:
            it = StreamReader(f).records
            while True:
                try:
                    rec = next(it)
                except StopIteration:
                    return
                except Exception as exc:  # the cut: an incomplete record or chunk
                    self.break_error = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
                    return
                yield rec

    def messages(self, connections: Any = ()) -> Iterator[tuple[Any, int, bytes]]:
        wanted = {c.id for c in connections} if connections else None
        for rec in self._records():
            if type(rec).__name__ == "Message" and rec.channel_id in self._by_id:
                if wanted is None or rec.channel_id in wanted:
                    yield self._by_id[rec.channel_id], rec.log_time, rec.data
        raise OSError(f"the file ends mid-record ({self.break_error or 'no footer'})")

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        return self.store.deserialize_cdr(raw, msgtype)

    def close(self) -> None:
        self.stack = None
