"""Minimum-snap trajectories: continuity, limits after scaling, parity with a generic QP."""

from math import factorial

import numpy as np
import pytest

from insulator_rs.exceptions import PlanningError
from insulator_rs.geodesy import line_frame
from insulator_rs.planning.minsnap import (
    optimize_segment_times,
    plan_min_snap,
    plan_min_snap_safe,
    snap_cost,
    solve_min_snap,
)
from insulator_rs.planning.safety import safety_volumes

VM = np.array([3.0, 3.0, 1.5])
AM = np.array([12.0, 12.0, 4.0])


def waypoints(seed, n=6):
    return np.random.default_rng(seed).uniform(-20, 20, size=(n, 3))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_continuity_up_to_snap_and_rest_at_the_ends(seed):
    wp = waypoints(seed)
    tr = plan_min_snap(wp, VM, AM)
    knots = np.cumsum(tr.durations)[:-1]
    for order in range(5):  # position, velocity, acceleration, jerk, snap
        left = tr.evaluate(knots - 1e-9, order)
        right = tr.evaluate(knots + 1e-9, order)
        scale = max(1.0, float(np.max(np.abs(tr.evaluate(np.linspace(0, tr.total_time, 500), order)))))
        assert np.max(np.abs(left - right)) < 1e-5 * scale, order
    np.testing.assert_allclose(tr.evaluate(np.concatenate([[0.0], np.cumsum(tr.durations)])), wp,
                               atol=1e-8)
    for order in (1, 2, 3):
        np.testing.assert_allclose(tr.evaluate(np.array([0.0, tr.total_time]), order), 0.0, atol=1e-8)


@pytest.mark.parametrize("seed", [0, 4])
def test_limits_hold_after_scaling_and_one_is_active(seed):
    tr = plan_min_snap(waypoints(seed), VM, AM)
    t = np.linspace(0, tr.total_time, 20001)
    v = np.max(np.abs(tr.evaluate(t, 1)), axis=0)
    a = np.max(np.abs(tr.evaluate(t, 2)), axis=0)
    assert np.all(v <= VM * (1 + 1e-9)) and np.all(a <= AM * (1 + 1e-9))
    assert max(np.max(v / VM), np.max(a / AM)) > 0.999  # scaled until a limit binds
    np.testing.assert_allclose(tr.max_abs(1), v, rtol=1e-3)


def kkt_reference(wp, durations):
    """Reference: min-snap as a generic equality-constrained QP over all coefficients, solved
    through its KKT system with numpy (positions at waypoints, continuity of derivatives 0..3,
    rest at both ends). Tolerance of the comparison: 1e-6 relative on positions sampled."""
    n_seg = len(durations)
    n = 8 * n_seg

    def row(order, t):
        r = np.zeros(8)
        for k in range(order, 8):
            r[k] = factorial(k) / factorial(k - order) * t ** (k - order)
        return r

    H = np.zeros((n, n))
    for i, T in enumerate(durations):
        for k in range(4, 8):
            for m in range(4, 8):
                e = k + m - 7
                H[8 * i + k, 8 * i + m] = (factorial(k) / factorial(k - 4)) * (factorial(m) / factorial(m - 4)) * T ** e / e
    out = []
    for axis in range(3):
        rows, rhs = [], []
        for i, T in enumerate(durations):
            r = np.zeros(n); r[8 * i: 8 * i + 8] = row(0, 0.0); rows.append(r); rhs.append(wp[i, axis])
            r = np.zeros(n); r[8 * i: 8 * i + 8] = row(0, T); rows.append(r); rhs.append(wp[i + 1, axis])
            if i + 1 < n_seg:
                for o in range(1, 4):
                    r = np.zeros(n); r[8 * i: 8 * i + 8] = row(o, T); r[8 * (i + 1): 8 * (i + 2)] = -row(o, 0.0)
                    rows.append(r); rhs.append(0.0)
        for o in range(1, 4):
            r = np.zeros(n); r[0:8] = row(o, 0.0); rows.append(r); rhs.append(0.0)
            r = np.zeros(n); r[-8:] = row(o, durations[-1]); rows.append(r); rhs.append(0.0)
        Aeq = np.array(rows)
        kkt = np.block([[2 * H, Aeq.T], [Aeq, np.zeros((len(rows), len(rows)))]])
        sol = np.linalg.lstsq(kkt, np.concatenate([np.zeros(n), rhs]), rcond=None)[0]
        out.append(sol[:n].reshape(n_seg, 8))
    return np.stack(out, axis=1)


