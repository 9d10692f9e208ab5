"""The perception runner (the flight's and the replay's) pairs a detection frame with the LiDAR
points of its whole window, driven by the data: a live 10 Hz LiDAR delivers the scan covering
``frame.time + window`` only once that scan's 100 ms window is closed (plus the driver's
reorder grace), so the runner asks every tick
until it has it, hands the same scan's points to perception once, and never waits longer
than ``PAIRING_WAIT`` past the window (then it pairs with what is there and counts it).

Reference: the scans' own per-point times (what the source delivered, and when)."""

from __future__ import annotations

import numpy as np

from insulator_rs.flight.loop import CONTROL_PERIOD
from insulator_rs.perception.pairing import PAIRING_WAIT
from insulator_rs.perception.pipeline import PerceptionPipeline
from insulator_rs.perception.runner import PerceptionRunner
from insulator_rs.poses import pose_from_yaw
from insulator_rs.ports.sensors import CameraFrame, LidarScan, PoseStamped
from insulator_rs.rig import simulator_rig

FRAME = 0.1  # s: the LiDAR's scan period
GRACE = 0.005  # s: the driver closes a scan once a packet this far past its end arrives


class LateLidar:
    """A camera that sees one box and a 10 Hz LiDAR delivering each scan ``FRAME``-aligned,
    ``GRACE`` after its end, until ``stop_at`` (s); every call is logged."""

    def __init__(self, rig, stop_at: float = np.inf) -> None:
        self.rig = rig
        self.stop_at = stop_at
        self.calls: list[float] = []
        self._scans: dict[int, LidarScan] = {}

    def detection_frame(self, now: float) -> CameraFrame:
        cam = self.rig.camera
        return CameraFrame(now, np.zeros((cam.height, cam.width, 3), np.uint8), cam, self.rig.T_b_c)

    def lidar_scan(self, now: float) -> LidarScan | None:
        self.calls.append(now)
        k = int(np.floor(min(now, self.stop_at) / FRAME - GRACE / FRAME + 1e-9)) - 1  # newest closed
        if k < 0:
            return None
        if k not in self._scans:  # the same object each time, as a driver's newest scan
            t = k * FRAME + np.linspace(0.0, FRAME, 200, endpoint=False)
            pts = np.column_stack([np.full(200, 5.0), np.zeros(200), np.zeros(200)])
            self._scans[k] = LidarScan(pts, t, self.rig.T_b_l)
        return self._scans[k]

    def photo(self, now, T_b_c):
        return None

    def health(self):
        return {}

    def close(self):
        pass


def _runner(sensors) -> PerceptionRunner:
    rig = simulator_rig()
    detector = lambda image: np.array([[10.0, 10.0, 50.0, 50.0, 0.9]])  # noqa: E731
    pipeline = PerceptionPipeline(rig.camera, rig.T_b_c, rig.T_b_l, insulator_length=2.0)
    return PerceptionRunner(sensors, detector, pipeline, detect_period=10.0)  # one detection event per run


def _run(runner: PerceptionRunner, t_frame: float, until: float) -> list[float]:
    """Detection at ``t_frame``, then control ticks to ``until``; the times at which perception
    got the frame (its frame counter went up)."""
    handed = []
    t = t_frame
    runner.add_pose(PoseStamped(t, pose_from_yaw(np.zeros(3), 0.0)))
    runner.step(t)
    while t < until:
        t = round(t + CONTROL_PERIOD, 9)
        runner.add_pose(PoseStamped(t, pose_from_yaw(np.zeros(3), 0.0)))
        before = runner.pipeline.counters.frames
        runner.step(t)
        if runner.pipeline.counters.frames > before:
            handed.append(t)
    return handed


