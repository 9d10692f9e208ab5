"""What the battery pays for a flight: consumption fitted online, and the demand of a route.

A multirotor's battery empties mostly with time in the air (the hover power, whatever it does)
and a little more with distance (climbs, accelerations, the drag of the passes): the consumed
fraction of the pack is modelled as ``per_s * t + per_m * d`` (t s in the air, d m flown).
:func:`fit_consumption` fits the two rates to the flight so far by least squares (numpy), with
the charge at the first sample as a free intercept (a pack rarely starts at exactly what the
autopilot reads, and MAVLink's ``battery_remaining`` is whole percents). Both rates are kept
non-negative: where the flight so far cannot tell time from distance (a steady pass at one
speed), the fit falls back to the one term that explains the drop, rather than a negative
rate that would promise energy back for flying further.

:func:`route_demand` gives the time and the distance of a route of waypoints (W, m): straight
legs between them, each from rest to rest at the mission's limits (the PMM time; the min-snap
through several waypoints does not stop at each, so this is on the long side), plus a stop time
at the points where the vehicle stops (inspection photos).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from insulator_rs.planning.pmm import rest_to_rest_times

# A fit needs this much flight behind it: s in the air, and a drop of the charge (fraction)
# of two of MAVLink's 1 % steps, so that a single step of the quantised reading is not a rate.
MIN_FIT_TIME = 20.0
MIN_FIT_DROP = 0.02
# The airframe class the project flies (a 1.5 kg quadrotor carrying a Mid-360 and a gimbal on a
# 4S 5 Ah pack): a 25-minute hover endurance, and 5e-5 of the pack per metre flown above the hover
# power (13 J of a 266 kJ pack per metre). Before any flight there is nothing to fit: the
# pre-flight estimate of a mission's need (flight/preflight.py) uses these; the simulated airframe
# drains at them (sim/kinematics.py). A real airframe of another class is not known to them.
NOMINAL_DRAIN_PER_S = 1.0 / 1500.0
NOMINAL_DRAIN_PER_M = 5e-5


@dataclass(frozen=True)
class ConsumptionFit:
    """Fitted consumption: ``per_s`` (fraction of the pack per s in the air), ``per_m``
    (fraction per m flown), ``start`` (the fitted charge at t = d = 0), over ``samples``
    readings spanning ``span_s`` s; ``rms`` the residual (fraction)."""

    per_s: float
    per_m: float
    start: float
    samples: int
    span_s: float
    rms: float

    def consumed(self, time_s: float, distance_m: float) -> float:
        """Fraction of the pack that ``time_s`` s in the air and ``distance_m`` m flown use."""
        return self.per_s * time_s + self.per_m * distance_m

    def as_record(self) -> dict[str, float | int | None]:
        return {"per_s": self.per_s, "per_m": self.per_m, "start": self.start, "samples": self.samples,
                "span_s": self.span_s, "rms": self.rms,
                "hover_endurance_s": 1.0 / self.per_s if self.per_s > 0 else None}


def fit_consumption(time_s: np.ndarray, distance_m: np.ndarray, fraction: np.ndarray) -> ConsumptionFit | None:
    """Least-squares fit of ``fraction = start - per_s * t - per_m * d`` to the readings (each
    (N,): s in the air, m flown, charge as a fraction), rates >= 0. None while the readings
    span less than MIN_FIT_TIME s or the charge dropped by less than MIN_FIT_DROP (no rate
    can be told yet)."""
    t = np.asarray(time_s, dtype=np.float64).reshape(-1)
    d = np.asarray(distance_m, dtype=np.float64).reshape(-1)
    f = np.asarray(fraction, dtype=np.float64).reshape(-1)
    if not (len(t) == len(d) == len(f)):
        raise ValueError(f"fit_consumption: time_s, distance_m and fraction must have one length, got "
                         f"{len(t)}, {len(d)}, {len(f)}")
    ok = np.isfinite(t) & np.isfinite(d) & np.isfinite(f)
    t, d, f = t[ok], d[ok], f[ok]
    if len(t) < 3 or float(t.max() - t.min()) < MIN_FIT_TIME or float(f.max() - f.min()) < MIN_FIT_DROP:
        return None
    # Scaled columns: seconds and metres are both in the hundreds, but keep the solve well
    # conditioned whatever the flight.
    ts, ds = max(float(np.abs(t).max()), 1.0), max(float(np.abs(d).max()), 1.0)
    best: tuple[float, float, float, float] | None = None
    for use in ((True, True), (True, False), (False, True)):
        cols = [np.ones_like(t)] + [-t / ts] * use[0] + [-d / ds] * use[1]
        A = np.stack(cols, axis=1)
        x, *_ = np.linalg.lstsq(A, f, rcond=None)
        rates = list(x[1:])
        per_s = rates.pop(0) / ts if use[0] else 0.0
        per_m = rates.pop(0) / ds if use[1] else 0.0
        if per_s < 0.0 or per_m < 0.0:
            continue  # a negative rate: try the fits with one term only
        rms = float(np.sqrt(np.mean((A @ x - f) ** 2)))
        if best is None or rms < best[3] - 1e-12:
            best = (per_s, per_m, float(x[0]), rms)
        if use == (True, True):
            break  # both rates non-negative: the full model is the fit
    if best is None:
        return None
    per_s, per_m, start, rms = best
    return ConsumptionFit(per_s=float(per_s), per_m=float(per_m), start=float(start), samples=len(t),
                          span_s=float(t.max() - t.min()), rms=rms)


@dataclass(frozen=True)
class RouteDemand:
    """What a route takes: ``time_s`` in the air and ``distance_m`` flown."""

    time_s: float
    distance_m: float

    def __add__(self, other: RouteDemand) -> RouteDemand:
        return RouteDemand(self.time_s + other.time_s, self.distance_m + other.distance_m)

    def as_record(self) -> dict[str, float]:
        return {"time_s": self.time_s, "distance_m": self.distance_m}


NOTHING = RouteDemand(0.0, 0.0)


def nominal_consumed(demand: RouteDemand) -> float:
    """The fraction of the pack ``demand`` takes at the airframe class's nominal rates
    (NOMINAL_DRAIN_PER_S, NOMINAL_DRAIN_PER_M): the estimate before a flight has been fitted."""
    return NOMINAL_DRAIN_PER_S * demand.time_s + NOMINAL_DRAIN_PER_M * demand.distance_m


def route_demand(points: np.ndarray, v_max: np.ndarray | float, a_max: np.ndarray | float, *,
                 stops: int = 0, stop_time: float = 0.0) -> RouteDemand:
    """The time (s) and distance (m) of flying ``points`` ((N, 3), W) in order, each leg from
    rest to rest at ``v_max``/``a_max`` (per axis, as the mission's), plus ``stops`` x
    ``stop_time`` s standing still (photos)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    extra = float(stops) * float(stop_time)
    if len(p) < 2:
        return RouteDemand(extra, 0.0)
    times = rest_to_rest_times(p[:-1], p[1:], v_max, a_max)
    return RouteDemand(float(np.sum(times)) + extra, float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))))