def test_closed_form_matches_generic_qp():
    wp = waypoints(7, n=5)
    durations = np.array([3.0, 2.0, 4.0, 2.5])
    ours = solve_min_snap(wp, durations)
    ref = kkt_reference(wp, durations)
    for i, T in enumerate(durations):
        t = np.linspace(0, T, 50)
        for k in range(3):
            a = np.polyval(ours[i, k][::-1], t)
            b = np.polyval(ref[i, k][::-1], t)
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)


def test_safe_replanning_adds_waypoints_until_clear():
    lf = line_frame(np.array([[0.0, -280.0, 0.0], [0.0, 300.0, 1.5]]))
    vol = safety_volumes(lf, max_width=10.0, max_height=31.0, margin=2.0)
    # approach the box face steeply, then run along it 0.3 m outside: the free interior
    # velocities make the unconstrained curve swing into the box
    wp = np.array([[20.0, -10, 10], [7.3, -9, 10], [7.3, 9, 10]])
    plain = plan_min_snap(wp, VM, AM)
    assert not vol.points_clear(plain.evaluate(np.linspace(0, plain.total_time, 5000))).all()
    tr = plan_min_snap_safe(wp, VM, AM, vol, dt=0.02)
    assert len(tr.waypoints) > len(wp)  # the rounded corners needed extra waypoints
    t = np.linspace(0, tr.total_time, 20000)
    assert vol.points_clear(tr.evaluate(t)).all()
    with pytest.raises(PlanningError, match="straight path"):  # a planning failure, not a bad argument
        plan_min_snap_safe(np.array([[8.0, 0, 5.0], [-8.0, 0, 5.0]]), VM, AM, vol)


def test_bad_input():
    with pytest.raises(ValueError, match="waypoints"):
        plan_min_snap(np.zeros((1, 3)), VM, AM)
    with pytest.raises(ValueError, match="repeated"):
        plan_min_snap(np.zeros((2, 3)), VM, AM)
    with pytest.raises(ValueError, match="time_allocation"):
        plan_min_snap(waypoints(0), VM, AM, time_allocation="fastest")


def test_moving_start_keeps_its_velocity_and_the_limits():
    wp = waypoints(11, n=4)
    v0 = np.array([2.5, -1.0, 1.2])
    tr = plan_min_snap(wp, VM, AM, v_start=v0)
    np.testing.assert_allclose(tr.evaluate(np.array([0.0]), 1)[0], v0, atol=1e-8)
    np.testing.assert_allclose(tr.evaluate(np.array([tr.total_time]), 1)[0], 0.0, atol=1e-8)
    assert np.all(tr.max_abs(1) <= VM * (1 + 1e-9)) and np.all(tr.max_abs(2) <= AM * (1 + 1e-9))
    # over the limit (it used to be refused): it starts with it and slows down to the limit
    fast = np.array([5.0, 0, 0])
    tr = plan_min_snap(wp, VM, AM, v_start=fast)
    np.testing.assert_allclose(tr.evaluate(np.array([0.0]), 1)[0], fast, atol=1e-8)
    assert np.all(tr.max_abs(1) <= np.maximum(VM, np.abs(fast)) * (1 + 1e-9))
    assert np.all(tr.max_abs(2) <= AM * (1 + 1e-9))
    t = np.linspace(tr.durations[0], tr.total_time, 5001)  # after the slow-down segment
    assert np.all(np.abs(tr.evaluate(t, 1)) <= VM * (1 + 1e-9))
    with pytest.raises(ValueError, match="v_start"):
        plan_min_snap(wp, VM, AM, v_start=np.array([np.inf, 0, 0]))