def test_a_frame_waits_for_the_scan_that_covers_its_window(tmp_path) -> None:
    sensors = LateLidar(simulator_rig())
    runner = _runner(sensors)
    for t in np.arange(0.0, 10.0, CONTROL_PERIOD):
        runner.add_pose(PoseStamped(float(t), pose_from_yaw(np.zeros(3), 0.0)))
    t_frame = 10.03
    handed = _run(runner, t_frame, 11.0)
    # the scan [10.1, 10.2) holds the window's end 10.13; delivered at 10.205, first seen at 10.23
    assert handed == [10.23]
    assert runner.pairing_short == 0
    times = np.concatenate([s.times for s in runner.pipeline.scans])
    assert len(times) == len(np.unique(times))  # each point handed over once, however often asked
    assert times.min() <= t_frame - 0.1 + 0.03 and times.max() >= t_frame + 0.1  # the whole window
    # asked every tick from the window's end until the covering scan came
    assert [round(c, 2) for c in sensors.calls] == [10.03, 10.13, 10.18, 10.23]
    # the figures the summary reports: it waited 0.20 s past its exposure, and was not short
    timing = runner.pairing.timing()
    assert timing["waited_s_max"] == 0.2 and timing["short_by_s_max"] == 0.0


def test_a_lidar_that_stops_costs_the_pairing_not_the_flight(tmp_path) -> None:
    sensors = LateLidar(simulator_rig(), stop_at=10.0)
    runner = _runner(sensors)
    t_frame = 10.03
    handed = _run(runner, t_frame, 13.0)
    # nothing covers 10.13 ever: handed over with what is there once the bounded wait is over
    assert handed == [round(t_frame + 0.1 + PAIRING_WAIT, 2)] == [12.13]
    assert runner.pairing_short == 1
    assert not runner.pairing.pending
    # the LiDAR stopped at 10.0 (its last closed scan ends at 9.9): 0.23 s short of the window's
    # end, after the whole bounded wait
    timing = runner.pairing.timing()
    assert timing["waited_s_p50"] == round(0.1 + PAIRING_WAIT, 3) and timing["short_by_s_p50"] == 0.23


class RenderingLidar(LateLidar):
    """A source that renders up to the instant asked for (the simulator): it says so with
    ``window_end``, though its last return is 30 ms earlier (nothing hit after it)."""

    def lidar_scan(self, now: float) -> LidarScan | None:
        self.calls.append(now)
        t = now - 0.1 + np.linspace(0.0, 0.07, 100)
        pts = np.column_stack([np.full(100, 5.0), np.zeros(100), np.zeros(100)])
        return LidarScan(pts, t, self.rig.T_b_l, window_end=now)


def test_a_source_that_knows_its_window_pairs_at_once(tmp_path) -> None:
    sensors = RenderingLidar(simulator_rig())
    runner = _runner(sensors)
    handed = _run(runner, 10.03, 11.0)
    assert handed == [10.13] and runner.pairing_short == 0  # not held for the returns it lacks
    assert [round(c, 2) for c in sensors.calls] == [10.03, 10.13]


def test_a_frame_still_waiting_when_the_search_ends_goes_with_what_there_is_counted_short(tmp_path) -> None:
    """The flight stops perceiving when its search is over (``finish``); a replay of it waits
    PAIRING_WAIT on the same scans and counts the frame short, so the flight must count it too
    (the one-pipeline test compares the counts)."""
    sensors = LateLidar(simulator_rig())
    runner = _runner(sensors)
    handed = _run(runner, 10.03, 10.1)  # the search ends before the window past the frame is over
    assert handed == [] and runner.waiting
    runner.finish(10.1)
    assert runner.pipeline.counters.frames == 1 and not runner.waiting
    assert runner.pairing_short == 1
    # one whose window is covered is not short
    runner = _runner(RenderingLidar(simulator_rig()))
    _run(runner, 10.03, 10.05)
    runner.finish(10.2)
    assert runner.pipeline.counters.frames == 1 and runner.pairing_short == 0


