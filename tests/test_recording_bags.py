"""Recorded flights: the MCAP writer, the bag reader, vendor types, and bad bags.

Independent references: ``mcap_ros2`` (Foxglove's decoder, not rosbags) decodes what the
recorder writes; rosbags' own writers (rosbag2 MCAP and sqlite3, ROS 1) write what the
reader must read. Tolerances: points are float32 and come back bit-exact; per-point times
go through float64 nanoseconds (1e-9 s); poses through ROS quaternions (1e-12).
"""

import math

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2

import insulator_rs as ir
from insulator_rs.exceptions import BagError
from insulator_rs.recording import convert as C
from insulator_rs.recording import types as T
from insulator_rs.recording.reader import FlightBag
from insulator_rs.recording.writer import McapRecorder
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped

CAM = ir.CameraModel(300, 300, 159.5, 119.5, 320, 240, dist=[0.1, -0.02, 0.001, 0.0, 0.0])
T_B_L = np.array([[1, 0, 0, 0.1], [0, 1, 0, 0], [0, 0, 1, 0.05], [0, 0, 0, 1.0]])
T_B_C = np.array([[0, 0, 1, 0.2], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1.0]])


def yaw_pose(t, x, yaw):
    T_ = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T_[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T_[:3, 3] = [x, 2.0, 10.0]
    return PoseStamped(t, T_)


def smooth_image(rng):
    """A gradient with a bright box (jpeg keeps such images within a few grey levels)."""
    y, x = np.mgrid[0:240, 0:320]
    img = np.stack([x * 0.7, y * 0.9, (x + y) * 0.4], axis=2) + rng.uniform(0, 30)
    x0, y0 = rng.integers(20, 200), rng.integers(20, 150)
    img[y0:y0 + 40, x0:x0 + 60] = 230
    return np.clip(img, 0, 255).astype(np.uint8)


def synthetic(n_ticks=30, seed=0):
    """(poses, scans, frames) of a short flight: poses at 20 Hz, scans at 10 Hz, frames at 4 Hz."""
    rng = np.random.default_rng(seed)
    poses, scans, frames = [], [], []
    for k in range(n_ticks):
        t = 1.0 + 0.05 * k
        poses.append(yaw_pose(t, 0.5 * t, 0.1 * t))
        if k % 2 == 0 and k + 2 < n_ticks:
            pts = rng.normal(size=(500, 3)).astype(np.float32) * 5
            scans.append(LidarScan(pts, t + np.linspace(0, 0.1, 500), T_B_L, rng.uniform(0, 255, 500).astype(np.float32)))
        if k % 5 == 0:
            frames.append(CameraFrame(t, smooth_image(rng), CAM, T_B_C))
    return poses, scans, frames


def record(path, data, **kw):
    poses, scans, frames = data
    rec = McapRecorder(path, **kw)
    items = [(p.time, 0, p) for p in poses] + [(s.time_start, 1, s) for s in scans] + [(f.time, 2, f) for f in frames]
    for _, kind, v in sorted(items, key=lambda x: (x[0], x[1])):
        if kind == 0:
            rec.pose(v, np.array([0.5, 0, 0]))
        elif kind == 1:
            rec.scan(v, T_B_C)
        else:
            rec.frame(v, T_B_L)
    rec.close()
    return path


def read_all(path, **kw):
    with FlightBag(path, **kw) as bag:
        return bag, list(bag.items())


def test_recorder_round_trip(tmp_path):
    data = synthetic()
    path = record(tmp_path / "f.mcap", data, image_format="raw")
    bag, items = read_all(path)
    assert np.allclose(bag.T_b_l, T_B_L, atol=1e-12) and np.allclose(bag.T_b_c, T_B_C, atol=1e-12)
    poses = [i.value for i in items if i.kind == "pose"]
    scans = [i.value for i in items if i.kind == "scan"]
    frames = [i.value for i in items if i.kind == "frame"]
    assert len(poses) == len(data[0]) and len(scans) == len(data[1]) and len(frames) == len(data[2])
    for a, b in zip(poses, data[0]):
        assert a.time == pytest.approx(b.time, abs=1e-9) and np.allclose(a.T_w_b, b.T_w_b, atol=1e-12)
    for a, b in zip(scans, data[1]):
        assert np.array_equal(a.points_l, b.points_l) and np.array_equal(a.intensity, b.intensity)
        assert np.max(np.abs(a.times - b.times)) < 1e-9
    for a, b in zip(frames, data[2]):
        assert np.array_equal(a.image, b.image)  # raw: lossless
        assert (a.camera.fx, a.camera.cy, a.camera.width, tuple(a.camera.dist)) == \
               (CAM.fx, CAM.cy, CAM.width, tuple(CAM.dist))


def test_jpeg_frames_and_an_independent_decoder(tmp_path):
    """The default (CompressedImage jpeg) decodes to the image within jpeg's error, and Foxglove's
    mcap_ros2 decoder reads every message of the file with the schemas written into it."""
    from mcap_ros2.reader import read_ros2_messages

    data = synthetic()
    path = record(tmp_path / "f.mcap", data)
    _, items = read_all(path)
    frames = [i.value for i in items if i.kind == "frame"]
    assert all(np.mean(np.abs(a.image.astype(float) - b.image)) < 3 for a, b in zip(frames, data[2]))
    topics = {}
    for m in read_ros2_messages(str(path)):
        topics[m.channel.topic] = topics.get(m.channel.topic, 0) + 1
        if m.channel.topic == "/livox/lidar":
            names = [f.name for f in m.ros_msg.fields]
            assert names == ["x", "y", "z", "intensity", "tag", "line", "timestamp"] and m.ros_msg.point_step == 26
    assert topics == {"/odom": len(data[0]), "/livox/lidar": len(data[1]), "/camera/image_raw/compressed": len(data[2]),
                      "/camera/camera_info": len(data[2]), "/tf_static": 1}


def _rosbags_write(writer, store, serialize, data, *, lidar_type=T.POINTCLOUD2, odom_type=T.ODOMETRY,
                   odom_topic="/odom"):
    """Write the synthetic flight with rosbags' writer (ROS 1 or rosbag2)."""
    poses, scans, frames = data
    conns = {}

    def put(topic, msgtype, t, msg):
        if topic not in conns:
            conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
        writer.write(conns[topic], int(round(t * 1e9)), serialize(msg, msgtype))

    tp = T.Topics()
    put("/tf_static", T.TF_MESSAGE, 0.5, C.tf_message([C.transform_stamped(T_B_L, 0.5, "base_link", "livox_frame"),
                                                      C.transform_stamped(T_B_C, 0.5, "base_link",
                                                                          "camera_optical_frame")]))
    items = [(p.time, 0, p) for p in poses] + [(s.time_start, 1, s) for s in scans] + [(f.time, 2, f) for f in frames]
    for t, kind, v in sorted(items, key=lambda x: (x[0], x[1])):
        if kind == 0:
            if odom_type == T.ODOMETRY:
                put(odom_topic, T.ODOMETRY, t, C.odometry(v, None, "map", "base_link"))
            else:
                put(odom_topic, T.PX4_ODOMETRY, t, px4_odometry(v))
        elif kind == 1:
            if lidar_type == T.POINTCLOUD2:
                put(tp.lidar, T.POINTCLOUD2, t, C.scan_to_pointcloud2(v, "livox_frame")[1])
            else:
                put(tp.lidar, lidar_type, t, custom_msg(v, lidar_type, store))
        else:
            put(tp.camera_info, T.CAMERA_INFO, t, C.camera_info(CAM, t, "camera_optical_frame"))
            put(tp.image, T.COMPRESSED_IMAGE, t, C.image_to_compressed(v, "camera_optical_frame"))


def px4_odometry(p):
    """PX4's VehicleOdometry of a pose: NED position, FRD->NED quaternion, µs stamps (the
    inverse of the reader's conversion, written out independently with explicit axes)."""
    R_enu_flu = p.T_w_b[:3, :3]
    ned_from_enu = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    frd_from_flu = np.diag([1.0, -1, -1])
    R_ned_frd = ned_from_enu @ R_enu_flu @ frd_from_flu
    pos = ned_from_enu @ p.T_w_b[:3, 3]
    us = int(round(p.time * 1e6))
    return T.typestore().types[T.PX4_ODOMETRY](
        timestamp=us, timestamp_sample=us, pose_frame=1, position=pos.astype(np.float32),
        q=C.quat_from_matrix(R_ned_frd).astype(np.float32), velocity_frame=1, velocity=np.zeros(3, np.float32),
        angular_velocity=np.zeros(3, np.float32), position_variance=np.zeros(3, np.float32),
        orientation_variance=np.zeros(3, np.float32), velocity_variance=np.zeros(3, np.float32),
        reset_counter=0, quality=0)


def custom_msg(scan, msgtype, store):
    ns0 = int(round(scan.time_start * 1e9))
    P = store.types[msgtype.replace("CustomMsg", "CustomPoint")]
    pts = [P(offset_time=int(round(t * 1e9)) - ns0, x=float(p[0]), y=float(p[1]), z=float(p[2]),
             reflectivity=int(i), tag=0, line=k % 4)
           for k, (p, t, i) in enumerate(zip(scan.points_l, scan.times, scan.intensity))]
    return store.types[msgtype](header=C._header(scan.time_start, "livox_frame"), timebase=ns0, point_num=len(pts),
                                lidar_id=0, rsvd=np.zeros(3, np.uint8), points=pts)


@pytest.mark.parametrize("storage", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_rosbag2_written_by_rosbags_is_read(tmp_path, storage):
    store = T.typestore()
    data = synthetic()
    with Writer2(tmp_path / "bag", version=9, storage_plugin=storage) as w:
        _rosbags_write(w, store, store.serialize_cdr, data)
    _, items = read_all(tmp_path / "bag")
    scans = [i.value for i in items if i.kind == "scan"]
    assert len(scans) == len(data[1]) and np.array_equal(scans[0].points_l, data[1][0].points_l)
    assert sum(i.kind == "pose" for i in items) == len(data[0])
    if storage == StoragePlugin.MCAP:  # the .mcap inside the folder opens on its own too
        (mcap_file,) = (tmp_path / "bag").glob("*.mcap")
        assert len(read_all(mcap_file)[1]) == len(items)


def test_px4_odometry_and_livox_custom_msg(tmp_path):
    """rosbag2 with px4_msgs/VehicleOdometry on /fmu/out/vehicle_odometry (NED/FRD -> ENU/FLU)
    and livox_ros_driver2/CustomMsg on /livox/lidar."""
    store = T.typestore()
    data = synthetic()
    with Writer2(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        _rosbags_write(w, store, store.serialize_cdr, data, lidar_type=T.LIVOX_CUSTOM, odom_type=T.PX4_ODOMETRY,
                       odom_topic="/fmu/out/vehicle_odometry")
    bag, items = read_all(tmp_path / "bag")
    assert bag.odometry_topic == "/fmu/out/vehicle_odometry"
    poses = [i.value for i in items if i.kind == "pose"]
    for a, b in zip(poses, data[0]):
        assert a.time == pytest.approx(b.time, abs=1e-6)
        assert np.allclose(a.T_w_b, b.T_w_b, atol=1e-5)  # float32 fields
    scans = [i.value for i in items if i.kind == "scan"]
    assert np.array_equal(scans[1].points_l, data[1][1].points_l)
    assert np.max(np.abs(scans[1].times - data[1][1].times)) < 1e-9


def test_ros1_bag_with_livox_custom_msg(tmp_path):
    store = T.typestore()
    store.register({k.replace("livox_ros_driver2", "livox_ros_driver"): v for k, v in store.fielddefs.items()
                    if k.startswith("livox_ros_driver2/")})
    data = synthetic()
    with Writer1(tmp_path / "f.bag") as w:
        _rosbags_write(w, store, store.serialize_ros1, data, lidar_type="livox_ros_driver/msg/CustomMsg")
    _, items = read_all(tmp_path / "f.bag")
    scans = [i.value for i in items if i.kind == "scan"]
    assert len(scans) == len(data[1]) and np.array_equal(scans[-1].points_l, data[1][-1].points_l)
    assert sum(i.kind == "frame" for i in items) == len(data[2])


# -- bad bags -------------------------------------------------------------------------------------
def _write_raw(path, messages):
    """An MCAP file of (topic, type, log time, msg)."""
    rec = McapRecorder(path)
    for topic, msgtype, t, msg in messages:
        rec.write(topic, msgtype, t, msg)
    rec.close()
    return path


def _good_messages(data=None, *, tweak=None):
    poses, scans, frames = data or synthetic()
    out = [("/tf_static", T.TF_MESSAGE, 0.5, C.tf_message([
        C.transform_stamped(T_B_L, 0.5, "base_link", "livox_frame"),
        C.transform_stamped(T_B_C, 0.5, "base_link", "camera_optical_frame")]))]
    items = [(p.time, 0, p) for p in poses] + [(s.time_start, 1, s) for s in scans] + [(f.time, 2, f) for f in frames]
    for t, kind, v in sorted(items, key=lambda x: (x[0], x[1])):
        if kind == 0:
            out.append(("/odom", T.ODOMETRY, t, C.odometry(v, None, "map", "base_link")))
        elif kind == 1:
            out.append(("/livox/lidar", T.POINTCLOUD2, t, C.scan_to_pointcloud2(v, "livox_frame")[1]))
        else:
            out.append(("/camera/camera_info", T.CAMERA_INFO, t, C.camera_info(CAM, t, "camera_optical_frame")))
            out.append(("/camera/image_raw/compressed", T.COMPRESSED_IMAGE, t,
                        C.image_to_compressed(v, "camera_optical_frame")))
    return out


def test_missing_file_and_not_a_recording(tmp_path):
    with pytest.raises(BagError, match="no such file"):
        FlightBag(tmp_path / "nope.mcap")
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(BagError, match="not a recorded flight"):
        FlightBag(tmp_path / "x.txt")
    (tmp_path / "garbage.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 50)
    with pytest.raises(BagError, match="garbage.mcap: cannot open"):
        FlightBag(tmp_path / "garbage.mcap")


def test_missing_topic_is_named(tmp_path):
    msgs = [m for m in _good_messages() if m[0] != "/livox/lidar"]
    path = _write_raw(tmp_path / "f.mcap", msgs)
    with pytest.raises(BagError, match=r"topic /livox/lidar \(LiDAR\) is not in the recording; topics present: .*/odom"):
        FlightBag(path)
    with pytest.raises(BagError, match="topic /scan"):
        FlightBag(path, T.Topics(lidar="/scan"))


def test_wrong_message_type_is_named(tmp_path):
    msgs = [m if m[0] != "/odom" else ("/odom", T.CAMERA_INFO, m[2], C.camera_info(CAM, m[2], "x"))
            for m in _good_messages()]
    path = _write_raw(tmp_path / "f.mcap", msgs)
    with pytest.raises(BagError, match=r"topic /odom \(vehicle pose\) has message type sensor_msgs/msg/CameraInfo; "
                                       r"expected nav_msgs/msg/Odometry or px4_msgs/msg/VehicleOdometry"):
        FlightBag(path)


def test_missing_extrinsics_are_named(tmp_path):
    msgs = _good_messages()
    msgs[0] = ("/tf_static", T.TF_MESSAGE, 0.5, C.tf_message([C.transform_stamped(T_B_L, 0.5, "base_link", "lidar")]))
    path = _write_raw(tmp_path / "f.mcap", msgs)
    with pytest.raises(BagError, match="/tf_static has no transform from base_link to livox_frame"):
        FlightBag(path)


def _stream_error(path):
    with FlightBag(path) as bag:
        n = 0
        with pytest.raises(BagError) as err:
            for _ in bag.items():
                n += 1
    return str(err.value), n


def test_out_of_order_stamps_are_named(tmp_path):
    msgs = _good_messages()
    odom = [k for k, m in enumerate(msgs) if m[0] == "/odom"]
    k = odom[10]
    topic, typ, t, _ = msgs[k]
    msgs[k] = (topic, typ, t, C.odometry(yaw_pose(t - 0.3, 0, 0), None, "map", "base_link"))
    text, n = _stream_error(_write_raw(tmp_path / "f.mcap", msgs))
    assert f"/odom at t={t - 0.3:.3f} s: stamp is earlier than the previous one" in text and "out of order" in text
    assert n > 10


def test_jumping_stamps_are_named(tmp_path):
    msgs = _good_messages()
    k = [k for k, m in enumerate(msgs) if m[0] == "/livox/lidar"][5]
    topic, typ, t, msg = msgs[k]
    scan = [s for s in synthetic()[1] if abs(s.time_start - t) < 1e-9][0]
    moved = LidarScan(scan.points_l, scan.times + 30.0, T_B_L, scan.intensity)
    msgs[k] = (topic, typ, t, C.scan_to_pointcloud2(moved, "livox_frame")[1])
    text, _ = _stream_error(_write_raw(tmp_path / "f.mcap", msgs))
    # a scan is named by its newest point (its pace: a live scan may hold seconds of points)
    assert f"/livox/lidar at t={float(moved.times.max()):.3f} s: stamp jumps +30.000 s against the recording's clock" in text


def test_truncated_file_is_read_up_to_the_cut_and_named(tmp_path):
    """A recording cut short (no summary, no end magic: a crash mid-flight) is read up to
    the last whole chunk, then the break is named; a cut inside the first chunk cannot be."""
    data = synthetic(n_ticks=400)
    path = record(tmp_path / "f.mcap", data, image_format="raw")  # large: several 1 MB chunks
    raw = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: int(len(raw) * 0.6)])
    got = []
    with pytest.raises(BagError, match=r"cut.mcap: the recording breaks off after .* at t=.*truncated"):
        with FlightBag(cut) as bag:
            assert bag.truncated
            for item in bag.items():
                got.append(item)
    n_all = len(data[0]) + len(data[1]) + len(data[2])
    assert 0.3 * n_all < len(got) < n_all
    poses = [i.value for i in got if i.kind == "pose"]
    assert np.allclose(poses[-1].T_w_b, data[0][len(poses) - 1].T_w_b)
    # the recorder finishes its chunk every second of log time (a killed flight keeps what it
    # recorded up to then): its first chunk, the first pose alone, ends within a few hundred bytes
    (tmp_path / "head.mcap").write_bytes(raw[:120])
    with pytest.raises(BagError, match="head.mcap: cannot open the recording"):
        FlightBag(tmp_path / "head.mcap")