def test_deviation_bound_keeps_the_curve_near_the_straight_path():
    lf = line_frame(np.array([[0.0, -280.0, 0.0], [0.0, 300.0, 1.5]]))
    vol = safety_volumes(lf, max_width=10.0, max_height=31.0, margin=2.0)
    # long and short legs mixed: the free min-snap swings far off the polyline
    wp = np.array([[13.0, -7, 7], [13.0, 7, 7], [13.0, 7, 8], [13.0, -7, 8], [30.0, -7, 8]])
    plain = plan_min_snap_safe(wp, VM, AM, vol, dt=0.02)
    bounded = plan_min_snap_safe(wp, VM, AM, vol, dt=0.02, max_deviation=1.0, max_refinements=10)

    def worst(tr):
        t = np.linspace(0, tr.total_time, 4000)
        pos = tr.evaluate(t)
        d = [min(np.linalg.norm(np.cross(b - a, p - a)) / np.linalg.norm(b - a)
                 if 0 <= (p - a) @ (b - a) <= (b - a) @ (b - a) else min(np.linalg.norm(p - a), np.linalg.norm(p - b))
                 for a, b in zip(wp[:-1], wp[1:])) for p in pos]
        return max(d)

    assert worst(bounded) <= 1.0 + 0.05 < worst(plain)


def test_segment_times_of_a_symmetric_path_become_equal():
    """Three equally spaced collinear waypoints, rest to rest: by symmetry the snap-optimal
    split of any total time is equal halves; started from 1:3 it gets there within 1 %."""
    wp = np.array([[0.0, 0, 0], [5.0, 0, 0], [10.0, 0, 0]])
    T = optimize_segment_times(wp, np.array([1.0, 3.0]))
    assert T.sum() == pytest.approx(4.0)
    np.testing.assert_allclose(T, [2.0, 2.0], rtol=1e-2)


@pytest.mark.parametrize("seed", [0, 3, 5])
def test_segment_times_match_scipy_slsqp(seed):
    """Reference: scipy.optimize.minimize (SLSQP) of the same snap cost over the segment times
    with sum(T) fixed. Tolerance: our cost within 1 % of SLSQP's (and never above the start)."""
    from scipy.optimize import minimize

    wp = waypoints(seed, n=5)
    start = np.linalg.norm(np.diff(wp, axis=0), axis=1) / 2.0
    ours = optimize_segment_times(wp, start)
    assert ours.sum() == pytest.approx(start.sum()) and np.all(ours > 0)
    scale = snap_cost(wp, start)
    ref = minimize(lambda t: snap_cost(wp, t) / scale, start, method="SLSQP",
                   bounds=[(0.1 * t, None) for t in start],
                   constraints=[{"type": "eq", "fun": lambda t: t.sum() - start.sum()}],
                   options={"ftol": 1e-10, "maxiter": 500})
    assert ref.success, ref.message
    assert snap_cost(wp, ours) <= snap_cost(wp, start)
    assert snap_cost(wp, ours) <= snap_cost(wp, ref.x) * 1.01


@pytest.mark.parametrize("seed", [1, 2])
def test_snap_time_allocation_keeps_the_limits_and_lowers_the_snap_at_equal_time(seed):
    wp = waypoints(seed)
    pmm = plan_min_snap(wp, VM, AM)
    snap = plan_min_snap(wp, VM, AM, time_allocation="snap")
    t = np.linspace(0, snap.total_time, 20001)
    assert np.all(np.max(np.abs(snap.evaluate(t, 1)), axis=0) <= VM * (1 + 1e-9))
    assert np.all(np.max(np.abs(snap.evaluate(t, 2)), axis=0) <= AM * (1 + 1e-9))
    np.testing.assert_allclose(snap.evaluate(np.concatenate([[0.0], np.cumsum(snap.durations)])), wp, atol=1e-8)
    # At the same total time the snap-optimal split has the lower cost.
    same_total = snap.durations * pmm.total_time / snap.total_time
    assert snap_cost(wp, same_total) <= snap_cost(wp, pmm.durations)
