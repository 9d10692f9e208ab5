"""Declarative description of a power-line tower scene, loaded from TOML.

A scene file describes one inspected tower standing at the origin of the world
frame W (local ENU, metres, z up): its lattice body, its cross-arms, the
insulator strings hanging from the cross-arm tips, the conductors and the
positions of the two neighbouring towers (which define the line direction).
``insulator_rs.sim.towers.build_tower`` turns a :class:`SceneSpec` into a
triangle mesh plus the ground truth of every insulator, so a new tower type is a
new TOML file, not new code.

Every error raised while loading names the file and the dotted field, e.g.
``tower_a.toml: field 'cross_arms[1].height': must be below body.height (28.0 m), got 31.0``.
Every number is also checked against its physical limit in :mod:`insulator_rs.bounds`
(a lattice tower of 1e8 panels would hang the mesh builder).
"""

from __future__ import annotations

import math
from insulator_rs._toml import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from insulator_rs.exceptions import ConfigError
from insulator_rs import bounds
from insulator_rs.textfile import read_config_text

InsulatorKind = Literal["strain", "suspension"]
INSULATOR_KINDS: tuple[str, ...] = ("strain", "suspension")

SCENES_DIR = Path(__file__).resolve().parent.parent / "scenes"
#: Most meshed cylinder segments per conductor span (80 m of 1 m segments in the built-in scenes).
MAX_CONDUCTOR_SEGMENTS = 2000


class SceneError(ConfigError):
    """A scene description is missing a field or holds an invalid or contradictory value."""


@dataclass(frozen=True)
class BodySpec:
    """The lattice body of the tower (square section, tapering upward).

    height: m, top of the body above ground. base_width / top_width: m, distance
    between the leg axes at the ground and at the top. panels: number of
    X-braced panels from the ground to the top. leg_size / brace_size: m, side
    of the square section used for legs and bracing members. peak_height: m of
    the earth-wire peak above the body top (0 = none).
    """

    height: float
    base_width: float
    top_width: float
    panels: int
    leg_size: float
    brace_size: float
    peak_height: float


@dataclass(frozen=True)
class CrossArmSpec:
    """A lattice cross-arm reaching out on both sides of the line (lateral axis).

    height: m, height of the arm's lower chord. reach: m, horizontal distance
    from the tower axis to each tip. depth: m, vertical depth of the arm where
    it meets the body (it tapers to a point at the tip). width: m, extent of the
    arm along the line at the body.
    """

    height: float
    reach: float
    depth: float
    width: float


@dataclass(frozen=True)
class InsulatorSpec:
    """Shape and placement of every insulator string (one set per tower).

    kind: "strain" (two nearly horizontal strings per arm tip, one toward each
    neighbouring tower, drooping by tilt_deg below horizontal) or "suspension"
    (one vertical string hanging from each arm tip). length: m, end to end of
    the shed stack. sheds: number of large sheds; a small shed sits between
    consecutive large ones (alternating radii, as on composite insulators).
    shed_radius / small_shed_radius / core_radius: m. shed_thickness: m, axial
    height of one shed (a cone frustum from its root on the core to its skirt).
    fitting_length: m of the metal fitting between the arm (or conductor) and
    the shed stack at each end.
    """

    kind: InsulatorKind
    length: float
    sheds: int
    shed_radius: float
    small_shed_radius: float
    core_radius: float
    shed_thickness: float
    fitting_length: float
    tilt_deg: float


@dataclass(frozen=True)
class ConductorSpec:
    """Phase conductors from each insulator's free end to the neighbouring towers.

    radius: m. catenary_parameter: m, a = H/w of the catenary y = a cosh(x/a)
    (larger = tighter). modelled_length: m of each span that is meshed
    (the rest is beyond LiDAR range and thinner than a pixel). segment_length:
    m per cylinder segment. jumper_sag: m, sag of the jumper loop joining the two
    strain strings of one arm tip (strain towers only).
    """

    radius: float
    catenary_parameter: float
    modelled_length: float
    segment_length: float
    jumper_sag: float


@dataclass(frozen=True)
class ObstacleSpec:
    """Something beside the tower that its model (GPS, maximum height and width) does not hold:
    a pole, a guy wire, a mast, a straight piece of a neighbouring structure. A cylinder in W
    from ``start`` to ``end`` (m) of ``radius`` (m); ``name`` for messages and the mesh."""

    name: str
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    radius: float


