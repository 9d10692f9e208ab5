"""Where the vehicle stands: its home, in W and in GPS, and a mission taking off from it.

An autopilot's home is its HOME_POSITION (:class:`~insulator_rs.ports.capabilities.NavigationStatus`,
PX4 sets it where the vehicle stands, again at arming), converted to W with pymap3d about the
tower base (W's origin), as every GPS position of the mission is. The in-process vehicle has no
autopilot and no home: it stands where the simulator put it, and that position is its home.

Two users: the pre-flight gate compares the home with the mission's take-off point
(:func:`insulator_rs.flight.preflight.check_home`), and a mission with ``takeoff = "home"`` takes
off from it (:func:`at_vehicle_home`): the take-off point, the ground the obstacle map leaves out,
the landing point and the heights of the passes then all follow from where the vehicle stands.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from insulator_rs.exceptions import ConfigError
from insulator_rs.geodesy import GeoPoint, enu_to_gps, gps_to_enu
from insulator_rs.mission.config import TAKEOFF_HOME, Mission
from insulator_rs.ports.vehicle import Vehicle, vehicle_navigation


@dataclass(frozen=True)
class VehicleHome:
    """The vehicle's home: ``local`` (3,) in W (m), ``gps`` the same point in WGS-84, ``source``
    what it was read from (for the messages)."""

    local: np.ndarray
    gps: GeoPoint
    source: str


def vehicle_home(vehicle: Vehicle, origin: GeoPoint) -> VehicleHome | None:
    """``vehicle``'s home with W's origin at ``origin`` (the tower base); None when its autopilot
    has set none yet."""
    nav = vehicle_navigation(vehicle)
    if nav is not None:
        if nav.home is None:
            return None
        gps = GeoPoint(*nav.home)
        return VehicleHome(gps_to_enu(gps, origin), gps, "the autopilot's home (HOME_POSITION)")
    position = np.asarray(vehicle.state().position, dtype=np.float64).copy()
    return VehicleHome(position, enu_to_gps(position, origin), "the in-process vehicle's position (it has no home)")


def at_vehicle_home(mission: Mission, vehicle: Vehicle) -> Mission:
    """``mission`` taking off from ``vehicle``'s home when it says ``takeoff = "home"`` (and has
    not been given it yet); as it is otherwise. ConfigError naming ``takeoff`` when the autopilot
    has no home yet, or the home lies where no take-off point may (too far from the tower)."""
    if not mission.takeoff_home or mission.takeoff is not None:
        return mission
    home = vehicle_home(vehicle, mission.tower)
    if home is None:
        raise ConfigError(f'{mission.source}: takeoff: "{TAKEOFF_HOME}": the autopilot has sent no home position '
                          f"(HOME_POSITION) to take off from")
    return mission.with_takeoff(home.gps)
