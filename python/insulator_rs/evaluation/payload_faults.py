"""The payload's faults in the fault matrix: the flight photographs through the simulated payload.

The matrix's flight against our simulated PX4 (:mod:`insulator_rs.evaluation.fault_matrix`) takes
its inspection photos through a MAVLink gimbal-and-zoom payload on UDP: the simulated one
(:class:`~insulator_rs.sim.payload.SimulatedPayload`, rendering the scene at the airframe's true
pose and the gimbal's true attitude) and the adapter on it
(:class:`~insulator_rs.mavlink.payload.MavlinkPayload`), composed as the live path composes them
(:class:`~insulator_rs.drivers.live_sensors.LiveSensors`: the flight loop waits for each shot
while the MAVLink client's thread streams the setpoints). The detection frames and the LiDAR
stay the simulator's. From the fault's moment on, the payload has the fault
(:data:`PAYLOAD_FAULTS`) to the end of the flight:

* capture never answers: every ``MAV_CMD_IMAGE_START_CAPTURE`` acknowledged, no image taken;
* gimbal at limit: the gimbal jammed at its upper pitch stop (it reaches no aim below it);
* zoom refused: ``MAV_CMD_SET_CAMERA_ZOOM`` denied;
* download cut: every download stops halfway through the file;
* payload lost: the payload falls silent (no HEARTBEAT, nothing answered).

Each shot is tried the adapter's bounded number of times (an aim past the gimbal's reach once:
it would fail the same way), then the photo session reports the insulator without a photo and
the attempts' faults (summary.json's ``photo_checks.insulators_without_fit_photo``).

The simulated PX4 runs :data:`~insulator_rs.evaluation.fault_matrix.TIME_SCALE` times faster
than the wall, and the adapter's bounds and the payload's motions are wall-clocked: both are
scaled by it (:func:`scaled_settings`, :func:`scaled_dynamics`), so that a shot's attempts take
the vehicle time a real payload's take at the adapter's defaults.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from insulator_rs._core import CameraModel
from insulator_rs.drivers.live_sensors import PAYLOAD_SHOT_WAIT_S, LiveSensors
from insulator_rs.geodesy import GeoPoint
from insulator_rs.inspection_camera import GimbalRoute, InspectionCamera
from insulator_rs.mavlink.payload import MavlinkPayload, PayloadSettings
from insulator_rs.ports.payload import PayloadFault
from insulator_rs.ports.sensors import CameraFrame, Sensors, SensorsDecorator
from insulator_rs.rig import scaled_camera
from insulator_rs.sim.payload import PayloadDynamics, PayloadFaults, SimulatedPayload, scene_photo_renderer

#: The payload's faults, each the fault matrix's row, and the PayloadFault the report must name.
PAYLOAD_FAULTS: dict[str, PayloadFault] = {
    "capture never answers": PayloadFault.NO_CAPTURE_ANSWER,
    "gimbal at limit": PayloadFault.GIMBAL_AT_LIMIT,
    "zoom refused": PayloadFault.ZOOM_REFUSED,
    "download cut": PayloadFault.DOWNLOAD_FAILED,
    "payload lost": PayloadFault.PAYLOAD_LOST,
}
#: Downloads cut from the fault's moment: every one to the end of the flight.
EVERY_DOWNLOAD = 1_000_000
#: Wall s for the adapter to hear the payload's first HEARTBEATs before the flight.
ALIVE_WAIT_S = 5.0
_SETTINGS_TIMES = ("command_timeout_s", "lost_after_s", "slew_timeout_s", "zoom_timeout_s", "capture_timeout_s",
                   "download_timeout_s", "ftp_retry_s", "ftp_idle_s", "heartbeat_period_s")


def scaled_settings(time_scale: float, settings: PayloadSettings | None = None) -> PayloadSettings:
    """``settings`` (default: the adapter's) with every wall-clock bound divided by ``time_scale``."""
    base = settings or PayloadSettings()
    return replace(base, **{name: getattr(base, name) / time_scale for name in _SETTINGS_TIMES})


def scaled_dynamics(time_scale: float, dynamics: PayloadDynamics | None = None) -> PayloadDynamics:
    """``dynamics`` (default: the simulated payload's) as seen at ``time_scale``: its wall-clocked
    motions (slew, zoom travel, HEARTBEAT and status periods) that much faster; the capture latency
    is counted on the vehicle clock already."""
    d = dynamics or PayloadDynamics()
    return replace(d, slew_rate=d.slew_rate * time_scale, zoom_time_s=d.zoom_time_s / time_scale,
                   heartbeat_period_s=d.heartbeat_period_s / time_scale,
                   status_period_s=d.status_period_s / time_scale)


def scaled_inspection(inspection: InspectionCamera, scale: float) -> InspectionCamera:
    """The rig's inspection camera at ``scale`` times its resolution (every calibrated zoom step
    and the zoom range scaled alike), as the simulator renders its photos at ``photo_scale``."""
    wide = scaled_camera(inspection.camera, scale)
    factor = 0.5 * (wide.fx / inspection.camera.fx + wide.fy / inspection.camera.fy)
    lo, hi = inspection.focal_px
    return replace(inspection, camera=wide, focal_px=(lo * factor, hi * factor),
                   zoom_steps=tuple(scaled_camera(c, scale) for c in inspection.zoom_steps))


class PayloadSensors(SensorsDecorator):
    """``inner``'s detection frames and scans; its photos through ``through`` (a
    :class:`LiveSensors` on a payload alone), the asked intrinsics scaled by ``photo_scale`` (the
    payload's camera is the rig's at that resolution)."""

    def __init__(self, inner: Sensors, through: LiveSensors, photo_scale: float) -> None:
        super().__init__(inner)
        self.through = through
        self.photo_scale = photo_scale

    def photo(self, now: float, T_b_c: np.ndarray, camera: CameraModel | None = None) -> CameraFrame | None:
        return self.through.photo(now, T_b_c, None if camera is None else scaled_camera(camera, self.photo_scale))

    def photo_failure(self) -> str | None:
        return self.through.photo_failure()

    def health(self) -> dict[str, object]:
        return {**self.inner.health(), **self.through.health()}

    def close(self) -> None:
        try:
            self.through.close()
        finally:
            self.inner.close()


@dataclass
class FlightPayload:
    """The simulated payload of one flight, the sensors that photograph through it, and the fault."""

    simulator: SimulatedPayload
    sensors: PayloadSensors

    def fault(self, name: str) -> Callable[[], None]:
        """What begins the fault ``name`` (one of :data:`PAYLOAD_FAULTS`)."""
        if name == "payload lost":
            return self.simulator.vanish
        g = self.simulator.inspection.gimbal
        faults = {"capture never answers": PayloadFaults(capture_silent=True),
                  "gimbal at limit": PayloadFaults(pitch_stop=g.pitch[1]),
                  "zoom refused": PayloadFaults(refuse_zoom=True),
                  "download cut": PayloadFaults(downloads_cut=EVERY_DOWNLOAD)}
        if name not in faults:
            raise ValueError(f"fault: {name!r} is not one of {', '.join(PAYLOAD_FAULTS)}")
        return lambda: self.simulator.inject(faults[name])

    def close(self) -> None:
        self.simulator.close()


def photograph_through_payload(inner: Sensors, *, inspection: InspectionCamera, mesh: Any, origin: GeoPoint,
                               true_pose: Callable[[float], np.ndarray], clock: Callable[[], float],
                               vehicle_pose: Callable[[], np.ndarray], photo_scale: float, time_scale: float,
                               seed: int) -> FlightPayload:
    """The simulated payload (the rig's ``inspection`` camera at ``photo_scale``, rendering ``mesh``
    at ``true_pose(t)``, ``clock()`` the vehicle time, ``origin`` W's in WGS-84) and ``inner``
    photographing through it (aimed from ``vehicle_pose()``, the vehicle's reported T_w_b), the
    gimbal device aimed directly; started, and its HEARTBEATs heard (RuntimeError if not)."""
    camera = scaled_inspection(inspection, photo_scale)
    simulator = SimulatedPayload(camera, pose=true_pose, clock=clock, render=scene_photo_renderer(mesh, seed=seed),
                                 origin=origin, dynamics=scaled_dynamics(time_scale), seed=seed).start()
    try:
        adapter = MavlinkPayload(simulator.url, camera, gimbal_route=GimbalRoute.DEVICE,
                                 settings=scaled_settings(time_scale))
        deadline = time.monotonic() + ALIVE_WAIT_S
        while not adapter.alive():
            if time.monotonic() > deadline:
                adapter.close()
                raise RuntimeError(f"the simulated payload at {simulator.url} was not heard in {ALIVE_WAIT_S:g} s")
            time.sleep(0.02)
    except BaseException:
        simulator.close()
        raise
    through = LiveSensors(None, None, payload=adapter, inspection=camera, pose=vehicle_pose,
                          shot_wait_s=PAYLOAD_SHOT_WAIT_S / time_scale)
    return FlightPayload(simulator, PayloadSensors(inner, through, photo_scale))


def photos_missing(summary: dict[str, Any]) -> str:
    """summary.json's insulators without a fit photo, and why: ``insulator 1: <reason> xN; ...``
    ("" when every insulator found has one)."""
    without = (summary.get("photo_checks") or {}).get("insulators_without_fit_photo") or []
    return "; ".join(f"insulator {w['insulator_id']}: "
                     + ", ".join(f"{reason} x{n}" for reason, n in sorted(w["reasons"].items()))
                     for w in without)


def max_setpoint_gap(summary: dict[str, Any]) -> float | None:
    """summary.json's longest gap in the offboard setpoint stream (s of vehicle time; None: the
    vehicle had no stream, the in-process one)."""
    stream = summary.get("setpoint_stream")
    return None if not stream else float(stream["max_gap_s"])



def payload_table(cells: list[dict[str, Any]]) -> list[str]:
    """The fault matrix's payload cells as markdown rows (none when no cell is a payload fault):
    how each ended, its clearance, the insulators left without a photo and why, the setpoint
    stream's longest gap."""
    rows = [c for c in cells if c["fault"] in PAYLOAD_FAULTS]
    if not rows:
        return []
    lines = ["", "| payload cell | ended | clearance | photos missing (why) | max setpoint gap |",
             "| --- | --- | --- | --- | --- |"]
    for c in rows:
        gap = "-" if c["max_setpoint_gap_s"] is None else f"{c['max_setpoint_gap_s']:.2f} s"
        lines.append(f"| {c['fault']} @ {c['moment']} | {c['ended']} | {c['clearance_m']:.1f} m "
                     f"| {c['photos_missing'] or 'none'} | {gap} |")
    return lines
