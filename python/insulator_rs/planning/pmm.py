"""Point-mass-model (PMM) time-optimal trajectories (after Teissing et al. 2024).

Each axis of W is a double integrator with |v| <= v_max and |a| <= a_max (per
axis). Between two waypoints with given velocities each axis follows a
bang-coast-bang profile; the segment time is that of the slowest axis, and the
other axes are synchronised to it with a profile of exactly that duration. The
velocities at intermediate waypoints are free variables optimised (L-BFGS-B,
bounded by v_max) to minimise the total time, starting from rest-to-rest.

A profile is three phases (t1 at a1, t2 coasting at vp, t3 at a3), units s,
m/s, m/s^2. Everything is vectorised over segments where it matters (costs of
TSP edges and of the velocity optimisation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from insulator_rs.planning.refinement import refine_until_clear
from insulator_rs.planning.safety import SafetyVolumes

# Numerical slack (s, m/s) when accepting a phase of a closed-form profile.
_EPS = 1e-9


def _check_limits(v_max: np.ndarray, a_max: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = np.broadcast_to(np.asarray(v_max, dtype=np.float64), (3,)).copy()
    a = np.broadcast_to(np.asarray(a_max, dtype=np.float64), (3,)).copy()
    if not (np.all(np.isfinite(v)) and np.all(v > 0)):
        raise ValueError(f"v_max: must be finite and > 0, got {v}")
    if not (np.all(np.isfinite(a)) and np.all(a > 0)):
        raise ValueError(f"a_max: must be finite and > 0, got {a}")
    return v, a


def _sign_candidates(d: np.ndarray, v0: np.ndarray, v1: np.ndarray, v_max: np.ndarray | float,
                     a_max: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Durations (s) of the bang-coast-bang profile whose first acceleration is +a_max and of
    the one whose first acceleration is -a_max (inf where that sign gives no valid profile).

    The peak velocity is vp with vp^2 = s a d + (v0^2 + v1^2) / 2 (s the sign of
    the first acceleration), clamped to s v_max with a coast phase when it would
    exceed it; a sign is valid when every phase duration is non-negative.
    """
    d, v0, v1, vm, am = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64)
                                              for x in (d, v0, v1, v_max, a_max)))
    out = []
    for s in (1.0, -1.0):
        vp2 = s * am * d + (v0 * v0 + v1 * v1) / 2
        ok = vp2 >= -_EPS
        vp = s * np.sqrt(np.maximum(vp2, 0.0))
        clamp = np.abs(vp) > vm
        vp = np.where(clamp, s * vm, vp)
        t1 = s * (vp - v0) / am
        t3 = s * (vp - v1) / am
        dist = (vp * vp - v0 * v0) / (2 * s * am) + (vp * vp - v1 * v1) / (2 * s * am)
        with np.errstate(divide="ignore", invalid="ignore"):
            t2 = np.where(clamp, (d - dist) / vp, 0.0)
        ok &= (t1 >= -_EPS) & (t3 >= -_EPS) & (t2 >= -_EPS)
        out.append(np.where(ok, np.maximum(t1, 0) + np.maximum(t2, 0) + np.maximum(t3, 0), np.inf))
    return out[0], out[1]


def axis_min_time(d: np.ndarray, v0: np.ndarray, v1: np.ndarray, v_max: np.ndarray | float,
                  a_max: np.ndarray | float) -> np.ndarray:
    """Minimum time (s) to move one axis by ``d`` (m) from velocity ``v0`` to ``v1`` (m/s).

    Vectorised (broadcasting); |v0|, |v1| must not exceed ``v_max``. The better
    of the two bang-coast-bang signs (see :func:`_sign_candidates`).
    """
    t_pos, t_neg = _sign_candidates(d, v0, v1, v_max, a_max)
    return np.minimum(t_pos, t_neg)


