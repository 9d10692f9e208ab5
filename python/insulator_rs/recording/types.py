"""ROS message types and the topic/frame names of a recorded flight.

The type store is rosbags' ROS 2 Humble store plus the two vendor types users' drivers
publish: ``livox_ros_driver2/msg/CustomMsg`` (Livox' own point format) and
``px4_msgs/msg/VehicleOdometry`` (PX4's uORB odometry over the uXRCE-DDS bridge, v1.14+
layout). Their definitions are copied from those packages' ``.msg`` files (field names and
types only; the constants PX4 defines are listed where they are used).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
ODOMETRY = "nav_msgs/msg/Odometry"
LIVOX_CUSTOM = "livox_ros_driver2/msg/CustomMsg"
LIVOX_POINT = "livox_ros_driver2/msg/CustomPoint"
PX4_ODOMETRY = "px4_msgs/msg/VehicleOdometry"

_LIVOX_POINT_MSG = """
uint32 offset_time
float32 x
float32 y
float32 z
uint8 reflectivity
uint8 tag
uint8 line
"""

_LIVOX_CUSTOM_MSG = """
std_msgs/Header header
uint64 timebase
uint32 point_num
uint8 lidar_id
uint8[3] rsvd
livox_ros_driver2/CustomPoint[] points
"""

_PX4_ODOMETRY_MSG = """
uint64 timestamp
uint64 timestamp_sample
uint8 pose_frame
float32[3] position
float32[4] q
uint8 velocity_frame
float32[3] velocity
float32[3] angular_velocity
float32[3] position_variance
float32[3] orientation_variance
float32[3] velocity_variance
uint8 reset_counter
int8 quality
"""

# px4_msgs/VehicleOdometry constants
PX4_POSE_FRAME_NED = 1
PX4_VELOCITY_FRAME_NED = 1


@lru_cache(maxsize=1)
def typestore() -> Typestore:
    """ROS 2 Humble types plus the Livox and PX4 vendor types (one shared instance)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    types.update(get_types_from_msg(_LIVOX_POINT_MSG, LIVOX_POINT))
    types.update(get_types_from_msg(_LIVOX_CUSTOM_MSG, LIVOX_CUSTOM))
    types.update(get_types_from_msg(_PX4_ODOMETRY_MSG, PX4_ODOMETRY))
    store.register(types)
    return store


@dataclass(frozen=True)
class Topics:
    """Topic and frame names of a recorded flight; defaults are what livox_ros_driver2, a ROS
    camera driver, PX4's uXRCE-DDS bridge and tf2 publish."""

    lidar: str = "/livox/lidar"
    image: str = "/camera/image_raw/compressed"
    camera_info: str = "/camera/camera_info"
    odometry: str = "/fmu/out/vehicle_odometry"
    tf_static: str = "/tf_static"
    world_frame: str = "map"
    body_frame: str = "base_link"
    lidar_frame: str = "livox_frame"
    camera_frame: str = "camera_optical_frame"
