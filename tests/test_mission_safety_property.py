"""Property: every trajectory the mission plans, in randomised towers, stays out of the safety
volumes (exploration path flown by min-snap and by PMM, inspection detours, TSP-style
side-to-side routes)."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from insulator_rs.exceptions import PlanningError
from insulator_rs.planning.exploration import crossing_route, exploration_path
from insulator_rs.geodesy import line_frame
from insulator_rs.planning.minsnap import plan_min_snap_safe
from insulator_rs.planning.pmm import plan_pmm_safe
from insulator_rs.planning.safety import safety_volumes
from insulator_rs.planning.waypoints import inspection_waypoints

DT = 0.02
GRAZING = 0.1  # m: a route passing this close to a safety box grazes it


@st.composite
def towers(draw):
    heading = draw(st.floats(0, 2 * math.pi))
    d0, d1 = draw(st.floats(80, 400)), draw(st.floats(80, 400))
    bend = draw(st.floats(-0.3, 0.3))  # the line may turn at the tower
    along = np.array([math.cos(heading), math.sin(heading), 0.0])
    along2 = np.array([math.cos(heading + bend), math.sin(heading + bend), 0.0])
    neighbours = np.array([-d0 * along, d1 * along2])
    width = draw(st.floats(4, 14))
    height = draw(st.floats(12, 45))
    margin = draw(st.floats(0.5, 3))
    standoff = draw(st.floats(margin + 1.0, 12))
    spacing = draw(st.floats(4, 12))
    side = draw(st.sampled_from([1, -1]))
    return neighbours, width, height, margin, standoff, spacing, side, draw(st.integers(0, 10**6))


def samples_clear(volumes, pos, vmax_norm):
    return volumes.samples_clear(pos, max_step=vmax_norm * DT)


@pytest.mark.slow  # 12 towers planned whole: about 15 s
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(towers())
def test_planned_trajectories_stay_out_of_the_safety_volumes(tower):
    neighbours, width, height, margin, standoff, spacing, side, seed = tower
    line = line_frame(neighbours)
    vol = safety_volumes(line, max_width=width, max_height=height, margin=margin)
    rng = np.random.default_rng(seed)
    # beyond the passes: a bent line's corridor may reach past the standoff near the tower
    takeoff = line.to_world(np.array([rng.uniform(-5, 5), side * (width / 2 + standoff + 6.0), 0.0]))
    path = exploration_path(line, vol, takeoff=takeoff, max_width=width, max_height=height,
                            standoff=standoff, pass_spacing=spacing, crossing_clearance=3.0)
    pts = np.array([w.position for w in path])
    assert vol.polyline_clear(pts, inflate=1.0)
    vm, am = np.array([3.0, 3.0, 2.0]), np.array([12.0, 12.0, 6.0])
    vmax_norm = float(np.linalg.norm(vm))

    snap = plan_min_snap_safe(pts, vm, am, vol, dt=DT)
    _, pos, _ = snap.sample(DT)
    assert samples_clear(vol, pos, vmax_norm)

    pmm = plan_pmm_safe(pts, vm, am, vol, dt=DT)
    _, pos, _, _ = pmm.sample(DT)
    assert samples_clear(vol, pos, vmax_norm)

    # inspection viewpoints of random insulators inside the tower, and routes between them
    wps = []
    for _ in range(4):
        c = line.to_world(np.array([rng.uniform(-1, 1) * width / 2, rng.uniform(-1, 1) * width / 2,
                                    rng.uniform(0.4, 1.0) * height]))
        axis = rng.normal(size=3)
        wps += inspection_waypoints(c, axis, insulator_id=1, line=line, volumes=vol, count=2,
                                    inspection_distance=rng.uniform(3, 10), insulator_length=2.0,
                                    fov=math.radians(60))
    assert vol.points_clear(np.array([w.position for w in wps])).all()
    for a, b in zip(wps[:-1], wps[1:]):
        route = np.array([a.position, *crossing_route(line, vol, a.position, b.position, 3.0),
                          b.position])
        assert vol.polyline_clear(route)
        try:
            traj = plan_pmm_safe(route, vm, am, vol, dt=DT)
        except PlanningError:
            # Refused, never flown unsafe. Known limit (found by the derandomized CI profile): a
            # direct route that clears a box corner by centimetres (3 cm in the case found) has
            # no PMM curve inside that gap. Only such a grazing route may be refused.
            assert not vol.polyline_clear(route, inflate=GRAZING), "a route with room was refused"
            continue
        _, pos, _, _ = traj.sample(DT)
        assert samples_clear(vol, pos, vmax_norm)
