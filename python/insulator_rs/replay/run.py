"""Re-process one recorded flight offline, through the flight's own perception.

The recording is played by two adapters of the flight's ports over one pass of the file
(:class:`~insulator_rs.replay.player.RecordingPlayer`): a passive
:class:`~insulator_rs.replay.vehicle.ReplayVehicle` whose clock steps from one recorded datum
to the next, and :class:`~insulator_rs.replay.sensors.ReplaySensors`, which hands over each
frame and scan when a live source would have. The flight's
:class:`~insulator_rs.perception.runner.PerceptionRunner` (detector, the one pairing rule,
:class:`~insulator_rs.perception.pipeline.PerceptionPipeline`) runs on them exactly as in
flight; its localizations feed the flight's
:class:`~insulator_rs.tracking.registry.InsulatorRegistry`.

The report folder has the flight's layout (``summary.json``: a
:class:`~insulator_rs.report.summary.RunSummary`, ``insulators.csv``, ``trajectory.csv``,
``trajectory.png``). Ground truth is not read here: the ``replay`` command scores the report
afterwards. A broken recording (a :class:`BagError` mid-way) ends the replay with status
``failed: <error>``; everything processed before it stays in the report.
"""

from __future__ import annotations

import math
import time as wallclock
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.exceptions import BagError
from insulator_rs.flight.record import candidate_records, insulator_records, perception_record
from insulator_rs.geodesy import GeoPoint
from insulator_rs.mission.config import Mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.perception.localization_method import DEFAULT_METHOD, LocalizationMethod
from insulator_rs.perception.pipeline import PAIRING_WINDOW
from insulator_rs.perception.stack import build_perception_stack
from insulator_rs.poses import tilt_of, yaw_of
from insulator_rs.ports.detector import BoxDetector, NetworkDetector, detector_name
from insulator_rs.recording.reader import FlightBag
from insulator_rs.replay.lookahead import Lookahead
from insulator_rs.replay.player import RecordingPlayer
from insulator_rs.replay.sensors import ReplaySensors
from insulator_rs.replay.vehicle import ReplayVehicle
from insulator_rs.report.summary import ReplayDetails, RunSummary
from insulator_rs.report.writer import ReportWriter
from insulator_rs.tracking.registry import InsulatorRegistry

RERUN_FILE = "replay.rrd"
# A recorded pose tilted less than this is level to the float: a yaw-only recording (a real
# airframe in flight is never within 1e-6 rad of level for a whole flight).
LEVEL_TILT_RAD = 1e-6


@dataclass(frozen=True)
class ReplaySettings:
    """``method``: localization method; ``deskew``: motion-compensate scans (default on);
    ``detect_period``: s between detection events (0: every recorded frame); ``pairing_window`` s;
    ``read_ahead``: decode (and, detecting every frame, run the network in batches) in a thread
    ahead of the loop (lookahead.py; off: all in the loop, frame by frame, as before);
    ``network_threads``: network runs at once while reading ahead (None: one a core)."""

    method: LocalizationMethod = DEFAULT_METHOD  # the flight's default
    deskew: bool = True
    detect_period: float = 0.0
    pairing_window: float = PAIRING_WINDOW
    progress: bool = False
    # s: frames exposed this much before their recorded stamps (a calibration made after the flight)
    camera_shift_s: float = 0.0
    read_ahead: bool = True
    network_threads: int | None = None


