"""Sensor data <-> ROS 2 messages, in the encodings users' own drivers produce.

* LiDAR: ``sensor_msgs/PointCloud2`` in livox_ros_driver2's layout (x, y, z, intensity
  float32; tag, line uint8; timestamp float64 = the point's absolute time in ns; packed,
  26 bytes a point; header stamp = the first point's time, frame = the LiDAR's). Reading
  takes any PointCloud2 with x, y, z (float32/float64) and an optional per-point time
  field, and livox_ros_driver2's ``CustomMsg``.
* Camera: ``sensor_msgs/CompressedImage`` (jpeg) or ``sensor_msgs/Image``
  (bgr8/rgb8/mono8) with ``sensor_msgs/CameraInfo`` (plumb_bob = OpenCV's k1 k2 p1 p2 k3).
* Extrinsics: ``tf2_msgs/TFMessage`` on ``/tf_static`` (parent body, child LiDAR/camera).
* Pose: ``nav_msgs/Odometry`` (pose of the body in the world frame, twist in the body
  frame, as REP 105 says), or PX4's ``px4_msgs/VehicleOdometry`` (NED/FRD, converted to
  ENU/FLU here, the only place a recorded flight meets NED).

Stamps: ROS ``builtin_interfaces/Time`` (sec, nanosec) <-> the vehicle clock in seconds.
Errors are :class:`~insulator_rs.exceptions.BagError` naming the field.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike

import insulator_rs as ir
from insulator_rs.exceptions import BagError
from insulator_rs.mavlink.frames import ENU_TO_NED, FLU_TO_FRD, ned_to_enu
from insulator_rs.recording import types as T
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped
from insulator_rs.poses import quaternion_from_rotation, rotation_from_quaternion

_store = T.typestore()
_types = _store.types

# livox_ros_driver2's PointXyzlt (packed): the layout of its PointCloud2 messages.
LIVOX_POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"),
                              ("tag", "u1"), ("line", "u1"), ("timestamp", "<f8")])
# sensor_msgs/PointField datatypes
_POINTFIELD = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_POINTFIELD_OF = {"<f4": 7, "<f8": 8, "|u1": 2}
# s: a per-point time column read as absolute must land this close to the header stamp.
TIME_FIELD_MATCH = 1.0


def to_stamp(t: float) -> Any:
    """ROS Time of a vehicle-clock time (s); negative times are refused."""
    if not (math.isfinite(t) and t >= 0):
        raise BagError(f"stamp: vehicle time must be finite and >= 0 to be a ROS time, got {t!r}")
    ns = int(round(t * 1e9))
    return _types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def from_stamp(stamp: Any) -> float:
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def _header(t: float, frame_id: str) -> Any:
    return _types["std_msgs/msg/Header"](stamp=to_stamp(t), frame_id=frame_id)


# -- rotations (w, x, y, z quaternions, as ROS and PX4 store them) -----------------------------
quat_from_matrix = quaternion_from_rotation  # (w, x, y, z), w >= 0: poses.py is the one home


def matrix_from_quat(q: ArrayLike, name: str) -> np.ndarray:
    """Rotation matrix of a (w, x, y, z) quaternion; BagError naming ``name`` if it is not
    close to unit length (a zero or garbage quaternion)."""
    qa = np.asarray(q, dtype=np.float64)
    n = float(np.linalg.norm(qa))
    if not (math.isfinite(n) and abs(n - 1.0) < 1e-3):
        raise BagError(f"{name}: not a unit quaternion (norm {n:.6g})")
    return rotation_from_quaternion(qa)


# -- LiDAR --------------------------------------------------------------------------------------
def scan_to_pointcloud2(scan: LidarScan, frame_id: str) -> tuple[float, Any]:
    """(stamp s, PointCloud2) of a scan in livox_ros_driver2's layout."""
    n = len(scan)
    rec = np.zeros(n, dtype=LIVOX_POINT_DTYPE)
    pts = np.asarray(scan.points_l)
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if scan.intensity is not None:
        rec["intensity"] = scan.intensity
    times = np.asarray(scan.times, dtype=np.float64)
    rec["timestamp"] = times * 1e9
    # stamped at its first point (livox_ros_driver2's convention); a scan with no return at its window's end
    t0 = float(times.min()) if n else float(scan.covered_until)
    layout: Any = LIVOX_POINT_DTYPE.fields or {}
    fields = [_types["sensor_msgs/msg/PointField"](name=name, offset=layout[name][1],
                                                   datatype=_POINTFIELD_OF[layout[name][0].str], count=1)
              for name in LIVOX_POINT_DTYPE.names or ()]
    msg = _types[T.POINTCLOUD2](header=_header(t0, frame_id), height=1, width=n, fields=fields,
                                is_bigendian=False, point_step=LIVOX_POINT_DTYPE.itemsize,
                                row_step=LIVOX_POINT_DTYPE.itemsize * n,
                                data=np.frombuffer(rec.tobytes(), dtype=np.uint8), is_dense=True)
    return t0, msg


