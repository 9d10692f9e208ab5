"""Minimum-snap polynomial trajectories (Richter, Bry and Roy, 2016).

Each segment and axis is a degree-7 polynomial. Waypoint positions are fixed,
the start and end are at rest (velocity, acceleration and jerk zero), and the
interior velocities, accelerations and jerks are free: the closed-form solution
of the unconstrained QP, d_P* = -R_PP^-1 R_FP^T d_F, gives them. Segment times
start from the rest-to-rest point-mass time of each segment (a time allocation
proportional to what the vehicle can do); with ``time_allocation="snap"`` they
are then redistributed at a fixed total to minimise the snap cost (Richter's
gradient descent on segment times, :func:`optimize_segment_times`). Then all
times are scaled by one factor so that the per-axis velocity and acceleration
limits hold exactly (the extremes are found from the roots of the derivative
polynomials, not from samples). :func:`plan_min_snap_safe` re-plans with extra waypoints at the
middle of any segment whose curve enters a safety volume (Richter's remedy,
:mod:`.refinement`).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import numpy as np

from insulator_rs.mission.pmm import rest_to_rest_times
from insulator_rs.mission.refinement import refine_until_clear
from insulator_rs.mission.safety import SafetyVolumes

DEGREE = 7
N_COEFF = DEGREE + 1
N_DERIV = 4  # position, velocity, acceleration, jerk fixed or free at each waypoint
SNAP = 4
MAX_SCALING_ROUNDS = 30
TIME_ALLOCATIONS = ("pmm", "snap")
MIN_TIME_FRACTION = 0.1  # segment-time optimisation keeps each segment above this share of its start time


def _deriv_row(order: int, t: float) -> np.ndarray:
    """Row r with r @ c = the ``order``-th derivative at t of sum_k c_k t^k."""
    row = np.zeros(N_COEFF)
    for k in range(order, N_COEFF):
        row[k] = factorial(k) / factorial(k - order) * t ** (k - order)
    return row


def _cost_matrix(T: float) -> np.ndarray:
    """Q with c^T Q c = integral over [0, T] of the squared snap."""
    Q = np.zeros((N_COEFF, N_COEFF))
    for k in range(SNAP, N_COEFF):
        for m in range(SNAP, N_COEFF):
            ck = factorial(k) / factorial(k - SNAP)
            cm = factorial(m) / factorial(m - SNAP)
            e = k + m - 2 * SNAP + 1
            Q[k, m] = ck * cm * T ** e / e
    return Q


def _boundary_matrix(T: float) -> np.ndarray:
    """A with A @ c = [derivatives 0..3 at t=0, derivatives 0..3 at t=T]."""
    return np.vstack([_deriv_row(r, 0.0) for r in range(N_DERIV)]
                     + [_deriv_row(r, T) for r in range(N_DERIV)])


def solve_min_snap(waypoints: np.ndarray, durations: np.ndarray,
                   v_start: np.ndarray | None = None) -> np.ndarray:
    """Coefficients (S, 3, 8) of the min-snap trajectory through ``waypoints`` (S+1, 3) with
    segment ``durations`` (S,) s (Richter's closed form). It starts with velocity ``v_start``
    (m/s, default rest) and zero acceleration and jerk, and ends at rest."""
    p = np.asarray(waypoints, dtype=np.float64)
    vs = np.zeros(3) if v_start is None else np.asarray(v_start, dtype=np.float64).reshape(3)
    T = np.asarray(durations, dtype=np.float64)
    n_seg = len(T)
    m = n_seg + 1
    # Unique derivative vector per axis: [d_0(0..3), d_1(0..3), ...]; C maps it to segment ends.
    C = np.zeros((2 * N_DERIV * n_seg, N_DERIV * m))
    for i in range(n_seg):
        for r in range(N_DERIV):
            C[2 * N_DERIV * i + r, N_DERIV * i + r] = 1.0
            C[2 * N_DERIV * i + N_DERIV + r, N_DERIV * (i + 1) + r] = 1.0
    blocks_ainv = [np.linalg.inv(_boundary_matrix(t)) for t in T]
    H = np.zeros((2 * N_DERIV * n_seg, 2 * N_DERIV * n_seg))
    for i, (ainv, t) in enumerate(zip(blocks_ainv, T)):
        sl = slice(2 * N_DERIV * i, 2 * N_DERIV * (i + 1))
        H[sl, sl] = ainv.T @ _cost_matrix(t) @ ainv
    R = C.T @ H @ C
    fixed = [N_DERIV * j for j in range(m)] + [r for r in range(1, N_DERIV)] \
        + [N_DERIV * (m - 1) + r for r in range(1, N_DERIV)]
    fixed = sorted(set(fixed))
    free = [k for k in range(N_DERIV * m) if k not in fixed]
    coeffs = np.zeros((n_seg, 3, N_COEFF))
    for axis in range(3):
        d = np.zeros(N_DERIV * m)
        d[[N_DERIV * j for j in range(m)]] = p[:, axis]
        d[1] = vs[axis]
        if free:
            R_pp = R[np.ix_(free, free)]
            R_fp = R[np.ix_(fixed, free)]
            d[free] = -np.linalg.solve(R_pp, R_fp.T @ d[fixed])
        ends = C @ d
        for i in range(n_seg):
            coeffs[i, axis] = blocks_ainv[i] @ ends[2 * N_DERIV * i: 2 * N_DERIV * (i + 1)]
    return coeffs


def snap_cost(waypoints: np.ndarray, durations: np.ndarray, v_start: np.ndarray | None = None) -> float:
    """The min-snap objective: integral of the squared snap, summed over axes and segments."""
    T = np.asarray(durations, dtype=np.float64)
    coeffs = solve_min_snap(waypoints, T, v_start)
    return float(sum(c @ _cost_matrix(t) @ c for i, t in enumerate(T) for c in coeffs[i]))


def optimize_segment_times(waypoints: np.ndarray, durations: np.ndarray, v_start: np.ndarray | None = None,
                           *, max_iterations: int = 40, tolerance: float = 1e-4) -> np.ndarray:
    """Segment times with the same total that minimise :func:`snap_cost` (Richter et al. 2016,
    time allocation): projected gradient descent on the plane sum(T) = const, the gradient by
    forward differences (one min-snap solve per segment), a backtracking line search, every
    segment kept above :data:`MIN_TIME_FRACTION` of its start time. Stops when an iteration
    lowers the cost by less than ``tolerance`` (relative)."""
    T = np.asarray(durations, dtype=np.float64).copy()
    if len(T) < 2:
        return T
    floor = MIN_TIME_FRACTION * T
    cost = snap_cost(waypoints, T, v_start)
    for _ in range(max_iterations):
        h = 1e-6 * T
        grad = np.array([(snap_cost(waypoints, T + h[i] * np.eye(len(T))[i], v_start) - cost) / h[i]
                         for i in range(len(T))])
        direction = -(grad - grad.mean())  # steepest descent that keeps the total time
        norm = float(np.max(np.abs(direction) / T))
        if norm == 0.0:
            break
        step = 0.5 / norm  # first try: the most-changed segment moves by half its time
        slope = float(grad @ direction)
        while step * norm > 1e-6:
            trial = np.maximum(T + step * direction, floor)
            trial *= T.sum() / trial.sum()
            trial_cost = snap_cost(waypoints, trial, v_start)
            if trial_cost <= cost + 1e-4 * step * slope:  # Armijo
                break
            step *= 0.5
        else:
            break
        improvement = (cost - trial_cost) / cost
        T, cost = trial, trial_cost
        if improvement < tolerance:
            break
    return T


def _poly_deriv(c: np.ndarray, order: int) -> np.ndarray:
    """Coefficients (ascending) of the ``order``-th derivative."""
    out = np.asarray(c, dtype=np.float64)
    for _ in range(order):
        out = out[1:] * np.arange(1, len(out))
    return out


def _max_abs_on(c: np.ndarray, T: float) -> float:
    """max |q(t)| over [0, T] for the ascending-coefficient polynomial q (exact: endpoints and
    the real roots of q' inside)."""
    cands = [0.0, T]
    dc = _poly_deriv(c, 1)
    if np.any(np.abs(dc) > 0) and len(dc) > 1:
        trimmed = np.trim_zeros(dc, "b")
        if len(trimmed) > 1:
            roots = np.roots(trimmed[::-1])
            cands += [float(r.real) for r in roots if abs(r.imag) < 1e-9 and 0 <= r.real <= T]
    t = np.array(cands)
    return float(np.max(np.abs(np.polyval(c[::-1], t))))


@dataclass(frozen=True)
class MinSnapTrajectory:
    """Piecewise degree-7 polynomials in W: ``coeffs`` (S, 3, 8) ascending in local time,
    ``durations`` (S,) s, through ``waypoints`` (S+1, 3)."""

    waypoints: np.ndarray
    durations: np.ndarray
    coeffs: np.ndarray

    @property
    def total_time(self) -> float:
        return float(np.sum(self.durations))

    def evaluate(self, times: np.ndarray, order: int = 0) -> np.ndarray:
        """The ``order``-th derivative (N, 3) at trajectory ``times`` (s, clipped to the span)."""
        t = np.clip(np.atleast_1d(np.asarray(times, dtype=np.float64)), 0.0, self.total_time)
        starts = np.concatenate([[0.0], np.cumsum(self.durations)])
        seg = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.durations) - 1)
        out = np.zeros((len(t), 3))
        for i in np.unique(seg):
            m = seg == i
            for k in range(3):
                out[m, k] = np.polyval(_poly_deriv(self.coeffs[i, k], order)[::-1], t[m] - starts[i])
        return out

    def max_abs(self, order: int) -> np.ndarray:
        """Exact per-axis maximum of |derivative ``order``| over the whole trajectory (3,)."""
        return np.array([max(_max_abs_on(_poly_deriv(self.coeffs[i, k], order), self.durations[i])
                             for i in range(len(self.durations))) for k in range(3)])

    def sample(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Setpoints every ``dt`` s (end included): times, positions, velocities (W)."""
        if not dt > 0:
            raise ValueError(f"dt: must be > 0, got {dt}")
        times = np.append(np.arange(0.0, self.total_time, dt), self.total_time)
        return times, self.evaluate(times, 0), self.evaluate(times, 1)


def plan_min_snap(waypoints: np.ndarray, v_max: np.ndarray | float,
                  a_max: np.ndarray | float, *, v_start: np.ndarray | None = None,
                  time_allocation: str = "pmm") -> MinSnapTrajectory:
    """Min-snap trajectory through ``waypoints`` (M >= 2, 3), from velocity ``v_start`` (default
    rest, within ``v_max``) to rest, scaled in time so that the per-axis limits ``v_max`` (m/s)
    and ``a_max`` (m/s^2) hold, one of them exactly. ``time_allocation``: "pmm" keeps the
    point-mass segment times' proportions, "snap" redistributes them to minimise the snap
    cost first (:func:`optimize_segment_times`).

    Scaling time by alpha divides velocities by alpha and accelerations by alpha^2; with a
    moving start the start velocity must not scale, so the problem is re-solved with the
    scaled times and scaled again until the factor settles (at most
    :data:`MAX_SCALING_ROUNDS` rounds; a last round only ever slows down)."""
    p = np.asarray(waypoints, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
        raise ValueError(f"waypoints: expected shape (M >= 2, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("waypoints: must be finite")
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if np.any(step < 1e-6):
        raise ValueError("waypoints: consecutive waypoints must differ (got a repeated waypoint)")
    vm = np.broadcast_to(np.asarray(v_max, dtype=np.float64), (3,))
    am = np.broadcast_to(np.asarray(a_max, dtype=np.float64), (3,))
    if time_allocation not in TIME_ALLOCATIONS:
        raise ValueError(f"time_allocation: expected one of {TIME_ALLOCATIONS}, got {time_allocation!r}")
    vs = None
    if v_start is not None:
        vs = np.asarray(v_start, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(vs)) or np.any(np.abs(vs) > vm + 1e-9):
            raise ValueError(f"v_start: must be finite and within v_max per axis, got {vs}")
    durations = rest_to_rest_times(p[:-1], p[1:], vm, am)
    if time_allocation == "snap":
        durations = optimize_segment_times(p, durations, vs)
    for _ in range(MAX_SCALING_ROUNDS):
        traj = MinSnapTrajectory(p, durations, solve_min_snap(p, durations, vs))
        alpha = max(float(np.max(traj.max_abs(1) / vm)), float(np.sqrt(np.max(traj.max_abs(2) / am))))
        durations = durations * alpha
        if vs is None or abs(alpha - 1.0) < 1e-6:  # from rest one scaling is exact
            break
    traj = MinSnapTrajectory(p, durations, solve_min_snap(p, durations, vs))
    for _ in range(MAX_SCALING_ROUNDS):  # only slow down from here on, until the limits hold
        alpha = max(float(np.max(traj.max_abs(1) / vm)), float(np.sqrt(np.max(traj.max_abs(2) / am))))
        if alpha <= 1.0 + 1e-9:
            return traj
        durations = durations * alpha * 1.01
        traj = MinSnapTrajectory(p, durations, solve_min_snap(p, durations, vs))
    raise ValueError("v_start: no time scaling keeps the limits with this start velocity")


def plan_min_snap_safe(waypoints: np.ndarray, v_max: np.ndarray | float, a_max: np.ndarray | float,
                       volumes: SafetyVolumes, *, dt: float = 0.05, max_refinements: int = 8,
                       v_start: np.ndarray | None = None,
                       max_deviation: float | None = None, time_allocation: str = "pmm") -> MinSnapTrajectory:
    """:func:`plan_min_snap`, re-planned with a waypoint inserted at the middle of every segment
    whose curve touches a safety volume (or strays more than ``max_deviation`` m from the
    straight segment, if given), until the sampled curve (checked conservatively, see
    :meth:`SafetyVolumes.samples_clear`) is clear. The straight polyline through the
    waypoints must itself be clear (ValueError otherwise). Only safety is required: if the
    deviation bound still fails after ``max_refinements`` the safe trajectory is returned."""
    vm = np.broadcast_to(np.asarray(v_max, dtype=np.float64), (3,))

    def positions(traj: MinSnapTrajectory, step: float) -> tuple[np.ndarray, np.ndarray]:
        times, pos, _ = traj.sample(step)
        return times, pos

    return refine_until_clear(np.asarray(waypoints, dtype=np.float64),
                              lambda p: plan_min_snap(p, vm, a_max, v_start=v_start,
                                                      time_allocation=time_allocation), positions,
                              volumes, max_speed=float(np.linalg.norm(vm)), dt=dt,
                              max_refinements=max_refinements, max_deviation=max_deviation)
