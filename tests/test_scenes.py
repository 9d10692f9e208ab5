"""Scene descriptions (sim.scene) and the towers built from them (sim.towers).

Ground truth is checked against the mesh itself with plain numpy: the insulator
triangles' vertices give the centre (mean of the core rod), the axis (numpy PCA
of the vertices) and the length (extent along the axis).
"""

from __future__ import annotations

import copy
import math
import re
from insulator_rs._toml import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from insulator_rs.sim import scene as scene_mod
from insulator_rs.sim.mesh import Mesh
from insulator_rs.sim.scene import SceneError, load_scene, parse_scene
from insulator_rs.sim.towers import (
    CONDUCTOR_ID_BASE,
    GROUND_ID,
    TOWER_STEEL_ID,
    _catenary_points,
    build_tower,
    canonical_axis,
    load_tower,
)

SCENES = scene_mod.SCENES_DIR


@pytest.fixture(scope="module")
def towers():
    return {name: load_tower(name) for name in ("tower_a", "tower_b")}


@pytest.fixture(scope="module")
def tower_a(towers):
    return towers["tower_a"]


@pytest.fixture(scope="module")
def tower_b(towers):
    return towers["tower_b"]


def _vertices_of(mesh: Mesh, instance_id: int) -> np.ndarray:
    tris = mesh.triangles[mesh.instance_ids == instance_id]
    return mesh.vertices[np.unique(tris.reshape(-1))]


def test_tower_a_has_twelve_nearly_horizontal_insulators(tower_a):
    ins = tower_a.insulators
    assert len(ins) == 12
    assert {i.kind for i in ins} == {"strain"}
    for i in ins:
        # "Nearly horizontal": within 10 degrees of the horizontal plane, along the line.
        assert abs(i.axis[2]) < math.sin(math.radians(10.0))
        assert abs(np.dot(i.axis, tower_a.spec.line_direction)) > 0.98
    assert sorted(i.side for i in ins) == [-1] * 6 + [1] * 6


def test_tower_b_has_four_vertical_insulators(tower_b):
    ins = tower_b.insulators
    assert len(ins) == 4
    for i in ins:
        np.testing.assert_allclose(i.axis, [0.0, 0.0, 1.0], atol=1e-12)
    assert sorted(i.side for i in ins) == [-1, -1, 1, 1]


@pytest.mark.parametrize("name", ["tower_a", "tower_b"])
def test_dimensions_are_those_of_a_110_to_400_kv_tower(towers, name):
    tower = towers[name]
    lo, hi = tower.mesh.bounds()
    steel = _vertices_of(tower.mesh, TOWER_STEEL_ID)
    height = steel[:, 2].max()
    assert 20.0 <= height <= 31.5
    assert tower.max_height == pytest.approx(height, abs=0.2)
    # Width across the line: tip to tip of the widest arm, up to ~10 m.
    lateral = np.asarray(tower.spec.lateral_direction)
    across = steel @ lateral
    assert 6.0 <= across.max() - across.min() <= 10.5
    assert tower.max_width == pytest.approx(across.max() - across.min(), abs=0.3)
    # The ground covers the scene and nothing hangs far below it.
    assert lo[2] > -0.2


@pytest.mark.parametrize("name", ["tower_a", "tower_b"])
def test_ground_truth_matches_the_insulator_mesh(towers, name):
    """Reference: numpy on the insulator's own vertices. Centre of the core rod's two end
    rings (mean of its ring centres), axis = first eigenvector of np.cov of all the
    insulator's vertices (tol 1e-6), length = extent of the vertices along the axis
    (exactly the core rod, tol 1e-9), side = sign of the centre's offset across the line."""
    tower = towers[name]
    lateral = np.asarray(tower.spec.lateral_direction)
    for ins in tower.insulators:
        v = _vertices_of(tower.mesh, ins.instance_id)
        cov = np.cov(v.T)
        w, vec = np.linalg.eigh(cov)
        axis = canonical_axis(vec[:, -1])
        np.testing.assert_allclose(axis, ins.axis, atol=1e-6)
        s = (v - ins.center) @ ins.axis
        assert s.min() == pytest.approx(-ins.length / 2, abs=1e-9)
        assert s.max() == pytest.approx(ins.length / 2, abs=1e-9)
        # The vertices are symmetric about the centre (sheds spread evenly).
        assert np.mean(s) == pytest.approx(0.0, abs=0.02)
        radial = np.linalg.norm((v - ins.center) - np.outer(s, ins.axis), axis=1)
        assert radial.max() == pytest.approx(ins.radius, rel=1e-9)
        assert int(np.sign(ins.center @ lateral)) == ins.side
        assert tower.mesh.instances[ins.instance_id].kind == "insulator"
        assert tower.mesh.instances[ins.instance_id].properties["side"] == ins.side


