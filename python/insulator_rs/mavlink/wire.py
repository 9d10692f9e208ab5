"""The MAVLink 2 dialect both ends use (pymavlink's generated ``common``).

pymavlink picks MAVLink 1 or 2 from the MAVLINK20 environment variable when
``mavutil`` loads its dialect, so it is set here, once, before that happens.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink2  # noqa: E402

if getattr(mavutil, "mavlink", None) is not mavlink2:
    mavutil.set_dialect("common")

__all__ = ["mavlink2", "mavutil", "result_name", "command_name"]


def result_name(result: int) -> str:
    """MAV_RESULT name, e.g. 'MAV_RESULT_TEMPORARILY_REJECTED'."""
    entry = mavlink2.enums["MAV_RESULT"].get(int(result))
    return entry.name if entry is not None else f"MAV_RESULT_{int(result)}"


def command_name(command: int) -> str:
    """MAV_CMD name, e.g. 'MAV_CMD_COMPONENT_ARM_DISARM'."""
    entry = mavlink2.enums["MAV_CMD"].get(int(command))
    return entry.name if entry is not None else f"MAV_CMD_{int(command)}"