@dataclass(frozen=True)
class SceneSpec:
    """One inspected tower at the origin of W, its neighbours and the ground.

    neighbours: the two neighbouring towers' base positions in W (m); the line
    direction is the horizontal unit vector from the first to the second.
    ground_size: m, side of the square ground plane centred on the tower.
    """

    name: str
    source: str
    neighbours: tuple[tuple[float, float, float], tuple[float, float, float]]
    body: BodySpec
    cross_arms: tuple[CrossArmSpec, ...]
    insulators: InsulatorSpec
    conductors: ConductorSpec
    ground_size: float
    obstacles: tuple[ObstacleSpec, ...] = ()

    @property
    def line_direction(self) -> tuple[float, float, float]:
        """Horizontal unit vector along the line in W (from neighbour 0 to neighbour 1)."""
        (x0, y0, _), (x1, y1, _) = self.neighbours
        n = math.hypot(x1 - x0, y1 - y0)
        return ((x1 - x0) / n, (y1 - y0) / n, 0.0)

    @property
    def lateral_direction(self) -> tuple[float, float, float]:
        """Horizontal unit vector across the line (line x z, to the right when looking along
        the line): the '+' side of the tower. [lateral, line, up] is right-handed."""
        dx, dy, _ = self.line_direction
        return (dy, -dx, 0.0)


def _finite(c: int | float) -> bool:
    """Whether ``c`` is a finite float (a TOML integer beyond float's range is not)."""
    try:
        return math.isfinite(float(c))
    except OverflowError:
        return False


class _Fields:
    """Typed access to one TOML table; every error names the file and the dotted field."""

    def __init__(self, table: dict[str, Any], source: str, prefix: str) -> None:
        self.table = table
        self.source = source
        self.prefix = prefix

    def error(self, name: str, reason: str) -> SceneError:
        return SceneError(f"{self.source}: field '{self.prefix}{name}': {reason}")

    def within_limit(self, name: str, value: float) -> None:
        """The field's limit in :data:`bounds.SCENE`, if it has one."""
        limit = bounds.field_limit(bounds.SCENE, f"{self.prefix}{name}")
        problem = limit.problem(value) if limit is not None else None
        if problem is not None:
            raise self.error(name, problem)

    def _raw(self, name: str, default: Any) -> Any:
        if name in self.table:
            return self.table[name]
        if default is None:
            raise self.error(name, "missing")
        return default

    def number(self, name: str, *, default: float | None = None, minimum: float | None = None,
               positive: bool = False) -> float:
        value = self._raw(name, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(name, f"must be a number, got {value!r}")
        try:
            value = float(value)
        except OverflowError:  # an integer beyond float range
            raise self.error(name, f"must be finite, got an integer of {len(str(value))} digits") from None
        if not math.isfinite(value):
            raise self.error(name, f"must be finite, got {value}")
        if positive and value <= 0.0:
            raise self.error(name, f"must be > 0, got {value}")
        if minimum is not None and value < minimum:
            raise self.error(name, f"must be >= {minimum}, got {value}")
        self.within_limit(name, value)
        return value

    def integer(self, name: str, *, minimum: int) -> int:
        value = self._raw(name, None)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(name, f"must be an integer, got {value!r}")
        if value < minimum:
            raise self.error(name, f"must be >= {minimum}, got {value}")
        self.within_limit(name, value)
        return value

    def string(self, name: str, *, choices: tuple[str, ...] | None = None) -> str:
        value = self._raw(name, None)
        if not isinstance(value, str) or not value:
            raise self.error(name, f"must be a non-empty string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(name, f"must be one of {', '.join(choices)}, got {value!r}")
        return value

    def sub(self, name: str) -> _Fields:
        value = self._raw(name, None)
        if not isinstance(value, dict):
            raise self.error(name, f"must be a table, got {type(value).__name__}")
        return _Fields(value, self.source, f"{self.prefix}{name}.")

    def sub_list(self, name: str, *, most: int = bounds.MAX_CROSS_ARMS,
                 why: str = "the tallest double-circuit towers carry 6 cross-arms") -> list[_Fields]:
        value = self._raw(name, None)
        if not isinstance(value, list) or not value or not all(isinstance(v, dict) for v in value):
            raise self.error(name, "must be a non-empty array of tables ([[...]])")
        if len(value) > most:
            raise self.error(name, f"at most {most} tables ({why}), got {len(value)}")
        return [_Fields(v, self.source, f"{self.prefix}{name}[{i}].") for i, v in enumerate(value)]

    def point(self, value: Any, name: str) -> tuple[float, float, float]:
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in value)
                or not all(_finite(c) for c in value)):
            raise self.error(name, f"must be [x, y, z] of 3 finite numbers, got {value!r}")
        for c in value:
            problem = bounds.SCENE_NEIGHBOUR.problem(float(c))
            if problem is not None:
                raise self.error(name, f"each coordinate {problem}")
        return (float(value[0]), float(value[1]), float(value[2]))

    def reject_unknown(self, known: tuple[str, ...]) -> None:
        # A typo in an optional field would otherwise silently use the default.
        for key in self.table:
            if key not in known:
                raise self.error(str(key), f"unknown field (known: {', '.join(known)})")