def test_insulators_are_shed_stacks_with_alternating_radii(tower_a):
    """Along the axis, the radius of the insulator's vertices alternates between the large and
    the small shed radius (a plain cylinder would have one radius)."""
    spec = tower_a.spec.insulators
    ins = tower_a.insulators[0]
    v = _vertices_of(tower_a.mesh, ins.instance_id)
    s = (v - ins.center) @ ins.axis
    radial = np.linalg.norm((v - ins.center) - np.outer(s, ins.axis), axis=1)
    shed = radial > spec.core_radius * 1.5
    # Group shed vertices by their axial position (one group per shed face pair).
    order = np.argsort(s[shed])
    s_shed, r_shed = s[shed][order], radial[shed][order]
    groups = np.split(r_shed, np.where(np.diff(s_shed) > spec.shed_thickness * 1.5)[0] + 1)
    radii = [g.max() for g in groups]
    assert len(radii) == 2 * spec.sheds - 1
    expected = [spec.shed_radius if k % 2 == 0 else spec.small_shed_radius for k in range(len(radii))]
    np.testing.assert_allclose(radii, expected, rtol=1e-9)


def test_conductors_hang_from_the_insulators(tower_a, tower_b):
    for tower in (tower_a, tower_b):
        ids = np.unique(tower.mesh.instance_ids)
        conductors = ids[ids >= CONDUCTOR_ID_BASE]
        n_ins = len(tower.insulators)
        # Strain: one conductor per string plus one jumper per arm tip; suspension: two per string.
        expected = n_ins + n_ins // 2 if tower.spec.insulators.kind == "strain" else 2 * n_ins
        assert len(conductors) == expected
        ends = []
        for ins in tower.insulators:
            a, b = ins.end_points
            ends.extend([a, b])
        ends = np.array(ends)
        fit = tower.spec.insulators.fitting_length
        for cid in conductors:
            v = _vertices_of(tower.mesh, int(cid))
            assert tower.mesh.instances[int(cid)].kind == "conductor"
            assert v[:, 2].min() > 3.0  # conductors clear the ground
            # Each conductor starts at an insulator's free end (one fitting beyond the stack).
            d = np.linalg.norm(v[:, None, :] - ends[None, :, :], axis=2).min()
            assert d <= fit + tower.spec.conductors.radius + 1e-6


def test_line_direction_is_defined_by_the_neighbours(tower_b):
    spec = tower_b.spec
    (x0, y0, _), (x1, y1, _) = spec.neighbours
    d = np.array([x1 - x0, y1 - y0, 0.0])
    np.testing.assert_allclose(spec.line_direction, d / np.linalg.norm(d), atol=1e-12)
    lat = np.asarray(spec.lateral_direction)
    np.testing.assert_allclose(np.cross(spec.line_direction, lat), [0, 0, -1], atol=1e-12)
    # The insulators lie on the two sides of the line, symmetrically.
    off = sorted(i.center @ lat for i in tower_b.insulators)
    np.testing.assert_allclose(off[:2], [-o for o in off[:1:-1]], atol=1e-9)


def test_mesh_instance_ids_and_ground(tower_a):
    ids = set(np.unique(tower_a.mesh.instance_ids).tolist())
    assert GROUND_ID in ids and TOWER_STEEL_ID in ids
    assert {i.instance_id for i in tower_a.insulators} <= ids
    ground = _vertices_of(tower_a.mesh, GROUND_ID)
    np.testing.assert_allclose(ground[:, 2], 0.0)
    assert np.ptp(ground[:, 0]) == pytest.approx(tower_a.spec.ground_size)


def test_catenary_passes_through_both_ends_and_satisfies_its_ode():
    """Reference: the catenary ODE z'' = sqrt(1 + z'^2) / a, by central finite differences
    (tol 1e-4 relative), and the end points exactly (1e-9)."""
    p = np.array([0.0, 0.0, 20.0])
    q = np.array([180.0, 240.0, 24.0])
    a = 1300.0
    pts = _catenary_points(p, q, a, max_horizontal=1e9, step=1.0)
    np.testing.assert_allclose(pts[0], p, atol=1e-9)
    np.testing.assert_allclose(pts[-1], q, atol=1e-9)
    s = np.linalg.norm(pts[:, :2] - p[:2], axis=1)
    h = s[1] - s[0]
    z = pts[:, 2]
    d1 = (z[2:] - z[:-2]) / (2 * h)
    d2 = (z[2:] - 2 * z[1:-1] + z[:-2]) / h**2
    np.testing.assert_allclose(d2, np.sqrt(1 + d1**2) / a, rtol=1e-4)
    assert z.min() < min(p[2], q[2]) - 1.0  # it sags


def test_deterministic_build(tower_b):
    a1, a2 = tower_b, load_tower("tower_b")
    np.testing.assert_array_equal(a1.mesh.vertices, a2.mesh.vertices)
    np.testing.assert_array_equal(a1.mesh.triangles, a2.mesh.triangles)


# --- bad input -------------------------------------------------------------------------

def _raw(name: str) -> dict[str, Any]:
    return tomllib.loads((SCENES / f"{name}.toml").read_text())


