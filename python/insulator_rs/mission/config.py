"""The mission file: what a grid owner knows, plus the vehicle's limits.

A mission file is TOML (``.toml``) or YAML (``.yaml``/``.yml``) with the tables
below; every error names the file and the field, and is raised before anything
flies (``insulator_rs.exceptions.ConfigError``, a ``ValueError``). Every number is
checked against its physical or mission limit in :mod:`insulator_rs.bounds` (the
message gives the range and the reason)::

    [tower]                       # the inspected tower (WGS-84, degrees / m)
    lat = 50.0
    lon = 14.0
    alt = 300.0
    max_height = 25.0             # m above the base
    max_width = 10.0              # m, widest horizontal extent (crossarms)

    [[neighbours]]                # one or two neighbouring towers on the line
    lat = 50.0
    lon = 13.9955
    alt = 300.0

    [takeoff]                     # optional; default: on the "+" side at the standoff
    lat = 50.0001
    lon = 14.0
    alt = 300.0
    # or, at the top of the file (before the tables): takeoff = "home": the take-off point is
    # the vehicle's own home, read from the autopilot before planning (flight/home.py)

    [vehicle]                     # limits (m/s, m/s^2); the paper's real flight: 1 and 3
    rig = "simulator"             # optional: the sensor rig file (camera calibration, T_b_c, T_b_l;
                                  # see insulator_rs.rig), relative to this file, or a shipped rig's name
    v_max_horizontal = 1.0
    a_max_horizontal = 3.0
    v_max_vertical = 1.0
    a_max_vertical = 3.0

    [inspection]
    standoff = 8.0                # m, exploration path distance from the tower's outer extent
    safety_margin = 2.0           # m, added round the tower's box and the conductor corridors
    inspection_distance = 6.0     # m, viewpoint distance from an insulator's centre (optional)
    waypoints_per_insulator = 2   # optional
    registry_gate = 1.5           # m, optional: a localization this close to a known insulator updates it
    pass_spacing = 8.0            # m, optional: vertical spacing of the exploration passes
    crossing_clearance = 3.0      # m, optional: height above the safety box when crossing sides
    insulator_length = 2.0        # m, optional: length of the insulator strings (for framing and plausibility)
    confirmations = 4             # optional: localizations within the gate before an insulator is registered
    battery_reserve = 0.25        # optional: fraction of the pack kept at landing; the vehicle comes back
                                  # (by the safe route out) before the rest of the plan would touch it
    photo_retakes = 2             # optional: times a photo the check finds unfit (cut, too small, off
                                  # centre, blurred, nothing detected) is taken again at its waypoint
                                  # (with the rig's inspection camera; without one, never)
    lidar_cue = false             # optional: strings found in the LiDAR's returns by geometry get a
                                  # look when no camera track covers them, and a camera find the
                                  # geometry contradicts needs more localizations (flight/lidar_cue.py)
"""

from __future__ import annotations

import math
from insulator_rs._toml import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from insulator_rs.exceptions import ConfigError
from insulator_rs import bounds
from insulator_rs.geodesy import GeoPoint, LineFrame, gps_to_enu, line_frame
from insulator_rs.rig import SensorRig, load_rig, resolve_rig, simulator_rig
from insulator_rs.textfile import read_config_text
from insulator_rs.tracking.confirmation import CONFIRMATIONS, MIN_CONFIRMATIONS


#: ``takeoff = "home"``: the take-off point is the vehicle's home, as the autopilot says
TAKEOFF_HOME = "home"


@dataclass(frozen=True)
class VehicleLimits:
    """Velocity (m/s) and acceleration (m/s^2) limits, horizontal (per axis) and vertical."""

    v_max_horizontal: float
    a_max_horizontal: float
    v_max_vertical: float
    a_max_vertical: float

    def v_max(self) -> np.ndarray:
        """Per-axis velocity limits (x, y, z) of W, m/s."""
        return np.array([self.v_max_horizontal, self.v_max_horizontal, self.v_max_vertical])

    def a_max(self) -> np.ndarray:
        """Per-axis acceleration limits (x, y, z) of W, m/s^2."""
        return np.array([self.a_max_horizontal, self.a_max_horizontal, self.a_max_vertical])


