"""The ``Sensors`` port: what the flight loop and the perception pipeline read from the world.

Like PX4's drivers publishing on uORB, every sensor source is an adapter behind this
one interface, and the consumers (the flight loop, :mod:`insulator_rs.perception`-side
code, the report) never know which one they read:

* the simulator (``insulator_rs.sim.sensors``): renders the scene from the airframe's
  true pose, which only the simulator knows;
* a recorded flight (MCAP / rosbag2 / ROS 1 bag), replayed offline;
* live drivers: a Livox Mid-360 over UDP and a camera through OpenCV.

Every stamp is in ONE clock, the vehicle's (seconds, the clock of
:attr:`insulator_rs.ports.vehicle.VehicleState.time`): a source whose sensor has a clock of
its own converts at its edge (see the time-sync module) before anything leaves it.
Frames follow DESIGN.md: points in the LiDAR frame L, images in the camera optical
frame C, extrinsics ``T_b_l``/``T_b_c`` (4x4 float64, ``p_b = T_b_x @ p_x``).
"""

from __future__ import annotations

import math

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs.ports.capabilities import ExplainsMissingPhoto, ReportsStreams
from insulator_rs.ports.capabilities import StreamStatus as StreamStatus  # re-exported: the streams capability's data


@dataclass(frozen=True)
class CameraFrame:
    """One camera image.

    ``time``: vehicle clock (s) at exposure. ``image``: (H, W, 3) uint8, BGR (OpenCV's
    order). ``camera``: the intrinsics of this image (its width/height match ``image``).
    ``T_b_c``: the camera's pose in the body frame at exposure (a gimbal's angle included).
    """

    time: float
    image: np.ndarray
    camera: CameraModel
    T_b_c: np.ndarray


@dataclass(frozen=True)
class LidarScan:
    """One LiDAR scan (a Mid-360 frame spans 100 ms of flight).

    ``points_l``: (N, 3) float32 or float64 in L, metres. ``times``: (N,) float64 vehicle
    clock (s) of each point. ``T_b_l``: the LiDAR's extrinsics. ``intensity``: (N,)
    reflectivity 0..255 where the sensor gives it. ``window_end``: the end (vehicle clock) of
    the time the scan covers, where the source knows it (the simulator renders up to the
    instant asked for); None: its last point's time.
    """

    points_l: np.ndarray
    times: np.ndarray
    T_b_l: np.ndarray
    intensity: np.ndarray | None = None
    window_end: float | None = None

    @property
    def covered_until(self) -> float:
        """The vehicle time up to which the scan holds every return: ``window_end`` or
        ``time_end``."""
        return self.time_end if self.window_end is None else float(self.window_end)

    @property
    def time_start(self) -> float:
        return float(self.times.min()) if len(self.times) else float("nan")

    @property
    def time_end(self) -> float:
        return float(self.times.max()) if len(self.times) else float("nan")

    def __len__(self) -> int:
        return len(self.points_l)


# s: a delivered scan that ends this far behind everything taken so far is not a repeat of the
# newest one (a live source hands that again until the next is complete: 0.1 s behind at most)
# but a step back of the clock its times were mapped with. Against PX4 SITL under load the
# lockstep vehicle clock stalls while the host's runs on; the companion's map of it then runs
# ahead, and once refitted steps back: every scan after that lay behind the horizon the ahead-run
# had set, was dropped as old, and the LiDAR read as silent for 10-15 s (two live tower B
# flights aborted "sensor lost"). A real autopilot's clock does not stall; the step is taken
# (counted) rather than waited out.
CLOCK_STEP_BACK_S = 1.0


class ScanIntake:
    """The points of each delivered scan that perception does not have yet.

    A live source returns the same newest scan until the next is complete, and the simulator's
    scans may overlap; only points newer than everything taken so far (the horizon) are new."""

    def __init__(self) -> None:
        self.horizon = -math.inf  # vehicle time of the newest LiDAR point taken
        self.steps_back = 0  # scans taken whole after a step back of the clock (CLOCK_STEP_BACK_S)

    def take(self, scan: LidarScan | None) -> LidarScan | None:
        """The new part of ``scan``, None when nothing in it is new; advances the horizon (or
        moves it back to a scan whose times the clock stepped back: taken whole, counted)."""
        if scan is None or not math.isfinite(scan.covered_until):  # no point, no window: nothing
            return None
        if scan.covered_until <= self.horizon - CLOCK_STEP_BACK_S:
            self.steps_back += 1
            self.horizon = scan.covered_until
            return scan
        if not scan.covered_until > self.horizon:
            return None
        if scan.time_start <= self.horizon:
            new = np.asarray(scan.times) > self.horizon
            scan = LidarScan(np.asarray(scan.points_l)[new], np.asarray(scan.times)[new], scan.T_b_l,
                             None if scan.intensity is None else np.asarray(scan.intensity)[new],
                             window_end=scan.window_end)
        self.horizon = scan.covered_until
        return scan