def test_a_step_back_of_the_clock_is_taken_not_read_as_a_silent_lidar() -> None:
    """Scans whose mapped times stepped back (PX4 SITL's lockstep clock stalled under load, the
    companion's map ran ahead, then refitted) are taken whole and counted; a repeat of the newest
    scan, or one overlapping it, still brings only what is new. Reference: the scans' own times."""
    from insulator_rs.ports.sensors import CLOCK_STEP_BACK_S, ScanIntake

    T_b_l = np.eye(4)

    def scan(t0: float, t1: float) -> LidarScan:
        return LidarScan(np.ones((5, 3)), np.linspace(t0, t1, 5), T_b_l, window_end=t1)

    intake = ScanIntake()
    assert intake.take(scan(10.0, 10.1)) is not None and intake.horizon == 10.1
    assert intake.take(scan(10.0, 10.1)) is None  # the same newest scan handed again
    part = intake.take(scan(10.05, 10.2))  # overlapping: its new points only
    assert part is not None and np.all(part.times > 10.1) and intake.horizon == 10.2
    assert intake.take(scan(9.5, 9.6)) is None  # within a second behind: old data, dropped
    back = scan(10.2 - CLOCK_STEP_BACK_S - 3.0, 10.2 - CLOCK_STEP_BACK_S - 2.9)  # the map stepped back 4 s
    assert intake.take(back) is back and intake.steps_back == 1 and intake.horizon == back.covered_until
    assert intake.take(scan(back.covered_until, back.covered_until + 0.1)) is not None  # and on from there


def test_a_frame_waits_for_the_poses_of_its_window_too() -> None:
    """A recording's odometry may come later than its scans (a replay feeds each stream in its
    own time order): the frame is held until the pose history reaches its window's end too,
    so no point of it is moved to W with a pose clamped at the newest. Reference: the times
    the test feeds."""
    runner = _runner(RenderingLidar(simulator_rig()))
    still = pose_from_yaw(np.zeros(3), 0.0)
    for t in np.arange(9.0, 10.05, CONTROL_PERIOD):
        runner.add_pose(PoseStamped(float(t), still))
    runner.step(10.03)  # the frame; poses end at 10.0
    for now in (10.13, 10.18):
        runner.step(now)  # its window is over and the LiDAR covers it, the poses do not
        assert runner.pipeline.counters.frames == 0 and runner.waiting
    runner.add_pose(PoseStamped(10.15, still))
    runner.step(10.2)
    assert runner.pipeline.counters.frames == 1 and runner.pairing_short == 0


def test_a_frame_outside_the_pose_history_is_refused_not_placed_at_a_clamped_pose() -> None:
    """Outside the pose history's span a pose would be clamped to its oldest or newest (5 m off
    at 5 m/s one second out): such a frame is counted ``outside_poses`` and localizes nothing;
    points past the newest pose by more than POSE_GAP_S are not paired."""
    from insulator_rs.poses import POSE_GAP_S, PoseHistory

    rig = simulator_rig()
    pipeline = PerceptionPipeline(rig.camera, rig.T_b_c, rig.T_b_l, insulator_length=2.0)
    for t in np.arange(20.0, 22.0, CONTROL_PERIOD):
        pipeline.add_pose(PoseStamped(float(t), pose_from_yaw(np.array([5.0 * t, 0.0, 10.0]), 0.0)))
    times = np.linspace(14.9, 22.5, 400)
    pts = np.column_stack([np.full(400, 5.0), np.zeros(400), np.zeros(400)])
    pipeline.add_scan(LidarScan(pts, times, rig.T_b_l))
    cam = rig.camera
    box = np.array([[10.0, 10.0, 50.0, 50.0, 0.9]])
    for t in (15.0, 22.0 + 2 * POSE_GAP_S):  # before the oldest pose; past the newest
        frame = CameraFrame(t, np.zeros((cam.height, cam.width, 3), np.uint8), cam, rig.T_b_c)
        assert pipeline.process(frame, box) == []
    assert pipeline.counters.outside_poses == 2 and pipeline.counters.unpaired == 0
    newest = pipeline.poses.newest.time
    paired_times = times[(np.abs(times - 21.95) <= pipeline.pairing_window) & (times <= newest + POSE_GAP_S)]
    assert len(pipeline.paired_points_w(21.95)) == len(paired_times) > 0
    assert PoseHistory().covers(1.0) is False
