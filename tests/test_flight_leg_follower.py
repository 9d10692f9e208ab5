"""The leg follower (flight/leg_follower.py), without a mission: a leg is streamed tick by tick
along its min-snap trajectory, and its rest is re-checked against the obstacle map once each time
the map gains occupied voxels (the one re-check every leg, the plan's and a second look's, uses).

Reference: the trajectory itself (``MinSnapTrajectory.evaluate``) for the setpoints streamed, and
for the re-check points put on the trajectory's rest (blocked) or far from it (clear), on the
small scene's geometry with the in-process vehicle.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers.flights import small_scene

from insulator_rs.exceptions import PlanningError
from insulator_rs.flight.leg_follower import SURVEY_PERIOD, LegFollower, follow
from insulator_rs.flight.pilot import CONTROL_PERIOD
from insulator_rs.mission.config import load_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import PlanItem
from insulator_rs.planning.exploration import PlanKind
from insulator_rs.sim.kinematics import KinematicVehicle


class TickPilot:
    """The loop's tick reduced to the vehicle: one setpoint, one control period."""

    def __init__(self, vehicle: KinematicVehicle) -> None:
        self.vehicle = vehicle
        self.sent: list[np.ndarray] = []

    def tick(self, position, velocity, yaw):
        self.sent.append(np.array(position, dtype=np.float64))
        self.vehicle.send_setpoint(position, velocity, yaw)
        return self.vehicle.advance(CONTROL_PERIOD)


@pytest.fixture
def scene(tmp_path):
    _, mission_path = small_scene(tmp_path)
    mission = load_mission(mission_path)
    geom = MissionGeometry.from_mission(mission)
    pilot = TickPilot(KinematicVehicle(start_position=geom.takeoff))
    return mission, geom, pilot


def _follower(mission, geom, pilot, *, obstacle_map=True):
    lim, p = mission.vehicle, mission.inspection
    return LegFollower(pilot, geom, v_max=lim.v_max(), a_max=lim.a_max(), clearance=p.crossing_clearance,
                       margin=p.safety_margin, time_allocation="pmm", obstacle_map=obstacle_map)


def _climb(geom, height=8.0):
    """A leg straight up from the take-off point (clear of the tower: the take-off is beside it)."""
    return PlanItem(PlanKind.SCAN, geom.takeoff + np.array([0.0, 0.0, height]), 0.0, 1)


def test_a_leg_is_streamed_along_its_trajectory_to_its_end(scene):
    mission, geom, pilot = scene
    leg = _follower(mission, geom, pilot).plan([_climb(geom)])
    traj = leg.trajectory
    assert traj is not None
    times = [t for t, _ in leg.fly(lambda: 0.0)]
    assert np.all(np.diff(times) > 0) and times[-1] == pytest.approx(traj.total_time)
    assert times[0] == pytest.approx(CONTROL_PERIOD)
    expected = traj.evaluate(np.array(times), 0)
    assert np.allclose(np.array(pilot.sent), expected)
    assert np.allclose(pilot.sent[-1], geom.takeoff + [0.0, 0.0, 8.0], atol=1e-9)


def test_follow_stops_where_the_caller_stops(scene):
    mission, geom, pilot = scene
    traj = _follower(mission, geom, pilot).plan([_climb(geom)]).trajectory
    for n, (t, _) in enumerate(follow(pilot, traj, lambda: 0.0), start=1):
        if n == 3:
            break
    assert len(pilot.sent) == 3 and t == pytest.approx(3 * CONTROL_PERIOD)


def test_the_rest_of_a_leg_is_rechecked_once_per_map_change(scene):
    mission, geom, pilot = scene
    follower = _follower(mission, geom, pilot)
    leg = follower.plan([_climb(geom)])
    traj = leg.trajectory
    assert not leg.blocked(0.0)  # the map has not changed since the leg was planned
    # a pole seen across the rest of the climb (each return twice: MIN_HITS)
    rest = traj.evaluate(np.linspace(0.6 * traj.total_time, traj.total_time, 20), 0)
    assert follower.obstacles.insert(np.repeat(rest, 2, axis=0)) > 0
    assert leg.blocked(0.3 * traj.total_time)
    assert not leg.blocked(0.3 * traj.total_time)  # checked at this map version already


def test_a_map_change_away_from_the_leg_leaves_it_clear(scene):
    mission, geom, pilot = scene
    follower = _follower(mission, geom, pilot)
    leg = follower.plan([_climb(geom)])
    far = geom.takeoff + np.array([[20.0, 20.0, 6.0], [20.0, 20.5, 6.0]])
    assert follower.obstacles.insert(np.repeat(far, 2, axis=0)) > 0
    assert not leg.blocked(0.0)


def test_without_a_map_nothing_is_rechecked_and_nothing_counted(scene):
    mission, geom, pilot = scene
    follower = _follower(mission, geom, pilot, obstacle_map=False)
    assert follower.obstacles is None and follower.seen() is None
    assert not follower.plan([_climb(geom)]).blocked(0.0)
    assert follower.record() == {"enabled": False}


def test_a_leg_blocked_by_the_map_is_refused_and_counted_and_a_look_is_not(scene):
    mission, geom, pilot = scene
    follower = _follower(mission, geom, pilot)
    # a wall of returns round the climb's top: no detour reaches it
    top = geom.takeoff + np.array([0.0, 0.0, 8.0])
    offsets = np.array([[x, y, z] for x in np.arange(-3, 3.01, 0.25) for y in np.arange(-3, 3.01, 0.25)
                        for z in (-0.5, 0.0, 0.5)])
    follower.obstacles.insert(np.repeat(top + offsets, 2, axis=0))
    with pytest.raises(PlanningError):
        follower.plan([_climb(geom)])
    with pytest.raises(PlanningError):
        follower.plan([_climb(geom)], counted=False)
    record = follower.record()
    assert record["enabled"] and record["legs_refused"] == 1 and record["legs_bent"] == 0


def test_the_survey_takes_a_scan_every_period(scene):
    mission, geom, pilot = scene
    follower = _follower(mission, geom, pilot)
    asked: list[float] = []

    def scan(time):
        asked.append(time)
        return np.zeros((0, 3))

    T_b_l = np.eye(4)
    st = pilot.vehicle.state()
    follower.survey(st, scan, T_b_l)  # the first survey a period after the start
    assert asked == []
    for _ in range(int(round(2 * SURVEY_PERIOD / CONTROL_PERIOD))):
        st = pilot.tick(st.position, None, 0.0)
        follower.survey(st, scan, T_b_l)
    assert len(asked) == 2 and asked[1] - asked[0] == pytest.approx(SURVEY_PERIOD)
