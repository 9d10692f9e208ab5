"""The pre-flight gate: before arming, every check named, with its outcome and its reason.

The flight loop runs :func:`preflight_checks` after the autopilot's parameters are set and before
the arm command (:meth:`insulator_rs.flight.autopilot_session.AutopilotSession.preflight`); one
failed check refuses the flight, and the refusal names every check that failed (the console, the
GCS's STATUSTEXT, summary.json's ``status`` ``refused_preflight: ...`` and its ``preflight``
record). The checks read only what the ports already expose:

* ``sensors``: every sensor streaming and stamped: the camera and the LiDAR each delivered
  something stamped on the vehicle clock, no older than STREAM_MAX_AGE and not ahead of it
  (``Sensors.streams``, which consumes nothing; see :class:`~insulator_rs.ports.sensors.StreamStatus`),
  looked at again for up to SENSORS_WAIT s (a sensor just started, or late on a loaded computer);
* ``clock``: the clock the stamps come from mapped to the vehicle's (MAVLink TIMESYNC, or the
  telemetry fallback of live sensors), waited for up to CLOCK_WAIT s;
* ``gps_home``: a 3D GPS fix (GPS_RAW_INT), a global position estimate and a home position
  (:class:`~insulator_rs.ports.vehicle.NavigationStatus`);
* ``home``: the vehicle stands on the mission's take-off point: PX4's home (HOME_POSITION; the
  in-process vehicle's own position) within HOME_MAX_DISTANCE across and HOME_MAX_HEIGHT_OFF in
  height of it (:mod:`insulator_rs.flight.home`); the mission's ground, landing point and pass
  heights are planned from that point. ``takeoff = "home"`` in the mission plans them from the home;
* ``detector``: a detector there, and a network one that runs (one blank frame through it);
* ``battery``: the charge above the mission's reserve holds what the exploration path and the
  landing take, at the airframe class's nominal rates (:mod:`insulator_rs.planning.energy`)
  with the reserve watch's ESTIMATE_MARGIN;
* ``geofence``: the mission inside the autopilot's geofence: GF_MAX_HOR_DIST / GF_MAX_VER_DIST
  as read back from the autopilot now, against the mission's extent from home
  (:func:`~insulator_rs.planning.px4_failsafes.mission_extent`) and PX4's own return altitude.

A check with no data source in a path is ``not_applicable``, with the reason; it neither passes
nor refuses (the report says so), as a pilot would expect of the in-process simulator: it has no
GPS receiver and no home (its positions are the simulator's own), no clock but the one every
stamp is in, and no autopilot geofence. The ground-truth stand-in has no model to load.
"""

from __future__ import annotations

import math
import time as wallclock
from dataclasses import dataclass
from enum import Enum
from collections.abc import Callable
from typing import Any

import numpy as np

from insulator_rs.exceptions import ParameterError, PreflightRefused
from insulator_rs.flight.home import vehicle_home
from insulator_rs.flight.pilot import LAND_HEIGHT
from insulator_rs.flight.record import timesync_record
from insulator_rs.geodesy import GeoPoint, enu_to_gps
from insulator_rs.mission.config import TAKEOFF_HOME
from insulator_rs.flight.reserve import ESTIMATE_MARGIN, READING_STEP
from insulator_rs.planning.energy import RouteDemand, nominal_consumed
from insulator_rs.planning.px4_failsafes import mission_extent
from insulator_rs.planning.safety import SafetyVolumes
from insulator_rs.ports.capabilities import MapsClock
from insulator_rs.ports.detector import NetworkDetector, detector_name
from insulator_rs.ports.sensors import sensor_streams
from insulator_rs.ports.vehicle import GPS_3D_FIX, Vehicle, vehicle_navigation, vehicle_parameters