def _fixed_time_candidates(d: np.ndarray | float, v0: np.ndarray | float, v1: np.ndarray | float,
                           duration: np.ndarray | float, v_max: np.ndarray | float,
                           a_max: np.ndarray | float) -> list[tuple[np.ndarray, ...]]:
    """Closed-form profiles of exactly ``duration`` s at full acceleration (vectorised).

    Three families: accelerate-coast-brake with either sign s (the coast
    velocity vp solves vp T - s[(vp-v0)^2 + (vp-v1)^2] / (2a) = d, two roots
    each), and accelerate-coast-accelerate in the direction of v1 - v0 (linear in
    vp), after the zero-length move in zero time (first). Each candidate is (valid,
    t1, t2, t3, a1, a3); a phase is valid down to ``-tol``.
    """
    d, v0, v1, T, vm, am = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64)
                                                 for x in (d, v0, v1, duration, v_max, a_max)))
    # A phase may be this much below zero (s). Durations come from :func:`segment_times`, whose
    # square root loses half the digits near a double root (a profile at its minimum time): a
    # segment of the efficiency study at 0.258 s came back with a phase at -3.9e-9 s and no
    # valid candidate. 1e-7 s at 12 m/s^2 and 3 m/s moves the axis by under a micrometre.
    tol = 1e-7
    # The zero-length move first: exact. Where it applies (T = 0, d = 0, v1 = v0) the quadratic
    # below has a double root, which rounding turns into two roots ~sqrt(eps) apart whose phases
    # are only within ``tol`` of zero.
    zero = (np.abs(T) <= tol) & (np.abs(d) <= tol) & (np.abs(v1 - v0) <= tol)
    z = np.zeros(d.shape)
    out: list[tuple[np.ndarray, ...]] = [(zero, z, z, z, z, z)]
    for s in (1.0, -1.0):
        qa, qb = -s / am, T + s * (v0 + v1) / am
        qc = -s * (v0 * v0 + v1 * v1) / (2 * am) - d
        disc = qb * qb - 4 * qa * qc
        sq = np.sqrt(np.maximum(disc, 0.0))
        for root in ((-qb + sq) / (2 * qa), (-qb - sq) / (2 * qa)):
            t1, t3 = s * (root - v0) / am, s * (root - v1) / am
            t2 = T - t1 - t3
            valid = (disc >= -1e-12) & (t1 >= -tol) & (t2 >= -tol) & (t3 >= -tol) \
                & (np.abs(root) <= vm + tol)
            out.append((valid, t1, t2, t3, s * am, -s * am))
    sigma = np.where(v1 >= v0, 1.0, -1.0)
    t2 = T - np.abs(v1 - v0) / am
    with np.errstate(divide="ignore", invalid="ignore"):
        vp = (d - sigma * (v1 * v1 - v0 * v0) / (2 * am)) / t2
    t1, t3 = sigma * (vp - v0) / am, sigma * (v1 - vp) / am
    valid = (t2 > 1e-12) & (t1 >= -tol) & (t3 >= -tol) & (np.abs(vp) <= vm + tol)
    out.append((valid, t1, t2, t3, sigma * am, sigma * am))
    return out


def axis_time_feasible(d: np.ndarray, v0: np.ndarray, v1: np.ndarray, duration: np.ndarray,
                       v_max: np.ndarray | float, a_max: np.ndarray | float) -> np.ndarray:
    """Whether a profile of exactly ``duration`` s exists (vectorised). With v0 and v1 of the
    same sign the feasible durations can have a gap (a *blocked interval*): short of
    reversing, the axis would overshoot."""
    cands = _fixed_time_candidates(d, v0, v1, duration, v_max, a_max)
    return np.logical_or.reduce([c[0] for c in cands])


def axis_earliest_time(d: np.ndarray, v0: np.ndarray, v1: np.ndarray, not_before: np.ndarray,
                       v_max: np.ndarray | float, a_max: np.ndarray | float) -> np.ndarray:
    """The earliest feasible duration (s) >= ``not_before``: ``not_before`` itself, or, inside a
    blocked interval, its end, which is the duration of the other (reversing) sign's
    bang-coast-bang profile."""
    t_pos, t_neg = _sign_candidates(d, v0, v1, v_max, a_max)
    later = np.maximum(t_pos, t_neg)
    later = np.where(np.isfinite(later), later, np.minimum(t_pos, t_neg))
    ok = axis_time_feasible(d, v0, v1, not_before, v_max, a_max)
    return np.where(ok, not_before, np.maximum(not_before, later))


