"""Point-mass-model planner against analytic one-axis cases and an LP feasibility reference."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

from insulator_rs.planning.pmm import (axis_earliest_time, axis_min_time, axis_profile_for_time,
                                      axis_time_feasible, plan_pmm, rest_to_rest_times)

V, A = 3.0, 12.0


@pytest.mark.parametrize("d, v0, v1, expected", [
    (0.5, 0.0, 0.0, 2 * np.sqrt(0.5 / A)),                 # triangular: never reaches v_max
    (10.0, 0.0, 0.0, 10.0 / V + V / A),                    # trapezoidal
    (-10.0, 0.0, 0.0, 10.0 / V + V / A),                   # symmetric in direction
    (6.0, V, V, 6.0 / V),                                  # pure coast
    (6.0, 0.0, V, (6.0 - V * V / (2 * A)) / V + V / A),    # accelerate then coast
    (0.0, V, 0.0, None),                                   # must overshoot and come back
])
def test_one_axis_analytic(d, v0, v1, expected):
    if expected is None:
        # brake from V to 0 (V/A s, V^2/(2A) m forward), then come back V^2/(2A) rest-to-rest
        back = V * V / (2 * A)
        expected = V / A + 2 * np.sqrt(back / A)
    assert axis_min_time(d, v0, v1, V, A) == pytest.approx(expected, rel=1e-12)


def lp_feasible(d, v0, v1, T, steps=200):
    """Reference: is there a piecewise-constant acceleration (``steps`` pieces, |a| <= A) over T s
    that moves the axis by d from v0 to v1 with |v| <= V at every knot? Exact integration makes
    the end state linear in the accelerations, so this is a linear program (scipy.linprog)."""
    h = T / steps
    n = steps
    # v_k = v0 + h * sum_{j<k} a_j ; p_T = v0 T + sum_j a_j (h^2/2 + h (T - (j+1) h))
    a_eq = np.vstack([np.full(n, h), h * h / 2 + h * (T - h * np.arange(1, n + 1))])
    b_eq = np.array([v1 - v0, d - v0 * T])
    lower = np.tril(np.full((n, n), h))
    a_ub = np.vstack([lower, -lower])
    b_ub = np.concatenate([np.full(n, V - v0), np.full(n, V + v0)])
    res = linprog(np.zeros(n), A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b_eq, bounds=[(-A, A)] * n,
                  method="highs")
    return res.status == 0


@settings(max_examples=20, deadline=None)
@given(d=st.floats(-15, 15), v0=st.floats(-V, V), v1=st.floats(-V, V))
def test_min_time_is_the_lp_boundary(d, v0, v1):
    """Reference: LP feasibility (above). Tolerance: 3 % of the time either way, which covers
    the LP's discretisation of the switching instants."""
    t = float(axis_min_time(d, v0, v1, V, A))
    later = float(axis_earliest_time(d, v0, v1, t * 1.03 + 0.01, V, A))
    assert lp_feasible(d, v0, v1, later)
    if t * 0.97 - 0.002 > 0:
        assert not lp_feasible(d, v0, v1, t * 0.97 - 0.002)


def test_blocked_interval():
    """d = 0 from v = 1 to v = 1: done in 0 s, else the axis must reverse, which takes 4/A s
    (brake to -1, accelerate back to 1); durations in between are infeasible (LP reference)."""
    assert axis_min_time(0.0, 1.0, 1.0, V, A) == 0.0
    assert not axis_time_feasible(0.0, 1.0, 1.0, 0.2, V, A)
    assert not lp_feasible(0.0, 1.0, 1.0, 0.2)
    assert axis_earliest_time(0.0, 1.0, 1.0, 0.2, V, A) == pytest.approx(4 / A)
    assert lp_feasible(0.0, 1.0, 1.0, 4 / A * 1.02)


@settings(max_examples=200, deadline=None)
@given(d=st.floats(-20, 20), v0=st.floats(-V, V), v1=st.floats(-V, V),
       extra=st.floats(0.0, 10.0))
