"""The energy budget (flight/energy_budget.py), without a mission: which route it costs for the
rest of the plan and for the way out, and when the reserve turns the vehicle back.

Reference: the rest-to-rest point-mass profile written out here (per axis: a triangle
``2 sqrt(d / a)`` below ``v^2 / a``, else a trapezoid ``d / v + v / a``; a leg takes its slowest
axis), Euclidean leg lengths, and the rules stated in the module: a photo stop at its longest
(PHOTO_SETTLE_TIMEOUT), the touchdown (TOUCHDOWN_TIME from LAND_HEIGHT), nothing after the landing
item, a deferred waypoint as a detour from the nearest plan point on its side.
"""

from __future__ import annotations

import numpy as np
import pytest

from insulator_rs.exceptions import PlanningError
from insulator_rs.flight.energy_budget import EnergyBudget
from insulator_rs.flight.photo_session import PHOTO_SETTLE_TIMEOUT
from insulator_rs.flight.pilot import LAND_HEIGHT
from insulator_rs.flight.reserve import TOUCHDOWN_TIME
from insulator_rs.mission.state_machine import PlanItem
from insulator_rs.planning.abort import AbortCase, AbortRoute
from insulator_rs.planning.exploration import PlanKind
from insulator_rs.planning.waypoints import InspectionWaypoint
from insulator_rs.ports.vehicle import VehicleState

V_MAX = np.array([4.0, 4.0, 2.0])
A_MAX = np.array([2.0, 2.0, 1.0])


def _leg_time(a, b):
    d = np.abs(np.asarray(b, float) - np.asarray(a, float))
    t = np.where(d < V_MAX ** 2 / A_MAX, 2 * np.sqrt(d / A_MAX), d / V_MAX + V_MAX / A_MAX)
    return float(t.max())


def _route(points):
    """(time, distance) of flying ``points`` rest to rest."""
    return (sum(_leg_time(a, b) for a, b in zip(points[:-1], points[1:])),
            sum(float(np.linalg.norm(np.subtract(b, a))) for a, b in zip(points[:-1], points[1:])))


class FakeVolumes:
    top = 20.0


class FakeGeometry:
    volumes = FakeVolumes()
    takeoff = np.array([0.0, -15.0, 0.0])

    def path_points(self):
        return np.array([[0.0, -15.0, 6.0], [10.0, -15.0, 6.0], [10.0, 15.0, 25.0], [0.0, -15.0, 2.0]])


def _budget(way_out):
    return EnergyBudget(FakeGeometry(), v_max=V_MAX, a_max=A_MAX, reserve=0.25, crossing_clearance=3.0,
                        way_out=way_out)


def _no_route(position):
    raise PlanningError("no route")


def _wp(position, side):
    return InspectionWaypoint(np.array(position, float), 0.0, 0.0, np.zeros(3), 1, side)


def test_the_rest_of_the_plan_is_its_items_to_the_landing_with_a_stop_at_each_photo():
    here = np.array([0.0, -10.0, 6.0])
    plan = [PlanItem(PlanKind.SCAN, np.array([5.0, -10.0, 6.0]), 0.0, -1),
            PlanItem(PlanKind.INSPECT, np.array([5.0, -8.0, 9.0]), 0.0, -1, _wp([5.0, -8.0, 9.0], -1)),
            PlanItem(PlanKind.CROSS, np.array([5.0, 0.0, 25.0]), 0.0, 0),
            PlanItem(PlanKind.LAND, np.array([0.0, -15.0, 0.0]), 0.0, -1),
            PlanItem(PlanKind.SCAN, np.array([50.0, 50.0, 6.0]), 0.0, -1)]  # after the landing: not flown
    rest = _budget(_no_route).rest_of_plan(here, plan, {})
    points = [here] + [it.position for it in plan[:3]] + [np.array([0.0, -15.0, LAND_HEIGHT])]
    time, distance = _route(points)
    assert rest.distance_m == pytest.approx(distance + LAND_HEIGHT)
    assert rest.time_s == pytest.approx(time + PHOTO_SETTLE_TIMEOUT + TOUCHDOWN_TIME)


def test_a_deferred_waypoint_costs_a_detour_from_the_nearest_plan_point_on_its_side():
    here = np.array([0.0, 10.0, 6.0])
    plan = [PlanItem(PlanKind.SCAN, np.array([0.0, 10.0, 10.0]), 0.0, 1),
            PlanItem(PlanKind.SCAN, np.array([8.0, 10.0, 10.0]), 0.0, 1),
            PlanItem(PlanKind.SCAN, np.array([8.0, -10.0, 10.0]), 0.0, -1)]
    budget = _budget(_no_route)
    without = budget.rest_of_plan(here, plan, {})
    w = _wp([9.0, 12.0, 11.0], 1)
    with_it = budget.rest_of_plan(here, plan, {1: [w]})
    near = np.array([8.0, 10.0, 10.0])  # the nearer of the two points on side +1
    time, distance = _route([near, w.position, near])
    assert with_it.distance_m - without.distance_m == pytest.approx(distance)
    assert with_it.time_s - without.time_s == pytest.approx(time + PHOTO_SETTLE_TIMEOUT)


def test_the_way_out_is_the_abort_route_or_else_home_over_the_crossing_height():
    here = np.array([10.0, 5.0, 12.0])
    landing = np.array([20.0, 5.0, LAND_HEIGHT])
    route = AbortRoute(AbortCase.DESCEND, (np.array([here, [20.0, 5.0, 12.0]]), np.array([[20.0, 5.0, 12.0], landing])),
                       landing, 1)
    time, distance = _route([here, [20.0, 5.0, 12.0], landing])
    way = _budget(lambda p: route).way_out_demand(here)
    assert way.distance_m == pytest.approx(distance + LAND_HEIGHT)
    assert way.time_s == pytest.approx(time + TOUCHDOWN_TIME)
    # no route now: up to 3 m over the tower's top (20 m), across, down to LAND_HEIGHT over home
    up = 23.0
    home = [0.0, -15.0, LAND_HEIGHT]
    time, distance = _route([here, [10.0, 5.0, up], [0.0, -15.0, up], home])
    way = _budget(_no_route).way_out_demand(here)
    assert way.distance_m == pytest.approx(distance + LAND_HEIGHT)
    assert way.time_s == pytest.approx(time + TOUCHDOWN_TIME)


def test_the_mission_demand_is_the_exploration_path_from_the_start():
    start = np.array([0.0, -15.0, 0.0])
    time, distance = _route([start, *FakeGeometry().path_points()])
    demand = _budget(_no_route).mission_demand(start)
    assert demand.distance_m == pytest.approx(distance + LAND_HEIGHT)
    assert demand.time_s == pytest.approx(time + TOUCHDOWN_TIME)


def _state(t, fraction, *, landed=False):
    return VehicleState(time=t, position=np.array([0.0, -10.0, 6.0]), velocity=np.zeros(3), yaw=0.0, armed=True,
                        mode="OFFBOARD", landed=landed, battery_fraction=fraction)


def test_the_reserve_turns_the_vehicle_back_in_the_air_only():
    budget = _budget(_no_route)
    budget.observe(_state(0.0, 0.9))
    assert budget.check(_state(0.05, 0.9), 0.05, [], {}) is None
    assert budget.check(_state(0.1, 0.24, landed=True), 0.1, [], {}) is None  # on the ground: nothing to decide
    reason = budget.check(_state(0.1, 0.24), 0.1, [], {})
    assert reason is not None and reason.startswith("battery at the reserve (24%, reserve 25%)")
    assert budget.record()["reason"] == reason