# s: the newest datum of a stream may be this old at the check (a Mid-360 scan every 0.1 s,
# cameras at 10 fps and more: ten periods; a live driver's newest complete scan ends 5-105 ms
# before now)
STREAM_MAX_AGE = 1.0
# s a stamp may lie ahead of the vehicle clock (the telemetry's own 20 ms sample period)
STAMP_AHEAD_TOLERANCE = 0.05
# wall s to wait for a clock map: the MAVLink client's TIMESYNC is ready after 5 exchanges
# at 10 Hz (0.5 s after connecting); an autopilot that answers none is told in 3 s
CLOCK_WAIT = 3.0
CLOCK_POLL = 0.05  # wall s between looks at the clock map while waiting
# wall s to wait for every sensor to be fresh at once: a Mid-360 just started, its clock map a few
# seconds old, or a loaded computer whose receive thread is a second behind (the live SITL head's
# scans left 0.25 s late at the median, 1.1 s at the 99th percentile) is streaming, only late;
# one look refused such a flight. A sensor that stays silent or stale this long is refused.
SENSORS_WAIT = 10.0
SENSORS_POLL = 0.2  # wall s between looks at the streams while waiting
SENSORS_NEEDED = ("camera", "lidar")  # detection frames and the points that localize them
# m: the farthest the vehicle's home may stand from the mission's take-off point, horizontally. A
# GNSS home wanders 1-3 m (a consumer receiver's CEP95 is about 2.5 m): a vehicle set down on the
# planned point is not refused for its receiver's noise. The default take-off point lies the
# standoff (8 m in the shipped missions) beyond the tower's widest extent, 6 m outside its 2 m
# safety margin: a vehicle within 5 m of it still climbs outside the safety volumes.
HOME_MAX_DISTANCE = 5.0
# m: the most the home may lie above or below the take-off point. The landing approach ends
# LAND_HEIGHT (2 m) above the take-off point: with the ground 2 m higher it would fly into it, so
# half of it, 1 m, is kept. (The obstacle map leaves out returns less than GROUND_BAND (1.5 m)
# above the take-off point, and ground returns scatter up to 1.2 m high: ground more than 0.3 m
# higher can enter the map and bend or refuse legs near the ground: a mission lost, not an unsafe
# one. takeoff = "home" plans from the home itself and avoids both.)
HOME_MAX_HEIGHT_OFF = LAND_HEIGHT / 2
PROBE_IMAGE_SIDE = 64  # px of the blank frame a network is run on (the letterbox takes any size)
GPS_FIX_NAMES = {0: "no GPS", 1: "no fix", 2: "2D fix", 3: "3D fix", 4: "DGPS", 5: "RTK float",
                 6: "RTK fixed", 7: "static", 8: "PPP"}  # MAVLink GPS_FIX_TYPE


class Check(str, Enum):
    """The pre-flight checks, in the order they are reported."""

    SENSORS = "sensors"
    CLOCK = "clock"
    GPS_HOME = "gps_home"
    HOME = "home"
    DETECTOR = "detector"
    BATTERY = "battery"
    GEOFENCE = "geofence"


class Outcome(str, Enum):
    PASSED = "passed"
    FAILED = "failed"
    NOT_APPLICABLE = "not_applicable"  # no data source in this path: neither a pass nor a refusal


@dataclass(frozen=True)
class CheckResult:
    check: Check
    outcome: Outcome
    reason: str


@dataclass(frozen=True)
class PreflightResult:
    """Every check's result; ``passed`` unless one failed."""

    checks: tuple[CheckResult, ...]

    @property
    def failed(self) -> list[CheckResult]:
        return [c for c in self.checks if c.outcome == Outcome.FAILED]

    @property
    def passed(self) -> bool:
        return not self.failed

    def refusal(self) -> PreflightRefused:
        """The exception that refuses the flight, naming every failed check."""
        return PreflightRefused([(c.check.value, c.reason) for c in self.failed])

    def as_record(self) -> dict[str, Any]:
        """summary.json's ``preflight``."""
        return {"passed": self.passed,
                "checks": [{"name": c.check.value, "outcome": c.outcome.value, "reason": c.reason}
                           for c in self.checks]}


def _result(check: Check, problems: list[str], ok: str) -> CheckResult:
    if problems:
        return CheckResult(check, Outcome.FAILED, "; ".join(problems))
    return CheckResult(check, Outcome.PASSED, ok)


def check_sensors_waiting(sensors: object, vehicle_time: Callable[[], float], *,
                          wait: float = SENSORS_WAIT) -> CheckResult:
    """:func:`check_sensors` at the vehicle's time of each look (``vehicle_time``), looked at
    again every SENSORS_POLL wall s until it passes or ``wait`` wall s are over (the last look's
    result is the check's; one that waited says how long)."""
    start = wallclock.monotonic()
    result = check_sensors(sensors, vehicle_time())
    while result.outcome is Outcome.FAILED and wallclock.monotonic() - start < wait:
        wallclock.sleep(SENSORS_POLL)
        result = check_sensors(sensors, vehicle_time())
    waited = wallclock.monotonic() - start
    if result.outcome is Outcome.PASSED and waited >= SENSORS_POLL:
        return CheckResult(result.check, result.outcome, f"{result.reason} (after {waited:.1f} s)")
    if result.outcome is Outcome.FAILED and waited >= SENSORS_POLL:
        return CheckResult(result.check, result.outcome, f"{result.reason} (for {waited:.1f} s)")
    return result


