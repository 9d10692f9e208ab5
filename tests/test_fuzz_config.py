"""Fuzzing the mission and scene loaders (hypothesis).

Contract (mission/config.py, sim/scene.py, textfile.py): any file, any bytes, any parsed
structure gives either a valid object or a ``ConfigError`` (``SceneError`` for scenes) whose
message starts with the file's name; never another exception, never a hang. And the other
half, so the suite cannot pass by refusing everything: missions generated inside the limits of
``bounds.py`` (random tower, neighbours, take-off point, vehicle and inspection values)
load from TOML and YAML, equal what was written, and round-trip; scenes scaled from the
built-in towers load and round-trip.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from insulator_rs._toml import tomllib
from insulator_rs.exceptions import ConfigError
from insulator_rs import bounds
from insulator_rs.mission.config import Mission, load_mission, parse_mission
from insulator_rs.geodesy import GeoPoint, enu_to_gps
from insulator_rs.sim.scene import SCENES_DIR, SceneError, SceneSpec, load_scene, parse_scene

MISSION_A = Path(__file__).resolve().parents[1] / "python" / "insulator_rs" / "missions" / "tower_a.toml"
FUZZ = settings(max_examples=60, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def _base_mission() -> dict[str, Any]:
    return tomllib.loads(MISSION_A.read_text())


def _base_scene(name: str = "tower_a") -> dict[str, Any]:
    return tomllib.loads((SCENES_DIR / f"{name}.toml").read_text())


# ---- a TOML writer for the test's own documents (tables, arrays of tables, scalars) ----

def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(type(v))


def to_toml(doc: dict[str, Any]) -> str:
    lines = [f"{k} = {_toml_value(v)}" for k, v in doc.items()
             if not isinstance(v, dict) and not (isinstance(v, list) and v and isinstance(v[0], dict))]
    for k, v in doc.items():
        if isinstance(v, dict):
            lines += ["", f"[{k}]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in v.items()]
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            for item in v:
                lines += ["", f"[[{k}]]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in item.items()]
    return "\n".join(lines) + "\n"


# ---- hostile input -----------------------------------------------------------------------

def _assert_clean(path: Path, loader, error: type[Exception]) -> object | None:
    """The loader returns an object or raises ``error`` naming the file; anything else fails."""
    try:
        return loader(path)
    except error as exc:
        assert str(exc).startswith(str(path)) or str(exc).startswith(path.name), str(exc)
        return None


SUFFIXES = st.sampled_from([".toml", ".yaml", ".yml"])

scalars = st.one_of(st.none(), st.booleans(), st.integers(min_value=-(10**30), max_value=10**30),
                    st.integers(min_value=10**300, max_value=10**400),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                    st.dates())
structures = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.one_of(st.text(max_size=12), st.integers()),
                                                 inner, max_size=5)), max_leaves=20)


@FUZZ
@given(data=st.binary(max_size=1500), suffix=SUFFIXES)
def test_mission_loader_survives_random_bytes(tmp_path_factory, data, suffix):
    path = tmp_path_factory.mktemp("m") / f"mission{suffix}"
    path.write_bytes(data)
    assert _assert_clean(path, load_mission, ConfigError) is None or True


@FUZZ
@given(text=st.text(max_size=1500), suffix=SUFFIXES)
def test_mission_loader_survives_random_text(tmp_path_factory, text, suffix):
    path = tmp_path_factory.mktemp("m") / f"mission{suffix}"
    path.write_text(text, encoding="utf-8")
    _assert_clean(path, load_mission, ConfigError)


@FUZZ
@given(doc=structures)
def test_mission_loader_survives_random_yaml_structures(tmp_path_factory, doc):
    path = tmp_path_factory.mktemp("m") / "mission.yaml"
    path.write_text(yaml.safe_dump(doc))
    _assert_clean(path, load_mission, ConfigError)


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path of a nested dict/list document."""
    out = []
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else []
    for k, v in items:
        out.append(prefix + (k,))
        out += _paths(v, prefix + (k,))
    return out


