"""Planning and flying one leg: the min-snap trajectory through plan items, streamed a tick at a
time, re-checked against the LiDAR's obstacle map as the map grows.

Every leg (the exploration's, an inspection waypoint's, a second look's view) is planned against
the safety volumes and, where the map is kept, what the LiDAR saw outside them
(:mod:`insulator_rs.planning.obstacle_map`), and while it is flown a map that gained occupied
voxels has the rest of the trajectory checked again (:meth:`FlownLeg.blocked`): one rule for
every caller, which then re-plans or gives the look up.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from insulator_rs.exceptions import ObstacleBlocked
from insulator_rs.flight.pilot import CONTROL_PERIOD, Pilot
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import PlanItem
from insulator_rs.planning.minsnap import MinSnapTrajectory
from insulator_rs.planning.obstacle_map import SURVEY_RANGE, ObstacleMap, SeenVolumes
from insulator_rs.planning.segments import SAFETY_CHECK_DT, Segment, plan_segment
from insulator_rs.ports.vehicle import VehicleState

# s between LiDAR scans taken into the obstacle map (planning/obstacle_map.py); each is one
# 100 ms scan, so the map sees a fifth of the returns: a pole fills its voxels within seconds
SURVEY_PERIOD = 0.5


def follow(pilot: Pilot, traj: MinSnapTrajectory,
           yaw: Callable[[], float]) -> Iterator[tuple[float, VehicleState]]:
    """Stream ``traj`` from its start, one tick at a time, at heading ``yaw()``; yields the
    trajectory time and the vehicle's state after each tick (the caller stops when it must)."""
    st = pilot.vehicle.state()
    t, t0 = 0.0, st.time
    while t < traj.total_time - 1e-9:
        # by vehicle time, not ticks: through MAVLink a period ends on a telemetry sample, and
        # sensing takes wall time while the vehicle flies on
        t = min(max(st.time - t0, t) + CONTROL_PERIOD, traj.total_time)
        pos = traj.evaluate(np.array([t]), 0)[0]
        vel = traj.evaluate(np.array([t]), 1)[0]
        st = pilot.tick(pos, vel, yaw())
        yield t, st


def rest_blocked(traj: MinSnapTrajectory, t: float, seen: SeenVolumes, v_max: np.ndarray) -> bool:
    """Whether ``seen`` (the map as it is now) blocks the rest of ``traj`` from its time ``t`` on,
    sampled as the planner checks it (SAFETY_CHECK_DT, at the limits' speed ``v_max``): the one
    re-check of a trajectory being flown, for the mission's legs and the abort's way out alike."""
    times = np.append(np.arange(t, traj.total_time, SAFETY_CHECK_DT), traj.total_time)
    reach = float(np.linalg.norm(v_max)) * SAFETY_CHECK_DT
    return not seen.samples_clear(traj.evaluate(times, 0), reach)


class FlownLeg:
    """A planned leg being flown: its segment, and the map's version its rest was last checked at."""

    def __init__(self, follower: LegFollower, segment: Segment, seen: SeenVolumes | None) -> None:
        self.follower = follower
        self.segment = segment
        self.seen = seen
        self._checked = -1 if follower.obstacles is None else follower.obstacles.version

    @property
    def trajectory(self) -> MinSnapTrajectory | None:
        return self.segment.trajectory

    def fly(self, yaw: Callable[[], float]) -> Iterator[tuple[float, VehicleState]]:
        """The leg's ticks (none when the vehicle is at its items already: no trajectory)."""
        if self.segment.trajectory is None:
            return iter(())
        return follow(self.follower.pilot, self.segment.trajectory, yaw)

    def blocked(self, t: float) -> bool:
        """Whether the map, grown since the last check (new occupied voxels), now blocks the rest
        of the trajectory from its time ``t`` on (sampled as the planner checks: SAFETY_CHECK_DT,
        at the limits' speed). False without a map or a trajectory."""
        obstacles, traj = self.follower.obstacles, self.segment.trajectory
        if traj is None or self.seen is None or obstacles is None or obstacles.version == self._checked:
            return False
        self._checked = obstacles.version
        return rest_blocked(traj, t, self.seen, self.follower.v_max)


