//! Ray casting against shapes whose hit distance is known in closed form.
//!
//! Reference: the exact ray/plane intersection, and Cyrus-Beck clipping of the
//! ray against the half-spaces of a convex polyhedron (a box; the faceted
//! prism a tessellated cylinder really is). Tolerance: 1e-6 m on distances.

mod common;

use std::f64::consts::PI;

use common::{aabb, cylinder_z, plane_z, Soup};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use scene_raycast::{RaycastError, Scene};

const TOL: f64 = 1e-6;

fn scene(soup: &Soup) -> Scene {
    match Scene::new(&soup.vertices, &soup.triangles, &soup.ids) {
        Ok(s) => s,
        Err(e) => panic!("test scene refused: {e}"),
    }
}

/// Entry distance of the ray into the convex set {x : n_i . x <= d_i}, None on a miss
/// (the origin must lie outside the set).
fn convex_entry(planes: &[(Vector3<f64>, f64)], o: &Vector3<f64>, d: &Vector3<f64>) -> Option<f64> {
    let (mut t_in, mut t_out) = (0.0_f64, f64::INFINITY);
    for (n, off) in planes {
        let denom = n.dot(d);
        let num = off - n.dot(o);
        if denom.abs() < 1e-15 {
            if num < 0.0 {
                return None;
            }
        } else if denom < 0.0 {
            t_in = t_in.max(num / denom);
        } else {
            t_out = t_out.min(num / denom);
        }
    }
    (t_in <= t_out).then_some(t_in)
}

fn box_planes(lo: [f64; 3], hi: [f64; 3]) -> Vec<(Vector3<f64>, f64)> {
    let mut planes = Vec::new();
    for k in 0..3 {
        let mut n = Vector3::zeros();
        n[k] = 1.0;
        planes.push((n, hi[k]));
        planes.push((-n, -lo[k]));
    }
    planes
}

fn prism_planes(r: f64, segments: u32, z0: f64, z1: f64) -> Vec<(Vector3<f64>, f64)> {
    let half = PI / f64::from(segments);
    let mut planes: Vec<_> = (0..segments)
        .map(|k| {
            let a = 2.0 * PI * f64::from(k) / f64::from(segments) + half;
            (Vector3::new(a.cos(), a.sin(), 0.0), r * half.cos())
        })
        .collect();
    planes.push((Vector3::z(), z1));
    planes.push((-Vector3::z(), -z0));
    planes
}

fn unit_sphere(rng: &mut Pcg64Mcg) -> Vector3<f64> {
    loop {
        let v = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let n = v.norm();
        if n > 0.1 && n < 1.0 {
            return v / n;
        }
    }
}

#[test]
fn plane_hit_distances_match_the_ray_plane_formula() {
    let s = scene(&plane_z(1.5, 500.0, 7));
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    let mut origins = Vec::new();
    let mut dirs = Vec::new();
    let mut expected = Vec::new();
    for _ in 0..2000 {
        let o = Vector3::new(
            rng.random_range(-50.0..50.0),
            rng.random_range(-50.0..50.0),
            rng.random_range(2.0..40.0),
        );
        let d = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            -rng.random_range(0.2..1.0),
        )
        .normalize();
        origins.push([o.x, o.y, o.z]);
        dirs.push([d.x, d.y, d.z]);
        expected.push((1.5 - o.z) / d.z);
    }
    let hits = s.cast(&origins, &dirs, f64::INFINITY).unwrap_or_default();
    assert_eq!(hits.len(), expected.len());
    for (i, want) in expected.iter().enumerate() {
        assert!(
            (hits.distance[i] - want).abs() < TOL,
            "ray {i}: {} vs {want}",
            hits.distance[i]
        );
        assert_eq!(hits.instance_id[i], 7);
        assert_eq!(hits.normal[i], [0.0, 0.0, 1.0]);
    }
}

