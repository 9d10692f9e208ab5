"""Every way out is checked against what the LiDAR saw (issue 48 item 3): the abort's safe route
(and so the battery reserve's return, which is that route) is bent round an obstacle of the
obstacle map, as the mission's legs are, or refused, and then the vehicle holds for the pilot.

Reference: the obstacle's true geometry (a vertical pole, a cylinder), its distance from the
route and from the flown trajectory computed here with numpy (helpers/reference_safety.py),
never the map's own distances.

* The planner (cheap): on tower B's volumes, a pole on the way back out from beside an arm. The
  straight way out comes closer than the margin to the pole; with the map, the leg is bent, and
  the bent polyline and the min-snap trajectory flown along it keep the margin from the pole's
  true surface. A pole by the way out's corner, and a wall across it, refuse the route, naming
  the leg, the point and where the obstacle was seen.
* A flight (the small scene, in process): a distribution pole the tower model does not hold
  stands beside the far-side inspection visit; the operator aborts at the visit's last
  waypoint; the way back out goes round the pole, and the airframe's true trajectory keeps the
  mission's margin from the pole and from the whole true mesh.
* The map growing on the way out (the safe exit flying an in-process airframe): the pole first
  seen a tenth of the way back stops the vehicle, and the rest of the leg goes round it.
* The battery reserve weighs the bent way out; the landing approach at the mission's end is a
  leg, bent round a pole or refused by one beside the landing point.
"""

from __future__ import annotations

import json
import re
from types import SimpleNamespace

import numpy as np
import pytest
from helpers.flights import POLE, POLE_END, POLE_RADIUS, POLE_START, small_scene
from helpers.reference_safety import cylinder_clearance, inside_any, polyline_samples

from insulator_rs.app.inspect_command import MISSIONS_DIR
from insulator_rs.evaluation.fault_matrix import Structure
from insulator_rs.exceptions import ObstacleBlocked
from insulator_rs.flight.energy_budget import EnergyBudget
from insulator_rs.flight.leg_follower import LegFollower
from insulator_rs.flight.loop import FlightLoop, FlightSettings
from insulator_rs.flight.pilot import CONTROL_PERIOD, LAND_HEIGHT
from insulator_rs.flight.safe_exit import SafeExit
from insulator_rs.mission.config import load_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import AbortContext, PlanItem
from insulator_rs.planning.abort import AbortCase, leg_trajectory, plan_abort_route
from insulator_rs.planning.exploration import PlanKind
from insulator_rs.planning.obstacle_map import ObstacleMap, SeenVolumes
from insulator_rs.planning.safety import safety_volumes
from insulator_rs.sim.flight_assembly import simulated_ports
from insulator_rs.sim.kinematics import KinematicVehicle
from insulator_rs.sim.mission_airframe import kinematic_vehicle
from insulator_rs.sim.sensors import kinematic_true_pose
from insulator_rs.sim.towers import load_tower

MISSION = load_mission(MISSIONS_DIR / "tower_b.toml")
LINE = MISSION.line()
VOL = safety_volumes(LINE, max_width=MISSION.max_width, max_height=MISSION.max_height,
                     margin=MISSION.inspection.safety_margin)
MARGIN = MISSION.inspection.safety_margin
PLAN = {"ground_z": 0.0, "land_height": 2.0, "crossing_clearance": 3.0}
V_MAX, A_MAX = MISSION.vehicle.v_max(), MISSION.vehicle.a_max()
RADIUS = 0.15
# beside tower B's arm (1 m from its box), and where the detour left the exploration path
BESIDE_ARM = LINE.to_world(np.array([0.0, -7.5, 16.0]))
BACK_TO = LINE.to_world(np.array([3.0, -14.5, 16.0]))


def _pole_on_the_way_back() -> tuple[np.ndarray, np.ndarray]:
    """The axis (start, end) of a 25 m pole half-way back out from beside the arm, 0.3 m off the
    straight way (across it, horizontally)."""
    along = BACK_TO - BESIDE_ARM
    across = np.array([-along[1], along[0], 0.0]) / np.linalg.norm(along[:2])
    foot = (BESIDE_ARM + BACK_TO) / 2 + 0.3 * across
    return np.array([foot[0], foot[1], 0.0]), np.array([foot[0], foot[1], 25.0])


def _pole_returns(x: float, y: float, height: float = 25.0, radius: float = RADIUS) -> np.ndarray:
    """LiDAR returns on a vertical pole's surface: rings 5 cm apart, 24 returns a ring."""
    ring = np.stack([np.cos(np.linspace(0, 2 * np.pi, 24)), np.sin(np.linspace(0, 2 * np.pi, 24))], axis=1) * radius
    return np.array([[x + c[0], y + c[1], z] for z in np.arange(0.0, height, 0.05) for c in ring])