def _set(doc: Any, path: tuple, value: Any) -> None:
    for k in path[:-1]:
        doc = doc[k]
    if value is _DELETE:
        del doc[path[-1]]
    else:
        doc[path[-1]] = value


_DELETE = object()
replacements = st.one_of(structures, st.just(_DELETE))


@FUZZ
@given(data=st.data())
def test_mission_parser_survives_any_mutated_field(data):
    """One field of a valid mission replaced by anything (or removed): a Mission or a
    ConfigError that names the file."""
    doc = _base_mission()
    doc["takeoff"] = {"lat": 50.0001, "lon": 14.0, "alt": 300.0}
    path = data.draw(st.sampled_from(_paths(doc)))
    _set(doc, path, data.draw(replacements))
    try:
        mission = parse_mission(doc, "fuzz.toml")
    except ConfigError as exc:
        assert str(exc).startswith("fuzz.toml: "), str(exc)
        return
    assert isinstance(mission, Mission)


@FUZZ
@given(data=st.binary(max_size=1500))
def test_scene_loader_survives_random_bytes(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("s") / "scene.toml"
    path.write_bytes(data)
    _assert_clean(path, load_scene, SceneError)


@FUZZ
@given(data=st.data())
def test_scene_parser_survives_any_mutated_field(data):
    doc = _base_scene(data.draw(st.sampled_from(["tower_a", "tower_b"])))
    path = data.draw(st.sampled_from(_paths(doc)))
    _set(doc, path, data.draw(replacements))
    try:
        spec = parse_scene(doc, "fuzz.toml")
    except SceneError as exc:
        assert str(exc).startswith("fuzz.toml: "), str(exc)
        return
    assert isinstance(spec, SceneSpec)


# ---- valid input is accepted -------------------------------------------------------------

def _within(limit: bounds.Limit, lo: float | None = None, hi: float | None = None):
    """Values inside a limit (optionally narrowed)."""
    a = max(limit.lo, lo if lo is not None else -math.inf)
    b = min(limit.hi, hi if hi is not None else math.inf)
    if limit.integer:
        return st.integers(int(math.ceil(a)), int(b))
    if limit.lo_open and a == limit.lo:
        a = a + 1e-3 * (b - a)
    return st.floats(a, b, allow_nan=False, allow_infinity=False)


@st.composite
def valid_missions(draw) -> dict[str, Any]:
    m = bounds.MISSION
    tower = GeoPoint(draw(st.floats(-60.0, 60.0)), draw(st.floats(-179.0, 179.0)),
                     draw(_within(m["tower.alt"], lo=-400.0, hi=8000.0)))
    bearing = draw(st.floats(0.0, 2 * math.pi))
    spans = [draw(st.floats(50.0, 5000.0)) for _ in range(draw(st.integers(1, 2)))]
    neighbours = []
    for k, span in enumerate(spans):
        b = bearing + k * (math.pi + draw(st.floats(-0.3, 0.3)))
        enu = np.array([span * math.cos(b), span * math.sin(b), draw(st.floats(-20.0, 20.0))])
        neighbours.append(dataclasses.asdict(enu_to_gps(enu, tower)))
    safety_margin = draw(_within(m["inspection.safety_margin"], hi=10.0))
    doc: dict[str, Any] = {
        "tower": {**dataclasses.asdict(tower),
                  "max_height": draw(_within(m["tower.max_height"])),
                  "max_width": draw(_within(m["tower.max_width"]))},
        "neighbours": neighbours,
        "vehicle": {k: draw(_within(m[f"vehicle.{k}"])) for k in
                    ("v_max_horizontal", "a_max_horizontal", "v_max_vertical", "a_max_vertical")},
        "inspection": {"standoff": draw(_within(m["inspection.standoff"], lo=safety_margin + 0.01)),
                       "safety_margin": safety_margin},
    }
    for key in ("inspection_distance", "waypoints_per_insulator", "registry_gate", "pass_spacing",
                "crossing_clearance", "insulator_length", "confirmations"):
        if draw(st.booleans()):
            doc["inspection"][key] = draw(_within(m[f"inspection.{key}"]))
    if draw(st.booleans()):
        d, b = draw(st.floats(0.0, 490.0)), draw(st.floats(0.0, 2 * math.pi))
        enu = np.array([d * math.cos(b), d * math.sin(b), draw(st.floats(-90.0, 90.0))])
        doc["takeoff"] = dataclasses.asdict(enu_to_gps(enu, tower))
    return doc


def mission_to_doc(mission: Mission) -> dict[str, Any]:
    """The mission file that describes ``mission`` (every optional field written out)."""
    doc: dict[str, Any] = {
        "tower": {**dataclasses.asdict(mission.tower), "max_height": mission.max_height,
                  "max_width": mission.max_width},
        "neighbours": [dataclasses.asdict(n) for n in mission.neighbours],
        "vehicle": dataclasses.asdict(mission.vehicle),
        "inspection": dataclasses.asdict(mission.inspection),
    }
    if mission.takeoff is not None:
        doc["takeoff"] = dataclasses.asdict(mission.takeoff)
    return doc


def _same_numbers(doc: dict[str, Any], mission: Mission) -> None:
    written = mission_to_doc(mission)
    for table, values in doc.items():
        rows = values if isinstance(values, list) else [values]
        got_rows = written[table] if isinstance(written[table], list) else [written[table]]
        for row, got in zip(rows, got_rows, strict=True):
            for key, value in row.items():
                assert got[key] == value, (table, key)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=valid_missions(), fmt=st.sampled_from(["toml", "yaml"]))
