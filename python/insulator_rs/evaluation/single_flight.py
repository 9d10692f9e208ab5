"""Timing of the online single-flight inspection with point-mass-model trajectories.

The state machine's plan is flown as one PMM trajectory (velocities at the
waypoints optimised) from the vehicle's current position and velocity. The
sensors are polled every ``sense_period`` s along it; when a poll yields a
localization the state machine is told, and if its plan changed the rest is
re-planned from the vehicle's state at that instant (position and velocity),
exactly as an onboard planner would. Reaching a plan item is reported to the
state machine at the end of its segment.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from insulator_rs.planning.pmm import plan_pmm
from insulator_rs.mission.state_machine import InspectionStateMachine, PlanItem

# (position (3,) W, yaw rad, time s) -> localizations [(center (3,), axis (3,))] that became available
Sense = Callable[[np.ndarray, float, float], list[tuple[np.ndarray, np.ndarray]]]


@dataclass(frozen=True)
class SingleFlightResult:
    """Flight time (s), the flown samples (times (K,), positions (K, 3) W), the number of
    re-plans, and the plan items in the order they were reached."""

    time: float
    times: np.ndarray
    positions: np.ndarray
    replans: int
    visited: list[PlanItem]


def fly_single_flight(sm: InspectionStateMachine, *, v_max: np.ndarray, a_max: np.ndarray,
                      sense: Sense, sense_period: float = 0.2,
                      max_replans: int = 10_000) -> SingleFlightResult:
    """Fly the mission of a started state machine ``sm`` to the end (PMM timing)."""
    if not sense_period > 0:
        raise ValueError(f"sense_period: must be > 0 s, got {sense_period}")
    t = 0.0
    p = sm.path[0].position.astype(np.float64)
    v = np.zeros(3)
    times, positions = [t], [p.copy()]
    replans = 0
    next_sense = 0.0
    while not sm.done:
        if sm.target() is None:
            raise RuntimeError(f"the mission stalled in state {sm.state.value}")
        replans += 1
        if replans > max_replans:
            raise RuntimeError(f"more than {max_replans} re-plans: the mission does not converge")
        items = list(sm.plan)
        traj = plan_pmm(np.vstack([p[None], [it.position for it in items]]), v_max, a_max, v_start=v)
        changed = False
        for i, item in enumerate(items):
            dur = float(traj.durations[i])
            profiles = traj.segment_profiles(i) if dur > 0 else []
            while next_sense <= t + dur and not changed:
                tau = np.array([next_sense - t])
                pos = np.array([prof.sample(tau)[0][0] for prof in profiles]) if profiles else p
                vel = np.array([prof.sample(tau)[1][0] for prof in profiles]) if profiles else v
                times.append(next_sense)
                positions.append(pos)
                plan_before = [id(it) for it in sm.plan]
                for center, axis in sense(pos, item.yaw, next_sense):
                    sm.localized(center, axis, pos, next_sense)
                next_sense += sense_period
                if [id(it) for it in sm.plan] != plan_before:
                    t, p, v = next_sense - sense_period, pos, vel
                    changed = True
            if changed:
                break
            t += dur
            p = item.position.astype(np.float64)
            v = traj.velocities[i + 1].copy()
            times.append(t)
            positions.append(p.copy())
            sm.reached(t)
            if sm.done:
                break
            if [id(it) for it in sm.plan] != [id(it) for it in items[i + 1:]]:
                break  # reaching it changed the plan (deferred waypoints released): re-plan
    return SingleFlightResult(t, np.array(times), np.array(positions), replans, list(sm.visited))
