"""The battery reserve: when the rest of the plan no longer fits in the battery, come back in
time to land with the mission's reserve (``[inspection] battery_reserve``) still in the pack.

Every control tick :meth:`BatteryReserve.observe` keeps the flight's time in the air, the
distance flown (from the reported positions) and, once a second, the charge the vehicle
reports (``VehicleState.battery_fraction``: BATTERY_STATUS / SYS_STATUS through MAVLink, the
simulated pack in process). :func:`insulator_rs.planning.energy.fit_consumption` fits the
consumption per second and per metre to those readings. Once a second :meth:`check` weighs what
the rest of the plan takes (the remaining exploration path, the buffered and the deferred
inspection waypoints, the landing) and what the safe way out from here takes (the abort route
of :mod:`insulator_rs.planning.abort`, then the landing) against the charge above the reserve:

* the rest of the plan fits: fly on (a battery that can finish never returns early);
* it does not, but the way out still fits with time to spare: fly on and inspect what it can;
* the way out no longer fits with ESTIMATE_MARGIN and RETURN_LOOKAHEAD s to spare: return now
  (the loop aborts and flies the safe route out; the report says what was left).

Before a fit is possible (the first MIN_FIT_TIME s, less than two 1 % steps of charge), and
when the fit is wrong, the charge itself at the reserve still sends the vehicle back. A
vehicle that reports no charge (MAVLink's -1, no battery message at all) gets no reserve
decision: the report says so, and the flight goes on under the autopilot's own battery
failsafes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from insulator_rs.planning.energy import ConsumptionFit, RouteDemand, fit_consumption
from insulator_rs.ports.vehicle import VehicleState

SAMPLE_PERIOD = 1.0  # s of vehicle time between kept charge readings (BATTERY_STATUS comes at 1 Hz)
CHECK_PERIOD = 1.0  # s between decisions (the plan changes on that time scale, not the tick's)
# The estimate is inflated by this factor before it is compared with the charge: the fit's error
# (quantised readings, time and distance nearly proportional on a steady pass), a head wind on
# the way out, and the sag of a LiPo near empty that the linear model does not see.
ESTIMATE_MARGIN = 1.15
# s of hover added to the way out: the next check comes CHECK_PERIOD s later, and an abort first
# brakes to a stop before it flies the route (at 3 m/s^2 from 1-3 m/s: about a second).
RETURN_LOOKAHEAD = 5.0
# s of the landing itself below the route's end (the loop's LAND_HEIGHT, 2 m, in PX4's LAND at
# MPC_LAND_SPEED 0.7 m/s, slowing near the ground) and COM_DISARM_LAND's 2 s armed on the ground.
TOUCHDOWN_TIME = 6.0
# MAVLink's battery_remaining is whole percents: the pack may hold half a step less than read.
READING_STEP = 0.01


@dataclass(frozen=True)
class ReserveEstimate:
    """One weighing, fractions of the pack: ``fraction`` the charge read then, ``available``
    what is above the reserve (of the lower of the reading and the fit's line, less half a
    READING_STEP), ``needed_finish`` / ``needed_return`` what the rest of the plan and
    the way out take (with ESTIMATE_MARGIN; the way out with RETURN_LOOKAHEAD), the routes'
    time and distance, and the fit used. ``time_s``: flight time of the weighing."""

    time_s: float
    fraction: float
    available: float
    needed_finish: float
    needed_return: float
    rest_of_plan: RouteDemand
    way_out: RouteDemand
    fit: ConsumptionFit

    @property
    def can_finish(self) -> bool:
        return self.needed_finish <= self.available

    @property
    def must_return(self) -> bool:
        return not self.can_finish and self.needed_return >= self.available

    def as_record(self) -> dict[str, Any]:
        return {"time_s": self.time_s, "fraction": self.fraction, "available": self.available,
                "needed_finish": self.needed_finish, "needed_return": self.needed_return,
                "can_finish": self.can_finish, "rest_of_plan": self.rest_of_plan.as_record(),
                "way_out": self.way_out.as_record(), "fit": self.fit.as_record()}


class BatteryReserve:
    """The reserve watch of one flight (see the module docstring). ``reserve``: the fraction of
    the pack kept at landing."""

    def __init__(self, reserve: float) -> None:
        if not 0.0 <= reserve < 1.0:
            raise ValueError(f"reserve: expected a fraction in [0, 1), got {reserve!r}")
        self.reserve = reserve
        self.t_air = 0.0  # s in the air so far
        self.d_air = 0.0  # m flown so far (reported positions)
        self.readings = 0  # charge readings seen (kept or not)
        self.unknown_readings = 0  # ticks in the air with no charge reported
        self.first_fraction: float | None = None
        self.last_fraction: float | None = None
        self.estimate: ReserveEstimate | None = None  # the latest weighing
        self.decision: ReserveEstimate | None = None  # the weighing that sent the vehicle back
        self.reason: str | None = None
        self._samples: list[tuple[float, float, float]] = []
        self._last: VehicleState | None = None
        self._next_sample = 0.0
        self._next_check = 0.0
        self._fit: ConsumptionFit | None = None
        self._fit_at = -1

    def observe(self, st: VehicleState) -> None:
        """One tick's state: time and distance in the air, and the charge once a second."""
        last, self._last = self._last, st
        fraction = st.battery_fraction
        if fraction is not None and self.first_fraction is not None:
            self.last_fraction = fraction  # on the ground after the landing too: the charge left
        airborne = st.armed and not st.landed
        if last is None or not airborne:
            return
        dt = st.time - last.time
        if dt > 0.0:
            self.t_air += dt
            self.d_air += float(np.linalg.norm(st.position - last.position))
        if fraction is None:
            self.unknown_readings += 1
            return
        self.readings += 1
        if self.first_fraction is None:
            self.first_fraction = fraction
        self.last_fraction = fraction
        if self.t_air >= self._next_sample:
            self._next_sample = self.t_air + SAMPLE_PERIOD
            self._samples.append((self.t_air, self.d_air, fraction))

    def fit(self) -> ConsumptionFit | None:
        """The consumption fitted to the readings so far (refitted when new ones came)."""
        if self._fit_at != len(self._samples):
            self._fit_at = len(self._samples)
            s = np.array(self._samples, dtype=np.float64).reshape(-1, 3)
            self._fit = fit_consumption(s[:, 0], s[:, 1], s[:, 2])
        return self._fit

    def check(self, st: VehicleState, time_s: float,
              demands: Callable[[], tuple[RouteDemand, RouteDemand]]) -> str | None:
        """Why the vehicle must return now, or None. ``demands()``: (the rest of the plan, the
        way out from here), asked only when a weighing is due and possible."""
        fraction = st.battery_fraction
        if fraction is None or not (st.armed and not st.landed):
            return None
        if fraction <= self.reserve:
            return self._decide(f"battery at the reserve ({fraction:.0%}, reserve {self.reserve:.0%})")
        if self.t_air < self._next_check:
            return None
        self._next_check = self.t_air + CHECK_PERIOD
        fit = self.fit()
        if fit is None:
            return None
        rest, way_out = demands()
        way_out_hover = RouteDemand(way_out.time_s + RETURN_LOOKAHEAD, way_out.distance_m)
        # the charge now: the reading, or the fit's line through the readings where that is lower
        # (it smooths the 1 % steps), less half a step of the reading's resolution
        charge = min(fraction, fit.start - fit.consumed(self.t_air, self.d_air)) - READING_STEP / 2
        est = ReserveEstimate(time_s=time_s, fraction=fraction, available=charge - self.reserve,
                              needed_finish=ESTIMATE_MARGIN * fit.consumed(rest.time_s, rest.distance_m),
                              needed_return=ESTIMATE_MARGIN * fit.consumed(way_out_hover.time_s,
                                                                           way_out_hover.distance_m),
                              rest_of_plan=rest, way_out=way_out, fit=fit)
        self.estimate = est
        if not est.must_return:
            return None
        self.decision = est
        return self._decide(f"battery reserve: returning at {fraction:.1%} (the rest of the plan needs "
                            f"{est.needed_finish:.1%}, the way out {est.needed_return:.1%}, "
                            f"{est.available:.1%} above the {self.reserve:.0%} reserve)")

    def spare_after(self, extra: RouteDemand) -> float | None:
        """What the latest weighing leaves above the reserve once the rest of the plan and
        ``extra`` (a detour not in the plan, with ESTIMATE_MARGIN, as the plan is weighed) are
        paid for: a fraction of the pack, negative where the detour would cost the plan its end.
        None before the first weighing (no consumption fit yet)."""
        est = self.estimate
        if est is None:
            return None
        return est.available - est.needed_finish - ESTIMATE_MARGIN * est.fit.consumed(extra.time_s, extra.distance_m)

    def _decide(self, reason: str) -> str:
        if self.reason is None:
            self.reason = reason
            if self.decision is None and self.estimate is not None:
                self.decision = self.estimate
        return reason

    def record(self) -> dict[str, Any]:
        """The battery part of summary.json: the reserve, what the vehicle reported, the fit,
        the latest weighing and the one at the decision (None when there was none)."""
        known = self.readings > 0
        fit = self.fit()
        note = None
        if not known:
            note = ("the vehicle reported no battery charge (no BATTERY_STATUS / SYS_STATUS, or -1: "
                    "unknown): no reserve decision was possible")
        elif fit is None:
            note = "too little flight or charge drop for a consumption fit: only the reserve itself was watched"
        return {"reserve": self.reserve, "known": known, "note": note,
                "fraction_at_takeoff": self.first_fraction, "fraction_last": self.last_fraction,
                "unknown_readings": self.unknown_readings, "time_in_air_s": self.t_air,
                "distance_m": self.d_air, "fit": None if fit is None else fit.as_record(),
                "estimate": None if self.estimate is None else self.estimate.as_record(),
                "decision": None if self.decision is None else self.decision.as_record(),
                "reason": self.reason}
