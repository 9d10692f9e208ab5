"""Ray casting through the binding (``insulator_rs._core.RaycastScene``) and the mesh container.

References: the exact ray/plane formula and Cyrus-Beck clipping against the
half-spaces of a convex polyhedron (box; a tessellated cylinder is exactly its
faceted prism), both in plain numpy here; for random triangle soups, a brute-force
numpy Moeller-Trumbore over every triangle. Distance tolerance 1e-6 m.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from insulator_rs._core import RaycastScene
from insulator_rs.sim.mesh import InstanceInfo, Mesh, box, cylinder, plane

TOL = 1e-6


def scene_of(mesh: Mesh) -> RaycastScene:
    return RaycastScene(mesh.vertices, mesh.triangles, mesh.instance_ids)


def convex_entry(normals: np.ndarray, offsets: np.ndarray, o: np.ndarray, d: np.ndarray) -> float | None:
    """Entry distance of ray o + t d into {x : normals @ x <= offsets} (o outside), else None."""
    t_in, t_out = 0.0, np.inf
    for n, off in zip(normals, offsets):
        denom, num = n @ d, off - n @ o
        if abs(denom) < 1e-15:
            if num < 0:
                return None
        elif denom < 0:
            t_in = max(t_in, num / denom)
        else:
            t_out = min(t_out, num / denom)
    return t_in if t_in <= t_out else None


def random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_plane_distances_match_the_ray_plane_formula() -> None:
    mesh = plane([0, 0, 2.0], [0, 0, 1], (400, 400), instance_id=5)
    rng = np.random.default_rng(0)
    n = 5000
    origins = np.column_stack([rng.uniform(-50, 50, n), rng.uniform(-50, 50, n), rng.uniform(3, 40, n)])
    dirs = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), -rng.uniform(0.3, 1, n)])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = scene_of(mesh).cast(origins, dirs, np.inf)
    expected = (2.0 - origins[:, 2]) / dirs[:, 2]
    np.testing.assert_allclose(hits.distance, expected, rtol=0, atol=TOL)
    assert np.all(hits.instance_id == 5)
    np.testing.assert_array_equal(hits.normal, np.tile([0.0, 0.0, 1.0], (n, 1)))


def check_against_convex(mesh: Mesh, normals: np.ndarray, offsets: np.ndarray, seed: int, *,
                         centre, radius: float, lo, hi, n: int) -> int:
    """Casts n rays from a sphere (centre, radius) toward random points of the box
    [lo, hi] and compares with Cyrus-Beck; returns how many hit. A disagreement on
    hit/miss is allowed only for a ray through an edge (two faces within 1e-5 m)."""
    rng = np.random.default_rng(seed)
    origins = radius * random_unit(rng, n) + np.asarray(centre)
    dirs = rng.uniform(lo, hi, size=(n, 3)) - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = scene_of(mesh).cast(origins, dirs, 100.0)
    n_hit = 0
    for o, d, dist in zip(origins, dirs, hits.distance):
        ref = convex_entry(normals, offsets, o, d)
        if ref is not None and np.isfinite(dist):
            n_hit += 1
            assert abs(dist - ref) < TOL
        elif (ref is None) != (not np.isfinite(dist)):
            p = o + d * (ref if ref is not None else dist)
            assert np.sum(np.abs(normals @ p - offsets) < 1e-5) >= 2, p
    return n_hit


def test_box_distances_match_cyrus_beck() -> None:
    lo, hi = np.array([-1.0, -2.0, 0.5]), np.array([1.5, 2.0, 3.0])
    mesh = box((lo + hi) / 2, hi - lo, instance_id=2)
    normals = np.vstack([np.eye(3), -np.eye(3)])
    offsets = np.concatenate([hi, -lo])
    n_hit = check_against_convex(mesh, normals, offsets, 1, centre=(lo + hi) / 2, radius=20.0,
                                 lo=lo - 0.5, hi=hi + 0.5, n=3000)
    assert n_hit > 1000


@pytest.mark.parametrize("segments", [6, 24])
def test_tessellated_cylinder_distances_match_its_exact_prism(segments: int) -> None:
    """The builder puts the polygon's vertices on the circle; the prism's faces are
    at r cos(pi/n) from the axis, facing angles 2 pi k / n + pi / n (builder's frame)."""
    r, z0, z1 = 0.7, -1.0, 3.0
    mesh = cylinder([0, 0, z0], [0, 0, z1], r, instance_id=1, segments=segments)
    # Recover the builder's angular frame from its first ring vertex.
    a0 = np.arctan2(mesh.vertices[0, 1], mesh.vertices[0, 0])
    ang = a0 + 2 * np.pi * np.arange(segments) / segments + np.pi / segments
    normals = np.vstack([np.column_stack([np.cos(ang), np.sin(ang), np.zeros(segments)]), [[0, 0, 1], [0, 0, -1]]])
    offsets = np.concatenate([np.full(segments, r * np.cos(np.pi / segments)), [z1, -z0]])
    n_hit = check_against_convex(mesh, normals, offsets, 2, centre=[0, 0, 1], radius=12.0,
                                 lo=[-1, -1, -1.5], hi=[1, 1, 3.5], n=2000)
    assert n_hit > 500


def test_fine_cylinder_matches_the_true_circle_along_radial_rays() -> None:
    """Sagitta of a 720-gon of radius 0.1 m is 9.5e-7 m < 1e-6 m."""
    mesh = cylinder([1, 2, 0], [1, 2, 10], 0.1, instance_id=3, segments=720)
    rng = np.random.default_rng(3)
    n = 1000
    a = rng.uniform(0, 2 * np.pi, n)
    radial = np.column_stack([np.cos(a), np.sin(a), np.zeros(n)])
    d0 = rng.uniform(1, 30, n)
    origins = np.array([1, 2, 0]) + radial * d0[:, None] + np.column_stack([np.zeros((n, 2)), rng.uniform(1, 9, n)])
    hits = scene_of(mesh).cast(origins, -radial, 100.0)
    np.testing.assert_allclose(hits.distance, d0 - 0.1, rtol=0, atol=TOL)


def test_misses_and_max_range() -> None:
    rc = scene_of(plane([0, 0, 0], [0, 0, 1], (10, 10), instance_id=0))
    o = np.tile([0.0, 0.0, 5.0], (3, 1))
    hits = rc.cast(o, np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 0, -3.0]]), 4.999)
    assert np.all(np.isinf(hits.distance)) and np.all(hits.instance_id == -1)
    assert np.all(hits.triangle == -1) and np.all(hits.normal == 0)
    hits = rc.cast(o, np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 0, -3.0]]).astype(np.float32), 5.0)
    np.testing.assert_array_equal(hits.instance_id, [-1, 0, 0])
    np.testing.assert_allclose(hits.distance[1:], [5.0, 5.0], atol=TOL)
    assert len(hits) == 3 and "n_hits=2" in repr(hits)
    with pytest.raises(ValueError):
        hits.distance[0] = 1.0  # results are read-only