@dataclass(frozen=True)
class InspectionParams:
    """Inspection parameters, metres unless stated."""

    standoff: float
    safety_margin: float
    inspection_distance: float = 6.0
    waypoints_per_insulator: int = 2
    registry_gate: float = 1.5
    pass_spacing: float = 8.0
    crossing_clearance: float = 3.0
    insulator_length: float = 2.0
    # the registry's confirmation count (why 4: tracking/confirmation.py)
    confirmations: int = CONFIRMATIONS
    # The fraction of the pack left at landing (flight/reserve.py returns in time to keep it).
    # 25 %: the share a LiPo keeps above its knee under load, and above the MAVLink client's own
    # low-battery failsafe (20 %, mavlink/failsafes.py) and PX4's BAT_CRIT_THR (7 %), so the
    # mission's return comes first.
    battery_reserve: float = 0.25
    # A photo judged unfit on itself (perception/photo_check.py) is retaken this many times at
    # most: each retake re-settles and re-aims (a few seconds of hover); 2 cures a gust or a
    # settle cut short, and a fault that survives three shots will not go away with a fourth.
    # Only with the rig's inspection camera: the detection camera's frame is not retaken
    # (PhotoSession.take_photo, flight/photo_session.py, says why).
    photo_retakes: int = 2
    # The LiDAR cue (flight/lidar_cue.py). Off by default until towers A and B are shown to keep
    # every string, no false find and the battery's margin with it on.
    lidar_cue: bool = False


@dataclass(frozen=True)
class Mission:
    """A validated mission. ``takeoff`` is None when the file gives none (the
    planner then takes off on the "+" side at the standoff); ``rig`` is None when the
    file names no sensor rig (the simulator then flies its own, a real flight refuses).
    ``takeoff_home``: the file says ``takeoff = "home"``: the take-off point is the vehicle's
    home, put in ``takeoff`` by :meth:`with_takeoff` once the autopilot has told it
    (:func:`insulator_rs.flight.home.at_vehicle_home`, before anything is planned for a flight)."""

    source: str
    tower: GeoPoint
    max_height: float
    max_width: float
    neighbours: tuple[GeoPoint, ...]
    takeoff: GeoPoint | None
    vehicle: VehicleLimits
    inspection: InspectionParams
    rig: SensorRig | None = None  # the airframe's sensors; None: the file names none
    takeoff_home: bool = False  # [takeoff] = "home"

    def sensor_rig(self) -> SensorRig:
        """The rig this mission flies: the file's, or the shipped simulator rig when it names none."""
        return self.rig if self.rig is not None else simulator_rig()

    def neighbours_enu(self) -> np.ndarray:
        """Neighbour tower bases in W (N, 3), m."""
        return gps_to_enu(list(self.neighbours), self.tower)

    def line(self) -> LineFrame:
        """The tower's line frame in W."""
        return line_frame(self.neighbours_enu())

    def takeoff_enu(self) -> np.ndarray:
        """Take-off point in W (3,), m: the file's (or the vehicle's home it was given), or on the
        "+" side at the standoff, on the ground. A ``takeoff = "home"`` mission whose home is not
        known yet stands on that default point (the simulated airframe is put there); a flight
        takes the vehicle's home first."""
        if self.takeoff is not None:
            return gps_to_enu(self.takeoff, self.tower)
        lf = self.line()
        return lf.to_world(np.array([0.0, self.max_width / 2 + self.inspection.standoff, 0.0]))


    def with_takeoff(self, point: GeoPoint) -> Mission:
        """This mission taking off from ``point`` (the vehicle's home, for ``takeoff = "home"``),
        checked as the file's ``[takeoff]`` is (ConfigError naming ``takeoff``)."""
        _check_placement(_Reader(self.source), self.tower, [], point, field='takeoff ("home")')
        return replace(self, takeoff=point)


