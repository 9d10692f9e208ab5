"""The live ``Sensors`` adapter: a Livox Mid-360 and an OpenCV camera behind one port.

Either may be absent (a LiDAR-only or camera-only rig): its methods then return None.
The camera is fixed to the airframe (no gimbal is commanded from here), so ``photo``
returns the newest frame with the camera's own ``T_b_c``, whatever pose was asked for;
the flight loop must aim the vehicle (yaw) for an inspection photo.
"""

from __future__ import annotations

import numpy as np

from insulator_rs.drivers.camera import OpenCvCamera
from insulator_rs.drivers.livox import LivoxMid360
from insulator_rs.sensors import CameraFrame, LidarScan


class LiveSensors:
    """``Sensors`` over live drivers (both already started)."""

    def __init__(self, lidar: LivoxMid360 | None, camera: OpenCvCamera | None) -> None:
        if lidar is None and camera is None:
            raise ValueError("LiveSensors: need a LiDAR, a camera, or both")
        self.lidar = lidar
        self.camera = camera

    def detection_frame(self, now: float) -> CameraFrame | None:
        return None if self.camera is None else self.camera.latest(now)

    def lidar_scan(self, now: float) -> LidarScan | None:
        return None if self.lidar is None else self.lidar.lidar_scan(now)

    def photo(self, now: float, T_b_c: np.ndarray) -> CameraFrame | None:
        return self.detection_frame(now)

    def health(self) -> dict[str, object]:
        out: dict[str, object] = {}
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
