"""``--lidar`` and ``--camera`` of ``insulator-rs inspect``: flying with live sensors.

Kept here so the command's module only registers, checks and opens (three calls):

* :func:`add_arguments` adds the flags;
* :func:`check_arguments` refuses a combination that cannot fly, before anything flies;
* :func:`open_from_arguments` starts the vehicle clock (the MAVLink client's TIMESYNC map;
  telemetry stamps while the autopilot has not answered TIMESYNC, or if it never does), the
  Mid-360 driver and the camera (its frames shifted by the rig's ``[camera] latency_s``), and
  returns them as one ``Sensors``.

A live flight needs both sensors (each detection is paired with the LiDAR points of the
same instant), a real autopilot (``--connection``: the vehicle clock is its TIMESYNC map),
and a detection network (by default the real-photo one; there is no ground truth to stand in for it).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from insulator_rs.drivers.live_sensors import LiveSensors, open_live_sensors
from insulator_rs.ports.detector import STANDIN
from insulator_rs.drivers.livox import parse_url
from insulator_rs.exceptions import SensorError
from insulator_rs.mavlink.payload import MavlinkPayload
from insulator_rs.timesync import TelemetryClock, TimesyncRecord, VehicleClock


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--lidar", default=None, metavar="URL",
                        help="live Livox Mid-360: mid360://HOST (configure and start the sensor at HOST) or "
                             "mid360://listen[:PORT] (only listen, default port 56301); needs --connection "
                             "and --camera (default: none, the simulated sensors)")
    parser.add_argument("--camera", default=None, metavar="SOURCE",
                        help="live camera: a V4L2 index (0), a GStreamer pipeline (gst:PIPELINE, or any text with "
                             "'!'; run through PyGObject, frames stamped at exposure; BGR appsink appended when "
                             "none is named), a stream URL, or a video file; its frames must match the rig's "
                             "calibration size (default: none, the simulated sensors)")


def check_arguments(args: argparse.Namespace) -> bool:
    """True for a live flight; ValueError (naming the flag) for one that cannot fly."""
    lidar, camera = getattr(args, "lidar", None), getattr(args, "camera", None)
    if lidar is None and camera is None:
        return False
    if lidar is None or camera is None:
        missing = "--lidar" if lidar is None else "--camera"
        raise ValueError(f"{missing}: a live flight needs both --lidar and --camera "
                         "(each detection is paired with the LiDAR points of the same instant)")
    if not getattr(args, "connection", None):
        raise ValueError("--lidar/--camera: live sensors fly a real autopilot: add --connection")
    if getattr(args, "sim_sensors", False):
        raise ValueError("--lidar/--camera: not with --sim-sensors (the sensors are either live or simulated)")
    if getattr(args, "detector", None) == STANDIN:
        raise ValueError("--detector standin: a live camera needs a detection network (default: the real-photo one)")
    try:
        parse_url(lidar)
    except SensorError as exc:
        raise ValueError(str(exc)) from exc
    return True


class _ClockedSensors(LiveSensors):
    """LiveSensors that also stop the vehicle clock they were stamped with."""

    def __init__(self, inner: LiveSensors, clock: VehicleClock) -> None:
        super().__init__(inner.lidar, inner.camera, payload=inner.payload, inspection=inner.inspection,
                         pose=inner.pose)
        self.clock = clock

    def health(self) -> dict[str, object]:
        out = super().health()
        out["clock_errors"] = self.clock.errors
        return out

    def timesync_record(self) -> TimesyncRecord:
        """The clock the sensors were stamped with (the summary's ``timesync``)."""
        return self.clock.record()

    def close(self) -> None:
        try:
            super().close()
        finally:
            self.clock.close()


def open_from_arguments(args: argparse.Namespace, vehicle: Any, rig: Any) -> LiveSensors:
    """Starts the vehicle clock (the vehicle's TIMESYNC map, ``vehicle.state().time`` stamps as
    the fallback), the Mid-360 and the camera of ``args`` with the extrinsics, calibration and
    camera and LiDAR latencies of ``rig``, and, when the rig's inspection camera names a MAVLink
    payload (``[inspection_camera] payload``), the payload the photos are taken through;
    SensorError names what failed."""
    clock = VehicleClock(getattr(vehicle, "timesync", None), TelemetryClock(lambda: vehicle.state().time)).start()
    payload = None
    try:
        # the LiDAR on the host's clock (a crystal, as its own), mapped to the vehicle's after
        sensors = open_live_sensors(args.lidar, args.camera, now=clock.now, T_b_l=rig.T_b_l, T_b_c=rig.T_b_c,
                                    camera_model=rig.camera, camera_latency_s=rig.camera_latency_s,
                                    lidar_latency_s=rig.lidar_latency_s, host_clock=clock.host_now,
                                    host_to_vehicle=clock.to_vehicle)
        payload = open_payload(rig, clock.now)
    except BaseException:
        clock.close()
        raise
    if payload is not None:
        sensors = LiveSensors(sensors.lidar, sensors.camera, payload=payload, inspection=rig.inspection,
                              pose=lambda: vehicle.state().T_w_b)
    return _ClockedSensors(sensors, clock)


def open_payload(rig: Any, vehicle_clock: Callable[[], float]) -> MavlinkPayload | None:
    """The MAVLink payload the rig's ``[inspection_camera] payload`` names (None when it names none),
    its stamps mapped to ``vehicle_clock``; SensorError naming the field for a connection that
    cannot be opened."""
    inspection = getattr(rig, "inspection", None)  # a rig without an inspection camera has none
    link = None if inspection is None else inspection.payload
    if inspection is None or link is None:
        return None
    try:
        return MavlinkPayload(link.connection, inspection, gimbal_route=link.gimbal_route,
                              target_system=link.system_id, vehicle_clock=vehicle_clock)
    except (OSError, ValueError, TypeError) as exc:
        raise SensorError(f"[inspection_camera] payload {link.connection!r}: {exc}") from exc