def moller_trumbore(verts: np.ndarray, tris: np.ndarray, o: np.ndarray, d: np.ndarray) -> tuple[float, float]:
    """(nearest distance or inf, smallest barycentric margin of that hit), brute force."""
    a, b, c = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    e1, e2 = b - a, c - a
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    margin = np.minimum(np.minimum(u, v), 1 - u - v)
    valid = ok & (margin >= 0) & (t >= 0)
    if not valid.any():
        return np.inf, np.inf
    k = np.argmin(np.where(valid, t, np.inf))
    return float(t[k]), float(margin[k])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 30))
def test_random_soups_match_brute_force(seed: int, n_tris: int) -> None:
    rng = np.random.default_rng(seed)
    verts = rng.uniform(-5, 5, size=(3 * n_tris, 3))
    tris = np.arange(3 * n_tris, dtype=np.uint32).reshape(-1, 3)
    rc = RaycastScene(verts, tris, np.arange(n_tris, dtype=np.int32))
    origins = rng.uniform(-8, 8, size=(50, 3))
    dirs = random_unit(rng, 50)
    hits = rc.cast(origins, dirs, np.inf)
    for i in range(50):
        t_ref, margin = moller_trumbore(verts, tris, origins[i], dirs[i])
        if abs(margin) < 1e-4:
            continue  # through an edge: the f32 BVH and f64 reference may differ
        if np.isinf(t_ref):
            assert np.isinf(hits.distance[i])
        else:
            assert abs(hits.distance[i] - t_ref) < TOL * (1 + t_ref)