@dataclass(frozen=True)
class AxisProfile:
    """One axis over one segment: phases (durations ``t`` (3,) s, accelerations ``a`` (3,) m/s^2)
    from position ``p0`` (m) and velocity ``v0`` (m/s)."""

    p0: float
    v0: float
    t: tuple[float, float, float]
    a: tuple[float, float, float]

    @property
    def duration(self) -> float:
        return float(sum(self.t))

    def sample(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration at ``times`` (s from the segment start, clipped)."""
        tt = np.clip(np.asarray(times, dtype=np.float64), 0.0, self.duration)
        p = np.full(tt.shape, self.p0)
        v = np.full(tt.shape, self.v0)
        acc = np.zeros(tt.shape)
        start = 0.0
        pk, vk = self.p0, self.v0
        for dur, ak in zip(self.t, self.a):
            tau = np.clip(tt - start, 0.0, dur)
            inside = (tt >= start) & (tt <= start + dur)
            p = np.where(tt >= start, pk + vk * tau + 0.5 * ak * tau * tau, p)
            v = np.where(tt >= start, vk + ak * tau, v)
            acc = np.where(inside & (dur > 0), ak, acc)
            pk, vk = pk + vk * dur + 0.5 * ak * dur * dur, vk + ak * dur
            start += dur
        return p, v, acc


def _phases_of_duration(t1: float, t2: float, t3: float, duration: float) -> tuple[float, float, float]:
    """Phase durations >= 0 that sum to ``duration`` (up to rounding).

    A candidate's phases are accepted down to ``-tol``; clamping a negative one to 0 alone
    would lengthen the profile by as much (up to 3 tol). The coast phase absorbs the
    difference, else the longest phase: a change of a few 1e-9 s.
    """
    t = [max(t1, 0.0), max(t2, 0.0), max(t3, 0.0)]
    excess = sum(t) - max(duration, 0.0)
    k = 1 if t[1] >= excess else max(range(3), key=lambda i: t[i])
    t[k] = max(t[k] - excess, 0.0)
    return t[0], t[1], t[2]


def axis_profile_for_time(p0: float, v0: float, p1: float, v1: float, duration: float,
                          v_max: float, a_max: float) -> AxisProfile:
    """A profile of exactly ``duration`` s taking one axis from (p0, v0) to (p1, v1).

    The first valid closed-form candidate of :func:`_fixed_time_candidates`;
    ValueError if none fits (the duration is infeasible, see
    :func:`axis_time_feasible`).
    """
    for valid, t1, t2, t3, a1, a3 in _fixed_time_candidates(p1 - p0, v0, v1, duration, v_max, a_max):
        if bool(valid):
            return AxisProfile(p0, v0, _phases_of_duration(float(t1), float(t2), float(t3), float(duration)),
                               (float(a1), 0.0, float(a3)))
    raise ValueError(f"duration: {duration} s is infeasible for d={p1 - p0}, v0={v0}, v1={v1}")


def segment_times(p: np.ndarray, v: np.ndarray, v_max: np.ndarray, a_max: np.ndarray) -> np.ndarray:
    """Synchronised PMM time (s) of each segment p[i] -> p[i+1] with waypoint velocities v (M, 3):
    the slowest axis's minimum time, pushed past any axis's blocked interval."""
    d = p[1:] - p[:-1]
    t = np.max(axis_min_time(d, v[:-1], v[1:], v_max, a_max), axis=-1)
    for _ in range(3):  # each pass can only move t to the end of some axis's blocked interval
        bumped = np.max(axis_earliest_time(d, v[:-1], v[1:], t[:, None], v_max, a_max), axis=-1)
        if np.array_equal(bumped, t):
            break
        t = bumped
    return t


@dataclass(frozen=True)
class PMMTrajectory:
    """A PMM trajectory through waypoints (M, 3) with velocities (M, 3) in W; ``durations`` (M-1,) s."""

    waypoints: np.ndarray
    velocities: np.ndarray
    durations: np.ndarray
    v_max: np.ndarray
    a_max: np.ndarray

    @property
    def total_time(self) -> float:
        return float(np.sum(self.durations))

    def segment_profiles(self, i: int) -> list[AxisProfile]:
        """The three synchronised axis profiles of segment i."""
        return [axis_profile_for_time(self.waypoints[i, k], self.velocities[i, k],
                                      self.waypoints[i + 1, k], self.velocities[i + 1, k],
                                      float(self.durations[i]), float(self.v_max[k]),
                                      float(self.a_max[k])) for k in range(3)]

    def sample(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Times (s), positions, velocities and accelerations (W) every ``dt`` s, end included."""
        if not dt > 0:
            raise ValueError(f"dt: must be > 0, got {dt}")
        times = np.arange(0.0, self.total_time, dt)
        times = np.append(times, self.total_time)
        starts = np.concatenate([[0.0], np.cumsum(self.durations)])
        pos = np.zeros((len(times), 3))
        vel = np.zeros((len(times), 3))
        acc = np.zeros((len(times), 3))
        seg = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(self.durations) - 1)
        for i in range(len(self.durations)):
            m = seg == i
            if not np.any(m):
                continue
            for k, prof in enumerate(self.segment_profiles(i)):
                pos[m, k], vel[m, k], acc[m, k] = prof.sample(times[m] - starts[i])
        return times, pos, vel, acc


