"""The photo session at one inspection waypoint: settle, aim, shoot, check, retake.

The vehicle holds the waypoint until it is settled (heading within PHOTO_YAW_TOLERANCE, speed
under PHOTO_SPEED_TOLERANCE, or PHOTO_SETTLE_TIMEOUT), the camera is aimed (the inspection
camera's gimbal and zoom from the pose it settled at, or the detection camera stabilised at the
waypoint's pitch), the photo is taken through ``Sensors.photo``, checked on itself by the detector
(:mod:`insulator_rs.perception.photo_check`), saved with its record
(:class:`~insulator_rs.flight.photos.InspectionPhotos`), and an unfit one is taken again.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from insulator_rs.exceptions import SensorError
from insulator_rs.flight.gimbal import aim_at, stabilised_T_b_c
from insulator_rs.flight.photos import InspectionPhotos
from insulator_rs.flight.pilot import Pilot
from insulator_rs.mission.config import InspectionParams
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import PlanItem, State
from insulator_rs.perception.photo_check import PhotoCheck, check_photo, expected_view
from insulator_rs.planning.framing import MIN_FILL
from insulator_rs.planning.waypoints import InspectionWaypoint, inspection_waypoints
from insulator_rs.ports.detector import BoxDetector
from insulator_rs.ports.capabilities import ExplainsMissingPhoto
from insulator_rs.ports.observer import FlightObserver, PhotoTaken
from insulator_rs.ports.sensors import Sensors
from insulator_rs.ports.vehicle import VehicleState, wrap_angle
from insulator_rs.rig import SensorRig
from insulator_rs.tracking.registry import Insulator, InsulatorRegistry

PHOTO_YAW_TOLERANCE = math.radians(3.0)
PHOTO_SPEED_TOLERANCE = 0.2  # m/s
PHOTO_SETTLE_TIMEOUT = 8.0  # s
# s held at the waypoint before a retake is settled: the gust or the swing that spoiled the
# photo has time to pass (the retake then re-aims from the pose it settled at)
RETAKE_HOLD = 1.0


def settle(pilot: Pilot, wp: InspectionWaypoint | PlanItem, hold: float) -> VehicleState | None:
    """Hold ``wp`` for at least ``hold`` s until settled (heading, speed) or PHOTO_SETTLE_TIMEOUT;
    the settled state, None when the mission aborted meanwhile."""
    t0 = pilot.vehicle.state().time
    while True:
        st = pilot.tick(wp.position, None, wp.yaw)
        if pilot.sm.state == State.ABORT:
            return None
        settled = (abs(wrap_angle(st.yaw - wp.yaw)) < PHOTO_YAW_TOLERANCE
                   and np.linalg.norm(st.velocity) < PHOTO_SPEED_TOLERANCE)
        if (settled and st.time - t0 >= hold) or st.time - t0 > PHOTO_SETTLE_TIMEOUT:
            return st


class PhotoSession:
    """Plans the inspection waypoints (``waypoints``: every one planned) and takes their photos
    (see the module docstring). ``photo_camera``: the photos' intrinsics (None: the rig camera's),
    which frame the insulator from the waypoints and give the planned GSD; ``detector``: what
    checks each photo."""

    def __init__(self, pilot: Pilot, geom: MissionGeometry, *, sensors: Sensors, rig: SensorRig,
                 detector: BoxDetector, registry: InsulatorRegistry, photos: InspectionPhotos,
                 params: InspectionParams, observer: FlightObserver,
                 on_sensor_error: Callable[[SensorError], None], photo_camera: Any = None) -> None:
        self.pilot = pilot
        self.geom = geom
        self.photo_model = rig.camera if photo_camera is None else photo_camera
        self.fov = 2 * math.atan((self.photo_model.height / 2) / self.photo_model.fy)
        self.waypoints: list[InspectionWaypoint] = []
        self.sensors = sensors
        self.rig = rig
        self.inspection = rig.inspection  # None: the detection camera's photos (no zoom, no gimbal)
        self.detector = detector  # what checks each photo
        self.registry = registry
        self.photos = photos
        self.params = params
        self.observer = observer
        self.on_sensor_error = on_sensor_error

    def plan(self, ins: Insulator) -> list[InspectionWaypoint]:
        """The inspection waypoints of ``ins`` (PlanningError when none is safe), kept."""
        p = self.params
        wps = inspection_waypoints(ins.center, ins.axis, insulator_id=ins.id, line=self.geom.line,
                                   volumes=self.geom.volumes, count=p.waypoints_per_insulator,
                                   inspection_distance=p.inspection_distance, insulator_length=p.insulator_length,
                                   fov=self.fov, camera=self.photo_model, inspection=self.inspection)
        self.waypoints.extend(wps)
        return wps

    def take_photo(self, wp: InspectionWaypoint) -> None:
        """Take the photo of ``wp`` (:meth:`shoot`) and check it on itself; an unfit one is taken
        again, re-settled and re-aimed, at most ``[inspection] photo_retakes`` times, when the rig
        has an inspection camera. Every attempt is saved and recorded (its ``attempt`` and ``check``).

        Without an inspection camera the photo is the detection camera's frame: no zoom to frame
        the string, no gimbal to re-aim, the view perception already has at 1 Hz. A retake then
        repeats the same view and holds the vehicle at the waypoint for nothing: measured on the
        live path against PX4 SITL (a soak of 10 small-scene flights), 0-1 of 12-18 such
        photos a flight were fit, with both retakes taken nearly every time, and those hovers
        (10-28 s at a string's viewpoints) were where the network's boxes on the tower's peak
        gathered into 3 false finds. The photo is kept with its check."""
        retakes = self.params.photo_retakes if self.inspection is not None else 0
        for attempt in range(1, retakes + 2):
            check = self.shoot(wp, attempt)
            if check is None or check.fit:
                return
            if attempt <= retakes:
                self.pilot.say(f"[{self.pilot.now():7.1f} s] photo of insulator {wp.insulator_id} unfit "
                               f"({check.verdict.describe()}): retake {attempt} of {retakes}")

    def shoot(self, wp: InspectionWaypoint, attempt: int) -> PhotoCheck | None:
        """Settle on the waypoint with the camera aimed, take the photo through the sensors,
        check it (the detector once on the photo), save it; its check, None without a photo."""
        st = settle(self.pilot, wp, 0.0 if attempt == 1 else RETAKE_HOLD)
        if st is None:
            return None
        zoom: Any = None
        ins = next((i for i in self.registry.insulators if i.id == wp.insulator_id), None)
        # a single shot aims at the string's centre as the registry knows it now: the localizations
        # since the waypoint was planned moved it (measured: 8 cm, 3.6 % of a frame the string
        # fills to 90 %); a tile keeps its planned place along the string
        target = ins.center if ins is not None and wp.tiles == 1 else wp.target
        if self.inspection is None:
            pitch, gimbal_yaw = wp.gimbal_pitch, 0.0
            T_b_c = stabilised_T_b_c(st.T_w_b, self.rig.T_b_c, wp.gimbal_pitch)
        else:  # aimed from where the vehicle settled, at the zoom the shot was framed for
            pitch, gimbal_yaw, T_b_c = aim_at(st.T_w_b, self.inspection.T_b_c, target, self.inspection.gimbal)
            if wp.focal_px is not None:
                zoom = self.inspection.at_focal(wp.focal_px)
        try:
            frame = self.sensors.photo(st.time, T_b_c, camera=zoom)
        except SensorError as exc:
            self.on_sensor_error(exc)
            frame = None
        if frame is None:
            why = self.sensors.photo_failure() if isinstance(self.sensors, ExplainsMissingPhoto) else None
            why = why or "no image from the camera"
            self.photos.missing(wp.insulator_id, why)
            self.pilot.say(f"[{self.pilot.now():7.1f} s] photo of insulator {wp.insulator_id}: {why}")
            return None
        axis = None if ins is None else ins.axis
        T_c_w = np.linalg.inv(st.T_w_b @ frame.T_b_c)
        view = expected_view(frame.camera, T_c_w, target, wp.target if ins is None else ins.center,
                             np.array([0.0, 0.0, 1.0]) if axis is None else axis,
                             self.params.insulator_length, required_span=MIN_FILL, tiled=wp.tiles > 1)
        check = check_photo(self.detector, frame.image, view)
        time_utc = self.pilot.clock.at(frame.time)
        record = self.photos.save(wp, frame, time_utc=time_utc, time_s=frame.time - self.pilot.t_start,
                                  position=st.position, yaw=st.yaw, T_w_b=st.T_w_b, velocity=st.velocity,
                                  axis=axis, gimbal=(pitch, gimbal_yaw), check=check, attempt=attempt)
        q = record["quality"]
        # the verdict's own words (it carries the detector's error): the log, summary.json,
        # report.html and score.json all say what this one PhotoVerdict says
        self.pilot.say(f"[{self.pilot.now():7.1f} s] photo {record['file']}: GSD {q['gsd_mm_px']:.1f} mm/px, "
                       f"motion blur {q['motion_blur_px']:.2f} px; checked on the photo: {check.verdict.describe()}")
        w = record["wgs84"]  # where the GCS draws the photo's marker
        self.observer.photo_taken(PhotoTaken(record["time_s"], time_utc.timestamp(), wp.insulator_id,
                                             len(self.photos), record["file"], st.position.copy(),
                                             (w["lat"], w["lon"], w["alt"]),
                                             wrap_angle(st.yaw + gimbal_yaw), pitch))
        self.pilot.write_summary()
        return check
