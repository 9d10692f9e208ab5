"""Faults injected at a moment of the flight, as decorators round the flight loop's ports.

The fault matrix (:mod:`insulator_rs.evaluation.fault_matrix`) flies every fault at every moment
of the flight; each fault is an adapter here, wired by the composition root round the real port,
never a hook inside the loop: the loop flies as it would against a sensor, a detector or an
autopilot that failed that way. Every fault starts at a flight time ``at`` (s since the arm command,
on a :class:`FaultClock` the :class:`FaultyVehicle` starts when it passes that command on) and
lasts to the end of the flight.

* :class:`FaultySensors` (the ``Sensors`` port): the LiDAR silent (no scan from ``at``: a driver
  whose datagrams stopped), the camera frozen (from ``at`` the last frame before it is handed
  again, its stamp no longer advancing: a driver stuck on its last buffer).
* :class:`FailingDetector` (the ``BoxDetector`` port): the network's runtime raises on every frame
  from ``at`` (as onnxruntime raises ``RuntimeError`` subclasses).
* :class:`FaultyVehicle` (the ``Vehicle`` port): actions fired once when the vehicle clock passes
  their time, after the ``advance`` that passed it: GPS loss (:func:`gps_loss`: the autopilot's
  position estimate lost), low battery (:func:`battery_drop`: the simulated pack's charge falls),
  link loss (:func:`link_loss`: our simulated PX4 stops hearing the companion and the companion
  stops hearing it), the operator's abort (the loop's ``request_abort``), the client killed
  (:func:`kill_client`: the MAVLink client closed, no more setpoints or heartbeats, and
  :class:`~insulator_rs.exceptions.ClientKilled` raised through the loop as ``kill -9`` would end
  it).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from insulator_rs.exceptions import ClientKilled
from insulator_rs.ports.detector import BoxDetector, detector_name
from insulator_rs.ports.sensors import CameraFrame, LidarScan, Sensors, SensorsDecorator
from insulator_rs.ports.vehicle import Vehicle, VehicleDecorator, VehicleState


class FaultClock:
    """Flight time (s since arming) of a vehicle time; before arming every fault waits."""

    def __init__(self) -> None:
        self.armed_at = math.inf

    def start(self, vehicle_time: float) -> None:
        if self.armed_at == math.inf:
            self.armed_at = float(vehicle_time)

    def elapsed(self, vehicle_time: float) -> float:
        return -math.inf if self.armed_at == math.inf else vehicle_time - self.armed_at


def _moment(at: float | None, name: str) -> float:
    if at is None:
        return math.inf
    if not math.isfinite(at):
        raise ValueError(f"{name}: a finite vehicle time (s) is needed, got {at}")
    return float(at)


class FaultySensors(SensorsDecorator):
    """The ``Sensors`` port with the LiDAR silent from ``lidar_silent_at`` and/or the camera frozen
    from ``camera_frozen_at`` (flight s on ``clock``; None: that sensor stays healthy). Photos and
    everything else pass through."""

    def __init__(self, inner: Sensors, clock: FaultClock, *, lidar_silent_at: float | None = None,
                 camera_frozen_at: float | None = None) -> None:
        super().__init__(inner)
        self.clock = clock
        self.lidar_silent_at = _moment(lidar_silent_at, "lidar_silent_at")
        self.camera_frozen_at = _moment(camera_frozen_at, "camera_frozen_at")
        self._last_frame: CameraFrame | None = None
        self.withheld = {"scans": 0, "frames_repeated": 0}

    def detection_frame(self, now: float) -> CameraFrame | None:
        if self.clock.elapsed(now) >= self.camera_frozen_at:
            self.withheld["frames_repeated"] += 1
            return self._last_frame  # the stuck buffer: the same image, the same stamp
        frame = self.inner.detection_frame(now)
        if frame is not None:
            self._last_frame = frame
        return frame

    def lidar_scan(self, now: float) -> LidarScan | None:
        if self.clock.elapsed(now) >= self.lidar_silent_at:
            self.withheld["scans"] += 1
            return None
        return self.inner.lidar_scan(now)

    def health(self) -> dict[str, object]:
        return {**self.inner.health(), "fault_withheld": dict(self.withheld)}


class FailingDetector:
    """The ``BoxDetector`` port whose runtime raises ``RuntimeError`` on every frame once
    ``clock()`` (the flight time) reaches ``at``; the frames before go to ``inner``."""

    def __init__(self, inner: BoxDetector, at: float, clock: Callable[[], float]) -> None:
        self.inner = inner
        self.at = _moment(at, "at")
        self.clock = clock
        self.name = detector_name(inner)
        self.failures = 0

    def __call__(self, image: np.ndarray) -> np.ndarray:
        if self.clock() >= self.at:
            self.failures += 1
            raise RuntimeError(f"[ONNXRuntimeError] : 6 : RUNTIME_EXCEPTION : simulated failure {self.failures}")
        return self.inner(image)

    def __getattr__(self, name: str) -> Any:  # the sanitiser's counts of a network
        return getattr(self.inner, name)


@dataclass
class TimedAction:
    """``action`` fired once, after the first ``advance`` that takes the flight time to ``at``."""

    at: float
    name: str
    action: Callable[[], None]
    fired_at: float | None = None


class FaultyVehicle(VehicleDecorator):
    """The ``Vehicle`` port firing ``actions`` (:class:`TimedAction`) at their flight times on
    ``clock`` (started by the arm command); every call goes to ``inner`` as it is. ``fired`` lists
    (name, vehicle time) of what fired; ``watch`` sees every state ``advance`` returns."""

    def __init__(self, inner: Vehicle, clock: FaultClock, actions: list[TimedAction], *,
                 watch: Callable[[VehicleState], None] | None = None) -> None:
        super().__init__(inner)
        self.clock = clock
        self.watch = watch
        self.actions = sorted(actions, key=lambda a: a.at)
        for a in self.actions:
            _moment(a.at, a.name)
        self.fired: list[tuple[str, float]] = []

    def _due(self, st: VehicleState) -> VehicleState:
        if self.watch is not None:
            self.watch(st)
        for a in self.actions:
            if a.fired_at is None and self.clock.elapsed(st.time) >= a.at:
                a.fired_at = st.time
                self.fired.append((a.name, st.time))
                a.action()  # may raise ClientKilled: the process ends here
        return st

    def advance(self, dt: float) -> VehicleState:
        return self._due(self.inner.advance(dt))

    def arm(self) -> None:
        self.clock.start(self.inner.state().time)
        self.inner.arm()


def gps_loss(airframe: Callable[[Callable[[Any], Any]], Any]) -> Callable[[], None]:
    """The autopilot's position estimate lost: ``airframe(f)`` calls ``f`` on the simulated airframe
    (:class:`~insulator_rs.sim.kinematics.KinematicVehicle`; under our simulated PX4's lock there)."""
    return lambda: airframe(lambda v: v.inject_position_loss(True))


def battery_drop(airframe: Callable[[Callable[[Any], Any]], Any], charge: float) -> Callable[[], None]:
    """The simulated pack's charge falls to ``charge`` (a fraction: a cell failing, a cold pack)."""
    if not (math.isfinite(charge) and 0.0 <= charge <= 1.0):
        raise ValueError(f"charge: a fraction in [0, 1] is needed, got {charge}")

    def drop(v: Any) -> None:
        v.battery_fraction = min(charge, v.battery_fraction if v.battery_fraction is not None else 1.0)
    return lambda: airframe(drop)


def link_loss(simulator: Any) -> Callable[[], None]:
    """Nothing more gets through between our simulated PX4 and the companion (both directions)."""
    def cut() -> None:
        simulator.faults.link_lost = True
    return cut


def kill_client(client: Vehicle) -> Callable[[], None]:
    """The companion process killed: its MAVLink client closed (no setpoint, no heartbeat from
    now), then :class:`ClientKilled` raised through the loop. The autopilot is not the client's to
    stop: a client built for the kill must not own the simulator it talks to."""
    def kill() -> None:
        client.close()
        raise ClientKilled("companion process killed")
    return kill
