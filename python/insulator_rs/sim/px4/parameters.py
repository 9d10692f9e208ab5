"""The simulated PX4's parameters: PARAM_REQUEST_READ, PARAM_REQUEST_LIST and PARAM_SET answered
with PARAM_VALUE as PX4 v1.16.0 SITL answers them (measured, ``tests/test_px4_sitl_parameters.py``):

* the table holds PX4's names, MAV_PARAM_TYPEs and the SITL's defaults (SIH quadrotor, airframe
  10040) for the parameters the mission sets and the ones the airframe honours;
* values travel bytewise (an INT32's bytes in the float field: ``mavlink/parameters.py``);
* a PARAM_SET with another type than the parameter's, or of a name not in the table (names
  are case-sensitive), gets no answer at all; a read of an unknown name neither;
* a set is answered with PARAM_VALUE twice when the value changed (the reply and PX4's change
  broadcast), once when it did not; no range is enforced (PX4 took RTL_RETURN_ALT 1000);
* PX4 refuses to arm while NAV_DLL_ACT is not 0 and no ground station's HEARTBEAT came within
  COM_DL_LOSS_T s ("Preflight Fail: No connection to the ground control station"):
  :meth:`Px4Parameters.arming_refusal`;
* in flight, NAV_DLL_ACT, COM_DL_LOSS_T, COM_DLL_EXCEPT and COM_FAIL_ACT_T drive the GCS
  connection loss failsafe (``sim/px4/datalink.py``).

The parameters the airframe honours change its behaviour when set (``AIRFRAME_FIELDS``: the
offboard-loss timeout and action, the return altitude, the disarm delays, the take-off
altitude, the landing speed). Not modelled (stored and answered, no effect): the geofence,
RTL_DESCEND_ALT (the simulated return descends at the landing speed from the return altitude,
as PX4 does with RTL_DESCEND_ALT at the return altitude), the return cone (the simulated return
always climbs to RTL_RETURN_ALT: PX4 with RTL_CONE_ANG 0), COM_OBL_RC_ACT values other than 0
(Position), 3 (Return), 4 (Land) and 5 (Hold), and NAV_DLL_ACT 5 (Terminate) and 6 (Lockdown).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from insulator_rs.mavlink.parameters import check_name, decode, encode, same_value
from insulator_rs.mavlink.wire import mavlink2
from insulator_rs.sim.kinematics import AutopilotParameters

M = mavlink2
INT32, REAL32 = M.MAV_PARAM_TYPE_INT32, M.MAV_PARAM_TYPE_REAL32
# PX4 v1.16.0 SITL's defaults (read over MAVLink from a fresh SITL, SIH quadrotor; COM_FAIL_ACT_T's
# from the SITL's own parameter metadata, etc/extras/parameters.json.xz)
SITL_DEFAULTS: dict[str, tuple[int, int | float]] = {
    "COM_DISARM_LAND": (REAL32, 2.0), "COM_DISARM_PRFLT": (REAL32, 10.0), "COM_DLL_EXCEPT": (INT32, 0),
    "COM_DL_LOSS_T": (INT32, 10), "COM_OBC_LOSS_T": (REAL32, 5.0), "COM_OBL_RC_ACT": (INT32, 0),
    "COM_FAIL_ACT_T": (REAL32, 5.0), "COM_OF_LOSS_T": (REAL32, 1.0), "COM_RC_LOSS_T": (REAL32, 1.0),
    "GF_ACTION": (INT32, 2),
    "GF_MAX_HOR_DIST": (REAL32, 0.0), "GF_MAX_VER_DIST": (REAL32, 0.0), "GF_PREDICT": (INT32, 0),
    "GF_SOURCE": (INT32, 0), "MIS_TAKEOFF_ALT": (REAL32, 2.5), "MPC_LAND_SPEED": (REAL32, 0.7),
    "NAV_DLL_ACT": (INT32, 0), "NAV_RCL_ACT": (INT32, 2), "RTL_CONE_ANG": (INT32, 45),
    "RTL_DESCEND_ALT": (REAL32, 10.0), "RTL_LAND_DELAY": (REAL32, 0.0), "RTL_MIN_DIST": (REAL32, 10.0),
    "RTL_RETURN_ALT": (REAL32, 30.0), "RTL_TYPE": (INT32, 0),
}
# COM_OBL_RC_ACT values and the mode the airframe then falls back to
OFFBOARD_LOSS_MODES = {0: "POSCTL", 3: "RTL", 4: "LAND", 5: "HOLD"}
_MODE_VALUES = {mode: value for value, mode in OFFBOARD_LOSS_MODES.items()}


def _float(value: int | float) -> float:
    return float(value)


def _loss_mode(value: int | float) -> str | None:
    return OFFBOARD_LOSS_MODES.get(int(value))


# parameter -> (AutopilotParameters field, PX4 value -> field value, field value -> PX4 value)
AIRFRAME_FIELDS: dict[str, tuple[str, Callable[[int | float], Any], Callable[[Any], int | float]]] = {
    "COM_OF_LOSS_T": ("offboard_loss_timeout", _float, _float),
    "COM_OBL_RC_ACT": ("offboard_loss_mode", _loss_mode, lambda mode: _MODE_VALUES[mode]),
    "COM_DISARM_LAND": ("disarm_land_delay", _float, _float),
    "COM_DISARM_PRFLT": ("preflight_disarm_delay", _float, _float),
    "RTL_RETURN_ALT": ("return_altitude", _float, _float),
    "MIS_TAKEOFF_ALT": ("takeoff_altitude", _float, _float),
    "MPC_LAND_SPEED": ("land_speed", _float, _float),
}


class Px4Parameters:
    """The table and its MAVLink answers; ``send(msg)`` puts a message on the link, ``airframe``
    gets and sets the airframe's :class:`AutopilotParameters` (under the simulator's lock)."""

    def __init__(self, send: Callable[[Any], None], get_airframe: Callable[[], AutopilotParameters],
                 set_airframe: Callable[[AutopilotParameters], None]) -> None:
        self._send = send
        self._get_airframe = get_airframe
        self._set_airframe = set_airframe
        self.values: dict[str, tuple[int, int | float]] = dict(SITL_DEFAULTS)
        airframe = get_airframe()
        for name, (field, _, to_px4) in AIRFRAME_FIELDS.items():
            self.values[name] = (self.values[name][0], to_px4(getattr(airframe, field)))
        self.names = sorted(self.values)  # PX4 lists its parameters sorted by name: param_index
        self.sets = 0  # PARAM_SETs that changed a value
        self.ignored = 0  # requests PX4 would not answer (unknown name, type mismatch)

    def handle(self, msg: Any) -> None:
        """PARAM_REQUEST_READ, PARAM_REQUEST_LIST or PARAM_SET addressed to the autopilot."""
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            for name in self.names:
                self._value(name)
        elif kind == "PARAM_REQUEST_READ":
            index = int(msg.param_index)
            name = self.names[index] if 0 <= index < len(self.names) else str(msg.param_id)
            if name in self.values:
                self._value(name)
            else:
                self.ignored += 1
        elif kind == "PARAM_SET":
            self._set(str(msg.param_id), float(msg.param_value), int(msg.param_type))

    def _set(self, name: str, raw: float, param_type: int) -> None:
        entry = self.values.get(name)
        if entry is None or entry[0] != param_type:
            self.ignored += 1  # PX4: "unknown param" / "param types mismatch", and no answer
            return
        value = decode(raw, param_type)
        changed = not same_value(value, entry[1], param_type)
        self.values[name] = (param_type, value)
        if changed:
            self.sets += 1
            self._apply_to_airframe(name, value)
        self._value(name)
        if changed:
            self._value(name)  # PX4's change notification follows its reply

    def _apply_to_airframe(self, name: str, value: int | float) -> None:
        spec = AIRFRAME_FIELDS.get(name)
        if spec is None:
            return
        field, to_field, _ = spec
        converted = to_field(value)
        if converted is None:
            return  # an action the airframe does not model: stored, no effect
        try:
            self._set_airframe(dataclasses.replace(self._get_airframe(), **{field: converted}))
        except ValueError:
            pass  # PX4 takes any value; the airframe keeps what it can fly

    def _value(self, name: str) -> None:
        param_type, value = self.values[name]
        self._send(M.MAVLink_param_value_message(check_name(name).encode("ascii"), encode(name, value, param_type),
                                                 param_type, len(self.names), self.names.index(name)))

    def arming_refusal(self, ground_station_age: float | None) -> str | None:
        """Why PX4 would refuse to arm now (None: it would not): NAV_DLL_ACT set and no ground
        station heard for COM_DL_LOSS_T s (``ground_station_age``: s since its last HEARTBEAT,
        None when never)."""
        if int(self.values["NAV_DLL_ACT"][1]) == 0:
            return None
        timeout = float(self.values["COM_DL_LOSS_T"][1])
        if ground_station_age is None or ground_station_age > timeout:
            return "No connection to the ground control station"
        return None