def _seen(returns: np.ndarray) -> SeenVolumes:
    obstacles = ObstacleMap(known=VOL, ground_z=0.0)
    obstacles.insert(returns)
    assert len(obstacles.occupied_centres()) > 0, "the returns lie outside the safety volumes"
    return SeenVolumes.of(VOL, obstacles, MARGIN)


def _back_out(seen: SeenVolumes | None):
    return plan_abort_route(LINE, VOL, BESIDE_ARM, toward_side=-1, back_to=BACK_TO, seen=seen, **PLAN)


def test_a_way_out_past_a_pole_the_map_holds_is_bent_clear_of_the_margin():
    start, end = _pole_on_the_way_back()
    foot = start
    straight = _back_out(None)
    assert straight.case == AbortCase.BACK_OUT and not straight.bends
    assert cylinder_clearance(polyline_samples(straight.legs[0]), start, end, RADIUS).min() < MARGIN, \
        "the pole stands on the straight way out"

    route = _back_out(_seen(_pole_returns(foot[0], foot[1])))
    assert route.case == AbortCase.BACK_OUT and np.allclose(route.landing, straight.landing)
    assert len(route.legs) == len(straight.legs) and len(route.legs[0]) > 2, "the way back is bent"
    assert np.allclose(route.legs[0][0], BESIDE_ARM) and np.allclose(route.legs[0][-1], BACK_TO)
    assert [b.leg for b in route.bends] == [0]
    seen_at = route.bends[0].bend.obstacle
    assert np.linalg.norm(seen_at[:2] - foot[:2]) < 0.6, f"the bend names the pole, not {seen_at}"
    assert "bent round the obstacle the LiDAR saw at" in route.bends[0].describe()
    space = _seen(_pole_returns(foot[0], foot[1]))
    for leg in route.legs:
        pts = polyline_samples(leg)
        assert cylinder_clearance(pts, start, end, RADIUS).min() >= MARGIN
        assert not inside_any(VOL, pts).any()
        # and the curve flown along the leg, from rest to rest
        traj = leg_trajectory(leg, space, v_max=V_MAX, a_max=A_MAX, dt=0.05)
        _, flown, _ = traj.sample(0.01)
        assert cylinder_clearance(flown, start, end, RADIUS).min() >= MARGIN
        assert not inside_any(VOL, flown).any()


def test_a_way_out_that_no_bend_clears_is_refused_naming_the_obstacle():
    # a pole 1 m beside where the detour began (the way out's corner above its landing column)
    corner = BACK_TO + np.array([1.0, 0.0, 0.0])
    with pytest.raises(ObstacleBlocked) as refused:
        _back_out(_seen(_pole_returns(corner[0], corner[1])))
    text = str(refused.value)
    assert text.startswith("abort: leg 1 of the way out (back out): waypoint ")
    assert "lies within the safety margin of an obstacle the LiDAR saw at [" in text
    seen_at = np.array([float(v) for v in re.findall(r"-?\d+\.\d", text.rsplit(" at ", 1)[1])])
    assert np.linalg.norm(seen_at[:2] - corner[:2]) < 0.6, text
    assert cylinder_clearance(BACK_TO[None], corner * [1, 1, 0], corner * [1, 1, 0] + [0, 0, 25], RADIUS)[0] < MARGIN

    # a wall across the whole way back, from the ground to 30 m high and 30 m wide: no bend
    along = (BACK_TO - BESIDE_ARM)[:2] / np.linalg.norm((BACK_TO - BESIDE_ARM)[:2])
    mid = (BESIDE_ARM + BACK_TO) / 2
    s, z = np.meshgrid(np.arange(-15.0, 15.0, 0.1), np.arange(0.0, 30.0, 0.1))
    wall = np.stack([mid[0] - along[1] * s.ravel(), mid[1] + along[0] * s.ravel(), z.ravel()], axis=1)
    with pytest.raises(ObstacleBlocked, match=r"^abort: leg 1 of the way out \(back out\): segment .* no detour "
                                              r"round the obstacle the LiDAR saw at \["):
        _back_out(_seen(wall))