def check_sensors(sensors: object, now: float) -> CheckResult:
    """Every sensor the flight needs streaming, stamped on the vehicle clock, fresh at ``now``."""
    streams = sensor_streams(sensors, now)
    if streams is None:
        return CheckResult(Check.SENSORS, Outcome.FAILED,
                           f"the sensors ({type(sensors).__name__}) cannot say whether they stream")
    by_name = {s.name: s for s in streams}
    problems, fine = [], []
    for name in SENSORS_NEEDED:
        s = by_name.get(name)
        if s is None:
            problems.append(f"no {name}")
        elif s.error is not None:
            problems.append(f"{name}: {s.error}")
        elif s.delivered == 0 or s.newest is None:
            problems.append(f"{name}: nothing received" + (f" ({s.unstamped} unstamped)" if s.unstamped else ""))
        elif not math.isfinite(s.newest):
            problems.append(f"{name}: its newest datum is not stamped")
        elif s.newest > now + STAMP_AHEAD_TOLERANCE:
            problems.append(f"{name}: stamped {s.newest - now:.2f} s ahead of the vehicle clock")
        elif now - s.newest > STREAM_MAX_AGE:
            problems.append(f"{name}: silent for {now - s.newest:.1f} s (newest at {s.newest:.2f} s)")
        else:
            fine.append(f"{name} {s.delivered} delivered, newest {now - s.newest:.2f} s old")
    # a further device the rig names (the inspection camera's MAVLink payload): flown only when it
    # answers, since a flight without it would bring back no inspection photo
    for s in streams:
        if s.name not in SENSORS_NEEDED:
            if s.error is not None:
                problems.append(f"{s.name}: {s.error}")
            else:
                fine.append(f"{s.name} answering")
    return _result(Check.SENSORS, problems, ", ".join(fine))


def check_clock(vehicle: object, sensors: object, *, wait: float = CLOCK_WAIT) -> CheckResult:
    """The clock the stamps come from mapped to the vehicle clock (waited for up to ``wait`` s)."""
    if not any(isinstance(port, MapsClock) for port in (sensors, vehicle)):
        # the in-process vehicle: its time is the clock the simulated sensors are rendered and
        # stamped in; there is no second clock to map
        return CheckResult(Check.CLOCK, Outcome.NOT_APPLICABLE,
                           "one clock: the in-process vehicle's time stamps the sensors directly")
    deadline = wallclock.monotonic() + wait
    record = timesync_record(vehicle, sensors)
    while record.source == "none" and wallclock.monotonic() < deadline:
        wallclock.sleep(CLOCK_POLL)
        record = timesync_record(vehicle, sensors)
    if record.source == "timesync":
        rtt = "" if record.rtt_ms is None else f", round trip {record.rtt_ms:.1f} ms"
        return CheckResult(Check.CLOCK, Outcome.PASSED, f"TIMESYNC: {record.exchanges} exchanges{rtt}")
    if record.source == "telemetry":
        return CheckResult(Check.CLOCK, Outcome.PASSED,
                           "the autopilot answers no TIMESYNC: mapped from its telemetry stamps (less exact)")
    return CheckResult(Check.CLOCK, Outcome.FAILED,
                       f"no clock map to the vehicle: the autopilot answered no TIMESYNC within {wait:g} s "
                       f"({record.exchanges} exchanges, {record.rejected} rejected)")


def check_gps_home(vehicle: object) -> CheckResult:
    """A 3D GPS fix, a global position estimate and a home position, as the autopilot says."""
    nav = vehicle_navigation(vehicle)
    if nav is None:
        # the in-process simulator: no GPS receiver and no home; its positions in W are the
        # simulator's own (a GPS glitch or a position loss is injected into them, not into a fix)
        return CheckResult(Check.GPS_HOME, Outcome.NOT_APPLICABLE,
                           "the in-process vehicle has no GPS and no home: its positions are the simulator's")
    problems, fine = [], []
    if nav.gps_fix_type is not None:
        name = GPS_FIX_NAMES.get(nav.gps_fix_type, f"fix type {nav.gps_fix_type}")
        sats = "" if nav.satellites is None else f", {nav.satellites} satellites"
        if nav.gps_fix_type >= GPS_3D_FIX:
            fine.append(f"GPS {name}{sats}")
        else:
            problems.append(f"no 3D GPS fix ({name}{sats})")
    if nav.global_position is None:
        problems.append("no global position estimate")
    elif nav.gps_fix_type is None:
        fine.append("a global position (no GPS_RAW_INT to read the fix from)")
    if nav.home is None:
        problems.append("no home position set")
    else:
        fine.append(f"home at {nav.home[0]:.6f} {nav.home[1]:.6f} {nav.home[2]:.1f} m")
    return _result(Check.GPS_HOME, problems, ", ".join(fine))


