"""Two-flight baseline and the single-flight PMM timing loop."""

import itertools

import numpy as np
import pytest

from insulator_rs.mission.config import load_mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.planning.pmm import plan_pmm
from insulator_rs.tracking.registry import InsulatorRegistry
from insulator_rs.evaluation.single_flight import fly_single_flight
from insulator_rs.mission.state_machine import InspectionStateMachine
from insulator_rs.planning.tsp import tour_cost
from insulator_rs.evaluation.two_flight import two_flight
from insulator_rs.planning.routes import cost_matrix, route
from insulator_rs.planning.waypoints import inspection_waypoints

from helpers.flights import MISSIONS

VM = np.array([3.0, 3.0, 3.0])
AM = np.array([12.0, 12.0, 12.0])


@pytest.fixture(scope="module")
def geom():
    return MissionGeometry.from_mission(load_mission(MISSIONS / "tower_a.toml"))


def viewpoints(geom, centers):
    out = []
    for i, c in enumerate(centers):
        out += inspection_waypoints(np.array(c), np.array([0.0, 1.0, 0.1]), insulator_id=i + 1,
                                    line=geom.line, volumes=geom.volumes, count=1,
                                    inspection_distance=6.0, insulator_length=2.2, fov=1.0)
    return out


CENTERS = [[5.0, -1.44, 16.85], [-5.0, 1.44, 20.85], [5.0, 1.44, 24.85], [-4.2, -1.44, 24.85],
           [5.0, 1.44, 16.85], [-5.0, -1.44, 16.85]]


def test_tour_is_optimal_against_brute_force_and_safe(geom):
    """Reference: brute force over all orders of the 6 waypoints (itertools), exact."""
    wps = np.array([w.position for w in viewpoints(geom, CENTERS)])
    res = two_flight(geom.path_points(), wps, line=geom.line, volumes=geom.volumes, clearance=3.0,
                     v_max=VM, a_max=AM)
    nodes = np.vstack([geom.takeoff[None], wps])
    c = cost_matrix(nodes, geom.line, geom.volumes, 3.0, VM, AM)
    best = min(tour_cost(c, (0, *p)) for p in itertools.permutations(range(1, len(nodes))))
    assert res.tour.cost == pytest.approx(best, abs=1e-9)
    assert geom.volumes.polyline_clear(res.tour_route)
    # the flown tour (optimised velocities) is no slower than its rest-to-rest cost
    assert res.t_tsp <= res.tour.cost + 1e-9
    assert res.t_scan == pytest.approx(plan_pmm(geom.path_points(), VM, AM).total_time)
    # crossing edges go over the top
    r = route(geom.line, geom.volumes, wps[0], wps[1], 3.0)
    assert len(r) == 4 and r[1, 2] == pytest.approx(geom.volumes.top + 3.0)


def run_single(geom, sense, policy="immediate"):
    reg = InsulatorRegistry(geom.line, 1.5, confirmations=1)  # the paper: at once

    def make(ins):
        return viewpoints(geom, [ins.center])

    sm = InspectionStateMachine(geom.path, reg, make, policy=policy,
                                cost=lambda a, b: float(np.linalg.norm(b - a)))
    sm.start(0.0)
    return sm, fly_single_flight(sm, v_max=VM, a_max=AM, sense=sense, sense_period=0.2)


def test_single_flight_without_detections_is_the_scan_flight(geom):
    calls = []

    def sense(p, yaw, t):
        calls.append(t)
        return []

    _, res = run_single(geom, sense)
    assert res.time == pytest.approx(plan_pmm(geom.path_points(), VM, AM).total_time, rel=1e-9)
    assert res.replans == 1 and calls[-1] <= res.time and len(calls) >= res.time / 0.2 - 1
    assert geom.volumes.samples_clear(res.positions, max_step=float(np.linalg.norm(VM)) * 0.2)


def test_single_flight_detour_costs_time_and_visits_the_viewpoint(geom):
    found = {"done": False}

    def sense(p, yaw, t):
        if t >= 3.0 and not found["done"]:
            found["done"] = True
            return [(np.array(CENTERS[0]), np.array([0.0, 1.0, 0.1]))]
        return []

    sm, res = run_single(geom, sense)
    scan = plan_pmm(geom.path_points(), VM, AM).total_time
    assert res.time > scan and res.replans >= 2
    kinds = [it.kind for it in res.visited]
    assert kinds.count("inspect") == 1 and kinds.count("return") == 1
    assert sm.registry.insulators[0].inspected
    assert geom.volumes.samples_clear(res.positions, max_step=float(np.linalg.norm(VM)) * 0.2)
