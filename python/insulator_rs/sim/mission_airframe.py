"""The simulated airframe a mission flies: :class:`~insulator_rs.sim.kinematics.KinematicVehicle` at the
mission's take-off point, its limits with headroom over the plan's (``insulator-rs inspect``'s and
the studies' one airframe)."""

from __future__ import annotations

from insulator_rs.mission.config import Mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.sim.kinematics import KinematicVehicle, MotionLimits

# The vehicle's own limits get this much headroom over the planning limits so the
# position loop can track the trajectory.
LIMIT_HEADROOM = 1.5


def kinematic_vehicle(mission: Mission, seed: int) -> KinematicVehicle:
    """The simulated airframe at the mission's take-off point, limits with headroom over the plan's
    (its pack full; `insulator-rs inspect --sim-battery` sets another charge)."""
    geom = MissionGeometry.from_mission(mission)
    lim = mission.vehicle
    return KinematicVehicle(
        start_position=geom.takeoff, start_yaw=geom.path[0].yaw, seed=seed,
        limits=MotionLimits(max_horizontal_speed=lim.v_max_horizontal * LIMIT_HEADROOM,
                            max_vertical_speed=lim.v_max_vertical * LIMIT_HEADROOM,
                            max_horizontal_acceleration=lim.a_max_horizontal * LIMIT_HEADROOM,
                            max_vertical_acceleration=lim.a_max_vertical * LIMIT_HEADROOM))