def _decimetres(value: float) -> float:
    """``value`` rounded to 0.1, without a minus on zero (the earth's curve puts a point 13 m
    away at the same altitude 13 um below W's horizon: "-0.0" would read as a fault)."""
    return round(float(value), 1) + 0.0


def _where(local: np.ndarray, gps: GeoPoint) -> str:
    e, n, u = (_decimetres(c) for c in local)
    return f"{gps.lat:.7f} {gps.lon:.7f} {gps.alt:.1f} m (W [{e:.1f}, {n:.1f}, {u:.1f}])"


def check_home(vehicle: Vehicle, takeoff: np.ndarray, origin: GeoPoint) -> CheckResult:
    """The vehicle's home (:func:`~insulator_rs.flight.home.vehicle_home`) within HOME_MAX_DISTANCE
    across and HOME_MAX_HEIGHT_OFF in height of the mission's ``takeoff`` point (W); ``origin``:
    W's origin in WGS-84 (the tower base). The reason names both points and the distance."""
    home = vehicle_home(vehicle, origin)
    if home is None:
        return CheckResult(Check.HOME, Outcome.FAILED,
                           "no home position from the autopilot to compare with the mission's take-off point")
    takeoff = np.asarray(takeoff, dtype=np.float64).reshape(3)
    offset = home.local - takeoff
    across, height = float(np.hypot(offset[0], offset[1])), float(offset[2])
    what = (f"{home.source} at {_where(home.local, home.gps)} is {across:.1f} m across and "
            f"{_decimetres(height):+.1f} m in "
            f"height from the mission's take-off point at {_where(takeoff, enu_to_gps(takeoff, origin))}")
    limits = f"at most {HOME_MAX_DISTANCE:g} m across and {HOME_MAX_HEIGHT_OFF:g} m in height"
    if across > HOME_MAX_DISTANCE or abs(height) > HOME_MAX_HEIGHT_OFF:
        return CheckResult(Check.HOME, Outcome.FAILED,
                           f"{what}, {limits}: set the vehicle down on the take-off point, or give "
                           f'takeoff = "{TAKEOFF_HOME}" in the mission to plan from where it stands')
    return CheckResult(Check.HOME, Outcome.PASSED, f"{what} ({limits})")


def check_detector(detector: object) -> CheckResult:
    """A detector there; a network one must run (one blank frame through its session)."""
    if detector is None:
        return CheckResult(Check.DETECTOR, Outcome.FAILED, "no detector loaded")
    if not callable(detector):
        return CheckResult(Check.DETECTOR, Outcome.FAILED, f"{detector_name(detector)} is not a detector")
    if not isinstance(detector, NetworkDetector):
        return CheckResult(Check.DETECTOR, Outcome.NOT_APPLICABLE,
                           f"{detector_name(detector)}: no network to load (the simulator's stand-in)")
    image = np.zeros((PROBE_IMAGE_SIDE, PROBE_IMAGE_SIDE, 3), dtype=np.uint8)
    t0 = wallclock.perf_counter()
    try:
        # the network itself, not the port: the sanitiser's flight counts stay the flight's
        boxes = np.asarray(detector.network(image).boxes)
    except Exception as exc:  # noqa: BLE001  (whatever the runtime raises is the reason to refuse)
        return CheckResult(Check.DETECTOR, Outcome.FAILED,
                           f"network {detector.name} does not run: {type(exc).__name__}: {exc}")
    if boxes.ndim != 2 or boxes.shape[1] != 4:
        return CheckResult(Check.DETECTOR, Outcome.FAILED,
                           f"network {detector.name} returned boxes of shape {boxes.shape}, not (M, 4)")
    return CheckResult(Check.DETECTOR, Outcome.PASSED,
                       f"network {detector.name} runs ({1e3 * (wallclock.perf_counter() - t0):.0f} ms a frame)")


