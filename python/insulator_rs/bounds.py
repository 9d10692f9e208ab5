"""The one validation layer: physical and mission limits of every number a mission file,
a scene file or a command-line option may hold, each with the reason for it.

Unbounded values used to fly: ``max_height = 1e300`` or ``pass_spacing = 1e-9`` planned
passes forever, ``waypoints_per_insulator = 1e9`` exhausted memory mid-flight, ``--v-max 1e6``
hung the trajectory refinement, ``panels = 1e8`` hung the mesh builder. The limits below come
from physics and from the mission (a tower is not 1 km high, a multirotor does not fly
1e6 m/s, the take-off point is near the tower), so a value outside them is a mistake in the
file, never a real mission. The loaders look a field up here by its dotted name
(``inspection.pass_spacing``, ``cross_arms.height``: list indices dropped), so adding a field
means adding its limit here, and the message names the file, the field, the range and why.

Command-line options use :func:`option` as their argparse ``type``: argparse then reports
``argument --v-max: must lie in [0.1, 25] m/s (...), got 1e6`` and exits with status 2,
before anything flies, wherever the option is registered.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
from dataclasses import dataclass

_INDEX = re.compile(r"\[\d+\]")


@dataclass(frozen=True)
class Limit:
    """An allowed range ``[lo, hi]`` (``(lo, hi]`` when ``lo_open``) with its unit and reason."""

    lo: float
    hi: float
    unit: str
    why: str
    lo_open: bool = False
    integer: bool = False

    def describe(self) -> str:
        left = "(" if self.lo_open else "["
        unit = f" {self.unit}" if self.unit else ""
        return f"must lie in {left}{_number(self.lo)}, {_number(self.hi)}]{unit} ({self.why})"

    def problem(self, value: float) -> str | None:
        """None when ``value`` lies in the range, else the message (without the field name)."""
        inside = (value > self.lo if self.lo_open else value >= self.lo) and value <= self.hi
        if isinstance(value, float) and not math.isfinite(value):
            inside = False
        return None if inside else f"{self.describe()}, got {_number(value)}"


def _number(x: float) -> str:
    """A number for a message: integers in full (up to 12 digits), others in %g."""
    if isinstance(x, int):
        return str(x) if abs(x) < 10**12 else f"an integer of {len(str(abs(x)))} digits"
    return f"{x:g}"


# ---- shared physical reasons -------------------------------------------------------------
_ELEVATION = Limit(-500.0, 9000.0, "m", "ground elevations on Earth lie between the Dead Sea "
                   "(-430 m) and Everest (8849 m)")
# The lower speed limit is the airframe's hover-and-creep, not the planner's: re-planning from a
# moving start used to fail in the min-snap time scaling below 1 m/s ("v_start: no time scaling
# keeps the limits"); the planner now slows down first when it must, at any speed.
_V_HORIZONTAL = Limit(0.1, 10.0, "m/s", "the detector runs about once a second and must see an "
                      "insulator several times in one pass: tower B flown at 25 m/s found 0 of 4 "
                      "insulators, at 10 m/s 4 of 4 (measured); below 0.1 m/s a multirotor's "
                      "position hold wanders more than it moves")
_V_VERTICAL = Limit(0.1, 8.0, "m/s", "multirotors climb and descend at most about 6-8 m/s; below "
                    "0.1 m/s the altitude hold wanders more than it moves")
_ACCELERATION = Limit(0.1, 20.0, "m/s^2", "about 2 g, a multirotor's thrust-to-weight ratio")
_TOWER_HEIGHT = Limit(0.0, 400.0, "m", "the tallest transmission towers in service are about "
                      "380 m (Zhoushan crossing)", lo_open=True)
_LIDAR_RANGE = Limit(0.0, 40.0, "m", "the Livox Mid-360 sees a 10 %-reflective target to 40 m; "
                     "further away the tower gives no LiDAR returns", lo_open=True)

#: Limits of the mission file's numeric fields (``insulator_rs.mission.config``).
MISSION: dict[str, Limit] = {
    "tower.alt": _ELEVATION,
    "neighbours.alt": _ELEVATION,
    "takeoff.alt": _ELEVATION,
    "tower.max_height": _TOWER_HEIGHT,
    "tower.max_width": Limit(0.0, 120.0, "m", "the widest cross-arms of UHV towers span about "
                             "100 m", lo_open=True),
    "vehicle.v_max_horizontal": _V_HORIZONTAL,
    "vehicle.v_max_vertical": _V_VERTICAL,
    "vehicle.a_max_horizontal": _ACCELERATION,
    "vehicle.a_max_vertical": _ACCELERATION,
    "inspection.standoff": _LIDAR_RANGE,
    "inspection.safety_margin": Limit(0.0, 20.0, "m", "a margin wider than the standoff range "
                                      "leaves no room for the path"),
    "inspection.inspection_distance": Limit(0.5, 40.0, "m", "closer than 0.5 m the camera "
                                            "cannot focus; beyond 40 m the LiDAR cannot see"),
    "inspection.waypoints_per_insulator": Limit(1, 12, "", "each waypoint is a photo stop; more "
                                                "than 12 round one insulator multiplies the "
                                                "flight time for no new view", integer=True),
    "inspection.registry_gate": Limit(0.0, 3.0, "m", "phases of the smallest lines hang about 3 m "
                                      "apart: a wider gate merges neighbouring insulators",
                                      lo_open=True),
    "inspection.pass_spacing": Limit(0.5, 40.0, "m", "the Mid-360's 59 degree vertical field of "
                                     "view covers 40 m at the standoff; below 0.5 m the path has "
                                     "hundreds of redundant passes"),
    "inspection.crossing_clearance": Limit(0.0, 50.0, "m", "the crossing flies over the tower, "
                                           "not into the sky", lo_open=True),
    "inspection.insulator_length": Limit(0.1, 15.0, "m", "the longest strings (1000 kV UHV) are "
                                         "about 10-12 m"),
    # the registry's bound too (tracking/confirmation.py reads it)
    "inspection.confirmations": Limit(1, 20, "", "an insulator is seen by about 10-30 detection "
                                      "events per pass; more confirmations never register one",
                                      integer=True),
    "inspection.battery_reserve": Limit(0.1, 0.9, "of the pack", "below 10 % a LiPo sags under "
                                        "load and PX4's own critical and emergency actions "
                                        "(BAT_CRIT_THR 7 %, BAT_EMERGEN_THR 5 %) take the vehicle; "
                                        "keeping more than 90 % leaves no flight"),
    "inspection.photo_retakes": Limit(0, 5, "", "each retake is a hover at the waypoint; a photo "
                                      "still unfit after five more shots has a cause another shot "
                                      "does not cure (the camera, the detector, the framing)",
                                      integer=True),
}

#: Horizontal distance of the take-off point from the tower base, m.
TAKEOFF_DISTANCE = Limit(0.0, 500.0, "m", "the pilot keeps the aircraft in visual line of sight "
                         "and the transit to the tower is flown without obstacle knowledge")
#: Height of the take-off point above (or below) the tower base, m.
TAKEOFF_HEIGHT = Limit(-100.0, 100.0, "m", "the take-off point is on the ground near the tower")
#: Horizontal distance of a neighbouring tower from the inspected one, m.
SPAN = Limit(10.0, 6000.0, "m", "the longest spans in service are about 5.4 km (Ameralik); "
             "towers closer than 10 m are one structure")

#: Limits of the scene file's numeric fields (``insulator_rs.sim.scene``).
SCENE: dict[str, Limit] = {
    "body.height": _TOWER_HEIGHT,
    "body.base_width": Limit(0.0, 60.0, "m", "lattice tower bases are at most a few tens of metres "
                             "wide", lo_open=True),
    "body.top_width": Limit(0.0, 60.0, "m", "no wider than the base", lo_open=True),
    "body.panels": Limit(1, 100, "", "a lattice panel is 1-5 m high: 100 panels cover a 400 m "
                         "tower, and every panel is meshed", integer=True),
    "body.leg_size": Limit(0.0, 2.0, "m", "lattice members are angle sections below 0.5 m",
                           lo_open=True),
    "body.brace_size": Limit(0.0, 2.0, "m", "lattice members are angle sections below 0.5 m",
                             lo_open=True),
    "body.peak_height": Limit(0.0, 50.0, "m", "an earth-wire peak is a few metres high"),
    "cross_arms.height": _TOWER_HEIGHT,
    "cross_arms.reach": Limit(0.0, 60.0, "m", "the widest cross-arms of UHV towers span about "
                              "100 m tip to tip", lo_open=True),
    "cross_arms.depth": Limit(0.0, 20.0, "m", "a cross-arm is a few metres deep", lo_open=True),
    "cross_arms.width": Limit(0.0, 20.0, "m", "a cross-arm is a few metres wide", lo_open=True),
    "insulators.length": Limit(0.1, 15.0, "m", "the longest strings (1000 kV UHV) are about "
                               "10-12 m"),
    "insulators.sheds": Limit(2, 300, "", "composite strings carry about 10-20 sheds per metre, "
                              "and every shed is meshed", integer=True),
    "insulators.shed_radius": Limit(0.0, 1.0, "m", "sheds are at most a few decimetres across",
                                    lo_open=True),
    "insulators.small_shed_radius": Limit(0.0, 1.0, "m", "sheds are at most a few decimetres "
                                          "across", lo_open=True),
    "insulators.core_radius": Limit(0.0, 0.5, "m", "an insulator core is a few centimetres thick",
                                    lo_open=True),
    "insulators.shed_thickness": Limit(0.0, 0.5, "m", "a shed is a few centimetres thick",
                                       lo_open=True),
    "insulators.fitting_length": Limit(0.0, 5.0, "m", "end fittings are below a metre long"),
    "conductors.radius": Limit(0.0, 0.1, "m", "the thickest conductors are about 6 cm across",
                               lo_open=True),
    "conductors.catenary_parameter": Limit(10.0, 100000.0, "m", "H/w of real spans lies between "
                                           "a few hundred and a few thousand metres"),
    "conductors.modelled_length": Limit(0.0, 1000.0, "m", "beyond the LiDAR's range a conductor "
                                        "is not seen; it is meshed segment by segment",
                                        lo_open=True),
    "conductors.segment_length": Limit(0.05, 1000.0, "m", "shorter segments only multiply the "
                                       "mesh"),
    "conductors.jumper_sag": Limit(0.0, 10.0, "m", "a jumper loop sags a few metres at most"),
    "ground_size": Limit(0.0, 10000.0, "m", "the ground plane only needs to reach past the LiDAR "
                         "range", lo_open=True),
    "obstacles.radius": Limit(0.005, 10.0, "m", "from a guy wire (a centimetre) to the width of a "
                              "neighbouring structure"),
}
#: Most obstacles (poles, guy wires, structures beside the tower) in one scene.
MAX_OBSTACLES = 50
#: Shortest scene obstacle, m.
OBSTACLE_MIN_LENGTH = 0.1
#: Most cross-arms on one tower (the tallest double-circuit towers carry 6 plus peaks).
MAX_CROSS_ARMS = 12
#: Neighbour coordinates in a scene file, m from the inspected tower (see :data:`SPAN`).
SCENE_NEIGHBOUR = Limit(-SPAN.hi, SPAN.hi, "m", SPAN.why)

#: Limits of command-line options (argparse ``type``: :func:`option`).
OPTIONS: dict[str, Limit] = {
    "--v-max": _V_HORIZONTAL,
    "--a-max": _ACCELERATION,
    "--detect-period": Limit(0.05, 60.0, "s", "detection cannot run faster than the 20 Hz control "
                             "loop; slower than a minute it sees an insulator once a pass"),
    "--detect-scale": Limit(0.0, 1.0, "", "a fraction of the camera's resolution", lo_open=True),
    "--photo-scale": Limit(0.0, 1.0, "", "a fraction of the camera's resolution", lo_open=True),
    "--sim-camera-latency": Limit(0.0, 0.5, "s", "a simulated camera's frames stamped this late; "
                                  "the rig's [camera] latency_s allows at most half a second"),
    "--max-flight-time": Limit(0.0, 7200.0, "s", "no multirotor battery lasts two hours",
                               lo_open=True),
    "--sim-battery": Limit(0.0, 1.0, "of the pack", "a charge is a fraction of the full pack; 0 "
                           "cannot arm", lo_open=True),
    "--seed": Limit(0, 2**32 - 1, "", "numpy seeds are non-negative; 32 bits are plenty",
                    integer=True),
    "--threads": Limit(1, 256, "", "more threads than cores only contend (23k threads took "
                       "16.8 GB); 256 covers any companion computer", integer=True),
    "--wind": Limit(0.0, 20.0, "m/s", "inspection multirotors are rated for 12-15 m/s of wind; "
                    "nobody inspects a tower in a gale"),
    "--wind direction": Limit(-360.0, 360.0, "deg", "where the wind blows from, clockwise from "
                              "north"),
    "--false-positives": Limit(0.0, 20.0, "per image", "a real detector at confidence 0.25 gives "
                               "a handful; 20 per image already drowns the localization"),
}


def field_limit(table: dict[str, Limit], field: str) -> Limit | None:
    """The limit of a dotted field (``neighbours[1].alt`` looks up ``neighbours.alt``)."""
    return table.get(_INDEX.sub("", field))


def option(flag: str) -> Callable[[str], float]:
    """An argparse ``type`` for ``flag``: parses the number and checks :data:`OPTIONS`."""
    limit = OPTIONS[flag]

    def parse(text: str) -> float:
        try:
            value: float = int(text) if limit.integer else float(text)
        except ValueError:
            kind = "an integer" if limit.integer else "a number"
            raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}") from None
        problem = limit.problem(value)
        if problem is not None:
            raise argparse.ArgumentTypeError(problem)
        return value

    parse.__name__ = flag.lstrip("-").replace("-", "_")
    return parse


def wind_option(text: str) -> tuple[float, float]:
    """An argparse ``type`` for ``--wind SPEED[,DIR_DEG]``: (speed m/s, from-direction deg
    clockwise from north; 0, a northerly, when not given), each checked against :data:`OPTIONS`."""
    parts = text.split(",")
    if len(parts) > 2:
        raise argparse.ArgumentTypeError(f"expected SPEED or SPEED,DIR_DEG, got {text!r}")
    values = []
    for flag, part in zip(("--wind", "--wind direction"), parts):
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag}: expected a number, got {part!r}") from None
        problem = OPTIONS[flag].problem(value)
        if problem is not None:
            raise argparse.ArgumentTypeError(f"{flag}: {problem}")
        values.append(value)
    return values[0], values[1] if len(values) > 1 else 0.0