#[test]
fn rays_away_from_the_plane_or_beyond_max_range_miss() {
    let s = scene(&plane_z(0.0, 100.0, 3));
    let origins = [
        [0.0, 0.0, 10.0],
        [0.0, 0.0, 10.0],
        [0.0, 0.0, 10.0],
        [0.0, 0.0, 10.0],
    ];
    let dirs = [
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        [0.0, 0.0, -2.0],
    ];
    let hits = s.cast(&origins, &dirs, 9.999).unwrap_or_default();
    assert_eq!(hits.instance_id, vec![-1; 4]);
    assert!(hits.distance.iter().all(|d| d.is_infinite()));
    assert_eq!(hits.triangle, vec![-1; 4]);
    // Within range, and with a non-unit direction: the distance is in metres.
    let hits = s.cast(&origins[2..], &dirs[2..], 10.0).unwrap_or_default();
    assert_eq!(hits.distance, vec![10.0, 10.0]);
}

#[test]
fn box_hit_distances_match_cyrus_beck() {
    let (lo, hi) = ([-1.0, -2.0, 0.5], [1.5, 2.0, 3.0]);
    let s = scene(&aabb(lo, hi, 4));
    let planes = box_planes(lo, hi);
    let mut rng = Pcg64Mcg::seed_from_u64(2);
    let mut n_hits = 0;
    for _ in 0..3000 {
        let o = 20.0 * unit_sphere(&mut rng) + Vector3::new(0.25, 0.0, 1.75);
        let target = Vector3::new(
            rng.random_range(-1.5..2.0),
            rng.random_range(-2.5..2.5),
            rng.random_range(0.0..3.5),
        );
        let d = (target - o).normalize();
        let expected = convex_entry(&planes, &o, &d);
        let hit = s.cast_one(&Point3::from(o), &d, f64::INFINITY);
        match (expected, hit) {
            (Some(t), Some(h)) => {
                n_hits += 1;
                assert!((h.distance - t).abs() < TOL, "{} vs {t}", h.distance);
                assert_eq!(h.instance_id, 4);
                // The face hit faces the ray (outward winding).
                assert!(h.normal.dot(&d) < 0.0);
            }
            (None, None) => {}
            // A ray that grazes an edge within float precision may go either way.
            (Some(t), None) | (None, Some(scene_raycast::Hit { distance: t, .. })) => {
                let p = o + d * t;
                let near_edge = (0..3)
                    .filter(|&k| (p[k] - lo[k]).abs() < 1e-5 || (p[k] - hi[k]).abs() < 1e-5)
                    .count()
                    >= 2;
                assert!(near_edge, "disagreement away from an edge at {p:?}");
            }
        }
    }
    assert!(n_hits > 1000, "too few hits to mean anything: {n_hits}");
}

#[test]
fn faceted_cylinder_hit_distances_match_the_exact_prism() {
    let (r, segments, z0, z1) = (0.8, 24, -1.0, 4.0);
    let s = scene(&cylinder_z(0.0, 0.0, r, z0, z1, segments, 9));
    let planes = prism_planes(r, segments, z0, z1);
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mut n_hits = 0;
    for _ in 0..3000 {
        let o = 15.0 * unit_sphere(&mut rng) + Vector3::new(0.0, 0.0, 1.5);
        let target = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.5..4.5),
        );
        let d = (target - o).normalize();
        let expected = convex_entry(&planes, &o, &d);
        let hit = s.cast_one(&Point3::from(o), &d, f64::INFINITY);
        if let (Some(t), Some(h)) = (expected, hit) {
            n_hits += 1;
            assert!((h.distance - t).abs() < TOL, "{} vs {t}", h.distance);
        } else {
            // Only a ray through a silhouette edge (within float precision) may disagree.
            let t = expected.or(hit.map(|h| h.distance)).unwrap_or(0.0);
            let p = o + d * t;
            let slack = planes
                .iter()
                .filter(|(n, off)| (n.dot(&p) - off).abs() < 1e-5)
                .count();
            assert!(
                expected.is_none() && hit.is_none() || slack >= 2,
                "disagreement at {p:?}"
            );
        }
    }
    assert!(n_hits > 1000, "too few hits: {n_hits}");
}