def check_battery(fraction: float | None, demand: RouteDemand, reserve: float) -> CheckResult:
    """The charge above ``reserve`` holds ``demand`` (the exploration and the landing) at the
    nominal rates with ESTIMATE_MARGIN; the inspections come on top, and the reserve watch
    brings the vehicle back in time for them in flight."""
    if fraction is None:
        return CheckResult(Check.BATTERY, Outcome.FAILED,
                           "the vehicle reports no charge (no BATTERY_STATUS / SYS_STATUS, or -1: unknown)")
    needed = ESTIMATE_MARGIN * nominal_consumed(demand)
    available = fraction - READING_STEP / 2 - reserve
    what = (f"charge {fraction:.0%}: the exploration path and landing ({demand.time_s:.0f} s, "
            f"{demand.distance_m:.0f} m) need {needed:.1%} above the {reserve:.0%} reserve")
    if needed > available:
        return CheckResult(Check.BATTERY, Outcome.FAILED, f"{what}, {max(available, 0.0):.1%} is there")
    return CheckResult(Check.BATTERY, Outcome.PASSED, f"{what}, {available:.1%} is there")


def check_geofence(vehicle: object, volumes: SafetyVolumes, mission_points: np.ndarray,
                   home: np.ndarray) -> CheckResult:
    """The mission (its extent from ``home``, W) and PX4's own return altitude inside the
    geofence the autopilot holds now (read back, not assumed from what was set)."""
    store = vehicle_parameters(vehicle)
    if store is None:
        # the in-process vehicle has no autopilot and no geofence; the planner keeps every
        # trajectory out of the mission's volumes, which is not a fence round a runaway
        return CheckResult(Check.GEOFENCE, Outcome.NOT_APPLICABLE,
                           "the in-process vehicle has no autopilot geofence")
    try:
        fence_h, fence_v, rtl = (float(store.read(n)) for n in ("GF_MAX_HOR_DIST", "GF_MAX_VER_DIST",
                                                                 "RTL_RETURN_ALT"))
    except ParameterError as exc:
        return CheckResult(Check.GEOFENCE, Outcome.FAILED, f"the geofence cannot be read: {exc}")
    horizontal, height = mission_extent(volumes, home, mission_points)
    problems = []
    for name, fence, reach, what in (("GF_MAX_HOR_DIST", fence_h, horizontal, "from home"),
                                     ("GF_MAX_VER_DIST", fence_v, max(height, rtl),
                                      "above home (the mission, or PX4's return altitude)")):
        if fence <= 0.0:
            problems.append(f"{name} {fence:g}: no geofence")  # PX4: 0 (or less) disables it
        elif reach > fence:
            problems.append(f"the mission reaches {reach:.1f} m {what}, beyond {name} {fence:g} m")
    return _result(Check.GEOFENCE, problems,
                   f"the mission reaches {horizontal:.1f} m from home (GF_MAX_HOR_DIST {fence_h:g} m) and "
                   f"{max(height, rtl):.1f} m above it (GF_MAX_VER_DIST {fence_v:g} m)")


def preflight_checks(vehicle: Vehicle, sensors: object, detector: object, *, demand: RouteDemand,
                     reserve: float, volumes: SafetyVolumes, mission_points: np.ndarray, takeoff: np.ndarray,
                     origin: GeoPoint, clock_wait: float = CLOCK_WAIT,
                     sensors_wait: float = SENSORS_WAIT) -> PreflightResult:
    """Every check (see the module docstring), each evaluated whatever the others gave.
    ``demand``: the exploration path and landing of the mission; ``reserve``: the mission's
    battery reserve; ``volumes`` and ``mission_points`` (N, 3) W: the mission's extent;
    ``takeoff`` (3,) W: the mission's take-off point, ``origin``: W's origin in WGS-84 (the tower
    base). The geofence's home is where the vehicle stands (PX4 sets it there at arming)."""
    # the clock first: the sensors' stamps are in the vehicle time it maps to
    clock = check_clock(vehicle, sensors, wait=clock_wait)
    sensors_result = check_sensors_waiting(sensors, lambda: vehicle.state().time, wait=sensors_wait)
    st = vehicle.state()
    return PreflightResult((
        sensors_result,
        clock,
        check_gps_home(vehicle),
        check_home(vehicle, takeoff, origin),
        check_detector(detector),
        check_battery(st.battery_fraction, demand, reserve),
        check_geofence(vehicle, volumes, mission_points, st.position),
    ))