def test_valid_missions_load_and_round_trip(tmp_path_factory, doc, fmt):
    folder = tmp_path_factory.mktemp("valid")
    path = folder / f"mission.{fmt}"
    path.write_text(to_toml(doc) if fmt == "toml" else yaml.safe_dump(doc))
    mission = load_mission(path)  # must not raise: the values lie inside every limit
    _same_numbers(doc, mission)
    again = folder / f"again.{'yaml' if fmt == 'toml' else 'toml'}"
    again.write_text(yaml.safe_dump(mission_to_doc(mission)) if fmt == "toml"
                     else to_toml(mission_to_doc(mission)))
    assert dataclasses.replace(load_mission(again), source=mission.source) == mission


def scene_to_doc(spec: SceneSpec) -> dict[str, Any]:
    return {"name": spec.name, "neighbours": [list(p) for p in spec.neighbours],
            "ground_size": spec.ground_size, "body": dataclasses.asdict(spec.body),
            "cross_arms": [dataclasses.asdict(a) for a in spec.cross_arms],
            "insulators": dataclasses.asdict(spec.insulators),
            "conductors": dataclasses.asdict(spec.conductors)}


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.sampled_from(["tower_a", "tower_b"]), scale=st.floats(0.8, 1.6),
       neighbour_scale=st.floats(0.5, 10.0))
def test_scaled_scenes_load_and_round_trip(tmp_path_factory, name, scale, neighbour_scale):
    """A built-in tower scaled as a whole (every length times ``scale``, shed count kept) is a
    valid scene; it loads from TOML and round-trips."""
    doc = _base_scene(name)
    lengths = {"body": ("height", "base_width", "top_width", "leg_size", "brace_size", "peak_height"),
               "insulators": ("length", "shed_radius", "small_shed_radius", "core_radius",
                              "shed_thickness", "fitting_length"),
               "conductors": ("radius", "jumper_sag")}
    for table, keys in lengths.items():
        for k in keys:
            if k in doc[table]:
                doc[table][k] *= scale
    for arm in doc["cross_arms"]:
        for k in ("height", "reach", "depth", "width"):
            arm[k] *= scale
    doc["neighbours"] = [[c * neighbour_scale for c in p] for p in doc["neighbours"]]
    assume(all(abs(c) <= bounds.SPAN.hi for p in doc["neighbours"] for c in p))
    path = tmp_path_factory.mktemp("scene") / f"{name}_x.toml"
    path.write_text(to_toml(doc))
    spec = load_scene(path)
    assert spec.body.height == pytest.approx(doc["body"]["height"])
    again = parse_scene(copy.deepcopy(scene_to_doc(spec)), spec.source)
    assert again == spec
