"""A simulated payload (sim/payload.py) and the MAVLink adapter (mavlink/payload.py) on it over UDP,
with bounds short enough for the quick tier: the payload tests' one rig."""

from __future__ import annotations

import math
import time

import numpy as np

import insulator_rs as ir
from insulator_rs.geodesy import GeoPoint
from insulator_rs.inspection_camera import GimbalLimits, InspectionCamera
from insulator_rs.mavlink.payload import GimbalRoute, MavlinkPayload, PayloadSettings
from insulator_rs.poses import pose_from_yaw
from insulator_rs.sim.mesh import InstanceInfo, Mesh, box
from insulator_rs.sim.payload import PayloadDynamics, PayloadFaults, SimulatedPayload, scene_photo_renderer

ORIGIN = GeoPoint(47.0, 8.0, 400.0)
TARGET = np.array([12.0, 2.0, 6.0])  # the box's centre (W)
SPEED = np.array([0.0, 1.5, 0.0])  # m/s: the airframe moves, so the capture's pose is not the request's
FAST = PayloadSettings(attempts=2, command_timeout_s=0.2, lost_after_s=0.4, slew_timeout_s=0.4,
                       zoom_timeout_s=0.8, capture_timeout_s=0.3, download_timeout_s=0.6, ftp_retry_s=0.15,
                       ftp_idle_s=0.4, heartbeat_period_s=0.1)
QUICK = PayloadDynamics(slew_rate=math.radians(300), zoom_time_s=0.2, capture_latency_s=0.05,
                        heartbeat_period_s=0.1, status_period_s=0.02)


def inspection_camera(*, pixel_pitch_um: float | None = 2.0) -> InspectionCamera:
    wide = ir.CameraModel(200.0, 200.0, 80.0, 60.0, 160, 120)
    step = ir.CameraModel(610.0, 590.0, 82.0, 61.0, 160, 120)  # a calibrated zoom step: not the wide one scaled
    return InspectionCamera(wide, np.array([[0, 0, 1, 0.1], [-1, 0, 0, 0], [0, -1, 0, -0.1], [0, 0, 0, 1.0]]),
                            (200.0, 800.0), GimbalLimits((math.radians(-90), math.radians(25)),
                                                         (math.radians(-60), math.radians(60))),
                            pixel_pitch_um=pixel_pitch_um, zoom_steps=(step,))


def scene() -> Mesh:
    """One red box (an "insulator") at TARGET."""
    return box(TARGET, (0.6, 0.6, 0.6), instance_id=1,
               info=InstanceInfo("insulator", kind="insulator", color=(1.0, 0.0, 0.0)))


class Rig:
    """A simulated payload on a one-box scene, the airframe flying past it at SPEED, and the
    adapter on the payload (the gimbal device aimed directly unless ``route`` says otherwise)."""

    def __init__(self, faults: PayloadFaults | None = None, *, pixel_pitch_um: float | None = 2.0,
                 route: str = GimbalRoute.DEVICE, http: bool = False, dynamics: PayloadDynamics = QUICK) -> None:
        self.t0 = time.monotonic()
        self.inspection = inspection_camera(pixel_pitch_um=pixel_pitch_um)
        self.sim = SimulatedPayload(self.inspection, pose=self.pose, clock=self.clock,
                                    render=scene_photo_renderer(scene()), origin=ORIGIN, dynamics=dynamics,
                                    faults=faults, seed=3, http=http).start()
        self.adapter = MavlinkPayload(self.sim.url, self.inspection, gimbal_route=route, settings=FAST)

    def clock(self) -> float:
        return time.monotonic() - self.t0

    def pose(self, t: float) -> np.ndarray:
        return pose_from_yaw(np.array([0.0, -1.0, 5.0]) + SPEED * t, 0.0)

    def aim(self) -> tuple[float, float]:
        """(pitch, yaw) at the target from where the airframe is now (a camera near the body origin)."""
        d = TARGET - self.pose(self.clock())[:3, 3]
        return math.atan2(d[2], math.hypot(d[0], d[1])), math.atan2(d[1], d[0])

    def close(self) -> None:
        self.adapter.close()
        self.sim.close()

    def __enter__(self) -> Rig:
        wait_alive(self)
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def wait_alive(r: Rig) -> None:
    """Until the adapter has heard the camera's and the gimbal's HEARTBEAT (2 s at most)."""
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and not r.adapter.alive():
        time.sleep(0.02)