class _Reader:
    """Pulls typed, range-checked fields out of a parsed table, naming file and field on error."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, field: str, reason: str) -> ConfigError:
        return ConfigError(f"{self.source}: {field}: {reason}")

    def table(self, data: Any, field: str, *, required: bool = True) -> dict[str, Any] | None:
        if field not in data:
            if required:
                raise self.fail(field, "missing table")
            return None
        value = data[field]
        if not isinstance(value, dict):
            raise self.fail(field, f"expected a table, got {type(value).__name__}")
        return value

    def number(self, table: dict[str, Any], prefix: str, key: str, *, default: float | None = None,
               positive: bool = False, nonnegative: bool = False,
               lo: float | None = None, hi: float | None = None) -> float:
        field = f"{prefix}.{key}"
        if key not in table:
            if default is None:
                raise self.fail(field, "missing")
            return default
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(field, f"expected a number, got {_short(value)}")
        try:
            value = float(value)
        except OverflowError:  # a YAML integer such as 10**400
            raise self.fail(field, f"must be finite, got an integer of {len(str(value))} digits") from None
        if not math.isfinite(value):
            raise self.fail(field, f"must be finite, got {value}")
        if positive and value <= 0:
            raise self.fail(field, f"must be > 0, got {value}")
        if nonnegative and value < 0:
            raise self.fail(field, f"must be >= 0, got {value}")
        if lo is not None and value < lo or hi is not None and value > hi:
            raise self.fail(field, f"must lie in [{lo}, {hi}], got {value}")
        self.within_limit(field, value)
        return value

    def within_limit(self, field: str, value: float) -> None:
        """The field's limit in :data:`bounds.MISSION`, if it has one."""
        limit = bounds.field_limit(bounds.MISSION, field)
        problem = limit.problem(value) if limit is not None else None
        if problem is not None:
            raise self.fail(field, problem)

    def integer(self, table: dict[str, Any], prefix: str, key: str, *, default: int, lo: int) -> int:
        field = f"{prefix}.{key}"
        value = table.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(field, f"expected an integer, got {_short(value)}")
        if value < lo:
            raise self.fail(field, f"must be >= {lo}, got {value}")
        self.within_limit(field, value)
        return value

    def boolean(self, table: dict[str, Any], prefix: str, key: str, *, default: bool) -> bool:
        value = table.get(key, default)
        if not isinstance(value, bool):
            raise self.fail(f"{prefix}.{key}", f"expected true or false, got {_short(value)}")
        return value

    def geo(self, table: dict[str, Any], prefix: str) -> GeoPoint:
        return GeoPoint(
            lat=self.number(table, prefix, "lat", lo=-90.0, hi=90.0),
            lon=self.number(table, prefix, "lon", lo=-180.0, hi=180.0),
            alt=self.number(table, prefix, "alt", default=0.0),
        )

    def unknown(self, table: dict[str, Any], prefix: str, allowed: set[str]) -> None:
        # str(): YAML keys may be numbers, dates or None, which do not sort against strings.
        extra = sorted(str(k) for k in table if k not in allowed)
        if extra:
            raise self.fail(f"{prefix}.{extra[0]}", f"unknown field (allowed: {', '.join(sorted(allowed))})")


