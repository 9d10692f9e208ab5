"""The fault matrix (issue 19 item 6): the fault adapters, the product's answer to each fault the
matrix found unanswered, and a representative subset of its cells flown end to end.

The cells fly the small scene (``insulator_rs.evaluation.fault_matrix``): the clearance is measured
from the scene's TRUE mesh (steel, insulators, fittings, conductors) to the airframe's TRUE
trajectory up to the landing, whoever flew it (our route out or PX4's failsafe); the link and
client cells fly our simulated PX4 over real UDP, with a ground station relayed by the companion
(PX4's NAV_DLL_ACT set); one cell runs the companion as a process of its own and kills it with
SIGKILL. The whole matrix: ``insulator-rs eval faults`` (README, "Security and failure
behaviour"); tower B's: ``insulator-rs eval faults --scene tower_b``.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from insulator_rs.evaluation import fault_matrix as FM
from insulator_rs.exceptions import ClientKilled, ParameterError, VehicleError, VehicleFailsafe
from insulator_rs.perception.pipeline import PerceptionPipeline
from insulator_rs.perception.runner import PerceptionRunner
from insulator_rs.ports.sensors import CameraFrame, LidarScan
from insulator_rs.rig import simulator_rig
from insulator_rs.sim import faults as F
from insulator_rs.sim.kinematics import KinematicVehicle

# s after arming, read by FM.moments_from off the clean flight's state log (docs/results/fault_matrix)
MOMENTS = {"take-off": 0.8, "exploration": 56.8, "inspection": 10.1, "crossing": 41.0, "return": 103.2}


class Source:
    """A sensor source that always delivers: a new frame and a new scan at every ask."""

    def __init__(self) -> None:
        self.rig = simulator_rig()
        self.asked = {"frames": 0, "scans": 0}

    def detection_frame(self, now: float) -> CameraFrame:
        self.asked["frames"] += 1
        return CameraFrame(now, np.zeros((4, 4, 3), np.uint8), self.rig.camera, self.rig.T_b_c)

    def lidar_scan(self, now: float) -> LidarScan:
        self.asked["scans"] += 1
        return LidarScan(np.ones((3, 3)), np.full(3, now), self.rig.T_b_l, window_end=now)

    def photo(self, now, T_b_c, camera=None):
        return None

    def health(self):
        return {"source": "test"}

    def close(self) -> None:
        pass


def started(at: float = 100.0) -> F.FaultClock:
    clock = F.FaultClock()
    clock.start(at)
    return clock


def test_a_silent_lidar_and_a_frozen_camera_start_at_their_moment():
    src = Source()
    sensors = F.FaultySensors(src, started(), lidar_silent_at=5.0, camera_frozen_at=3.0)
    assert sensors.lidar_scan(104.9) is not None
    assert sensors.lidar_scan(105.0) is None and src.asked["scans"] == 1  # nothing asked of the driver
    before = sensors.detection_frame(102.9)
    assert sensors.detection_frame(103.0) is before and sensors.detection_frame(110.0).time == 102.9
    assert sensors.health()["fault_withheld"] == {"scans": 1, "frames_repeated": 2}


def test_nothing_fails_before_arming():
    sensors = F.FaultySensors(Source(), F.FaultClock(), lidar_silent_at=0.0, camera_frozen_at=0.0)
    assert sensors.lidar_scan(1e6) is not None and sensors.detection_frame(1e6).time == 1e6
    with pytest.raises(ValueError, match="lidar_silent_at"):
        F.FaultySensors(Source(), F.FaultClock(), lidar_silent_at=math.nan)


def test_the_detector_raises_from_its_moment():
    now = [0.0]
    det = F.FailingDetector(lambda image: np.zeros((0, 5)), 2.0, lambda: now[0])
    assert det(np.zeros((2, 2, 3))).shape == (0, 5)
    now[0] = 2.0
    with pytest.raises(RuntimeError, match="ONNXRuntimeError"):
        det(np.zeros((2, 2, 3)))


def test_vehicle_faults_fire_once_at_their_flight_time_gps_loss_is_the_autopilots_failsafe():
    airframe = KinematicVehicle(seed=0)
    clock = F.FaultClock()
    calls = []
    vehicle = F.FaultyVehicle(airframe, clock, [
        F.TimedAction(0.2, "GPS loss", F.gps_loss(lambda f: f(airframe))),
        F.TimedAction(0.1, "note", lambda: calls.append(airframe.clock.now))])
    airframe.send_setpoint(np.array([0.0, 0.0, 5.0]), None, 0.0)
    vehicle.advance(0.5)  # before arming: nothing fires
    assert not vehicle.fired
    vehicle.arm()
    vehicle.start_offboard()
    vehicle.advance(0.15)
    assert [n for n, _ in vehicle.fired] == ["note"] and len(calls) == 1
    with pytest.raises(VehicleFailsafe, match="position estimate lost"):
        vehicle.advance(0.1)
        vehicle.advance(0.05)
    vehicle.advance(0.1)
    assert [n for n, _ in vehicle.fired] == ["note", "GPS loss"] and len(calls) == 1


def test_low_battery_and_the_kill():
    airframe = KinematicVehicle(seed=0)
    F.battery_drop(lambda f: f(airframe), 0.26)()
    assert airframe.battery_fraction == 0.26
    with pytest.raises(ValueError, match="charge"):
        F.battery_drop(lambda f: f(airframe), 1.5)
    with pytest.raises(ClientKilled):
        F.kill_client(airframe)()
    with pytest.raises(VehicleError, match="closed"):
        airframe.advance(0.1)  # the killed client is closed: nothing more is sent


def _runner(sensors, detector) -> PerceptionRunner:
    rig = simulator_rig()
    return PerceptionRunner(sensors, detector, PerceptionPipeline(rig.camera, rig.T_b_c, rig.T_b_l),
                            detect_period=0.5)


def test_a_detector_that_raises_costs_the_event_then_the_mission_once_it_keeps_failing():
    runner = _runner(Source(), F.FailingDetector(lambda image: np.zeros((0, 5)), 0.0, lambda: 0.0))
    for k in range(25):
        runner.step(float(k) * 0.5)  # no traceback: each failure is counted
    assert runner.counts.detector_errors == 25 and runner.counts.frames == 25
    assert runner.lost(5.0, 10.0) is None
    assert runner.lost(12.0, 10.0).startswith("detector failed for 10 s (RuntimeError: [ONNXRuntimeError]")


def test_a_lidar_asked_for_points_and_silent_is_lost():
    box = np.array([[1.0, 1.0, 3.0, 3.0, 0.9]])
    runner = _runner(F.FaultySensors(Source(), started(0.0), lidar_silent_at=2.0), lambda image: box)
    for k in range(4):
        runner.step(k * 0.5)
        assert runner.lost(k * 0.5 + 9.9, 10.0) is None  # scans came while it was healthy
    for k in range(5, 30):
        runner.step(k * 0.5)
    assert runner.lost(14.5, 10.0) == "sensor lost: no LiDAR scan for 10 s"
    assert runner.lost(11.0, 10.0) is None


def test_a_late_lidar_whose_frames_were_given_up_on_is_not_lost_while_nothing_asks():
    """Boxes for 3 s while the LiDAR is late (its asks unanswered), then nothing in view: no ask is
    made, so the LiDAR is not judged silent however long that lasts (a loaded companion's late
    stream, not a dead sensor)."""
    boxes = np.array([[1.0, 1.0, 3.0, 3.0, 0.9]])
    runner = _runner(F.FaultySensors(Source(), started(0.0), lidar_silent_at=1.0),
                     lambda image: boxes if runner_time[0] < 3.0 else np.zeros((0, 5)))
    runner_time = [0.0]
    for k in range(80):
        runner_time[0] = k * 0.5
        runner.step(k * 0.5)
    assert runner.lidar_unanswered_since is not None  # its asks went unanswered, then stopped
    assert runner.lost(40.0, 10.0) is None


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    from insulator_rs.mission.config import load_mission
    from insulator_rs.sim.towers import load_tower

    folder = tmp_path_factory.mktemp("faults")
    scene, mission = FM.small_scene(folder, FM.PACKAGE / "scenes", FM.PACKAGE / "missions")
    tower = load_tower(str(scene))
    return FM.Setup(scene, mission, tower, FM.Structure(tower.mesh), load_mission(mission).inspection.safety_margin)


# a representative subset: the two product fixes, the autopilot's own failsafe over the conductors,
# the operator mid-crossing, and the companion lost or killed against our simulated PX4 over UDP
CELLS = [("LiDAR silent", "exploration"), ("detector error", "inspection"), ("GPS loss", "crossing"),
         ("operator abort", "crossing"), ("link loss", "inspection"), ("client killed", "crossing")]


@pytest.mark.slow
@pytest.mark.parametrize("fault,moment", CELLS, ids=[f"{f}@{m}" for f, m in CELLS])
def test_a_fault_cell_stays_clear_ends_landed_and_is_reported(setup, tmp_path, fault, moment):
    cell = FM.fly_cell(setup, fault, moment, MOMENTS[moment], tmp_path / "cell")
    assert cell.clearance_m >= setup.margin, f"{cell.clearance_m} m from the {cell.nearest}"
    assert cell.ended.startswith("landed"), cell.ended
    if fault in FM.MAVLINK_FAULTS:
        assert cell.ended.startswith("landed: PX4") and cell.max_altitude_m > 12.0  # PX4 came back over the top
    assert cell.report_names_fault, f"{cell.status} / {cell.reason}"
    assert cell.recording_intact, cell.recording


@pytest.mark.slow
def test_a_companion_process_killed_with_sigkill_mid_inspection_is_flown_home_by_px4(setup, tmp_path):
    """``insulator-rs inspect --connection`` in a process of its own, against our simulated PX4
    started here, ended by a real SIGKILL mid-inspection: PX4's offboard loss (COM_OBL_RC_ACT set
    to Return by that process before take-off) climbs over the tower, returns and lands; the true
    trajectory keeps the margin from the true mesh, the report stays as the kill left it, the
    recording reads back up to its last flush."""
    cell = FM.fly_cell(setup, "process killed", "inspection", MOMENTS["inspection"], tmp_path / "cell")
    assert cell.ended == "landed: PX4 (RTL)", cell.ended
    assert cell.clearance_m >= setup.margin, f"{cell.clearance_m} m from the {cell.nearest}"
    assert cell.max_altitude_m > 12.0  # the return went over the 12 m tower
    assert cell.status == "running" and cell.recording_intact, cell.recording  # killed by SIGKILL, not ended


def test_the_relayed_ground_station_goes_with_the_companion():
    from insulator_rs.sim.px4_gcs import GcsLink, RelayedGroundStation

    link = GcsLink()
    gcs = RelayedGroundStation(link.address).start()
    try:
        deadline = time.monotonic() + 3.0
        while link.last_heartbeat is None and time.monotonic() < deadline:
            link.receive(1, 1)
            time.sleep(0.05)
        assert link.last_heartbeat is not None
        FM._with_the_relay(gcs, lambda: None)()
        time.sleep(0.1)
        link.receive(1, 1)
        heard = link.last_heartbeat
        time.sleep(1.5)  # more than the HEARTBEAT period
        link.receive(1, 1)
        assert link.last_heartbeat == heard
    finally:
        gcs.close()
        link.close()


# s after arming on tower B's clean flight (FM.moments_from; insulator-rs eval faults --scene tower_b)
TOWER_B_MOMENTS = {"take-off": 0.8, "exploration": 457.0, "inspection": 62.9, "crossing": 245.0, "return": 580.6}


@pytest.fixture(scope="module")
def tower_b(tmp_path_factory):
    from insulator_rs.mission.config import load_mission
    from insulator_rs.sim.towers import load_tower

    scene, mission = FM.scene_files("tower_b", tmp_path_factory.mktemp("tower_b"))  # the shipped files
    tower = load_tower(str(scene))
    return FM.Setup(scene, mission, tower, FM.Structure(tower.mesh), load_mission(mission).inspection.safety_margin)


# tower B's two places the small scene lacks: the companion killed over the 26 m top in the crossing
# (PX4 climbs to its return altitude there and comes home), the operator's abort beside an arm
TOWER_B_CELLS = [("client killed", "crossing"), ("operator abort", "inspection")]


@pytest.mark.slow
@pytest.mark.parametrize("fault,moment", TOWER_B_CELLS, ids=[f"{f}@{m}" for f, m in TOWER_B_CELLS])
def test_a_tower_b_fault_cell_stays_clear_and_ends_landed(tower_b, tmp_path, fault, moment):
    cell = FM.fly_cell(tower_b, fault, moment, TOWER_B_MOMENTS[moment], tmp_path / "cell")
    assert cell.clearance_m >= tower_b.margin, f"{cell.clearance_m} m from the {cell.nearest}"
    assert cell.ended == ("landed: PX4 (RTL)" if fault in FM.MAVLINK_FAULTS else "landed: our route"), cell.ended
    assert cell.report_names_fault, f"{cell.status} / {cell.reason}"
    assert cell.recording_intact, cell.recording


class Unheard:
    """A parameter store whose autopilot answered the setup, then nothing (the link lost)."""

    def __init__(self) -> None:
        self.values = {"A": 1.0, "B": 2.0, "C": 3.0}
        self.lost = False
        self.asked: list[str] = []

    def read(self, name):
        return self.values[name]

    def set(self, name, value):
        self.asked.append(name)
        if self.lost:
            raise ParameterError(name, "no PARAM_VALUE after 3 tries of 1 s: the autopilot did not answer")
        self.values[name] = value
        return value


def test_the_restore_stops_asking_an_autopilot_that_no_longer_answers():
    from insulator_rs.flight.autopilot_setup import AutopilotSetup
    from insulator_rs.planning.px4_failsafes import ParameterSetting

    store = Unheard()
    setup = AutopilotSetup(store, [ParameterSetting(n, 9.0, "test") for n in "ABC"], ground_station=False)
    setup.apply()
    store.lost, store.asked = True, []
    setup.restore()  # the link loss at take-off waited minutes here, every parameter's retries
    assert store.asked == ["A"]
    assert setup.restore_status == "restore failed for A, B, C"
    assert setup.records[1].error == "not tried: the autopilot did not answer for A"


# -- a descent in place from every moment of the clean flight ---------------------------------------

class _Kind:
    def __init__(self, kind: str) -> None:
        self.kind = kind


class _Wire:
    """A mesh of one horizontal conductor: a thin ribbon 10 m up along x (-20..20 m) at y = 0,
    and a ground triangle (left out of the structure, as the scene's)."""

    vertices = np.array([[-20.0, -0.01, 10.0], [20.0, -0.01, 10.0], [20.0, 0.01, 10.0], [-20.0, 0.01, 10.0],
                         [-50.0, -50.0, 0.0], [50.0, -50.0, 0.0], [0.0, 50.0, 0.0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]])
    instance_ids = np.array([1, 1, 2])
    instances = {1: _Kind("conductor"), 2: _Kind("ground")}


def test_a_descent_in_place_is_measured_down_its_whole_column():
    """Reference: the distance from a vertical segment (x, y, 0..z) to the wire (y = 0, z = 10,
    along x): |y| when the segment reaches down past 10 m, else the height gap as well. The
    measure never exceeds it and is within twice the samplings' bounds of it."""
    structure = FM.Structure(_Wire())
    positions = np.array([[0.0, 1.0, 20.0], [3.0, -4.0, 30.0], [0.0, 0.0, 6.0], [0.0, 3.0, 7.0], [30.0, 0.0, 15.0]])
    truth = np.array([1.0, 4.0, 4.0, math.hypot(3.0, 3.0), 10.0]) - 0.01  # the ribbon's half-width
    got, kinds = FM.descent_clearances(structure, positions, ground_z=0.0)
    # the nearest samples are each up to their bound off the truth, and that much is subtracted again
    slack = 2 * (structure.bound + FM.DESCENT_STEP / 2) + 1e-9
    assert np.all(got <= truth + 1e-9) and np.all(got >= truth - slack), (got, truth)
    assert list(kinds) == ["conductor"] * 5  # the ground is not structure
    far, kind = FM.descent_clearances(structure, np.array([[0.0, 40.0, 20.0]]), ground_z=0.0)
    assert far[0] == FM.DESCENT_RANGE and kind[0] == ""  # beyond the search: reported as the range


def test_the_descent_exposure_of_each_phase(tmp_path):
    """A flight that explores 8 m beside the wire and crosses over it: the crossing's descents
    come within the margin while it is within 2 m of the wire's line, the pass's never."""
    log = tmp_path / "trajectory.csv"
    rows = ["time_s,x_m,y_m,z_m,yaw_rad,state", "0.000,-10.0,-8.0,0.0,0.0,idle"]  # on the ground first
    t = 0.05
    for x in np.arange(-10.0, 10.0, 0.05):  # 20 s along x at 1 m/s, 8 m off the wire
        rows.append(f"{t:.3f},{x:.3f},-8.0,15.0,0.0,explore")
        t += 0.05
    for y in np.arange(-8.0, 8.0, 0.05):  # 16 s across it at 1 m/s, 15 m up
        rows.append(f"{t:.3f},10.0,{y:.3f},15.0,0.0,cross")
        t += 0.05
    log.write_text("\n".join(rows) + "\n")
    exposure = FM.descent_exposure(log, FM.Structure(_Wire()), margin=2.0)
    assert list(exposure) == ["idle", "explore", "cross"]
    assert exposure["explore"]["within_margin_s"] == 0.0 and exposure["explore"]["min_clearance_m"] > 7.5
    cross = exposure["cross"]
    assert cross["seconds"] == pytest.approx(16.0, abs=0.6)
    assert cross["within_margin_s"] == pytest.approx(4.0, abs=1.1)  # |y| < 2 m: 4 s at 1 m/s
    assert cross["min_clearance_m"] < 0.3 and cross["nearest"] == "conductor"
    md = FM.markdown({"cells": [], "moments_s": {}, "margin_m": 2.0, "descent_in_place": exposure})
    assert "| cross | 16 |" in md and "**BELOW**" in md
