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

A re-plan from a moving vehicle starts with its velocity. Time scaling alone cannot always keep
the limits then: the start velocity does not scale, and when it is at a limit or points away
from the path the curve's own speed near the start exceeds it however slowly the rest is flown
(20-50 % of random start velocities failed). So the planner also tries a smooth straight
slow-down along the current velocity (:func:`braking_segment`, to rest, or to the limit when the
vehicle is over it) followed by the min-snap from there, and flies the fastest candidate that
keeps the limits; the stop always exists, so only a safety volume in the stopping distance
leaves no plan (:class:`~insulator_rs.exceptions.PlanningError`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from math import factorial

import numpy as np

from insulator_rs.exceptions import PlanningError
from insulator_rs.planning.pmm import rest_to_rest_times
from insulator_rs.planning.refinement import refine_until_clear
from insulator_rs.planning.safety import SafetyVolumes

DEGREE = 7
N_COEFF = DEGREE + 1
N_DERIV = 4  # position, velocity, acceleration, jerk fixed or free at each waypoint
SNAP = 4
MAX_SCALING_ROUNDS = 30
TIME_ALLOCATIONS = ("pmm", "snap")
MIN_TIME_FRACTION = 0.1  # segment-time optimisation keeps each segment above this share of its start time
MIN_STEP = 1e-6  # m: closer consecutive waypoints count as one
# A moving-start plan slowed down to more than this many times the rest-to-rest time is given
# up (the curve's speed near the start does not shrink with time; the durations would overflow).
MAX_SLOWDOWN = 1e3
# The quintic smoothstep h(x) = 10 x^3 - 15 x^4 + 6 x^5 (h' and h'' zero at both ends) is
# steepest at x = 1/2, with slope 15/8: a slow-down by dv in T peaks at dv 15/8 / T.
SMOOTHSTEP_PEAK_SLOPE = 15.0 / 8.0
MIN_BRAKING_TIME = 1e-3  # s: keeps the slow-down's coefficients finite for a tiny velocity


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



def braking_segment(position: np.ndarray, velocity: np.ndarray, fraction: float,
                    a_max: np.ndarray | float) -> tuple[np.ndarray, float]:
    """Coefficients (3, 8) and duration (s) of a smooth straight slow-down at ``position`` (3,) m
    from ``velocity`` v0 (3,) m/s to ``fraction`` s (in [0, 1)) times it, along v0's own line:
    v(t) = v0 (1 - (1 - s) h(t/T)) with h the quintic smoothstep. Each axis' speed falls
    monotonically (never above its start value); acceleration and jerk are zero at both ends, so
    the segment joins a min-snap segment that starts with s v0 continuously up to jerk; the
    acceleration peaks at (1 - s) |v0_k| h'(1/2) / T, and T makes that at most ``a_max`` on
    every axis (exactly on one). It covers v0 T (1 + s) / 2."""
    p0 = np.asarray(position, dtype=np.float64).reshape(3)
    v0 = np.asarray(velocity, dtype=np.float64).reshape(3)
    am = np.broadcast_to(np.asarray(a_max, dtype=np.float64), (3,))
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"fraction: must lie in [0, 1), got {fraction}")
    dv = (1.0 - fraction) * v0
    T = max(SMOOTHSTEP_PEAK_SLOPE * float(np.max(np.abs(dv) / am)), MIN_BRAKING_TIME)
    # p(t) = p0 + v0 t - dv T H(t/T), with H(x) = 5/2 x^4 - 3 x^5 + x^6 the integral of h
    c = np.zeros((3, N_COEFF))
    c[:, 0], c[:, 1] = p0, v0
    c[:, 4], c[:, 5], c[:, 6] = -2.5 * dv / T ** 3, 3.0 * dv / T ** 4, -dv / T ** 5
    return c, T


