"""MAVLink 2 link to PX4: the offboard client, a simulated PX4, frame and mode conversions.

``connect_vehicle(None)`` starts the simulated PX4 on loopback and returns the
client connected to it; ``connect_vehicle("udpin:0.0.0.0:14540")`` (or a serial
``DEVICE:BAUD``) connects to a real PX4 or its SITL. Both return a
``insulator_rs.vehicle.Vehicle``. Submodules load pymavlink lazily so importing
this package stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from insulator_rs.mavlink.client import MavlinkVehicle

__all__ = ["connect_vehicle"]


def connect_vehicle(connection: str | None = None, **options: Any) -> MavlinkVehicle:
    """See ``insulator_rs.mavlink.client.connect_vehicle``."""
    from insulator_rs.mavlink.client import connect_vehicle as _connect

    return _connect(connection, **options)