# -- a flight: the operator's abort beside the pole -------------------------------------------
@pytest.mark.slow
def test_an_abort_beside_a_pole_the_tower_model_lacks_flies_round_it(tmp_path):
    scene, mission_file = small_scene(tmp_path)
    scene.write_text(scene.read_text() + POLE)
    mission = load_mission(mission_file)
    tower = load_tower(str(scene))
    vehicle = kinematic_vehicle(mission, 0)
    rig = mission.sensor_rig()
    ports = simulated_ports(tower.mesh, kinematic_true_pose(vehicle), rig, seed=0, detect_scale=0.2, photo_scale=0.2)
    truth: list[np.ndarray] = []
    aborted_at: list[int] = []
    advance = vehicle.advance

    def flown(dt):
        st = advance(dt)
        truth.append(vehicle.true_pose_at(st.time)[:3, 3].copy())
        # the operator aborts at the far-side visit's last waypoint (its photo, the 4th, taken):
        # the way back out to where the visit left the pass goes past the pole
        if len(loop.photos) >= 4 and not aborted_at:
            aborted_at.append(len(truth))
            loop.request_abort()
        return st

    vehicle.advance = flown
    loop = FlightLoop(mission, vehicle, ports.sensors, ports.detector, tmp_path / "report", rig=rig,
                      settings=FlightSettings(detect_period=0.5, quiet=True), photo_camera=ports.photo_camera)
    loop.fly()
    summary = loop.finish_report()
    assert aborted_at, "the flight never took its 4th photo"
    ab = summary["abort"]
    assert summary["status"] == "aborted: operator" and ab["handed_over"] is None, summary["status"]
    assert ab["route"] == AbortCase.BACK_OUT.value
    assert vehicle.landed
    path = np.array(truth)
    after = path[aborted_at[0]:]
    margin = mission.inspection.safety_margin
    pole = cylinder_clearance(path, POLE_START, POLE_END, POLE_RADIUS)
    mesh, nearest = Structure(tower.mesh).clearance(path)
    print(f"true clearance: the pole {pole.min():.2f} m (after the abort "
          f"{cylinder_clearance(after, POLE_START, POLE_END, POLE_RADIUS).min():.2f} m), "
          f"the whole mesh {mesh:.2f} m ({nearest}); bends {json.dumps(ab.get('bends'))}")
    assert pole.min() >= margin
    assert mesh >= margin
    assert ab["bends"], "the way back out was not bent round the pole"
    assert np.linalg.norm(np.array(ab["bends"][0]["obstacle"])[:2] - POLE_START[:2]) < 0.6, ab["bends"]


# -- the map grows on the way out: stop, and plan the rest of the leg again ---------------------
class _Pilot:
    """The loop as the safe exit sees it, reduced to an in-process airframe that stands beside
    tower B's arm in offboard; ``on_tick(state)`` runs after every tick (the LiDAR's survey)."""

    def __init__(self, on_tick):
        self.vehicle = KinematicVehicle(start_position=BESIDE_ARM, ground_z=0.0)
        self.vehicle.send_setpoint(BESIDE_ARM)
        self.vehicle.arm()
        self.vehicle.start_offboard()
        self.on_tick = on_tick
        self.failsafe, self.airborne = None, True
        self.sm = SimpleNamespace(aborted=AbortContext("operator", 0.0, -1, BACK_TO))
        self.said: list[str] = []
        self.path: list[np.ndarray] = []
        self.landed = False

    def tick(self, position, velocity, yaw):
        self.vehicle.send_setpoint(position, velocity, yaw)
        st = self.vehicle.advance(CONTROL_PERIOD)
        self.path.append(self.vehicle.true_pose_at(st.time)[:3, 3].copy())
        self.on_tick(st)
        return st

    def say(self, text):
        self.said.append(text)

    def now(self):
        return self.vehicle.state().time

    def write_summary(self):
        pass

    def land(self):
        self.landed = True


@pytest.mark.slow
def test_an_obstacle_seen_on_the_rest_of_the_way_out_stops_the_vehicle_and_it_goes_round():
    geom = MissionGeometry.from_mission(MISSION)
    obstacles = ObstacleMap(known=geom.volumes, ground_z=0.0)
    start, end = _pole_on_the_way_back()
    foot = start
    seen_when: list[float] = []

    def survey(st):
        # the LiDAR first sees the pole once the vehicle is a tenth of the way back out
        if not seen_when and np.linalg.norm(st.position - BESIDE_ARM) > 0.1 * np.linalg.norm(BACK_TO - BESIDE_ARM):
            seen_when.append(st.time)
            obstacles.insert(_pole_returns(foot[0], foot[1]))

    pilot = _Pilot(survey)
    exit_ = SafeExit(pilot, geom, SimpleNamespace(insulators=[]), v_max=V_MAX, a_max=A_MAX, crossing_clearance=3.0,
                     observer=SimpleNamespace(handed_over=lambda *_: None),
                     seen=lambda: SeenVolumes.of(geom.volumes, obstacles, MARGIN))
    exit_.leave()
    assert seen_when, "the vehicle never got going"
    assert exit_.handed_over is None and pilot.landed, pilot.said
    path = np.array(pilot.path)
    clearance = cylinder_clearance(path, start, end, RADIUS)
    print(f"true clearance to the pole seen late: {clearance.min():.2f} m")
    assert clearance.min() >= MARGIN, f"{clearance.min():.2f} m from the pole"
    assert not inside_any(VOL, path).any()
    assert any("the LiDAR sees an obstacle on the rest of leg 1 of the way out" in s for s in pilot.said), pilot.said
    assert any("bent round the obstacle the LiDAR saw at" in s for s in pilot.said), pilot.said
    route = exit_.route
    assert route is not None and route.bends and route.bends[0].leg == 0
    assert np.linalg.norm(path[-1, :2] - BACK_TO[:2]) < 0.3 and path[-1, 2] == pytest.approx(2.0, abs=0.3)