def _short(value: Any) -> str:
    """repr of a bad value, cut short (a YAML document can put a whole table in a field)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_placement(r: _Reader, tower: GeoPoint, neighbours: list[GeoPoint],
                     takeoff: GeoPoint | None, *, field: str = "takeoff") -> None:
    """Neighbours a span away, the take-off point near the tower (:mod:`bounds`)."""
    for i, nb in enumerate(neighbours):
        e, n, _ = gps_to_enu(nb, tower)
        problem = bounds.SPAN.problem(float(math.hypot(e, n)))
        if problem is not None:
            raise r.fail(f"neighbours[{i}]", f"horizontal distance from the tower {problem}")
    if takeoff is None:
        return
    e, n, _ = gps_to_enu(takeoff, tower)
    problem = bounds.TAKEOFF_DISTANCE.problem(float(math.hypot(e, n)))
    if problem is not None:
        raise r.fail(field, f"horizontal distance from the tower {problem}")
    problem = bounds.TAKEOFF_HEIGHT.problem(takeoff.alt - tower.alt)
    if problem is not None:
        raise r.fail(f"{field}.alt", f"height above the tower base {problem}")


def parse_mission(data: Any, source: str = "<mission>", base: Path | None = None) -> Mission:
    """Validate a parsed mission document (a dict) into a :class:`Mission`; ``source`` names it in
    errors, ``base`` is the folder its relative paths (the rig file) start from (None: the
    folder of ``source``, a file's path)."""
    r = _Reader(source)
    if not isinstance(data, dict):
        raise r.fail("<root>", f"expected a table, got {type(data).__name__}")
    r.unknown(data, "<root>", {"tower", "neighbours", "takeoff", "vehicle", "inspection"})
    tower_t = r.table(data, "tower")
    assert tower_t is not None
    r.unknown(tower_t, "tower", {"lat", "lon", "alt", "max_height", "max_width"})
    tower = r.geo(tower_t, "tower")
    max_height = r.number(tower_t, "tower", "max_height", positive=True)
    max_width = r.number(tower_t, "tower", "max_width", positive=True)

    if "neighbours" not in data:
        raise r.fail("neighbours", "missing (give one or two neighbouring towers)")
    nbs = data["neighbours"]
    if not isinstance(nbs, list) or not 1 <= len(nbs) <= 2:
        raise r.fail("neighbours", "expected a list of one or two tables")
    neighbours = []
    for i, nb in enumerate(nbs):
        if not isinstance(nb, dict):
            raise r.fail(f"neighbours[{i}]", "expected a table")
        r.unknown(nb, f"neighbours[{i}]", {"lat", "lon", "alt"})
        neighbours.append(r.geo(nb, f"neighbours[{i}]"))

    takeoff_home = data.get("takeoff") == TAKEOFF_HOME
    if "takeoff" in data and not takeoff_home and not isinstance(data["takeoff"], dict):
        raise r.fail("takeoff", f'expected a table (lat, lon, alt) or "{TAKEOFF_HOME}" (the vehicle\'s own '
                                f'home, read from the autopilot), got {_short(data["takeoff"])}')
    takeoff_t = None if takeoff_home else r.table(data, "takeoff", required=False)
    takeoff = None
    if takeoff_t is not None:
        r.unknown(takeoff_t, "takeoff", {"lat", "lon", "alt"})
        takeoff = r.geo(takeoff_t, "takeoff")

    veh_t = r.table(data, "vehicle")
    assert veh_t is not None
    keys = ("v_max_horizontal", "a_max_horizontal", "v_max_vertical", "a_max_vertical")
    r.unknown(veh_t, "vehicle", {*keys, "rig"})
    vehicle = VehicleLimits(*(r.number(veh_t, "vehicle", k, positive=True) for k in keys))
    rig = None
    if "rig" in veh_t:
        name = veh_t["rig"]
        if not isinstance(name, str) or not name.strip():
            raise r.fail("vehicle.rig", f"expected a rig file's path or a shipped rig's name, got {name!r}")
        try:
            rig = load_rig(resolve_rig(name, Path(source).resolve().parent if base is None else base))
        except ConfigError as exc:
            raise r.fail("vehicle.rig", str(exc)) from exc

    insp_t = r.table(data, "inspection")
    assert insp_t is not None
    d = InspectionParams(standoff=1.0, safety_margin=0.0)
    r.unknown(insp_t, "inspection", set(InspectionParams.__dataclass_fields__))
    inspection = InspectionParams(
        standoff=r.number(insp_t, "inspection", "standoff", positive=True),
        safety_margin=r.number(insp_t, "inspection", "safety_margin", nonnegative=True),
        inspection_distance=r.number(insp_t, "inspection", "inspection_distance",
                                     default=d.inspection_distance, positive=True),
        waypoints_per_insulator=r.integer(insp_t, "inspection", "waypoints_per_insulator",
                                          default=d.waypoints_per_insulator, lo=1),
        registry_gate=r.number(insp_t, "inspection", "registry_gate", default=d.registry_gate,
                               positive=True),
        pass_spacing=r.number(insp_t, "inspection", "pass_spacing", default=d.pass_spacing,
                              positive=True),
        crossing_clearance=r.number(insp_t, "inspection", "crossing_clearance",
                                    default=d.crossing_clearance, positive=True),
        insulator_length=r.number(insp_t, "inspection", "insulator_length",
                                  default=d.insulator_length, positive=True),
        confirmations=r.integer(insp_t, "inspection", "confirmations",
                                default=d.confirmations, lo=MIN_CONFIRMATIONS),
        battery_reserve=r.number(insp_t, "inspection", "battery_reserve", default=d.battery_reserve),
        photo_retakes=r.integer(insp_t, "inspection", "photo_retakes", default=d.photo_retakes, lo=0),
        lidar_cue=r.boolean(insp_t, "inspection", "lidar_cue", default=d.lidar_cue),
    )
    if inspection.standoff <= inspection.safety_margin:
        raise r.fail("inspection.standoff",
                     f"must exceed inspection.safety_margin ({inspection.safety_margin} m), "
                     f"or the exploration path would lie inside the safety volume")
    mission = Mission(source, tower, max_height, max_width, tuple(neighbours), takeoff,
                      vehicle, inspection, rig, takeoff_home=takeoff_home)
    try:
        mission.line()
    except ValueError as exc:
        raise r.fail("neighbours", str(exc)) from exc
    _check_placement(r, tower, neighbours, takeoff)
    return mission


def load_mission(path: str | Path) -> Mission:
    """Read and validate a TOML or YAML mission file."""
    p = Path(path)
    source = str(p)
    text = read_config_text(p, f"{source}: <file>")
    suffix = p.suffix.lower()
    if suffix not in (".toml", ".yaml", ".yml"):
        raise ConfigError(f"{source}: <file>: unknown mission file type {suffix!r} "
                          f"(use .toml, .yaml or .yml)")
    try:
        data: Any = tomllib.loads(text) if suffix == ".toml" else yaml.safe_load(text)
    except (tomllib.TOMLDecodeError, yaml.YAMLError) as exc:
        raise ConfigError(f"{source}: <file>: cannot parse: {exc}") from exc
    except (ValueError, OverflowError, RecursionError) as exc:
        # PyYAML's constructors: a date such as 2001-02-30, a too deeply nested document.
        raise ConfigError(f"{source}: <file>: cannot parse: {type(exc).__name__}: {exc}") from exc
    return parse_mission(data, source)