def _parse_body(f: _Fields) -> BodySpec:
    f.reject_unknown(("height", "base_width", "top_width", "panels", "leg_size", "brace_size",
                      "peak_height"))
    body = BodySpec(
        height=f.number("height", positive=True),
        base_width=f.number("base_width", positive=True),
        top_width=f.number("top_width", positive=True),
        panels=f.integer("panels", minimum=1),
        leg_size=f.number("leg_size", positive=True),
        brace_size=f.number("brace_size", positive=True),
        peak_height=f.number("peak_height", default=0.0, minimum=0.0),
    )
    if body.top_width > body.base_width:
        raise f.error("top_width", f"must not exceed base_width ({body.base_width} m), "
                                   f"got {body.top_width}")
    if body.leg_size >= body.top_width / 2:
        raise f.error("leg_size", f"must be below half of top_width ({body.top_width} m), "
                                  f"got {body.leg_size}")
    return body


def _parse_arm(f: _Fields, body: BodySpec) -> CrossArmSpec:
    f.reject_unknown(("height", "reach", "depth", "width"))
    arm = CrossArmSpec(
        height=f.number("height", positive=True),
        reach=f.number("reach", positive=True),
        depth=f.number("depth", positive=True),
        width=f.number("width", positive=True),
    )
    if arm.height + arm.depth > body.height:
        raise f.error("height", f"arm top (height + depth = {arm.height + arm.depth} m) must not "
                                f"exceed body.height ({body.height} m)")
    # Leg spacing at the arm's height: the arm must reach out of the body.
    width_here = body.base_width + (body.top_width - body.base_width) * arm.height / body.height
    if arm.reach <= width_here / 2:
        raise f.error("reach", f"must exceed half the body width at the arm ({width_here / 2:.2f} m), "
                               f"got {arm.reach}")
    return arm


def _parse_insulators(f: _Fields) -> InsulatorSpec:
    f.reject_unknown(("kind", "length", "sheds", "shed_radius", "small_shed_radius", "core_radius",
                      "shed_thickness", "fitting_length", "tilt_deg"))
    ins = InsulatorSpec(
        kind=f.string("kind", choices=INSULATOR_KINDS),  # type: ignore[arg-type]
        length=f.number("length", positive=True),
        sheds=f.integer("sheds", minimum=2),
        shed_radius=f.number("shed_radius", positive=True),
        small_shed_radius=f.number("small_shed_radius", positive=True),
        core_radius=f.number("core_radius", positive=True),
        shed_thickness=f.number("shed_thickness", positive=True),
        fitting_length=f.number("fitting_length", default=0.0, minimum=0.0),
        tilt_deg=f.number("tilt_deg", default=0.0),
    )
    if not ins.core_radius < ins.small_shed_radius <= ins.shed_radius:
        raise f.error("small_shed_radius", "radii must satisfy core_radius < small_shed_radius "
                                           f"<= shed_radius, got {ins.core_radius}, "
                                           f"{ins.small_shed_radius}, {ins.shed_radius}")
    # Large and small sheds alternate: 2*sheds - 1 sheds must fit along the stack.
    if (2 * ins.sheds - 1) * ins.shed_thickness >= ins.length:
        raise f.error("sheds", f"{2 * ins.sheds - 1} sheds of shed_thickness {ins.shed_thickness} m "
                               f"do not fit in length {ins.length} m")
    if not -45.0 <= ins.tilt_deg <= 45.0:
        raise f.error("tilt_deg", f"must be within [-45, 45] degrees, got {ins.tilt_deg}")
    if ins.kind == "suspension" and ins.tilt_deg != 0.0:
        raise f.error("tilt_deg", "applies to strain insulators only (suspension strings hang "
                                  f"vertically), got {ins.tilt_deg}")
    return ins


def _parse_conductors(f: _Fields) -> ConductorSpec:
    f.reject_unknown(("radius", "catenary_parameter", "modelled_length", "segment_length",
                      "jumper_sag"))
    cond = ConductorSpec(
        radius=f.number("radius", positive=True),
        catenary_parameter=f.number("catenary_parameter", positive=True),
        modelled_length=f.number("modelled_length", positive=True),
        segment_length=f.number("segment_length", positive=True),
        jumper_sag=f.number("jumper_sag", default=0.0, minimum=0.0),
    )
    if cond.segment_length > cond.modelled_length:
        raise f.error("segment_length", f"must not exceed modelled_length ({cond.modelled_length} m), "
                                        f"got {cond.segment_length}")
    if cond.modelled_length / cond.segment_length > MAX_CONDUCTOR_SEGMENTS:
        raise f.error("segment_length", f"modelled_length / segment_length must be at most "
                                        f"{MAX_CONDUCTOR_SEGMENTS} segments per span (each is meshed), "
                                        f"got {cond.modelled_length / cond.segment_length:.0f}")
    return cond