@example(d=0.0, v0=0.625, v1=0.625, extra=0.0)  # zero length at speed: duration 1.3e-9 s, not 0, once
@example(d=0.0, v0=0.0, v1=0.0, extra=0.0)
@example(d=0.0, v0=-V, v1=-V, extra=0.0)
def test_synchronised_profile_has_the_duration_and_respects_limits(d, v0, v1, extra):
    t_min = float(axis_min_time(d, v0, v1, V, A))
    target = float(axis_earliest_time(d, v0, v1, t_min + extra, V, A))
    assert axis_time_feasible(d, v0, v1, target, V, A)
    prof = axis_profile_for_time(0.0, v0, d, v1, target, V, A)
    assert prof.duration == pytest.approx(target, abs=1e-9)
    ts = np.linspace(0, prof.duration, 2001)
    p, v, a = prof.sample(ts)
    assert p[-1] == pytest.approx(d, abs=1e-6) and v[-1] == pytest.approx(v1, abs=1e-6)
    assert np.all(np.abs(v) <= V + 1e-6) and np.all(np.abs(a) <= A + 1e-9)


@pytest.mark.parametrize("v", [0.625, -1.3, V, 0.0])
def test_zero_length_move_at_constant_speed_takes_zero_time(v):
    """d = 0 with v0 = v1: 0 s exactly, with three empty phases (the zero-length move; the
    accelerate-brake roots are a rounded double root there)."""
    assert axis_min_time(0.0, v, v, V, A) == 0.0
    prof = axis_profile_for_time(0.0, v, 0.0, v, 0.0, V, A)
    assert prof.t == (0.0, 0.0, 0.0) and prof.duration == 0.0


def test_infeasible_duration_is_refused():
    with pytest.raises(ValueError, match="duration"):
        axis_profile_for_time(0.0, 0.0, 10.0, 0.0, 1.0, V, A)


def test_path_reaches_every_waypoint_and_optimised_is_faster():
    rng = np.random.default_rng(3)
    wp = rng.uniform(-15, 15, size=(8, 3))
    vm, am = np.array([3.0, 3.0, 1.0]), np.array([12.0, 12.0, 3.0])
    stop = plan_pmm(wp, vm, am, optimise=False)
    fast = plan_pmm(wp, vm, am)
    assert fast.total_time < stop.total_time
    assert stop.total_time == pytest.approx(float(np.sum(rest_to_rest_times(wp[:-1], wp[1:], vm, am))))
    starts = np.concatenate([[0.0], np.cumsum(fast.durations)])
    for i in range(len(wp) - 1):
        for k, prof in enumerate(fast.segment_profiles(i)):
            p, v, _ = prof.sample(np.array([0.0, prof.duration]))
            assert p[0] == pytest.approx(wp[i, k]) and p[1] == pytest.approx(wp[i + 1, k], abs=1e-6)
            assert v[1] == pytest.approx(fast.velocities[i + 1, k], abs=1e-6)
            assert prof.duration == pytest.approx(fast.durations[i])
    t, pos, vel, acc = fast.sample(0.01)
    assert t[-1] == pytest.approx(starts[-1])
    assert np.all(np.abs(vel) <= vm + 1e-6) and np.all(np.abs(acc) <= am + 1e-9)
    np.testing.assert_allclose(pos[-1], wp[-1], atol=1e-6)


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="waypoints"):
        plan_pmm(np.zeros((1, 3)), 3.0, 12.0)
    with pytest.raises(ValueError, match="v_max"):
        plan_pmm(np.zeros((2, 3)), -3.0, 12.0)
    with pytest.raises(ValueError, match="a_max"):
        plan_pmm(np.zeros((2, 3)), 3.0, np.nan)
    with pytest.raises(ValueError, match="v_start"):
        plan_pmm(np.zeros((2, 3)), 3.0, 12.0, v_start=np.array([5.0, 0, 0]))


def test_a_segment_at_its_minimum_time_has_a_profile_despite_rounding():
    """Regression (the efficiency study with the inspection camera's viewpoints, tower A, N=24):
    segment_times gave 0.258333370 s for an axis braking from 0.1000004 to -3 m/s over
    -0.3746 m, 1.2e-9 s above its minimum time, and no candidate was valid (a phase at
    -3.9e-9 s). Reference: the profile sampled at its end reaches (p1, v1)."""
    p0, v0, p1, v1, duration = 0.0, 0.10000042297209097, -0.3745833333333346, -3.0, 0.25833336975593296
    prof = axis_profile_for_time(p0, v0, p1, v1, duration, 3.0, 12.0)
    assert abs(prof.duration - duration) < 1e-12
    p, v, _ = prof.sample(np.array([duration]))
    assert abs(p[0] - p1) < 1e-6 and abs(v[0] - v1) < 1e-6
