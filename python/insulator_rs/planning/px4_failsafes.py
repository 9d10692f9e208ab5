"""PX4's own failsafes, chosen for this tower: what PX4 must do if the companion computer dies.

Once the companion stops streaming offboard setpoints (it crashed, was killed, lost power) PX4
is alone with the vehicle, somewhere round the tower: over the top in a crossing, or beside an
arm. Its defaults do not know the tower: RTL_RETURN_ALT 30 m may be under the tower's top (or
60 m, or what the vehicle last had), the return cone (RTL_CONE_ANG 45 deg) lowers the return
altitude near home, the offboard-loss action is Position mode (COM_OBL_RC_ACT 0: a hover, then a
descent in place when the battery runs out), and no geofence is set.

Here every choice is a climb, then a return home over the tower's safety volumes, then a
landing at home (the take-off point, clear of the tower):

* RTL_RETURN_ALT: at least the safety volumes' top (the tower's maximum height plus the safety
  margin) plus the crossing clearance plus :data:`RETURN_EXTRA`, relative to home, rounded up
  to :data:`ALTITUDE_STEP`; a higher value the vehicle already has is kept (the operator's, for
  what stands round the take-off site). PX4 climbs vertically to it first (wherever it is:
  beside an arm it stays outside the tower's box on the way up; over the top it is above the
  box already), then flies home straight at that height, over everything the mission plans round;
* RTL_DESCEND_ALT: the tower's height above (the first one without the vehicle's): PX4's
  cone never brings the return below it, and PX4 then descends only over home;
* RTL_CONE_ANG 0 (no cone: always the full return altitude), RTL_TYPE 0 (home, or a rally
  point), RTL_LAND_DELAY 0 (land once over home, not hover there until the battery ends);
* COM_OBL_RC_ACT 3 (Return) after COM_OF_LOSS_T 1 s without setpoints: the companion's death
  is an offboard loss;
* NAV_DLL_ACT 2 (Return) when a ground station is on PX4's data link (a companion that relays
  the GCS link takes it down when it dies). Without a ground station PX4 refuses to arm with
  any data-link-loss action ("No connection to the ground control station", measured on
  v1.16.0 SITL), so then it is left as the vehicle has it, and the report says so;
* a geofence round the mission volume (GF_MAX_HOR_DIST from home, GF_MAX_VER_DIST above
  home, each with :data:`GEOFENCE_MARGIN`), GF_ACTION 3 (Return): a runaway that leaves the
  mission's volume returns too.

PX4 takes any value a PARAM_SET carries (it does not clamp to its documented ranges: measured),
so the ranges are checked here, with the parameter named.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from insulator_rs.exceptions import PlanningError
from insulator_rs.planning.safety import SafetyVolumes

# m above the crossing height (the volumes' top plus the crossing clearance): PX4 climbs to
# its return altitude from wherever it is, so over the top it climbs too, rather than fly home
# at whatever height the crossing's trajectory had when the companion died
RETURN_EXTRA = 2.0
ALTITUDE_STEP = 0.5  # m: the altitudes are rounded up to this
GEOFENCE_MARGIN = 10.0  # m beyond the mission's extent: PX4's tracking, a braking overshoot
OFFBOARD_LOSS_TIMEOUT = 1.0  # s: PX4's default COM_OF_LOSS_T, set so a vehicle's other value goes
# PX4 v1.16 enum values (its parameter reference)
RETURN = 3  # COM_OBL_RC_ACT / GF_ACTION: Return mode
DATALINK_RETURN = 2  # NAV_DLL_ACT: Return mode
NO_CONE = 0  # RTL_CONE_ANG: no cone, the full return altitude everywhere
RTL_HOME_OR_RALLY = 0  # RTL_TYPE: return to home (or the closest rally point)
# PX4's documented ranges of the altitudes (m)
RTL_RETURN_ALT_MAX = 150.0
RTL_DESCEND_ALT_MAX = 100.0
GEOFENCE_MAX = 10000.0


@dataclass(frozen=True)
class ParameterSetting:
    """One PX4 parameter to set before take-off: its ``name``, the ``value`` (an int for PX4's
    INT32 parameters, a float for its FLOAT ones) and ``why`` (for the report)."""

    name: str
    value: int | float
    why: str


def _up(value: float) -> float:
    return math.ceil(value / ALTITUDE_STEP - 1e-9) * ALTITUDE_STEP


def _in_range(name: str, value: float, high: float) -> float:
    if not (math.isfinite(value) and 0.0 < value <= high):
        raise PlanningError(f"{name}: {value:.1f} m is outside PX4's range (0, {high:g}] m; the tower is "
                            "too tall or the mission too wide for PX4's own return")
    return value


def mission_extent(volumes: SafetyVolumes, home: np.ndarray, mission_points: np.ndarray) -> tuple[float, float]:
    """How far the mission reaches from ``home`` (W): (the largest horizontal distance, m, of
    ``mission_points`` (N, 3) and the tower box's corners; the largest height of the points
    above home, m). What a geofence round the mission must hold."""
    home = np.asarray(home, dtype=np.float64).reshape(3)
    points = np.asarray(mission_points, dtype=np.float64).reshape(-1, 3)
    tower = volumes.boxes[0]
    corners = np.array([[sx, sy, 1.0] for sx in (-1, 1) for sy in (-1, 1)]) * tower.half_extents
    corners = tower.center + corners @ tower.axes
    extent = np.vstack([points[:, :2], corners[:, :2]])
    horizontal = float(np.max(np.hypot(extent[:, 0] - home[0], extent[:, 1] - home[1])))
    return horizontal, float(np.max(points[:, 2])) - float(home[2])


def tower_failsafe_parameters(volumes: SafetyVolumes, home: np.ndarray, mission_points: np.ndarray, *,
                              crossing_clearance: float, ground_station: bool,
                              vehicle_return_alt: float | None = None) -> tuple[ParameterSetting, ...]:
    """The PX4 parameters for this tower (see the module docstring), in the order to set them.

    ``volumes``: the mission's safety volumes (W); ``home``: the take-off point in W (PX4's home
    is where it armed); ``mission_points`` (N, 3) W: every point the mission may fly to (the
    exploration path; the tower's box is added here); ``crossing_clearance`` m above the
    volumes' top where the mission crosses; ``ground_station``: whether a ground station is on
    PX4's data link (NAV_DLL_ACT is set only then); ``vehicle_return_alt``: the vehicle's
    RTL_RETURN_ALT now (m above home; kept when higher). Raises PlanningError naming the parameter
    when a value is outside PX4's range.
    """
    home = np.asarray(home, dtype=np.float64).reshape(3)
    over_tower = _up(volumes.top + crossing_clearance + RETURN_EXTRA - home[2])
    descend_alt = _in_range("RTL_DESCEND_ALT", over_tower, RTL_DESCEND_ALT_MAX)
    own = math.nan if vehicle_return_alt is None else float(vehicle_return_alt)
    kept = math.isfinite(own) and own > over_tower
    return_alt = _in_range("RTL_RETURN_ALT", own if kept else over_tower, RTL_RETURN_ALT_MAX)
    horizontal, height = mission_extent(volumes, home, mission_points)
    vertical = max(height, return_alt)
    fence_h = _in_range("GF_MAX_HOR_DIST", _up(horizontal + GEOFENCE_MARGIN), GEOFENCE_MAX)
    fence_v = _in_range("GF_MAX_VER_DIST", _up(vertical + GEOFENCE_MARGIN), GEOFENCE_MAX)
    top = f"the safety volumes' top {volumes.top:.1f} m + crossing clearance {crossing_clearance:g} m + {RETURN_EXTRA:g} m"
    settings = [
        ParameterSetting("RTL_RETURN_ALT", return_alt, "above home: the vehicle's own, higher than " + top
                         if kept else f"above home: {top}"),
        ParameterSetting("RTL_DESCEND_ALT", descend_alt, f"above home: {top}; the return descends only over home"),
        ParameterSetting("RTL_CONE_ANG", NO_CONE, "no cone: the full return altitude near home too"),
        ParameterSetting("RTL_TYPE", RTL_HOME_OR_RALLY, "return to home (the take-off point, clear of the tower)"),
        ParameterSetting("RTL_LAND_DELAY", 0.0, "land once over home"),
        ParameterSetting("GF_MAX_HOR_DIST", fence_h, f"the mission's extent from home + {GEOFENCE_MARGIN:g} m"),
        ParameterSetting("GF_MAX_VER_DIST", fence_v, f"the mission's height above home + {GEOFENCE_MARGIN:g} m"),
        ParameterSetting("GF_ACTION", RETURN, "a geofence breach returns"),
        ParameterSetting("COM_OF_LOSS_T", OFFBOARD_LOSS_TIMEOUT, "s without setpoints: the companion is lost"),
        ParameterSetting("COM_OBL_RC_ACT", RETURN, "offboard lost (the companion died): climb, return, land"),
    ]
    if ground_station:
        settings.append(ParameterSetting("NAV_DLL_ACT", DATALINK_RETURN,
                                         "ground station link lost (it may run through the companion): return"))
    return tuple(settings)