def _write(tmp_path: Path, text: str, name: str = "bad.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_missing_field_names_the_field_and_the_file(tmp_path):
    text = (SCENES / "tower_a.toml").read_text().replace("base_width = 7.0\n", "")
    with pytest.raises(SceneError, match=r"bad\.toml: field 'body\.base_width': missing"):
        load_scene(_write(tmp_path, text))


def test_contradictory_fields_name_the_field_and_the_file(tmp_path):
    text = (SCENES / "tower_a.toml").read_text().replace("top_width = 1.8", "top_width = 9.0")
    with pytest.raises(SceneError, match=r"bad\.toml: field 'body\.top_width'.*base_width"):
        load_scene(_write(tmp_path, text))
    text = (SCENES / "tower_a.toml").read_text().replace("height = 25.0", "height = 27.5")
    with pytest.raises(SceneError, match=r"bad\.toml: field 'cross_arms\[2\]\.height'"):
        load_scene(_write(tmp_path, text))
    text = (SCENES / "tower_b.toml").read_text().replace("sheds = 10", "sheds = 60")
    with pytest.raises(SceneError, match=r"field 'insulators\.sheds'"):
        load_scene(_write(tmp_path, text))


@pytest.mark.parametrize("old,new,field", [
    ('kind = "strain"', 'kind = "post"', "insulators.kind"),
    ("panels = 10", "panels = 2.5", "body.panels"),
    ("reach = 5.0", "reach = 1.0", "cross_arms[0].reach"),
    ("[0.0, 300.0, 1.5]]", "[0.0, -300.0, 1.5]]", "neighbours"),
    ("radius = 0.0135", "radius = -1.0", "conductors.radius"),
    ("leg_size = 0.16", "leg_size = 0.16\nleg_sise = 2", "body.leg_sise"),
    ("tilt_deg = 6.0", "tilt_deg = 80.0", "insulators.tilt_deg"),
])
def test_invalid_values_name_the_field(tmp_path, old, new, field):
    text = (SCENES / "tower_a.toml").read_text()
    assert old in text
    with pytest.raises(SceneError, match=rf"tower_x\.toml: field '{re.escape(field)}'"):
        load_scene(_write(tmp_path, text.replace(old, new, 1), "tower_x.toml"))


def test_bad_toml_and_missing_file(tmp_path):
    with pytest.raises(SceneError, match=r"bad\.toml: invalid TOML"):
        load_scene(_write(tmp_path, "name = \n"))
    with pytest.raises(SceneError, match="not found.*tower_a"):
        load_scene(tmp_path / "nope.toml")


def test_new_tower_type_needs_no_code(tmp_path):
    """A third tower type (a single-level 400 kV suspension tower) from a TOML file alone."""
    text = (SCENES / "tower_b.toml").read_text()
    arm2 = text.index("[[cross_arms]]", text.index("[[cross_arms]]") + 1)
    ins = text.index("[insulators]")
    text = text[:arm2] + text[ins:]
    text = text.replace('name = "tower_b"', 'name = "tower_c"').replace("length = 1.5", "length = 3.2")
    tower = build_tower(load_scene(_write(tmp_path, text, "tower_c.toml")))
    assert tower.spec.name == "tower_c" and len(tower.spec.cross_arms) == 1
    assert len(tower.insulators) == 2
    assert all(i.length == 3.2 for i in tower.insulators)


_NUMERIC_FIELDS = [("body", k) for k in ("height", "base_width", "top_width", "leg_size",
                                          "brace_size", "peak_height")] + \
                  [("insulators", k) for k in ("length", "shed_radius", "small_shed_radius",
                                               "core_radius", "shed_thickness", "tilt_deg")] + \
                  [("conductors", k) for k in ("radius", "catenary_parameter", "segment_length")]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    field=st.sampled_from(_NUMERIC_FIELDS),
    value=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 100),
                    st.text(max_size=3), st.booleans(), st.none()),
)
def test_parser_accepts_or_rejects_cleanly(field, value):
    """Property: any value in any numeric field gives a SceneSpec or a SceneError naming that
    field (or a field it contradicts), never another exception."""
    data = copy.deepcopy(_raw("tower_a"))
    table, key = field
    if value is None:
        del data[table][key]
    else:
        data[table][key] = value
    try:
        spec = parse_scene(data, "prop.toml")
    except SceneError as exc:
        assert str(exc).startswith("prop.toml: field '")
        return
    assert math.isfinite(getattr(getattr(spec, table), key))


def test_a_built_in_name_is_not_hidden_by_a_folder_of_that_name(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A crew's report folder named after the tower (``--out tower_b``) beside the recording it
    replays: the recording names scene "tower_b", the folder must not stand in for it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tower_b").mkdir()
    assert load_scene("tower_b").name == "tower_b"
    (tmp_path / "mine").mkdir()
    with pytest.raises(SceneError, match="mine"):
        load_scene("mine")  # not a built-in: the folder is still refused by name
