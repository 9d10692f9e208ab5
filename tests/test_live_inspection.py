"""A whole small-scene inspection with the LiDAR through the wire.

The flight loop flies the kinematic vehicle over the small scene (one cross-arm, two
insulators: ``test_mission_inspect.small_scene``); the cameras are the simulator's, the
LiDAR is :class:`~insulator_rs.sim.livox_wire.WireLidar`: frames rendered at the
vehicle's REPORTED pose, encoded as Mid-360 datagrams on a sensor clock of its own
(offset 1234.5 s, +25 ppm), sent on loopback, parsed and assembled by the live driver,
whose per-point times are mapped to the vehicle clock from packet arrivals. Reference:
the scene's ground truth, read by the post-flight scorer.

Measured (this test, seed 0): the flight completes (137 s of flight, about 30 s of wall
time) with no datagram lost or malformed, the clock map recovers the sensor's drift
(-24.9994 ppm, truth -24.9994) from the streamed arrivals, and both insulators are found
(mean error 0.09 m). Two changes made the second one: the wire LiDAR streams (every frame
rendered once, its datagrams stamped with arrival times fixed by the data, not by when the
loop asks), and the flight loop pairs by the data: after the pairing window it asks for the
newest scan every tick until one covers the window's end (a 10 Hz driver's newest complete
scan ends 5-105 ms before ``now``), instead of taking the one scan returned 100 ms after the
frame, which gave a live driver 100-200 ms of points instead of +-100 ms (1 of 2 found).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers.flights import small_scene

from insulator_rs.evaluation.scoring import score_flight
from insulator_rs.flight.loop import FlightLoop, FlightSettings
from insulator_rs.app.inspect_command import kinematic_vehicle, mavlink_vehicle
from insulator_rs.mission.config import load_mission
from insulator_rs.rig import simulator_rig
from insulator_rs.sim.ground_truth_detector import GroundTruthDetector
from insulator_rs.sim.livox_emitter import SensorClock
from insulator_rs.sim.livox_wire import SplitSensors, WireLidar
from insulator_rs.sim.sensors import SimulatedSensors, kinematic_true_pose, reported_pose, simulated_px4_true_pose
from insulator_rs.sim.towers import load_tower


def fly_with_wire_lidar(tmp_path: Path, px4: bool) -> tuple[dict, dict, dict]:
    """(summary, score, driver health) of one flight: the kinematic vehicle in process, or
    the simulated PX4 over MAVLink on loopback (time scale 4; measured with the data-driven
    pairing: the flight finishes with clean LiDAR counters and the drift recovered, but finds
    0 of 2 insulators: 24 frames with boxes, 1 localization -- at 4x the in-process rendering
    takes more wall time than the vehicle leaves it, and the stream restarted 10 times after
    silences -- so no test asserts on it; the real PX4 SITL at 1x with the sensor head in a
    process of its own is ``test_px4_sitl``'s live-sensor flight)."""
    scene, mission_path = small_scene(tmp_path)
    tower = load_tower(str(scene))
    mission = load_mission(mission_path)
    rig = mission.rig if mission.rig is not None else simulator_rig()
    if px4:
        vehicle, simulator = mavlink_vehicle(mission, 0, connection=None, time_scale=4.0, signing_key=None)
        true_pose = simulated_px4_true_pose(simulator)
    else:
        vehicle = kinematic_vehicle(mission, 0)
        true_pose = kinematic_true_pose(vehicle)
    cameras = SimulatedSensors(tower.mesh, true_pose, rig, detect_scale=0.2, photo_scale=0.2, seed=0)
    wire = WireLidar(tower.mesh, reported_pose(vehicle), rig.T_b_l, clock=SensorClock(offset_s=1234.5, drift=25e-6),
                     seed=7)
    sensors = SplitSensors(cameras, wire)
    loop = FlightLoop(mission, vehicle, sensors, GroundTruthDetector(cameras, seed=0), tmp_path / "report", rig=rig,
                      # The product's method (bounded), detection at 2 Hz as every other small-scene
                      # flight (test_mission_inspect: "at 3 m/s a 1 Hz pass saw the far string only
                      # three times"). At 1 Hz this flight found the far-side string in some runs
                      # only, with either method: its side's one pass is at the crossing height,
                      # 30 degrees below the Mid-360's field of view, so the string is localized from
                      # the near side through the tower alone (README, "What is not done yet").
                      settings=FlightSettings(method="bounded", detect_period=0.5, quiet=True))
    try:
        loop.fly()
        health = sensors.health()
        summary = loop.summary().as_dict()
    finally:
        vehicle.close()
        sensors.close()
    return summary, score_flight(summary, tower), health


@pytest.fixture(scope="module")
def wire_flight(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, dict, dict]:
    """The in-process flight (about 35 s)."""
    return fly_with_wire_lidar(tmp_path_factory.mktemp("wire_flight"), px4=False)


def check_flight(summary: dict, score: dict, health: dict, *, drift_ppm: float = 5.0) -> None:
    assert summary["status"] == "finished", summary["status"]
    assert health["lidar_scans"] > 0 and health["lidar_lost"] == 0 and health["lidar_malformed"] == 0
    assert health["lidar_unmapped_scans"] == 0 and health["lidar_receive_errors"] == 0
    assert abs(health["lidar_clock_drift_ppm"] - (1 / (1 + 25e-6) - 1) * 1e6) < drift_ppm
    assert score["insulators_matched"] >= 1 and score["mean_error_m"] < 0.3


@pytest.mark.slow
def test_whole_inspection_with_the_lidar_through_the_wire(wire_flight: tuple[dict, dict, dict]) -> None:
    check_flight(*wire_flight)


@pytest.mark.slow
def test_whole_inspection_with_the_lidar_through_the_wire_finds_both(wire_flight: tuple[dict, dict, dict]) -> None:
    """Both insulators, each frame paired with the scans covering its whole window."""
    summary, score, _ = wire_flight
    assert score["insulators_matched"] == 2 and score["mean_error_m"] < 0.3
    assert summary["pairing_short"] == 0