def _optimise_velocities(p: np.ndarray, v_start: np.ndarray, v_end: np.ndarray, v_max: np.ndarray,
                         a_max: np.ndarray, max_iterations: int) -> np.ndarray:
    """Intermediate waypoint velocities minimising the total synchronised time (L-BFGS-B).

    The gradient is by forward differences computed for all waypoints at once:
    a waypoint's velocity only affects its two adjacent segments, so perturbing
    every other waypoint together (two colours) needs six extra evaluations.
    """
    m = len(p)
    n_free = m - 2
    bounds_lo = np.tile(-v_max, n_free)
    bounds_hi = np.tile(v_max, n_free)
    h = 1e-6

    def full(x: np.ndarray) -> np.ndarray:
        return np.vstack([v_start, x.reshape(n_free, 3), v_end])

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        v = full(x)
        seg = segment_times(p, v, v_max, a_max)
        grad = np.zeros((n_free, 3))
        for colour in (0, 1):
            idx = np.arange(1 + colour, m - 1, 2)
            for k in range(3):
                vp = v.copy()
                step = np.where(vp[idx, k] + h > v_max[k], -h, h)
                vp[idx, k] += step
                seg_p = segment_times(p, vp, v_max, a_max)
                delta = seg_p - seg  # segment j changed by its perturbed endpoint (j or j+1)
                grad[idx - 1, k] = (delta[idx - 1] + delta[idx]) / step
        return float(np.sum(seg)), grad.ravel()

    x0 = np.zeros(n_free * 3)
    res = minimize(fun, x0, jac=True, method="L-BFGS-B",
                   bounds=list(zip(bounds_lo, bounds_hi)), options={"maxiter": max_iterations})
    x = np.clip(res.x, bounds_lo, bounds_hi)
    return full(x) if fun(x)[0] <= fun(x0)[0] else full(x0)


def plan_pmm(waypoints: np.ndarray, v_max: np.ndarray | float, a_max: np.ndarray | float, *,
             v_start: np.ndarray | None = None, v_end: np.ndarray | None = None,
             optimise: bool = True, max_iterations: int = 200) -> PMMTrajectory:
    """Time-optimal PMM trajectory through ``waypoints`` (M, 3) in W.

    ``v_start``/``v_end`` (m/s, W) default to rest. With ``optimise`` the
    intermediate velocities are optimised; otherwise the vehicle stops at each
    waypoint (rest-to-rest segments).
    """
    p = np.asarray(waypoints, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
        raise ValueError(f"waypoints: expected shape (M >= 2, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("waypoints: must be finite")
    vm, am = _check_limits(np.asarray(v_max), np.asarray(a_max))
    vs = np.zeros(3) if v_start is None else np.asarray(v_start, dtype=np.float64).reshape(3)
    ve = np.zeros(3) if v_end is None else np.asarray(v_end, dtype=np.float64).reshape(3)
    for name, v in (("v_start", vs), ("v_end", ve)):
        if not np.all(np.isfinite(v)) or np.any(np.abs(v) > vm + 1e-9):
            raise ValueError(f"{name}: must be finite and within v_max per axis, got {v}")
    vs, ve = np.clip(vs, -vm, vm), np.clip(ve, -vm, vm)
    if optimise and len(p) > 2:
        vel = _optimise_velocities(p, vs, ve, vm, am, max_iterations)
    else:
        vel = np.zeros_like(p)
        vel[0], vel[-1] = vs, ve
    return PMMTrajectory(p, vel, segment_times(p, vel, vm, am), vm, am)


def rest_to_rest_times(a: np.ndarray, b: np.ndarray, v_max: np.ndarray | float,
                       a_max: np.ndarray | float) -> np.ndarray:
    """Rest-to-rest PMM time (s) from each a[i] to each b[i] ((..., 3) in W), vectorised."""
    vm, am = _check_limits(np.asarray(v_max), np.asarray(a_max))
    d = np.asarray(b, dtype=np.float64) - np.asarray(a, dtype=np.float64)
    z = np.zeros_like(d)
    return np.max(axis_min_time(d, z, z, vm, am), axis=-1)


def plan_pmm_safe(waypoints: np.ndarray, v_max: np.ndarray | float, a_max: np.ndarray | float,
                  volumes: SafetyVolumes, *, dt: float = 0.05, max_refinements: int = 8,
                  v_start: np.ndarray | None = None) -> PMMTrajectory:
    """:func:`plan_pmm` whose curve (the synchronised axes do not move in straight lines)
    is re-planned with midpoints until it stays out of the safety volumes
    (:func:`~.refinement.refine_until_clear`)."""
    vm, am = _check_limits(np.asarray(v_max), np.asarray(a_max))

    def positions(traj: PMMTrajectory, step: float) -> tuple[np.ndarray, np.ndarray]:
        times, pos, _, _ = traj.sample(step)
        return times, pos

    return refine_until_clear(np.asarray(waypoints, dtype=np.float64),
                              lambda p: plan_pmm(p, vm, am, v_start=v_start), positions, volumes,
                              max_speed=float(np.linalg.norm(vm)), dt=dt,
                              max_refinements=max_refinements)