def test_bad_scene_input_names_the_argument() -> None:
    good = box([0, 0, 0], [1, 1, 1], instance_id=0)
    v, t, i = good.vertices, good.triangles, good.instance_ids
    cases = [
        ((np.where(np.arange(v.size).reshape(v.shape) == 4, np.nan, v), t, i), ValueError, "vertices"),
        ((v[:, :2].copy(), t, i), ValueError, "vertices"),
        ((v, t + 100, i), ValueError, "triangles"),
        ((v, t[:, :2].copy(), i), ValueError, "triangles"),
        ((v, t.astype(np.int64) - 1, i), ValueError, "triangles"),
        ((v, t, i[:-1]), ValueError, "instance_ids"),
        ((v, t, i - 1), ValueError, "instance_ids"),
        ((v, t[:0], i[:0]), ValueError, "triangles"),
        ((v, t.astype(np.float64), i), TypeError, "triangles"),
        (("nope", t, i), TypeError, "vertices"),
    ]
    for args, exc, name in cases:
        with pytest.raises(exc, match=name):
            RaycastScene(*args)
    degenerate = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2.0]])
    with pytest.raises(ValueError, match="triangles: triangle 0 is degenerate"):
        RaycastScene(degenerate, np.array([[0, 1, 2]], np.uint32), np.zeros(1, np.int32))


def test_bad_cast_input_names_the_argument() -> None:
    rc = scene_of(box([0, 0, 0], [1, 1, 1], instance_id=0))
    o, d = np.zeros((2, 3)), np.tile([1.0, 0, 0], (2, 1))
    with pytest.raises(ValueError, match="origins"):
        rc.cast(np.zeros((2, 2)), d, 1.0)
    with pytest.raises(ValueError, match="origins: row 1 is not finite"):
        rc.cast(np.array([[0, 0, 0], [np.inf, 0, 0]]), d, 1.0)
    with pytest.raises(ValueError, match="directions: row 0 has zero length"):
        rc.cast(o, np.zeros((2, 3)), 1.0)
    with pytest.raises(ValueError, match="directions: expected 2 rows"):
        rc.cast(o, d[:1], 1.0)
    with pytest.raises(TypeError, match="directions"):
        rc.cast(o, d.astype(np.int32), 1.0)
    for bad in (0.0, -1.0, np.nan):
        with pytest.raises(ValueError, match="max_range"):
            rc.cast(o, d, bad)


