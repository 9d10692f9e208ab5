"""The online inspection state machine (the paper's Fig. "state machine").

The machine owns the *plan*: the remaining exploration-path waypoints with the
inspection waypoints of buffer B spliced in. The state follows from what the
plan's head is: EXPLORE (a scan waypoint), INSPECT (an inspection waypoint),
RETURN (back to the point where exploration was left), CROSS (over the top to
the other side), FINISH (nothing left to scan or inspect: flying home and
landing); HOLD and ABORT are entered on faults. Every transition is logged and
kept in :attr:`InspectionStateMachine.transitions`.

Two buffering policies:

* ``"immediate"`` (the paper): waypoints of a newly localized near-side
  insulator are visited at once; the vehicle then returns to where it left the
  path. Found during a detour, they join the detour before the return.
* ``"insertion"``: each new waypoint is inserted where it adds the least cost
  (``cost(a, b)``, s) along the remaining plan on its side, so inspections can
  wait until the path passes by.

Insulators on the far side are recorded and their waypoints deferred until the
vehicle has crossed to that side.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from insulator_rs.planning.exploration import PathWaypoint, PlanKind
from insulator_rs.tracking.registry import Insulator, InsulatorRegistry
from insulator_rs.planning.waypoints import InspectionWaypoint

LOG = logging.getLogger("insulator_rs.mission")

class Policy(str, Enum):
    """How new inspection waypoints enter the plan: ``immediate`` (fly to them now, then
    return) or ``insertion`` (cheapest insertion into the rest of the plan)."""

    IMMEDIATE = "immediate"
    INSERTION = "insertion"

    def __str__(self) -> str:  # "scan", not "PlanKind.SCAN", in reasons and reports
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


POLICIES = tuple(p.value for p in Policy)


class State(str, Enum):
    IDLE = "idle"
    EXPLORE = "explore"
    INSPECT = "inspect"
    RETURN = "return"
    CROSS = "cross"
    FINISH = "finish"
    HOLD = "hold"
    ABORT = "abort"


@dataclass(frozen=True)
class PlanItem:
    """One target of the plan in W. ``kind``: scan, inspect, return, cross, land (PlanKind).
    ``side``: +1/-1, or 0 above the tower. ``waypoint``: the inspection waypoint for "inspect"."""

    kind: PlanKind
    position: np.ndarray
    yaw: float
    side: int
    waypoint: InspectionWaypoint | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", PlanKind(self.kind))  # a bad kind is refused here


@dataclass(frozen=True)
class Transition:
    """A logged state change at vehicle ``time`` (s)."""

    time: float
    source: State
    target: State
    reason: str


@dataclass(frozen=True)
class AbortContext:
    """What the plan said when the mission aborted, for the safe route out
    (:func:`insulator_rs.planning.abort.plan_abort_route`): ``toward_side`` (+1/-1), the side
    the vehicle was heading for (the plan's next item on a side; the current side when none),
    and ``back_to`` (W), where the detour for inspection the vehicle was in left the exploration
    path (the way back out beside an arm), None outside a detour."""

    reason: str
    time: float
    toward_side: int
    back_to: np.ndarray | None


@dataclass
class InspectionStateMachine:
    """The mission's decision logic, driven by events (no I/O, no clock of its own).

    ``make_waypoints`` turns a new insulator into its inspection waypoints;
    ``cost`` (s) is only used by the insertion policy.
    """

    path: list[PathWaypoint]
    registry: InsulatorRegistry
    make_waypoints: Callable[[Insulator], list[InspectionWaypoint]]
    policy: Policy = Policy.IMMEDIATE
    cost: Callable[[np.ndarray, np.ndarray], float] | None = None
    state: State = State.IDLE
    plan: list[PlanItem] = field(default_factory=list)
    deferred: dict[int, list[InspectionWaypoint]] = field(default_factory=dict)
    transitions: list[Transition] = field(default_factory=list)
    visited: list[PlanItem] = field(default_factory=list)
    skipped: list[tuple[PlanItem, str]] = field(default_factory=list)
    side: int = 0
    # bumped by every change of the plan other than reaching its head: a leg being flown is
    # re-planned when it moves (the loop compares it before and after each tick)
    plan_version: int = 0
    aborted: AbortContext | None = None  # set by :meth:`abort`
    _held_from: State | None = None
    _remaining: dict[int, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.policy not in POLICIES:
            raise ValueError(f"policy: expected one of {POLICIES}, got {self.policy!r}")
        self.policy = Policy(self.policy)
        if self.policy == Policy.INSERTION and self.cost is None:
            raise ValueError("cost: the insertion policy needs a cost function")
        if len(self.path) < 2 or self.path[0].kind != "takeoff":
            raise ValueError("path: expected an exploration path starting with its take-off point")
        self.side = self.path[0].side

    # -- state bookkeeping -------------------------------------------------------------
    def _set(self, new: State, time: float, reason: str) -> None:
        if new == self.state:
            return
        tr = Transition(time, self.state, new, reason)
        self.transitions.append(tr)
        LOG.info("t=%.2f s %s -> %s (%s)", time, self.state.value, new.value, reason)
        self.state = new

    def _derive(self, time: float, reason: str) -> None:
        if self.state in (State.HOLD, State.ABORT):
            return
        if not any(it.kind in (PlanKind.SCAN, PlanKind.INSPECT, PlanKind.RETURN) for it in self.plan):
            self._set(State.FINISH, time, reason)
            return
        head = self.plan[0].kind
        new = {PlanKind.SCAN: State.EXPLORE, PlanKind.INSPECT: State.INSPECT, PlanKind.RETURN: State.RETURN,
               PlanKind.CROSS: State.CROSS, PlanKind.LAND: State.FINISH}[head]
        self._set(new, time, reason)

    @property
    def done(self) -> bool:
        """True when the plan is empty (landed) or the mission was aborted."""
        return self.state == State.ABORT or (self.state == State.FINISH and not self.plan)

    def target(self) -> PlanItem | None:
        """What to fly to now (None when done, holding or aborted)."""
        if self.state in (State.HOLD, State.ABORT, State.IDLE) or not self.plan:
            return None
        return self.plan[0]

    # -- events ------------------------------------------------------------------------
    def start(self, time: float = 0.0) -> None:
        """Take-off done: start the exploration path."""
        if self.state != State.IDLE:
            raise RuntimeError(f"start: the mission already started (state {self.state.value})")
        self.plan = [PlanItem(w.kind, w.position, w.yaw, w.side) for w in self.path[1:]]
        self.plan_version += 1
        self._derive(time, "take-off complete")

    def reached(self, time: float, item: PlanItem | None = None) -> PlanItem:
        """The vehicle reached the plan's head; returns it (an "inspect" item means: take the photo).
        ``item``: the item the caller flew to; refused unless it is still the head (a find may
        have put its inspection waypoints in front of it meanwhile, and reaching one of those
        unflown would count a photo never taken)."""
        if self.state in (State.HOLD, State.ABORT, State.IDLE) or not self.plan:
            raise RuntimeError(f"reached: no active target in state {self.state.value}")
        if item is not None and self.plan[0] is not item:
            raise RuntimeError(f"reached: {item.kind} item is no longer the plan's head ({self.plan[0].kind} is)")
        item = self.plan.pop(0)
        self.visited.append(item)
        reason = f"reached {item.kind} waypoint"
        if item.kind == PlanKind.INSPECT and item.waypoint is not None:
            iid = item.waypoint.insulator_id
            self._remaining[iid] = self._remaining.get(iid, 1) - 1
            if self._remaining[iid] == 0:
                for ins in self.registry.insulators:
                    if ins.id == iid:
                        ins.inspected = True
        if item.side != 0 and item.side != self.side:
            self.side = item.side
            reason = f"arrived on side {item.side:+d}"
            released = self.deferred.pop(item.side, [])
            if released:
                self._buffer(released, item.position)
                reason += f", {len(released)} deferred waypoints released"
        self._derive(time, reason)
        return item

    def skip(self, item: PlanItem, time: float, reason: str) -> None:
        """An inspection waypoint of the plan that cannot be flown to (no safe trajectory) is
        dropped: its insulator stays uninspected (``skipped`` keeps the item and the reason)
        and the mission goes on. Only inspection waypoints may be skipped."""
        if item.kind != PlanKind.INSPECT or not any(it is item for it in self.plan):
            raise RuntimeError(f"skip: only a planned inspection waypoint can be skipped, got {item.kind}")
        self.plan = [it for it in self.plan if it is not item]
        self.plan_version += 1
        self.skipped.append((item, reason))
        self._derive(time, f"inspection waypoint skipped: {reason}")

    def localized(self, center: np.ndarray, axis: np.ndarray, position: np.ndarray,
                  time: float) -> str:
        """A localization in W arrived while the vehicle is at ``position``. Returns "new",
        "updated", "candidate" (not yet confirmed by the registry), "deferred" (new, on the
        far side) or "ignored" (after the mission ended)."""
        if self.state in (State.ABORT, State.FINISH, State.IDLE):
            return "ignored"
        ins, is_new = self.registry.observe(center, axis)
        if not is_new:
            return "updated" if ins.confirmed else "candidate"
        wps = self.make_waypoints(ins)
        self._remaining[ins.id] = len(wps)
        if not wps:
            return "new"
        if ins.side != self.side:
            self.deferred.setdefault(ins.side, []).extend(wps)
            LOG.info("t=%.2f s insulator %d on the far side (%+d): %d waypoints deferred",
                     time, ins.id, ins.side, len(wps))
            return "deferred"
        before = self.state
        self._buffer(wps, np.asarray(position, dtype=np.float64))
        if self.state != State.HOLD:
            self._derive(time, f"insulator {ins.id} localized, {len(wps)} waypoints buffered")
        if before == self.state:
            LOG.info("t=%.2f s insulator %d localized: %d waypoints buffered (%s)", time, ins.id,
                     len(wps), self.state.value)
        return "new"

    def fault(self, reason: str, time: float) -> None:
        """A recoverable fault (e.g. localization lost, link degraded): hold position."""
        if self.state in (State.HOLD, State.ABORT):
            return
        self._held_from = self.state
        self._set(State.HOLD, time, f"fault: {reason}")

    def resume(self, time: float) -> None:
        """The fault cleared: continue where the mission was."""
        if self.state != State.HOLD:
            raise RuntimeError(f"resume: not holding (state {self.state.value})")
        assert self._held_from is not None
        self._set(self._held_from, time, "fault cleared")
        self._derive(time, "fault cleared")

    def abort(self, reason: str, time: float) -> None:
        """Unrecoverable fault: stop the mission. What the plan said about the way out is kept in
        :attr:`aborted` (the first abort's; the flight then flies the safe route out and lands,
        or the vehicle's own failsafe has it)."""
        if self.aborted is None:
            self.aborted = self.exit_context(reason, time)
        self._set(State.ABORT, time, f"abort: {reason}")
        self.plan = []
        self.plan_version += 1

    def exit_context(self, reason: str, time: float) -> AbortContext:
        """What an abort now would keep for the safe route out (the battery reserve weighs that
        route before it decides)."""
        return AbortContext(reason, time, self._toward_side(), self._detour_start())

    def _toward_side(self) -> int:
        return next((it.side for it in self.plan if it.side != 0), self.side)

    def _detour_start(self) -> np.ndarray | None:
        """Where the detour at the plan's head left the path: its RETURN item (immediate policy),
        else the item visited last before an inspection waypoint (the way the vehicle came)."""
        if not self.plan or self.plan[0].kind not in (PlanKind.INSPECT, PlanKind.RETURN):
            return None
        for it in self.plan:
            if it.kind == PlanKind.RETURN:
                return np.array(it.position, dtype=np.float64)
            if it.kind != PlanKind.INSPECT:
                break
        last = next((it for it in reversed(self.visited) if it.side == self.side), None)
        return None if last is None else np.array(last.position, dtype=np.float64)

    def head_ends_search(self) -> bool:
        """Whether reaching the plan's head ends the search: it is still on (not finished), and
        no scan, inspection or return item follows the head (crossings back and the landing, at
        most, are left)."""
        return (self.state != State.FINISH and bool(self.plan) and self.plan[0].kind != PlanKind.LAND
                and not any(it.kind in (PlanKind.SCAN, PlanKind.INSPECT, PlanKind.RETURN) for it in self.plan[1:]))

    def head_ends_side(self) -> bool:
        """Whether reaching the plan's head ends a side's passes: it is a pass corner (scan) and a
        crossing follows it (the first side's top pass; the last side's is also where the search
        ends, :meth:`head_ends_search`)."""
        return (self.state != State.FINISH and len(self.plan) > 1 and self.plan[0].kind == PlanKind.SCAN
                and self.plan[1].kind == PlanKind.CROSS)

    def next_leg(self) -> list[PlanItem]:
        """The plan's items flown as one trajectory: from the head up to and including the first
        inspection waypoint (a photo ends a leg), stopping before the landing."""
        items: list[PlanItem] = []
        for it in self.plan:
            if it.kind == PlanKind.LAND:
                break
            items.append(it)
            if it.kind == PlanKind.INSPECT:
                break
        return items

    def approach_landing(self, height: float) -> PlanItem | None:
        """The plan's head is the landing: where inspection waypoints found on the far side are
        owed on the landing side (they are released on arrival there), a scan item ``height`` m
        above the landing point is put first, so the vehicle arrives there in the air, not on the
        ground. Returns that item, or None when the landing can go ahead."""
        head = self.target()
        if head is None or head.kind != PlanKind.LAND:
            raise RuntimeError("approach_landing: the plan's head is not the landing")
        if head.side == self.side or not self.deferred.get(head.side):
            return None
        above = PlanItem(PlanKind.SCAN, head.position + np.array([0.0, 0.0, height]), head.yaw, head.side)
        self.plan.insert(0, above)
        self.plan_version += 1
        return above

    # -- buffering ---------------------------------------------------------------------
    def _items(self, wps: list[InspectionWaypoint]) -> list[PlanItem]:
        return [PlanItem(PlanKind.INSPECT, w.position, w.yaw, w.side, w) for w in wps]

    def _buffer(self, wps: list[InspectionWaypoint], position: np.ndarray) -> None:
        self.plan_version += 1
        if self.policy == Policy.IMMEDIATE:
            self._buffer_immediate(wps, position)
        else:
            self._buffer_insertion(wps, position)

    def _buffer_immediate(self, wps: list[InspectionWaypoint], position: np.ndarray) -> None:
        items = self._items(wps)
        in_detour = self.plan and self.plan[0].kind in (PlanKind.INSPECT, PlanKind.RETURN)
        if in_detour:
            k = next((i for i, it in enumerate(self.plan) if it.kind == PlanKind.RETURN), len(self.plan))
            self.plan[k:k] = items
        else:
            back = PlanItem(PlanKind.RETURN, position.copy(), self.plan[0].yaw if self.plan else 0.0,
                            self.side)
            self.plan[0:0] = items + [back]

    def _buffer_insertion(self, wps: list[InspectionWaypoint], position: np.ndarray) -> None:
        assert self.cost is not None
        for item in self._items(wps):
            best_k, best_cost = None, np.inf
            for k in range(len(self.plan) + 1):
                prev_pos = position if k == 0 else self.plan[k - 1].position
                prev_side = self.side if k == 0 else self.plan[k - 1].side
                nxt = self.plan[k] if k < len(self.plan) else None
                if prev_side != item.side or (nxt is not None and nxt.side not in (item.side, 0)):
                    continue
                added = self.cost(prev_pos, item.position)
                if nxt is not None:
                    added += self.cost(item.position, nxt.position) - self.cost(prev_pos, nxt.position)
                if added < best_cost:
                    best_k, best_cost = k, added
            if best_k is None:  # nowhere on this side: visit now and come back
                self._buffer_immediate([item.waypoint], position)  # type: ignore[list-item]
            else:
                self.plan.insert(best_k, item)