# -- the battery reserve's return and the landing approach -------------------------------------
def test_the_reserve_weighs_the_way_out_as_bent_round_the_map():
    """The reserve's return is the abort's route (flight/energy_budget.py): with the pole on the
    way back out, the distance it weighs is the bent route's, corner to corner (numpy here)."""
    foot, _ = _pole_on_the_way_back()
    seen = _seen(_pole_returns(foot[0], foot[1]))
    geom = MissionGeometry.from_mission(MISSION)
    budget = EnergyBudget(geom, v_max=V_MAX, a_max=A_MAX, reserve=0.25, crossing_clearance=3.0,
                          way_out=lambda p: plan_abort_route(LINE, VOL, p, toward_side=-1, back_to=BACK_TO,
                                                             seen=seen, **PLAN))
    straight = _back_out(None)
    bent = _back_out(seen)
    corners = np.vstack([BESIDE_ARM] + [leg[1:] for leg in bent.legs])
    length = float(np.sum(np.linalg.norm(np.diff(corners, axis=0), axis=1)))
    straight_length = float(np.sum([np.linalg.norm(leg[-1] - leg[0]) for leg in straight.legs]))
    way = budget.way_out_demand(BESIDE_ARM)
    assert length > straight_length + 0.1, "the bend is longer than the straight way"
    assert way.distance_m == pytest.approx(length + PLAN["land_height"])  # and the touchdown's 2 m


class _LegPilot:
    """What a leg follower asks of the loop: the vehicle, the clock, the log."""

    def __init__(self, position):
        self.vehicle = KinematicVehicle(start_position=position, ground_z=0.0)
        self.said: list[str] = []

    def say(self, text):
        self.said.append(text)

    def now(self):
        return self.vehicle.state().time


def test_the_landing_approach_is_bent_round_the_map_or_refused_as_a_leg():
    """The landing approach (the loop's leg to LAND_HEIGHT above the landing point) is a leg: bent
    round a pole between the vehicle and the landing point, and logged naming the pole; refused
    when the pole stands by the landing point (the loop then aborts and the way out lands clear)."""
    geom = MissionGeometry.from_mission(MISSION)
    above = geom.takeoff + np.array([0.0, 0.0, LAND_HEIGHT])
    outward = np.array([*geom.takeoff[:2], 0.0]) / np.linalg.norm(geom.takeoff[:2])  # away from the tower
    start_at = above + 12.0 * outward + np.array([0.0, 0.0, 8.0])
    foot = (start_at + above) / 2
    lim, p = MISSION.vehicle, MISSION.inspection
    for pole_at, bent in ((foot, True), (above + np.array([0.0, 1.0, 0.0]), False)):
        pilot = _LegPilot(start_at)
        follower = LegFollower(pilot, geom, v_max=lim.v_max(), a_max=lim.a_max(), clearance=p.crossing_clearance,
                               margin=p.safety_margin, time_allocation="pmm", obstacle_map=True)
        follower.obstacles.insert(_pole_returns(pole_at[0], pole_at[1]))
        item = PlanItem(PlanKind.LAND, above, 0.0, 1)
        if not bent:
            with pytest.raises(ObstacleBlocked, match=r"lies within the safety margin of an obstacle the LiDAR saw at"):
                follower.plan([item])
            assert follower.record()["legs_refused"] == 1
            continue
        leg = follower.plan([item])
        assert leg.segment.bends and follower.record()["legs_bent"] == 1
        assert any("bent round the obstacle the LiDAR saw at" in s for s in pilot.said), pilot.said
        _, flown, _ = leg.trajectory.sample(0.01)
        start, end = np.array([*pole_at[:2], 0.0]), np.array([*pole_at[:2], 25.0])
        assert cylinder_clearance(flown, start, end, RADIUS).min() >= MARGIN
        assert np.allclose(flown[-1], above, atol=1e-6)