class ReplayRun:
    """One recorded flight re-processed (see the module docstring)."""

    def __init__(self, bag: FlightBag, out: Path, *, mission: Mission, detector: BoxDetector,
                 settings: ReplaySettings = ReplaySettings(), rerun: bool = False, overwrite: bool = False) -> None:
        self.bag = bag
        self.out = Path(out)
        self.mission = mission
        self.geom = MissionGeometry.from_mission(mission)
        self.detector = detector
        self.settings = settings
        self.registry = InsulatorRegistry(self.geom.line, mission.inspection.registry_gate,
                                          mission.inspection.confirmations)
        self.report = ReportWriter(self.out, origin=GeoPoint(mission.tower.lat, mission.tower.lon, mission.tower.alt),
                                   overwrite=overwrite)
        self.rerun: Any = None
        if rerun:  # inside the report folder being written (swapped in with it)
            from insulator_rs.replay.rerun_log import RerunLog

            self.rerun = RerunLog(self.report.layout.path / RERUN_FILE, name=bag.path.name)
        # read and detected ahead in threads (lookahead.py): every frame a replay detecting each
        # one will ask for; a replay that detects every detect_period s only decodes ahead
        network = detector if isinstance(detector, NetworkDetector) and settings.detect_period == 0 else None
        self.lookahead = (Lookahead(bag.items(), network, workers=settings.network_threads)
                          if settings.read_ahead else None)
        if self.lookahead is not None:
            detector = self.lookahead.detector() or detector
        self.player = RecordingPlayer(bag.items() if self.lookahead is None else self.lookahead.items())
        self.vehicle = ReplayVehicle(self.player)
        self.sensors = ReplaySensors(self.player, settings.camera_shift_s)
        # The rig's camera and T_b_c serve only the pipeline's known-pose form; frames carry their
        # own intrinsics and camera pose, scans the recording's T_b_l.
        _, self.runner = build_perception_stack(
            mission.sensor_rig(), self.sensors, detector, T_b_c=bag.T_b_c, T_b_l=bag.T_b_l, method=settings.method,
            insulator_length=mission.inspection.insulator_length, detect_period=settings.detect_period,
            pairing_window=settings.pairing_window, deskew=settings.deskew, viewer=self.rerun)
        self.status = "running"
        self.error: str | None = None
        self.t0: float | None = None
        self.poses_level = 0  # recorded poses with no roll or pitch at all
        self.t_last = 0.0
        self.wall = 0.0

    # -- the stream ---------------------------------------------------------------------------
    def run(self) -> RunSummary:
        wall0 = wallclock.perf_counter()
        bar = None
        if self.settings.progress:
            from tqdm import tqdm

            bar = tqdm(total=self.bag.counts.get(self.bag.image_topic, 0), unit="frame",
                       desc=self.bag.path.name, dynamic_ncols=True)
        try:
            while not self.vehicle.ended:
                self._tick()
                if bar is not None:
                    bar.update(self.player.counts["frames"] - bar.n)
                    bar.set_postfix(insulators=len(self.registry), refresh=False)
            self._observe(self.runner.finish(math.inf))
            self.status = "finished"
        except BagError as exc:
            self._observe(self.runner.finish(math.inf))
            self.status = f"failed: {exc}"
            self.error = str(exc)
        except KeyboardInterrupt:
            self.status = "interrupted"
        finally:
            if bar is not None:
                bar.close()
            self.wall = wallclock.perf_counter() - wall0
        return self.finish()

    def _tick(self) -> None:
        before = self.vehicle.pose()
        self.vehicle.step()
        if self.player.time is None:
            return
        if self.t0 is None:
            self.t0 = self.player.time
        self.t_last = self.player.time
        pose = self.vehicle.pose()
        if pose is not None and pose is not before:  # a new recorded pose: the history, the path
            self.poses_level += bool(tilt_of(pose.T_w_b) < LEVEL_TILT_RAD)
            self.runner.add_pose(pose)
            self.report.log_pose(pose.time - self.t0, pose.T_w_b[:3, 3], yaw_of(pose.T_w_b), "replay")
            if self.rerun is not None:
                self.rerun.pose(pose)
        self._observe(self.runner.step(self.player.time))

    def _observe(self, fixes: list[Any]) -> None:
        for fix in fixes:
            self.registry.observe(fix.center, fix.axis)
        if fixes and self.rerun is not None:
            self.rerun.insulators(fixes[-1].time, self.registry.insulators)

    # -- report -------------------------------------------------------------------------------
    def summary(self) -> RunSummary:
        duration = self.t_last - self.t0 if self.t0 is not None else 0.0
        c = self.player.counts
        details = ReplayDetails(
            recording=str(self.bag.path),
            topics={"lidar": self.bag.lidar_topic, "image": self.bag.image_topic, "odometry": self.bag.odometry_topic},
            deskew=self.settings.deskew, poses=c["poses"], scans=c["scans"], frames=c["frames"],
            wall_time_s=self.wall, speed_vs_real_time=duration / self.wall if self.wall > 0 else None,
            rerun=RERUN_FILE if self.rerun is not None else None,
            attitude="yaw-only" if c["poses"] > 0 and self.poses_level == c["poses"] else "full",
            network_threads=(self.lookahead.workers if self.lookahead is not None
                             and self.lookahead.network is not None else None))
        return RunSummary(run="replay", status=self.status, error=self.error, detector=detector_name(self.detector),
                          method=self.settings.method, flight_time_s=duration,
                          perception=perception_record(self.runner),
                          insulators=insulator_records(self.registry, {}),  # a replay takes no photos
                          candidates=candidate_records(self.registry),
                          sensors_health=self.sensors.health(), replay=details)

    def finish(self) -> RunSummary:
        if self.lookahead is not None:
            self.lookahead.close()
        if self.rerun is not None:
            self.rerun.close()
        self.report.flush()
        summary = self.summary()
        self.report.write_summary(summary)
        found = np.array([i.center for i in self.registry.insulators]) if len(self.registry) else np.zeros((0, 3))
        try:
            self.report.plot(self.geom.volumes, np.zeros((0, 3)), found, np.zeros((0, 3)),
                             f"replay of {self.bag.path.name}: {summary.status[:40]}, "
                             f"{summary.insulators_found} insulators")
        finally:
            self.report.close()
        return summary