def _segment_end(coeffs: np.ndarray, duration: float) -> np.ndarray:
    """Where a segment (3, N_COEFF coefficients, ascending powers) ends after ``duration`` s."""
    return np.array([np.polyval(coeffs[k][::-1], duration) for k in range(3)])


def stop_trajectory(position: np.ndarray, velocity: np.ndarray, a_max: np.ndarray | float) -> MinSnapTrajectory:
    """The smooth straight stop from ``velocity`` (m/s) at ``position`` (W) to rest, along the
    velocity's own line, within ``a_max`` (:func:`braking_segment` to zero speed)."""
    coeffs, T = braking_segment(position, velocity, 0.0, a_max)
    p0 = np.asarray(position, dtype=np.float64).reshape(3)
    return _with_prefix(p0, coeffs, T, None, _segment_end(coeffs, T))


def _limits(v_max: np.ndarray | float, a_max: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    vm = np.broadcast_to(np.asarray(v_max, dtype=np.float64), (3,))
    am = np.broadcast_to(np.asarray(a_max, dtype=np.float64), (3,))
    if not (np.all(np.isfinite(vm)) and np.all(vm > 0)):
        raise ValueError(f"v_max: must be finite and > 0, got {vm}")
    if not (np.all(np.isfinite(am)) and np.all(am > 0)):
        raise ValueError(f"a_max: must be finite and > 0, got {am}")
    return vm, am


def _check_inputs(waypoints: np.ndarray, v_start: np.ndarray | None,
                  time_allocation: str) -> tuple[np.ndarray, np.ndarray | None]:
    """The waypoints (M, 3) and the start velocity (3,), or None for a start at rest."""
    p = np.asarray(waypoints, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
        raise ValueError(f"waypoints: expected shape (M >= 2, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("waypoints: must be finite")
    if np.any(np.linalg.norm(np.diff(p, axis=0), axis=1) < MIN_STEP):
        raise ValueError("waypoints: consecutive waypoints must differ (got a repeated waypoint)")
    if time_allocation not in TIME_ALLOCATIONS:
        raise ValueError(f"time_allocation: expected one of {TIME_ALLOCATIONS}, got {time_allocation!r}")
    if v_start is None:
        return p, None
    vs = np.asarray(v_start, dtype=np.float64)
    if vs.size != 3 or not np.all(np.isfinite(vs)):
        raise ValueError(f"v_start: expected 3 finite components (m/s), got {v_start!r}")
    return p, (vs.reshape(3) if np.any(vs != 0.0) else None)


def _limit_factor(traj: MinSnapTrajectory, vm: np.ndarray, am: np.ndarray) -> float:
    """The time-scaling factor that brings the trajectory's worst axis exactly to its limit."""
    return max(float(np.max(traj.max_abs(1) / vm)), float(np.sqrt(np.max(traj.max_abs(2) / am))))


def _plan_scaled(p: np.ndarray, vm: np.ndarray, am: np.ndarray, vs: np.ndarray | None,
                 time_allocation: str) -> MinSnapTrajectory:
    """Min-snap through ``p`` from velocity ``vs`` (None: rest, else within ``vm`` per axis),
    scaled in time until the limits hold. Scaling time by alpha divides velocities by alpha and
    accelerations by alpha^2; with a moving start the start velocity must not scale, so the
    problem is re-solved with the scaled times and scaled again until the factor settles (at
    most :data:`MAX_SCALING_ROUNDS` rounds; a last round only ever slows down). That can fail
    (PlanningError): when the start velocity is at a limit, or points away from the path, the
    curve's own speed near the start does not shrink with time."""
    durations = rest_to_rest_times(p[:-1], p[1:], vm, am)
    if time_allocation == "snap":
        durations = optimize_segment_times(p, durations, vs)
    crawling = PlanningError("v_start: no time scaling keeps the limits with this start velocity")
    longest = MAX_SLOWDOWN * float(np.sum(rest_to_rest_times(p[:-1], p[1:], vm, am)))
    for _ in range(MAX_SCALING_ROUNDS):
        traj = MinSnapTrajectory(p, durations, solve_min_snap(p, durations, vs))
        alpha = _limit_factor(traj, vm, am)
        durations = durations * alpha
        if vs is None or abs(alpha - 1.0) < 1e-6:  # from rest one scaling is exact
            break
        if not np.sum(durations) <= longest:  # crawling: the curve's speed does not shrink with time
            raise crawling
    traj = MinSnapTrajectory(p, durations, solve_min_snap(p, durations, vs))
    for _ in range(MAX_SCALING_ROUNDS):  # only slow down from here on, until the limits hold
        alpha = _limit_factor(traj, vm, am)
        if alpha <= 1.0 + 1e-9:
            return traj
        durations = durations * alpha * 1.01
        if not np.sum(durations) <= longest:
            break
        traj = MinSnapTrajectory(p, durations, solve_min_snap(p, durations, vs))
    raise crawling


def _without_repeats(points: list[np.ndarray]) -> np.ndarray:
    """The points with any closer than :data:`MIN_STEP` to the previous kept one dropped."""
    keep = [points[0]]
    for q in points[1:]:
        if np.linalg.norm(q - keep[-1]) >= MIN_STEP:
            keep.append(q)
    return np.array(keep)


def _with_prefix(p0: np.ndarray, coeffs: np.ndarray, duration: float,
                 rest: MinSnapTrajectory | None, end: np.ndarray) -> MinSnapTrajectory:
    """The braking segment (from ``p0`` to ``end``) followed by ``rest`` (if any)."""
    if rest is None:
        return MinSnapTrajectory(np.stack([p0, end]), np.array([duration]), coeffs[None])
    return MinSnapTrajectory(np.vstack([p0, rest.waypoints]), np.concatenate([[duration], rest.durations]),
                             np.concatenate([coeffs[None], rest.coeffs]))


PlanFrom = Callable[[np.ndarray, "np.ndarray | None"], MinSnapTrajectory]


def _plan_moving_start(p: np.ndarray, vm: np.ndarray, am: np.ndarray, vs: np.ndarray, plan_from: PlanFrom,
                       volumes: SafetyVolumes | None) -> MinSnapTrajectory:
    """The fastest of: the min-snap straight from ``vs`` (when it is within the limits), a
    smooth slow-down to the largest multiple of ``vs`` within the limits and the min-snap from
    there (when ``vs`` is over them), and a smooth stop followed by the min-snap from rest. The
    stop always exists, so this fails only when the vehicle cannot stop before a safety volume
    (or the path cannot be cleared). ``plan_from(waypoints, v_start)`` plans one of them;
    ``volumes`` (if given) must not be entered by the slow-down's straight line, and the
    continuation goes back through ``p[0]`` when the straight line from the slow-down's end to
    ``p[1]`` would enter one (the way back along the slow-down and on from ``p[0]`` is clear)."""
    within = float(np.min(vm / np.maximum(np.abs(vs), 1e-300)))
    fractions = [1.0, 0.0] if within >= 1.0 else [within, 0.0]
    found: list[MinSnapTrajectory] = []
    reasons: list[str] = []
    for s in fractions:
        try:
            if s == 1.0:
                found.append(plan_from(p, vs))
                continue
            coeffs, T = braking_segment(p[0], vs, s, am)
            end = _segment_end(coeffs, T)
            if volumes is not None:
                for box in volumes.boxes:
                    if bool(box.segments_intersect(p[0], end)):
                        raise PlanningError(
                            f"v_start: slowing from {np.round(vs, 2).tolist()} m/s within a_max takes "
                            f"{np.linalg.norm(end - p[0]):.2f} m and enters the {box.name}")
            q = _without_repeats([end, *p[1:]])
            if volumes is not None and not volumes.polyline_clear(q):
                q = _without_repeats([end, *p])
            rest = plan_from(q, s * vs if s > 0 else None) if len(q) >= 2 else None
            if rest is None and s > 0:
                raise PlanningError("v_start: the slow-down ends at the last waypoint still moving")
            found.append(_with_prefix(p[0], coeffs, T, rest, end))
        except PlanningError as exc:
            reasons.append(str(exc))
    if not found:
        raise PlanningError("; ".join(dict.fromkeys(reasons)))
    return min(found, key=lambda tr: tr.total_time)


def plan_min_snap(waypoints: np.ndarray, v_max: np.ndarray | float,
                  a_max: np.ndarray | float, *, v_start: np.ndarray | None = None,
                  time_allocation: str = "pmm") -> MinSnapTrajectory:
    """Min-snap trajectory through ``waypoints`` (M >= 2, 3), from velocity ``v_start`` (m/s,
    default rest) to rest, within the per-axis limits ``v_max`` (m/s) and ``a_max`` (m/s^2).
    ``time_allocation``: "pmm" keeps the point-mass segment times' proportions, "snap"
    redistributes them to minimise the snap cost first (:func:`optimize_segment_times`).

    From rest it is scaled in time until one limit holds exactly. From a moving start it
    always starts with exactly ``v_start`` and is the fastest of the candidates of
    :func:`_plan_moving_start` (the direct min-snap, or a smooth slow-down first): each axis'
    speed stays within max(v_max, |v_start|) (a start over the limit slows down monotonically
    to it) and the acceleration within ``a_max``. Then, between waypoints the curve may leave
    the straight path by more than from rest (the slow-down's line, or the way back from it)."""
    p, vs = _check_inputs(waypoints, v_start, time_allocation)
    vm, am = _limits(v_max, a_max)
    if vs is None:
        return _plan_scaled(p, vm, am, None, time_allocation)
    return _plan_moving_start(p, vm, am, vs, lambda q, v: _plan_scaled(q, vm, am, v, time_allocation), None)


def plan_min_snap_safe(waypoints: np.ndarray, v_max: np.ndarray | float, a_max: np.ndarray | float,
                       volumes: SafetyVolumes, *, dt: float = 0.05, max_refinements: int = 8,
                       v_start: np.ndarray | None = None,
                       max_deviation: float | None = None, time_allocation: str = "pmm") -> MinSnapTrajectory:
    """:func:`plan_min_snap`, re-planned with a waypoint inserted at the middle of every segment
    whose curve touches a safety volume (or strays more than ``max_deviation`` m from the
    straight segment, if given), until the sampled curve (checked conservatively, see
    :meth:`SafetyVolumes.samples_clear`) is clear. The straight polyline through the
    waypoints must itself be clear (PlanningError otherwise). Only safety is required: if the
    deviation bound still fails after ``max_refinements`` the safe trajectory is returned.

    From a moving start each candidate of :func:`_plan_moving_start` is refined on its own; a
    slow-down segment (straight) is checked exactly against the volumes. PlanningError when no
    candidate is safe (the vehicle cannot stop before a volume, or refining did not clear it)."""
    p, vs = _check_inputs(waypoints, v_start, time_allocation)
    vm, am = _limits(v_max, a_max)
    if not volumes.polyline_clear(p):
        raise PlanningError("waypoints: the straight path through them enters a safety volume")

    def positions(traj: MinSnapTrajectory, step: float) -> tuple[np.ndarray, np.ndarray]:
        times, pos, _ = traj.sample(step)
        return times, pos

    def plan_from(q: np.ndarray, v: np.ndarray | None) -> MinSnapTrajectory:
        return refine_until_clear(q, lambda r: _plan_scaled(r, vm, am, v, time_allocation), positions,
                                  volumes, max_speed=float(np.linalg.norm(vm)), dt=dt,
                                  max_refinements=max_refinements, max_deviation=max_deviation)

    if vs is None:
        return plan_from(p, None)
    return _plan_moving_start(p, vm, am, vs, plan_from, volumes)
