"""The way out after an abort: stop, fly the safe route out, land clear of the tower and the
conductor corridors, or hold and hand the vehicle to the pilot.

The route is :mod:`insulator_rs.planning.abort`'s, planned from what the state machine knew (on
across over the tower where a crossing was heading, back out beside an arm where a detour
began), checked against the LiDAR's obstacle map as the mission's legs are: a leg that comes
within the safety margin of an obstacle seen is bent round it, each leg is checked again against
the map as it stands when it is flown, and, while it is flown, a map that gained occupied voxels
on its rest stops the vehicle, and the rest of that leg is planned again from there, bent round
what is seen now (at most MAX_REPLANS times a leg). Where no route can be
planned (the map's refusals included: why a hold then, :mod:`insulator_rs.planning.abort`), or
the vehicle stops taking setpoints on it, the vehicle holds in the autopilot's HOLD and the pilot
is told: never a blind descent. Nothing is flown while a vehicle failsafe has the vehicle (the
autopilot flies it) or when it never took off.

The stop before the route is checked against the safety volumes only: it brakes along the leg
being flown, which was checked against the map (and again as the map grew), and no other way to
stop exists; the autopilot's HOLD, the only alternative, brakes the same way.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from enum import Enum
from typing import Any

import numpy as np

from insulator_rs.exceptions import PlanningError, VehicleError
from insulator_rs.flight.leg_follower import follow, rest_blocked
from insulator_rs.flight.pilot import LAND_HEIGHT, Pilot
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.planning.abort import (AbortCase, AbortRoute, bent_round_the_map, leg_trajectory,
                                         plan_abort_route, plan_stop)
from insulator_rs.planning.exploration import PlanKind
from insulator_rs.planning.minsnap import MinSnapTrajectory
from insulator_rs.planning.obstacle_map import SeenVolumes
from insulator_rs.planning.segments import SAFETY_CHECK_DT
from insulator_rs.ports.observer import FlightObserver
from insulator_rs.ports.vehicle import FlightMode
from insulator_rs.tracking.registry import InsulatorRegistry

OFFBOARD_WARMUP = 0.5  # s of setpoints streamed before asking for OFFBOARD (PX4 wants a stream)
# times one leg of the way out is stopped and planned again as the map grows on it: a map that
# keeps finding more on the way (a tree line seen branch by branch) hands the vehicle to the pilot
MAX_REPLANS = 5


class LegEnd(Enum):
    """How flying one trajectory of the way out ended."""

    FLOWN = "flown"  # to its end
    LEFT = "left"  # the vehicle stopped taking setpoints (handed over) or a failsafe has it
    BLOCKED = "blocked"  # the obstacle map now blocks its rest: stop, and plan the rest again


class SafeExit:
    """The abort's way out of one flight: ``route`` flown (None: none), ``handed_over`` why the
    vehicle was left holding for the pilot, ``left`` what the plan still held at the abort.
    ``seen()``: the safety volumes with the LiDAR's obstacle map as it is now (None: no map kept,
    the safety volumes only)."""

    def __init__(self, pilot: Pilot, geom: MissionGeometry, registry: InsulatorRegistry, *, v_max: np.ndarray,
                 a_max: np.ndarray, crossing_clearance: float, observer: FlightObserver,
                 seen: Callable[[], SeenVolumes | None]) -> None:
        self.pilot = pilot
        self.seen = seen
        self.geom = geom
        self.registry = registry
        self.v_max, self.a_max = v_max, a_max
        self.crossing_clearance = crossing_clearance
        self.observer = observer
        self.route: AbortRoute | None = None
        self.handed_over: str | None = None
        self.left: dict[str, Any] | None = None

    def route_from(self, position: np.ndarray) -> AbortRoute:
        """The safe route out from ``position`` (at rest) that an abort flies, from what the state
        machine knows (the abort's context once aborted, else what an abort now would keep), bent
        round the obstacle map (the battery reserve weighs this route too). PlanningError
        (ObstacleBlocked: the map refuses it) where none can be planned."""
        sm = self.pilot.sm
        ctx = sm.aborted or sm.exit_context("battery reserve", self.pilot.vehicle.state().time)
        return plan_abort_route(self.geom.line, self.geom.volumes, position, toward_side=ctx.toward_side,
                                back_to=ctx.back_to, ground_z=float(self.geom.takeoff[2]),
                                land_height=LAND_HEIGHT, crossing_clearance=self.crossing_clearance,
                                seen=self.seen())

    def note_what_is_left(self) -> None:
        """What the plan still holds (at the moment of an abort, before the state machine drops
        it): the insulators found and not yet inspected, the inspection waypoints not flown
        (buffered and deferred), the exploration path not flown (its waypoints and length)."""
        sm = self.pilot.sm
        scan = [np.asarray(it.position, dtype=np.float64) for it in sm.plan
                if it.kind in (PlanKind.SCAN, PlanKind.CROSS)]
        length = float(np.sum(np.linalg.norm(np.diff(np.array(scan), axis=0), axis=1))) if len(scan) > 1 else 0.0
        self.left = {"insulators_uninspected": [i.id for i in self.registry.insulators if not i.inspected],
                     "inspection_waypoints": sum(it.kind == PlanKind.INSPECT for it in sm.plan)
                     + sum(len(w) for w in sm.deferred.values()),
                     "exploration_waypoints": len(scan), "exploration_left_m": length}

    def leave(self) -> None:
        """After an abort: stop, fly the safe route out and land at its end; where no route can
        be planned, or the vehicle will not fly it, hold and hand over to the pilot. Nothing when
        a failsafe has the vehicle or it never flew."""
        pilot = self.pilot
        if pilot.failsafe is not None or not pilot.airborne:
            return
        st = pilot.vehicle.state()
        if st.landed:
            return
        offboard = st.mode == FlightMode.OFFBOARD.value
        yaw = st.yaw
        try:
            stop = plan_stop(self.geom.volumes, st.position, st.velocity, self.a_max)
            if stop is not None and offboard and self._fly(stop, yaw) is not LegEnd.FLOWN:
                return
            route = self.route_from(pilot.vehicle.state().position)
        except PlanningError as exc:
            self.hand_over(f"no safe route to land: {exc}")
            return
        self.route = route
        pilot.say(f"[{pilot.now():7.1f} s] abort: {route.case} to the landing point "
                  f"{np.round(route.landing, 1).tolist()} ({len(route.legs)} legs)")
        self._say_bends(route, 0)
        pilot.write_summary()
        if route.case == AbortCase.DESCEND and not offboard and not route.bends:
            pilot.land()  # straight down is clear: the autopilot's own landing, no offboard needed
            return
        if not offboard and not self._take_offboard():
            return
        for i in range(len(route.legs)):
            flown = self._fly_leg(route, i, yaw)
            if flown is None:
                return
            route = flown
        pilot.land()

    def _fly_leg(self, route: AbortRoute, i: int, yaw: float) -> AbortRoute | None:
        """Fly leg ``i`` of ``route``, checked against the map as it is now, stopped and planned
        again from where the vehicle is whenever the map comes to block its rest; the route as
        flown (also :attr:`route`), or None (the vehicle handed over, unless a failsafe has it)
        when the leg cannot be flown to its end."""
        for _ in range(MAX_REPLANS + 1):
            try:
                # the map grew while the legs before were flown: this leg is checked (and bent)
                # against it as it is now, the route kept as flown in the summary
                route = self.route = self._checked_again(route, i)
                seen = self.seen()
                traj = leg_trajectory(route.legs[i], self.geom.volumes if seen is None else seen,
                                      v_max=self.v_max, a_max=self.a_max, dt=SAFETY_CHECK_DT)
            except PlanningError as exc:
                self.hand_over(f"no safe trajectory along the route out: {exc}")
                return None
            end = self._fly(traj, yaw, seen)
            if end is not LegEnd.BLOCKED:
                return route if end is LegEnd.FLOWN else None
            # the rest of the leg from where the vehicle stops: straight to the leg's end, bent
            # round what the map holds now by the next round's check
            st = self.pilot.vehicle.state()
            self.pilot.say(f"[{self.pilot.now():7.1f} s] abort: the LiDAR sees an obstacle on the rest of leg "
                           f"{i + 1} of the way out: stopping and planning it again")
            try:
                stop = plan_stop(self.geom.volumes, st.position, st.velocity, self.a_max)
            except PlanningError as exc:
                self.hand_over(f"no safe stop on the route out: {exc}")
                return None
            if stop is not None and self._fly(stop, yaw) is not LegEnd.FLOWN:
                return None
            here = self.pilot.vehicle.state().position.copy()
            rest = np.stack([here, route.legs[i][-1]])
            route = self.route = replace(route, legs=route.legs[:i] + (rest,) + route.legs[i + 1:])
        self.hand_over(f"the LiDAR kept finding obstacles on leg {i + 1} of the route out "
                       f"({MAX_REPLANS} re-plans)")
        return None

    def _checked_again(self, route: AbortRoute, i: int) -> AbortRoute:
        """``route`` with its leg ``i`` bent round the obstacle map as it is now (unchanged where it
        is still clear, or with no map); ObstacleBlocked when the map now refuses it."""
        seen = self.seen()
        if seen is None:
            return route
        again = bent_round_the_map(route, seen, only=i)
        self._say_bends(again, len(route.bends))
        return again

    def _say_bends(self, route: AbortRoute, first: int) -> None:
        """Tell the pilot of each bend of the way out from ``route.bends[first]`` on."""
        for bend in route.bends[first:]:
            self.pilot.say(f"[{self.pilot.now():7.1f} s] abort: {bend.describe()}")

    def _fly(self, traj: MinSnapTrajectory, yaw: float, seen: SeenVolumes | None = None) -> LegEnd:
        """Fly one trajectory of the way out; LEFT (and the vehicle handed over, unless a failsafe
        has it) when the vehicle stops taking setpoints on the way; BLOCKED when ``seen``'s map
        gains occupied voxels that block the trajectory's rest (None: not watched)."""
        obstacles = None if seen is None else seen.obstacles
        checked = -1 if obstacles is None else obstacles.version
        for t, st in follow(self.pilot, traj, lambda: yaw):
            if self.pilot.failsafe is not None:
                return LegEnd.LEFT
            if not st.healthy or st.mode != FlightMode.OFFBOARD.value:
                self.hand_over(st.fault or f"the vehicle left offboard on the way out (mode {st.mode})")
                return LegEnd.LEFT
            if seen is not None and obstacles is not None and obstacles.version != checked:
                checked = obstacles.version
                if rest_blocked(traj, t, seen, self.v_max):
                    return LegEnd.BLOCKED
        return LegEnd.FLOWN

    def _take_offboard(self) -> bool:
        """Back into offboard for the way out (setpoints streamed here first, as PX4 wants);
        False, and the vehicle handed over, when the autopilot refuses."""
        pilot = self.pilot
        st = pilot.vehicle.state()
        here, t0 = st.position.copy(), st.time
        while st.time - t0 < OFFBOARD_WARMUP and pilot.failsafe is None:
            st = pilot.tick(here, None, st.yaw)
        try:
            pilot.vehicle.start_offboard()
        except VehicleError as exc:
            self.hand_over(f"offboard refused for the way out: {exc}")
            return False
        return pilot.failsafe is None

    def hand_over(self, reason: str) -> None:
        """No safe way on: hold in the autopilot's HOLD where the vehicle is (never a blind
        descent), say so to the pilot (the GCS's STATUSTEXT), stop commanding."""
        self.handed_over = reason
        try:
            self.pilot.vehicle.hold()
        except VehicleError as exc:
            reason += f"; the hold command failed too: {exc}"
            self.handed_over = reason
        self.observer.handed_over(self.pilot.now(), reason)
        self.pilot.say(f"[{self.pilot.now():7.1f} s] holding for the pilot: {reason}")
        self.pilot.write_summary()