def _parse_obstacle(f: _Fields, index: int) -> ObstacleSpec:
    f.reject_unknown(("name", "start", "end", "radius"))
    start = f.point(f._raw("start", None), "start")
    end = f.point(f._raw("end", None), "end")
    if math.dist(start, end) < bounds.OBSTACLE_MIN_LENGTH:
        raise f.error("end", f"must be at least {bounds.OBSTACLE_MIN_LENGTH} m from start, got {end}")
    name = f.string("name") if "name" in f.table else f"obstacle {index}"
    return ObstacleSpec(name=name, start=start, end=end, radius=f.number("radius", positive=True))


def parse_scene(data: dict[str, Any], source: str) -> SceneSpec:
    """Validate a parsed TOML document (``source`` names it in errors) and build a :class:`SceneSpec`."""
    if not isinstance(data, dict):
        raise SceneError(f"{source}: expected a table at the top level, got {type(data).__name__}")
    root = _Fields(data, source, "")
    root.reject_unknown(("name", "neighbours", "ground_size", "body", "cross_arms", "insulators",
                         "conductors", "obstacles"))
    name = root.string("name")
    raw_neighbours = root._raw("neighbours", None)
    if not isinstance(raw_neighbours, list) or len(raw_neighbours) != 2:
        raise root.error("neighbours", "must be an array of exactly 2 points [[x, y, z], [x, y, z]]")
    n0 = root.point(raw_neighbours[0], "neighbours[0]")
    n1 = root.point(raw_neighbours[1], "neighbours[1]")
    if math.hypot(n1[0] - n0[0], n1[1] - n0[1]) < 1.0:
        raise root.error("neighbours", "the two neighbouring towers must be at least 1 m apart "
                                       "horizontally (they define the line direction)")
    for i, p in enumerate((n0, n1)):
        if math.hypot(p[0], p[1]) < 10.0:
            raise root.error(f"neighbours[{i}]", "must be at least 10 m from the inspected tower "
                                                 f"at the origin, got {p}")
    # The inspected tower sits between its neighbours: they lie on opposite sides of it.
    d0 = (n0[0], n0[1])
    d1 = (n1[0], n1[1])
    if d0[0] * d1[0] + d0[1] * d1[1] >= 0.0:
        raise root.error("neighbours", "the neighbours must lie on opposite sides of the inspected "
                                       "tower at the origin")
    body = _parse_body(root.sub("body"))
    arms = tuple(_parse_arm(f, body) for f in root.sub_list("cross_arms"))
    insulators = _parse_insulators(root.sub("insulators"))
    conductors = _parse_conductors(root.sub("conductors"))
    ground_size = root.number("ground_size", positive=True)
    obstacles = () if "obstacles" not in data else tuple(
        _parse_obstacle(f, i) for i, f in enumerate(root.sub_list(
            "obstacles", most=bounds.MAX_OBSTACLES, why="poles and wires beside one tower, each meshed")))
    heights = sorted(a.height for a in arms)
    reach_needed = insulators.length + 2 * insulators.fitting_length
    for i, arm in enumerate(arms):
        if insulators.kind == "suspension" and arm.height - reach_needed <= 1.0:
            raise root.error(f"cross_arms[{i}].height", f"a suspension string of {reach_needed} m "
                                                        f"would hang into the ground (arm at {arm.height} m)")
    for lower, upper in zip(heights, heights[1:]):
        if insulators.kind == "suspension" and upper - lower <= reach_needed:
            raise root.error("cross_arms", f"arms at {lower} m and {upper} m are closer than the "
                                           f"suspension string length {reach_needed} m")
    return SceneSpec(name=name, source=source, neighbours=(n0, n1), body=body, cross_arms=arms,
                     insulators=insulators, conductors=conductors, ground_size=ground_size,
                     obstacles=obstacles)


def load_scene(path: str | Path) -> SceneSpec:
    """Load a scene TOML file. ``path`` may also be a bare scene name in the package's
    ``scenes/`` folder (``"tower_a"``). Raises :class:`SceneError` naming the file and field."""
    p = Path(path)
    # a bare name is a built-in scene unless a file of that name is here: a folder named like it
    # (a report folder "tower_b" beside the recording being replayed) does not hide it
    if not p.is_file() and not p.suffix and (SCENES_DIR / f"{p.name}.toml").exists():
        p = SCENES_DIR / f"{p.name}.toml"
    if not p.exists():
        raise SceneError(f"{p}: scene file not found (built-in scenes: "
                         f"{', '.join(sorted(q.stem for q in SCENES_DIR.glob('*.toml')))})")
    text = read_config_text(p, str(p), error=SceneError)
    try:
        data = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise SceneError(f"{p.name}: invalid TOML: {exc}") from exc
    return parse_scene(data, p.name)
