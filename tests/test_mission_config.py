"""Mission files: TOML and YAML, errors that name the file and the field."""

import numpy as np
import pytest
import yaml
from helpers.flights import MISSIONS
from helpers.mission_files import GOOD_MISSION

from insulator_rs.exceptions import ConfigError
from insulator_rs.mission.config import load_mission, parse_mission

TOML = """
[tower]
lat = 50.0
lon = 14.0
alt = 300.0
max_height = 25.0
max_width = 10.0

[[neighbours]]
lat = 50.0
lon = 13.997
alt = 300.0

[vehicle]
v_max_horizontal = 1.0
a_max_horizontal = 3.0
v_max_vertical = 1.0
a_max_vertical = 3.0

[inspection]
standoff = 8.0
safety_margin = 2.0
waypoints_per_insulator = 3
"""


def test_toml_and_yaml_give_the_same_mission(tmp_path):
    t = tmp_path / "m.toml"
    t.write_text(TOML)
    m = load_mission(t)
    assert m.max_height == 25.0 and m.inspection.waypoints_per_insulator == 3
    assert m.vehicle.v_max_vertical == 1.0
    y = tmp_path / "m.yaml"
    y.write_text(yaml.safe_dump({**GOOD_MISSION, "neighbours": GOOD_MISSION["neighbours"][:1],
                                 "inspection": {**GOOD_MISSION["inspection"], "waypoints_per_insulator": 3}}))
    m2 = load_mission(y)
    assert m2.tower == m.tower and m2.neighbours == m.neighbours
    # the line runs west from the tower (the neighbour is west), so along is -x
    np.testing.assert_allclose(m.line().along, [-1, 0, 0], atol=1e-4)  # meridian convergence


def test_default_takeoff_is_outside_the_safety_box():
    m = parse_mission(GOOD_MISSION)
    t = m.takeoff_enu()
    assert abs(t @ m.line().lateral) == pytest.approx(5.0 + 8.0)


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d.pop("tower"), "tower: missing table"),
    (lambda d: d["tower"].pop("max_height"), "tower.max_height: missing"),
    (lambda d: d["tower"].update(max_width=-1.0), "tower.max_width: must be > 0"),
    (lambda d: d["tower"].update(lat=91.0), "tower.lat: must lie in"),
    (lambda d: d["tower"].update(lat="fifty"), "tower.lat: expected a number"),
    (lambda d: d.pop("neighbours"), "neighbours: missing"),
    (lambda d: d.update(neighbours=[]), "neighbours: expected a list of one or two"),
    (lambda d: d["neighbours"][1].pop("lon"), r"neighbours\[1\].lon: missing"),
    (lambda d: d["vehicle"].update(a_max_vertical=0), "vehicle.a_max_vertical: must be > 0"),
    (lambda d: d["vehicle"].update(v_max_horizontal=float("nan")), "vehicle.v_max_horizontal: must be finite"),
    (lambda d: d["inspection"].update(standoff=1.0), "inspection.standoff: must exceed"),
    (lambda d: d["inspection"].update(waypoints_per_insulator=0), "inspection.waypoints_per_insulator"),
    (lambda d: d["inspection"].update(waypoints_per_insulator=True), "inspection.waypoints_per_insulator"),
    (lambda d: d["inspection"].update(stand_off=3.0), "inspection.stand_off: unknown field"),
    (lambda d: d["neighbours"][0].update(lat=50.0, lon=14.0), "neighbours: "),
])
def test_bad_field_is_named_with_the_file(mutate, field):
    import copy
    d = copy.deepcopy(GOOD_MISSION)
    mutate(d)
    with pytest.raises(ConfigError, match=f"^mission.toml: {field}"):
        parse_mission(d, "mission.toml")


def test_file_errors(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        load_mission(tmp_path / "absent.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[tower\nlat=1")
    with pytest.raises(ConfigError, match="bad.toml: <file>: cannot parse"):
        load_mission(bad)
    other = tmp_path / "m.json"
    other.write_text("{}")
    with pytest.raises(ConfigError, match="unknown mission file type"):
        load_mission(other)
    assert issubclass(ConfigError, ValueError)


@pytest.mark.parametrize("name", ["tower_a.toml", "tower_b.toml"])
def test_example_missions_load(name):
    m = load_mission(MISSIONS / name)
    assert m.max_height > 0 and len(m.neighbours) == 2