class LegFollower:
    """Keeps the obstacle map (``obstacle_map``: False, the safety volumes only: what the map
    buys, measured), plans legs from where the vehicle is and counts what the map did to them."""

    def __init__(self, pilot: Pilot, geom: MissionGeometry, *, v_max: np.ndarray, a_max: np.ndarray,
                 clearance: float, margin: float, time_allocation: str, obstacle_map: bool) -> None:
        self.pilot = pilot
        self.geom = geom
        self.v_max, self.a_max = v_max, a_max
        self.clearance = clearance  # m above the tower where the sides are crossed
        self.margin = margin  # m kept from what the map holds
        self.time_allocation = time_allocation
        # what the LiDAR saw outside the safety volumes (None: not kept); the first survey a
        # period in: a scan asked for at once would reach back before the clock's start (the
        # simulator renders the 100 ms before; a recording refuses negative stamps)
        self.obstacles = (ObstacleMap(known=geom.volumes, ground_z=float(geom.takeoff[2]))
                          if obstacle_map else None)
        self._next_survey = pilot.vehicle.state().time + SURVEY_PERIOD
        self.legs_bent = 0  # legs planned round an obstacle of the map
        self.legs_replanned = 0  # legs left mid-way because the map saw their rest blocked
        self.legs_refused = 0  # legs no detour round the map's obstacles cleared

    def survey(self, st: VehicleState, scan: Callable[[float], np.ndarray], T_b_l: np.ndarray, *,
               wanted: bool = False) -> np.ndarray | None:
        """Every SURVEY_PERIOD s: the LiDAR's returns at ``st``'s time (``scan(time)``: points in
        W) into the map, from the sensor's place (``T_b_l``: the LiDAR in the body). The returns
        taken (None: no survey this tick), for another user of the same scans (the LiDAR cue:
        ``wanted`` surveys without a map too)."""
        if (self.obstacles is None and not wanted) or st.time < self._next_survey:
            return None
        self._next_survey = st.time + SURVEY_PERIOD
        sensor = (st.T_w_b @ T_b_l)[:3, 3]
        points = scan(st.time)
        if self.obstacles is not None:
            self.obstacles.insert(points, sensor_w=sensor)
        # the map's range rule, one home: farther returns are the least accurate
        return points[np.linalg.norm(points - sensor, axis=1) <= SURVEY_RANGE] if len(points) else points

    def seen(self) -> SeenVolumes | None:
        """The safety volumes with the obstacle map, at the mission's margin (None: no map)."""
        if self.obstacles is None:
            return None
        return SeenVolumes.of(self.geom.volumes, self.obstacles, self.margin)

    def plan(self, items: Sequence[PlanItem], *, counted: bool = True) -> FlownLeg:
        """The leg through ``items`` from the vehicle's state; PlanningError when none is safe.
        ``counted``: a leg of the plan (the map's bends and refusals go into the summary)."""
        st = self.pilot.vehicle.state()
        seen = self.seen()
        try:
            seg = plan_segment(self.geom.line, self.geom.volumes, st.position, st.velocity, list(items),
                               v_max=self.v_max, a_max=self.a_max, clearance=self.clearance,
                               time_allocation=self.time_allocation, seen=seen)
        except ObstacleBlocked:
            self.legs_refused += counted
            raise
        self.legs_bent += counted and seg.detours > 0
        if counted:
            for bend in seg.bends:
                self.pilot.say(f"[{self.pilot.now():7.1f} s] leg to {np.round(items[-1].position, 1).tolist()}: "
                               f"{bend.describe()}")
        return FlownLeg(self, seg, seen)

    def record(self) -> dict[str, Any]:
        """What the obstacle map held and did (summary.json's ``obstacle_map``)."""
        if self.obstacles is None:
            return {"enabled": False}
        return {"enabled": True, **self.obstacles.record(), "margin_m": self.margin,
                "legs_bent": self.legs_bent, "legs_replanned": self.legs_replanned,
                "legs_refused": self.legs_refused}