@dataclass(frozen=True)
class PoseStamped:
    """The vehicle's estimated pose: ``T_w_b`` (4x4 float64, W = local ENU) at ``time`` (s)."""

    time: float
    T_w_b: np.ndarray


def sensor_streams(sensors: object, now: float) -> list[StreamStatus] | None:
    """The streams of ``sensors`` at vehicle time ``now``
    (:class:`~insulator_rs.ports.capabilities.ReportsStreams`, which consumes nothing: the flight's
    data stay the flight's), or None for an adapter that cannot say."""
    return list(sensors.streams(now)) if isinstance(sensors, ReportsStreams) else None


@runtime_checkable
class Sensors(Protocol):
    """A source of timestamped camera frames and LiDAR scans (vehicle clock).

    ``now`` is the vehicle time of the caller: a live source returns the newest data it
    has received up to then, the simulator renders at that instant, a replay returns what
    was recorded up to then. None means nothing (new) is there, which is not an error:
    a sensor that stopped delivering is reported through ``health()``.
    """

    def detection_frame(self, now: float) -> CameraFrame | None:
        """The newest camera frame for detection, stamped at or before ``now``."""
        ...

    def lidar_scan(self, now: float) -> LidarScan | None:
        """The newest complete LiDAR scan ending at or before ``now``; a live source returns
        every complete scan since the last call, merged (a caller polling slower than the scan
        rate then loses no point; callers keep the points newer than those they already have)."""
        ...

    def photo(self, now: float, T_b_c: np.ndarray, camera: CameraModel | None = None) -> CameraFrame | None:
        """The inspection photo at ``now`` with the camera at ``T_b_c`` (gimbal aimed);
        ``camera``: the full-resolution intrinsics of the inspection camera at the zoom the shot
        was framed for (None: its only lens). The frame says the intrinsics it was taken with."""
        ...

    def health(self) -> dict[str, object]:
        """Counters a crew would want in the report: frames, scans, drops, errors."""
        ...

    def close(self) -> None:
        ...


def sensors_name(sensors: object) -> str:
    """The sensors in words for the report's sensors row: the adapter's ``name`` when it has
    one (a live rig names its drivers), else its class's name; never a private wrapper's."""
    name = getattr(sensors, "name", None)
    if isinstance(name, str) and name:
        return name
    return type(sensors).__name__.lstrip("_")


class SensorsDecorator:
    """A :class:`Sensors` adapter round ``inner`` that passes every call of the port on as it is: a
    decorator (the recording's, the fault matrix's) subclasses it and overrides what it watches or
    changes. Of the optional capabilities (:mod:`insulator_rs.ports.capabilities`) it offers
    ``streams`` and ``photo_failure`` when ``inner`` has them, and only then, so the pre-flight gate
    and the photo session find the same through it; ``name`` is ``inner``'s in words (:func:`sensors_name`), so the report names the sensor,
    never the decorator. Anything else of the adapter is ``inner``'s, reached there."""

    def __init__(self, inner: Sensors) -> None:
        self.inner = inner
        self.name = sensors_name(inner)
        if isinstance(inner, ReportsStreams):
            self.streams = inner.streams
        if isinstance(inner, ExplainsMissingPhoto):
            self.photo_failure = inner.photo_failure

    def detection_frame(self, now: float) -> CameraFrame | None:
        return self.inner.detection_frame(now)

    def lidar_scan(self, now: float) -> LidarScan | None:
        return self.inner.lidar_scan(now)

    def photo(self, now: float, T_b_c: np.ndarray, camera: CameraModel | None = None) -> CameraFrame | None:
        return self.inner.photo(now, T_b_c, camera)

    def health(self) -> dict[str, object]:
        return self.inner.health()

    def close(self) -> None:
        self.inner.close()