def test_render_shades_a_sunlit_plane_by_lambert() -> None:
    """Reference: albedo * (ambient + sun * cos) gamma-encoded by 1/2.2, rounded."""
    mesh = plane([0, 0, 0], [0, 0, 1], (1000, 1000), instance_id=0)
    rc = scene_of(mesh)
    T_w_c = np.eye(4)
    T_w_c[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking straight down
    T_w_c[2, 3] = 10.0
    rays = np.tile([0.0, 0.0, 1.0], (4 * 3, 1))
    sun = np.array([0.0, 0.6, 0.8])
    albedo, ambient, sun_color = [0.4, 0.5, 0.6], [0.2, 0.1, 0.3], [1.0, 0.9, 0.8]
    rgb, ids, depth = rc.render(T_w_c, rays, 4, 3, np.array([albedo]), sun_direction=list(sun),
                                sun_color=sun_color, ambient=ambient, noise_sigma=0.0)
    linear = np.array(albedo) * (np.array(ambient) + np.array(sun_color) * 0.8)
    expected = np.round(255 * linear ** (1 / 2.2)).astype(np.uint8)
    assert rgb.shape == (3, 4, 3) and ids.shape == (3, 4) and depth.shape == (3, 4)
    assert np.all(rgb == expected)
    assert np.all(ids == 0)
    np.testing.assert_allclose(depth, 10.0, atol=1e-5)
    # Looking straight up (identity rotation: C's z is W's z): the zenith colour, id -1, inf depth.
    T_up = np.eye(4)
    T_up[2, 3] = 10.0
    rgb, ids, depth = rc.render(T_up, np.array([[0.0, 0.0, 1.0]]), 1, 1, np.array([albedo]),
                                sky_zenith=[0.2, 0.4, 0.8], noise_sigma=0.0)
    np.testing.assert_array_equal(rgb[0, 0], np.round(255 * np.array([0.2, 0.4, 0.8]) ** (1 / 2.2)))
    assert ids[0, 0] == -1 and np.isinf(depth[0, 0])


def test_render_shadow_leaves_only_ambient_light() -> None:
    ground = plane([0, 0, 0], [0, 0, 1], (100, 100), instance_id=0)
    roof = box([0, 0, 5], [4, 4, 0.2], instance_id=1)
    rc = scene_of(Mesh.concatenate([ground, roof]))
    T_w_c = np.eye(4)
    T_w_c[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T_w_c[:3, 3] = [0, 0, 3]  # under the roof, looking down at shaded ground
    ambient = [0.3, 0.3, 0.3]
    albedo = np.array([[0.5, 0.5, 0.5], [0.1, 0.1, 0.1]])
    kwargs = dict(sun_direction=[0, 0, 1], ambient=ambient, noise_sigma=0.0)
    lit, _, _ = rc.render(T_w_c, np.array([[0, 0, 1.0]]), 1, 1, albedo, shadows=False, **kwargs)
    dark, _, _ = rc.render(T_w_c, np.array([[0, 0, 1.0]]), 1, 1, albedo, shadows=True, **kwargs)
    assert lit[0, 0, 0] == round(255 * (0.5 * (0.3 + 1.0)) ** (1 / 2.2))
    assert dark[0, 0, 0] == round(255 * (0.5 * 0.3) ** (1 / 2.2))


def test_render_bad_input_names_the_argument() -> None:
    rc = scene_of(box([0, 0, 0], [1, 1, 1], instance_id=0))
    rays = np.tile([0.0, 0.0, 1.0], (4, 1))
    albedo = np.ones((1, 3)) * 0.5
    with pytest.raises(ValueError, match="width"):
        rc.render(np.eye(4), rays[:0], 0, 2, albedo)
    with pytest.raises(ValueError, match="height"):
        rc.render(np.eye(4), rays[:0], 2, 0, albedo)
    with pytest.raises(ValueError, match="rays_c: expected 4 rows"):
        rc.render(np.eye(4), rays[:3], 2, 2, albedo)
    with pytest.raises(ValueError, match="T_w_c"):
        rc.render(np.diag([2.0, 1, 1, 1]), rays, 2, 2, albedo)
    with pytest.raises(ValueError, match="sun_direction"):
        rc.render(np.eye(4), rays, 2, 2, albedo, sun_direction=[0, 0, 0])
    with pytest.raises(ValueError, match="haze_density"):
        rc.render(np.eye(4), rays, 2, 2, albedo, haze_density=-1.0)
    with pytest.raises(ValueError, match="albedo"):
        rc.render(np.eye(4), rays, 2, 2, -albedo)


def test_render_noise_is_seeded() -> None:
    rc = scene_of(plane([0, 0, 0], [0, 0, 1], (100, 100), instance_id=0))
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[2, 3] = 5
    rays = np.tile([0.0, 0.0, 1.0], (64 * 64, 1))
    a = rc.render(T, rays, 64, 64, np.full((1, 3), 0.3), noise_sigma=4.0, seed=7)[0]
    b = rc.render(T, rays, 64, 64, np.full((1, 3), 0.3), noise_sigma=4.0, seed=7)[0]
    c = rc.render(T, rays, 64, 64, np.full((1, 3), 0.3), noise_sigma=4.0, seed=8)[0]
    clean = rc.render(T, rays, 64, 64, np.full((1, 3), 0.3), noise_sigma=0.0)[0]
    np.testing.assert_array_equal(a, b)
    assert np.any(a != c)
    noise = a.astype(float) - clean.astype(float)
    assert abs(noise.std() - 4.0) < 0.3 and abs(noise.mean()) < 0.2


# --- the mesh container ---------------------------------------------------------

def test_builders_wind_triangles_outward() -> None:
    for mesh, centre in [
        (box([1, 2, 3], [1, 2, 3], instance_id=0), np.array([1, 2, 3])),
        (cylinder([0, 0, 0], [1, 1, 1], 0.3, instance_id=0, segments=12), np.array([0.5, 0.5, 0.5])),
        (cylinder([0, 0, 0], [0, 0, 0.1], 0.5, radius_end=0.2, instance_id=0), np.array([0, 0, 0.05])),
    ]:
        tri = mesh.vertices[mesh.triangles]
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        assert np.all(np.einsum("ij,ij->i", normals, tri.mean(axis=1) - centre) > 0)
    p = plane([0, 0, 1], [1, 1, 0], (2, 3), instance_id=0)
    tri = p.vertices[p.triangles]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    np.testing.assert_allclose(n / np.linalg.norm(n, axis=1, keepdims=True), [[2**-0.5, 2**-0.5, 0]] * 2, atol=1e-12)
    assert np.isclose(np.linalg.norm(n, axis=1).sum() / 2, 6.0)


def test_concatenate_keeps_ids_and_refuses_conflicts() -> None:
    a = box([0, 0, 0], [1, 1, 1], instance_id=3, info=InstanceInfo("a", "tower"))
    b = cylinder([5, 0, 0], [5, 0, 1], 0.2, instance_id=7, info=InstanceInfo("b", "insulator"))
    m = Mesh.concatenate([a, b, a])
    assert m.n_triangles == 2 * a.n_triangles + b.n_triangles
    assert set(m.instances) == {3, 7} and m.instances[7].kind == "insulator"
    np.testing.assert_array_equal(m.vertices[m.triangles[-a.n_triangles:]], a.vertices[a.triangles])
    assert m.instance_ids_of_kind("insulator") == [7]
    assert m.albedo_table().shape == (8, 3)
    with pytest.raises(ValueError, match="instance id 3"):
        Mesh.concatenate([a, box([0, 0, 0], [1, 1, 1], instance_id=3, info=InstanceInfo("c", "tower"))])
    with pytest.raises(ValueError, match="kind"):
        InstanceInfo("x", "insulater")
    with pytest.raises(ValueError, match="return_probability"):
        InstanceInfo("x", return_probability=1.5)
    with pytest.raises(ValueError, match="triangles"):
        Mesh(np.zeros((3, 3)), np.array([[0, 1, 3]]), np.zeros(1, np.int32))
    with pytest.raises(ValueError, match="size"):
        box([0, 0, 0], [1, 0, 1], instance_id=0)
    with pytest.raises(ValueError, match="p1"):
        cylinder([0, 0, 0], [0, 0, 0], 1.0, instance_id=0)


def test_enclosing_instance_finds_points_inside_closed_meshes() -> None:
    m = Mesh.concatenate([
        plane([0, 0, 0], [0, 0, 1], (100, 100), instance_id=0, info=InstanceInfo("g", "ground")),
        box([0, 0, 5], [2, 2, 2], instance_id=4, info=InstanceInfo("b", "tower")),
    ])
    assert m.enclosing_instance([0, 0, 5]) == 4
    assert m.enclosing_instance([0, 0, -1]) == 0
    assert m.enclosing_instance([3, 0, 5]) is None
    assert m.enclosing_instance([0, 0, 7.5]) is None


def test_tower_hits_match_open3d_embree() -> None:
    """The sim's tower B mesh against Open3D's ``RaycastingScene`` (Embree, an independent
    caster): rays from around the tower toward its vertices and the inspection camera's view.

    Tolerance: 1e-4 m relative (Embree works in float32); hit versus miss may differ only on rays
    through an edge or grazing a face, which float32 rounds the other way (at most 1 in 1000).
    """
    o3d = pytest.importorskip("open3d")
    from insulator_rs.sim.towers import load_tower

    mesh = load_tower("tower_b").mesh
    rng = np.random.default_rng(7)
    n = 20_000
    v = mesh.vertices
    lo, hi = v.min(axis=0), v.max(axis=0)
    origins = rng.uniform(lo, hi, size=(n, 3)) * [0.3, 0.3, 1.0] + [0.0, 0.0, 0.5]
    targets = v[rng.integers(0, len(v), n)] + rng.normal(0.0, 0.05, (n, 3))
    dirs = targets - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs[: n // 4] = random_unit(rng, n // 4)  # a quarter in any direction: misses too
    ours = mesh.raycaster.cast(origins, dirs, np.inf)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor.from_numpy(np.ascontiguousarray(v, np.float32)),
                        o3d.core.Tensor.from_numpy(np.ascontiguousarray(mesh.triangles, np.uint32)))
    rays = np.ascontiguousarray(np.hstack([origins, dirs]), np.float32)
    theirs = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
    t_theirs = theirs["t_hit"].numpy().astype(np.float64)
    both = np.isfinite(ours.distance) & np.isfinite(t_theirs)
    assert both.mean() > 0.3 and (~np.isfinite(ours.distance)).mean() > 0.05
    np.testing.assert_allclose(ours.distance[both], t_theirs[both], rtol=1e-4, atol=1e-4)
    same_triangle = ours.triangle[both] == theirs["primitive_ids"].numpy()[both].astype(np.int64)
    assert same_triangle.mean() > 0.999
    assert (np.isfinite(ours.distance) != np.isfinite(t_theirs)).mean() <= 1e-3
