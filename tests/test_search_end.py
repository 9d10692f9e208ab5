"""The search ends only once perception has caught up with the sensors.

On a loaded computer a frame's LiDAR points come late: against PX4 SITL the pairing waited
1.3-1.5 s at the median (``summary.json`` ``pairing_timing``), up to ``PAIRING_WAIT``. Once the
search is over a localization only refines the registry, so a string seen in the last pass's
last seconds was reported without a photo, or never confirmed. The flight now hovers at the
last pass's end until every frame taken up to its arrival there has been handed to perception
(``SecondLookFlight.may_end``).

Here the simulator's sensors carry a 10 Hz LiDAR whose newest scan ends 1.5 s in the past (a
loaded computer's lag). Reference: the frames' own exposure times against the arrival at the
last pass's end (nothing exposed before it may be left to the drain at the search's end), and
the scene's ground truth (both strings found and photographed)."""

from __future__ import annotations

import math

import pytest
from helpers.flights import small_scene

from insulator_rs.app.inspect_command import kinematic_vehicle
from insulator_rs.evaluation.scoring import score_flight
from insulator_rs.flight.loop import FlightLoop, FlightSettings
from insulator_rs.flight.second_look import SecondLookFlight
from insulator_rs.mission.config import load_mission
from insulator_rs.perception.runner import PerceptionRunner
from insulator_rs.rig import simulator_rig
from insulator_rs.sim.ground_truth_detector import GroundTruthDetector
from insulator_rs.sim.sensors import SimulatedSensors, kinematic_true_pose
from insulator_rs.sim.towers import load_tower

LAG = 1.5  # s: the newest scan's end behind the vehicle clock
SCAN_PERIOD = 0.1


class LaggingLidar:
    """The simulator's sensors, but the LiDAR's newest scan (10 Hz, the same object until the
    next) ends ``LAG`` s before ``now``."""

    def __init__(self, inner: SimulatedSensors) -> None:
        self.inner = inner
        self._k: int | None = None
        self._scan = None

    def __getattr__(self, name: str):
        return getattr(self.inner, name)

    def lidar_scan(self, now: float):
        k = math.floor((now - LAG) / SCAN_PERIOD + 1e-9)
        if k < 1:
            return None
        if k != self._k:
            self._k, self._scan = k, self.inner.lidar_scan(k * SCAN_PERIOD)
        return self._scan


@pytest.mark.slow
def test_the_search_ends_once_every_frame_of_the_last_pass_is_paired(tmp_path, monkeypatch):
    scene, mission_path = small_scene(tmp_path)
    tower = load_tower(str(scene))
    mission = load_mission(mission_path)
    rig = mission.rig if mission.rig is not None else simulator_rig()
    vehicle = kinematic_vehicle(mission, 0)
    cameras = SimulatedSensors(tower.mesh, kinematic_true_pose(vehicle), rig, detect_scale=0.2, photo_scale=0.2,
                               seed=0)
    sensors = LaggingLidar(cameras)
    arrivals: list[float] = []
    drained: list[float] = []
    may_end = SecondLookFlight.may_end
    finish = PerceptionRunner.finish

    def spy_arrival(self, item):
        if self.pilot.sm.head_ends_search() and self._search_end is not item:
            arrivals.append(self.pilot.vehicle.state().time)  # where the search would end
        return may_end(self, item)

    def spy_drain(self, now):
        drained.extend(p.frame.time for p in self.pairing.pending if len(p.boxes))
        return finish(self, now)

    monkeypatch.setattr(SecondLookFlight, "may_end", spy_arrival)
    monkeypatch.setattr(PerceptionRunner, "finish", spy_drain)
    loop = FlightLoop(mission, vehicle, sensors, GroundTruthDetector(cameras, seed=0), tmp_path / "report", rig=rig,
                      settings=FlightSettings(quiet=True))  # the mission's defaults
    try:
        loop.fly()
        summary = loop.summary().as_dict()
    finally:
        vehicle.close()
    assert summary["status"] == "finished", summary["status"]
    assert len(arrivals) == 1, arrivals  # the search ends once
    late = [t for t in drained if t <= arrivals[0]]
    print(f"arrived at the last pass's end at {arrivals[0]:.1f} s; frames with boxes left to the drain: "
          f"{len(drained)}, exposed before the arrival: {len(late)}; pairing {summary['pairing_timing']}; "
          f"perception {summary['perception']}, events {summary['detection_events']}, transitions "
          f"{summary['transitions'][-3:]}")
    assert not late
    score = score_flight(summary, tower)
    assert score["insulators_matched"] == 2 and score["mean_error_m"] < 0.3, score
    assert summary["insulators_inspected"] == 2
