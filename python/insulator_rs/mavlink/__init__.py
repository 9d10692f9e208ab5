"""MAVLink 2 link to PX4: the offboard client, frame and mode conversions, signing.

``connect_vehicle("udpin:0.0.0.0:14540")`` (or a serial ``DEVICE:BAUD``)
connects to a real PX4 or its SITL and returns a
``insulator_rs.ports.vehicle.Vehicle``. The simulated PX4 is one of the simulator's
adapters (``insulator_rs.sim.px4``): nothing here imports the simulator.
Submodules load pymavlink lazily so importing this package stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from insulator_rs.mavlink.client import MavlinkVehicle

__all__ = ["connect_vehicle"]


def connect_vehicle(connection: str, **options: Any) -> MavlinkVehicle:
    """See ``insulator_rs.mavlink.client.connect_vehicle``."""
    from insulator_rs.mavlink.client import connect_vehicle as _connect

    return _connect(connection, **options)
