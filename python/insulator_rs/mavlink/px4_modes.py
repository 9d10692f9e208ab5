"""PX4's custom_mode encoding of flight modes in HEARTBEAT and MAV_CMD_DO_SET_MODE.

PX4 packs its mode into the 32-bit ``custom_mode`` as ``main_mode << 16 |
sub_mode << 24`` (px4_custom_mode.h); DO_SET_MODE carries base_mode (with
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED) in param1, the main mode in param2 and the
sub mode in param3. Mode names are those of ``insulator_rs.ports.vehicle.FlightMode``.
"""

from __future__ import annotations

from insulator_rs.ports.vehicle import FlightMode

# px4_custom_mode.h: PX4_CUSTOM_MAIN_MODE_*
MAIN_MODE_MANUAL = 1
MAIN_MODE_ALTCTL = 2
MAIN_MODE_POSCTL = 3
MAIN_MODE_AUTO = 4
MAIN_MODE_ACRO = 5
MAIN_MODE_OFFBOARD = 6
MAIN_MODE_STABILIZED = 7
# PX4_CUSTOM_SUB_MODE_AUTO_*
SUB_MODE_AUTO_READY = 1
SUB_MODE_AUTO_TAKEOFF = 2
SUB_MODE_AUTO_LOITER = 3
SUB_MODE_AUTO_MISSION = 4
SUB_MODE_AUTO_RTL = 5
SUB_MODE_AUTO_LAND = 6

MODE_TO_PX4: dict[FlightMode, tuple[int, int]] = {
    FlightMode.MANUAL: (MAIN_MODE_MANUAL, 0),
    FlightMode.POSCTL: (MAIN_MODE_POSCTL, 0),
    FlightMode.HOLD: (MAIN_MODE_AUTO, SUB_MODE_AUTO_LOITER),
    FlightMode.TAKEOFF: (MAIN_MODE_AUTO, SUB_MODE_AUTO_TAKEOFF),
    FlightMode.LAND: (MAIN_MODE_AUTO, SUB_MODE_AUTO_LAND),
    FlightMode.RTL: (MAIN_MODE_AUTO, SUB_MODE_AUTO_RTL),
    FlightMode.MISSION: (MAIN_MODE_AUTO, SUB_MODE_AUTO_MISSION),
    FlightMode.OFFBOARD: (MAIN_MODE_OFFBOARD, 0),
}
_PX4_TO_MODE = {value: mode for mode, value in MODE_TO_PX4.items()}


def encode_custom_mode(mode: FlightMode | str) -> int:
    """HEARTBEAT.custom_mode of ``mode`` (ValueError for a mode PX4 has no encoding of here)."""
    try:
        main, sub = MODE_TO_PX4[FlightMode(mode)]
    except (KeyError, ValueError) as exc:
        raise ValueError(f"mode has no PX4 encoding: {mode!r}") from exc
    return (main << 16) | (sub << 24)


def main_sub_modes(mode: FlightMode | str) -> tuple[int, int]:
    """(main, sub) for MAV_CMD_DO_SET_MODE param2/param3."""
    custom = encode_custom_mode(mode)
    return (custom >> 16) & 0xFF, (custom >> 24) & 0xFF


def decode_custom_mode(custom_mode: int) -> str:
    """Mode name of a HEARTBEAT.custom_mode; unknown modes read "PX4_<main>_<sub>".

    PX4 reports POSCTL sub modes (e.g. slow) and other main modes the mission does
    not use; those decode to their numbers so nothing is silently misnamed.
    """
    if not 0 <= int(custom_mode) <= 0xFFFFFFFF:
        raise ValueError(f"custom_mode must be a uint32, got {custom_mode!r}")
    main = (int(custom_mode) >> 16) & 0xFF
    sub = (int(custom_mode) >> 24) & 0xFF
    mode = _PX4_TO_MODE.get((main, sub))
    if mode is None and main in (MAIN_MODE_MANUAL, MAIN_MODE_POSCTL, MAIN_MODE_OFFBOARD):
        mode = _PX4_TO_MODE.get((main, 0))
    return mode.value if mode is not None else f"PX4_{main}_{sub}"


def mode_from_set_mode(custom_main: int, custom_sub: int) -> FlightMode | None:
    """The mode a DO_SET_MODE (custom mode enabled) asks for, None if not modelled here."""
    if custom_main in (MAIN_MODE_MANUAL, MAIN_MODE_POSCTL, MAIN_MODE_OFFBOARD):
        custom_sub = 0
    return _PX4_TO_MODE.get((custom_main, custom_sub))