def pointcloud2_points(msg: Any, topic: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(points (N,3) float32/64, times (N,) s, intensity or None) of any PointCloud2 with x, y, z.

    The per-point time is the first of ``timestamp``, ``time``, ``t``, ``offset_time``: taken
    as absolute (ns or s) when it lands within TIME_FIELD_MATCH of the header stamp, else as an
    offset from the stamp (ns for integers and for float64 values above 1e3, else s). Without
    one every point gets the header stamp."""
    stamp = from_stamp(msg.header.stamp)
    if msg.is_bigendian:
        raise BagError(f"{topic}: big-endian PointCloud2 is not supported")
    fields = {f.name: f for f in msg.fields}
    missing = [c for c in ("x", "y", "z") if c not in fields]
    if missing:
        raise BagError(f"{topic} at t={stamp:.3f} s: PointCloud2 has no {'/'.join(missing)} field "
                       f"(fields: {sorted(fields)})")
    n = int(msg.width) * int(msg.height)
    step = int(msg.point_step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if n == 0:
        return np.zeros((0, 3), np.float32), np.zeros(0), None
    if step <= 0 or len(data) < n * step:
        raise BagError(f"{topic} at t={stamp:.3f} s: PointCloud2 data holds {len(data)} bytes, "
                       f"{n} points of {step} bytes need {n * step}")

    def column(name: str) -> np.ndarray:
        f = fields[name]
        kind = _POINTFIELD.get(int(f.datatype))
        if kind is None:
            raise BagError(f"{topic}: PointField {name!r} has unknown datatype {f.datatype}")
        dt = np.dtype({"names": [name], "formats": ["<" + kind], "offsets": [int(f.offset)], "itemsize": step})
        return np.frombuffer(data[: n * step].tobytes(), dtype=dt)[name]

    xyz = [column(c) for c in ("x", "y", "z")]
    dtype = np.float64 if any(c.dtype == np.float64 for c in xyz) else np.float32
    points = np.stack(xyz, axis=1).astype(dtype, copy=False)
    intensity = column("intensity").astype(np.float32) if "intensity" in fields else None
    time_name = next((c for c in ("timestamp", "time", "t", "offset_time") if c in fields), None)
    if time_name is None:
        return points, np.full(n, stamp), intensity
    raw = column(time_name).astype(np.float64)
    # absolute times hold the stamp near their first point (livox_ros_driver2) or their middle;
    # a live flight's scan may span seconds (every scan since the flight last asked), so both
    first, med = float(np.min(raw)), float(np.median(raw))
    for scale in (1e-9, 1.0):
        if min(abs(first * scale - stamp), abs(med * scale - stamp)) <= TIME_FIELD_MATCH:
            return points, raw * scale, intensity
    integer = fields[time_name].datatype not in (7, 8)
    scale = 1e-9 if integer or abs(med) > 1e3 else 1.0
    return points, stamp + raw * scale, intensity


def custom_msg_points(msg: Any, topic: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (N,3) float32, times (N,) s, reflectivity) of a livox_ros_driver2 CustomMsg:
    a point's time is ``timebase + offset_time`` (ns)."""
    pts = msg.points
    if len(pts) != int(msg.point_num):
        stamp = from_stamp(msg.header.stamp)
        raise BagError(f"{topic} at t={stamp:.3f} s: CustomMsg point_num {msg.point_num} but {len(pts)} points")
    points = np.array([[p.x, p.y, p.z] for p in pts], dtype=np.float32).reshape(-1, 3)
    times = (float(msg.timebase) + np.array([p.offset_time for p in pts], dtype=np.float64)) * 1e-9
    intensity = np.array([p.reflectivity for p in pts], dtype=np.float32)
    return points, times, intensity


# -- camera -------------------------------------------------------------------------------------
JPEG_QUALITY = 95


def image_to_compressed(frame: CameraFrame, frame_id: str) -> Any:
    ok, buf = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise BagError(f"image at t={frame.time:.3f} s: jpeg encoding failed")
    return _types[T.COMPRESSED_IMAGE](header=_header(frame.time, frame_id), format="jpeg",
                                      data=np.asarray(buf, dtype=np.uint8).ravel())


def image_raw(frame: CameraFrame, frame_id: str) -> Any:
    img = np.ascontiguousarray(frame.image, dtype=np.uint8)
    h, w = img.shape[:2]
    return _types[T.IMAGE](header=_header(frame.time, frame_id), height=h, width=w, encoding="bgr8",
                           is_bigendian=0, step=3 * w, data=img.reshape(-1))


def image_from(msg: Any, msgtype: str, topic: str) -> np.ndarray:
    """(H, W, 3) uint8 BGR of a CompressedImage or an Image (bgr8, rgb8, mono8)."""
    stamp = from_stamp(msg.header.stamp)
    if msgtype == T.COMPRESSED_IMAGE:
        img = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise BagError(f"{topic} at t={stamp:.3f} s: could not decode the {msg.format!r} image")
        return img
    h, w, enc = int(msg.height), int(msg.width), str(msg.encoding)
    channels = {"bgr8": 3, "rgb8": 3, "mono8": 1}.get(enc)
    if channels is None:
        raise BagError(f"{topic} at t={stamp:.3f} s: Image encoding {enc!r} not supported (bgr8, rgb8, mono8)")
    data = np.asarray(msg.data, dtype=np.uint8)
    if int(msg.step) < w * channels or len(data) < h * int(msg.step):
        raise BagError(f"{topic} at t={stamp:.3f} s: Image data too short for {w}x{h} {enc}")
    img = data[: h * int(msg.step)].reshape(h, int(msg.step))[:, : w * channels].reshape(h, w, channels)
    if enc == "rgb8":
        return np.ascontiguousarray(img[:, :, ::-1])
    if enc == "mono8":
        return np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img)