#[test]
fn finely_tessellated_cylinder_matches_the_true_cylinder_along_radial_rays() {
    // Sagitta of a 720-gon of radius 0.1 m: 0.1 (1 - cos(pi/720)) = 9.5e-7 m < TOL.
    let (r, segments) = (0.1, 720);
    let s = scene(&cylinder_z(2.0, -1.0, r, 0.0, 2.0, segments, 1));
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    for _ in 0..2000 {
        let a = rng.random_range(0.0..2.0 * PI);
        let z = rng.random_range(0.1..1.9);
        let dist0 = rng.random_range(1.0..30.0);
        let radial = Vector3::new(a.cos(), a.sin(), 0.0);
        let o = Vector3::new(2.0, -1.0, z) + radial * dist0;
        let hit = s.cast_one(&Point3::from(o), &(-radial), 100.0);
        let Some(h) = hit else {
            panic!("radial ray missed the cylinder")
        };
        assert!(
            (h.distance - (dist0 - r)).abs() < TOL,
            "{} vs {}",
            h.distance,
            dist0 - r
        );
    }
}

#[test]
fn nearest_of_several_instances_wins() {
    let mut soup = plane_z(0.0, 100.0, 0);
    soup.add(aabb([-1.0, -1.0, 0.0], [1.0, 1.0, 2.0], 1));
    soup.add(aabb([-1.0, -1.0, 5.0], [1.0, 1.0, 6.0], 2));
    let s = scene(&soup);
    let hits = s
        .cast(
            &[[0.0, 0.0, 10.0], [5.0, 5.0, 10.0], [0.0, 0.0, 3.0]],
            &[[0.0, 0.0, -1.0]; 3],
            50.0,
        )
        .unwrap_or_default();
    assert_eq!(hits.instance_id, vec![2, 0, 1]);
    assert!((hits.distance[0] - 4.0).abs() < TOL);
    assert!((hits.distance[1] - 10.0).abs() < TOL);
    assert!((hits.distance[2] - 1.0).abs() < TOL);
}

#[test]
fn bad_rays_are_refused_with_the_argument_named() {
    let s = scene(&plane_z(0.0, 1.0, 0));
    let err = s.cast(&[[0.0; 3]], &[[0.0; 3]], 1.0).err();
    assert_eq!(
        err,
        Some(RaycastError::ZeroDirection {
            name: "directions",
            index: 0
        })
    );
    let err = s
        .cast(&[[f64::NAN, 0.0, 0.0]], &[[0.0, 0.0, 1.0]], 1.0)
        .err();
    assert_eq!(
        err,
        Some(RaycastError::NonFiniteRay {
            name: "origins",
            index: 0
        })
    );
    let err = s.cast(&[[0.0; 3]; 2], &[[0.0, 0.0, 1.0]], 1.0).err();
    assert!(matches!(
        err,
        Some(RaycastError::LengthMismatch {
            name: "directions",
            expected: 2,
            got: 1
        })
    ));
    for bad in [0.0, -1.0, f64::NAN] {
        let err = s.cast(&[[0.0; 3]], &[[0.0, 0.0, 1.0]], bad).err();
        assert!(matches!(
            err,
            Some(RaycastError::BadParameter {
                name: "max_range",
                ..
            })
        ));
    }
    assert!(s.cast(&[], &[], 1.0).map(|h| h.is_empty()).unwrap_or(false));
}

#[test]
fn long_thin_triangles_boxed_piecewise_are_hit_everywhere() {
    // One 10 m x 5 cm sliver in the plane z = 1: its BVH leaves are pieces of it.
    // Rays straight down anywhere over it must hit at distance 4 (from z = 5).
    for n_extra in [0usize, 1] {
        let mut vertices = vec![[0.0, 0.0, 1.0], [10.0, 0.0, 1.0], [10.0, 0.05, 1.0]];
        let mut triangles = vec![[0u32, 1, 2]];
        if n_extra == 1 {
            vertices.extend([[0.0, 3.0, 1.0], [10.0, 3.0, 1.0], [10.0, 3.05, 1.0]]);
            triangles.push([3, 4, 5]);
        }
        let ids = vec![0; triangles.len()];
        let s = match Scene::new(&vertices, &triangles, &ids) {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        };
        let mut rng = Pcg64Mcg::seed_from_u64(5);
        for _ in 0..2000 {
            let x: f64 = rng.random_range(0.01..9.99);
            // Strictly inside: y < 0.05 x / 10.
            let y = rng.random_range(0.0..1.0) * 0.005 * x * 0.999;
            let hit = s.cast_one(&Point3::new(x, y, 5.0), &-Vector3::z(), 10.0);
            assert!(
                hit.is_some_and(|h| (h.distance - 4.0).abs() < TOL && h.triangle == 0),
                "missed at x={x}"
            );
        }
    }
}