def camera_info(camera: ir.CameraModel, t: float, frame_id: str) -> Any:
    k = np.array([camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0])
    p = np.array([camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    roi = _types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return _types[T.CAMERA_INFO](header=_header(t, frame_id), height=int(camera.height), width=int(camera.width),
                                 distortion_model="plumb_bob", d=np.array([float(v) for v in camera.dist]),
                                 k=k, r=np.eye(3).ravel(), p=p, binning_x=0, binning_y=0, roi=roi)


def camera_from_info(msg: Any, topic: str) -> ir.CameraModel:
    stamp = from_stamp(msg.header.stamp)
    model = str(msg.distortion_model)
    d = [float(v) for v in msg.d]
    if model not in ("plumb_bob", "rational_polynomial", "") or (model == "rational_polynomial" and any(d[5:])):
        raise BagError(f"{topic} at t={stamp:.3f} s: distortion model {model!r} not supported (plumb_bob)")
    dist = (d + [0.0] * 5)[:5]
    k = np.asarray(msg.k, dtype=np.float64)
    try:
        return ir.CameraModel(float(k[0]), float(k[4]), float(k[2]), float(k[5]), int(msg.width), int(msg.height),
                              dist=dist)
    except (ValueError, TypeError) as exc:
        raise BagError(f"{topic} at t={stamp:.3f} s: bad CameraInfo: {exc}") from exc


# -- extrinsics ---------------------------------------------------------------------------------
def transform_stamped(T_parent_child: np.ndarray, t: float, parent: str, child: str) -> Any:
    q = quat_from_matrix(T_parent_child[:3, :3])
    tr = T_parent_child[:3, 3]
    return _types["geometry_msgs/msg/TransformStamped"](
        header=_header(t, parent), child_frame_id=child,
        transform=_types["geometry_msgs/msg/Transform"](
            translation=_types["geometry_msgs/msg/Vector3"](x=float(tr[0]), y=float(tr[1]), z=float(tr[2])),
            rotation=_types["geometry_msgs/msg/Quaternion"](x=float(q[1]), y=float(q[2]), z=float(q[3]),
                                                            w=float(q[0]))))


def tf_message(transforms: list[Any]) -> Any:
    return _types[T.TF_MESSAGE](transforms=transforms)


def transforms_from(msg: Any, topic: str) -> dict[tuple[str, str], np.ndarray]:
    """{(parent, child): T_parent_child} of a TFMessage."""
    out = {}
    for ts in msg.transforms:
        tr, q = ts.transform.translation, ts.transform.rotation
        T_pc = np.eye(4)
        T_pc[:3, :3] = matrix_from_quat([q.w, q.x, q.y, q.z], f"{topic} {ts.header.frame_id}->{ts.child_frame_id}")
        T_pc[:3, 3] = [tr.x, tr.y, tr.z]
        out[(str(ts.header.frame_id).lstrip("/"), str(ts.child_frame_id).lstrip("/"))] = T_pc
    return out


# -- pose ---------------------------------------------------------------------------------------
def odometry(pose: PoseStamped, velocity_w: np.ndarray | None, world: str, body: str) -> Any:
    R = pose.T_w_b[:3, :3]
    q = quat_from_matrix(R)
    p = pose.T_w_b[:3, 3]
    v_b = R.T @ (np.zeros(3) if velocity_w is None else np.asarray(velocity_w, dtype=np.float64))
    g = _types
    cov = np.zeros(36)
    return g[T.ODOMETRY](
        header=_header(pose.time, world), child_frame_id=body,
        pose=g["geometry_msgs/msg/PoseWithCovariance"](
            pose=g["geometry_msgs/msg/Pose"](
                position=g["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
                orientation=g["geometry_msgs/msg/Quaternion"](x=float(q[1]), y=float(q[2]), z=float(q[3]),
                                                              w=float(q[0]))),
            covariance=cov),
        twist=g["geometry_msgs/msg/TwistWithCovariance"](
            twist=g["geometry_msgs/msg/Twist"](
                linear=g["geometry_msgs/msg/Vector3"](x=float(v_b[0]), y=float(v_b[1]), z=float(v_b[2])),
                angular=g["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
            covariance=cov))


def pose_from_odometry(msg: Any, topic: str) -> PoseStamped:
    t = from_stamp(msg.header.stamp)
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    T_w_b = np.eye(4)
    T_w_b[:3, :3] = matrix_from_quat([q.w, q.x, q.y, q.z], f"{topic} at t={t:.3f} s: pose.orientation")
    T_w_b[:3, 3] = [p.x, p.y, p.z]
    if not np.all(np.isfinite(T_w_b)):
        raise BagError(f"{topic} at t={t:.3f} s: non-finite pose")
    return PoseStamped(t, T_w_b)


def pose_from_px4(msg: Any, topic: str) -> PoseStamped:
    """PX4 VehicleOdometry (NED position, FRD->NED quaternion, µs stamps) as T_w_b in ENU/FLU."""
    t = float(msg.timestamp_sample or msg.timestamp) * 1e-6
    if int(msg.pose_frame) != T.PX4_POSE_FRAME_NED:
        raise BagError(f"{topic} at t={t:.3f} s: VehicleOdometry pose_frame {msg.pose_frame} "
                       f"(only NED = {T.PX4_POSE_FRAME_NED} is a world pose)")
    R_ned_frd = matrix_from_quat(np.asarray(msg.q, dtype=np.float64), f"{topic} at t={t:.3f} s: q")
    T_w_b = np.eye(4)
    T_w_b[:3, :3] = ENU_TO_NED.T @ R_ned_frd @ FLU_TO_FRD
    T_w_b[:3, 3] = ned_to_enu(np.asarray(msg.position, dtype=np.float64))
    if not np.all(np.isfinite(T_w_b)):
        raise BagError(f"{topic} at t={t:.3f} s: non-finite position (PX4 sends NaN when it has no estimate)")
    return PoseStamped(t, T_w_b)
