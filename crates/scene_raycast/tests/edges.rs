//! Rays on the boundaries of the BVH's f32 triangle filter, against a
//! brute-force f64 Moeller-Trumbore over every triangle (`common::brute_force`).
//!
//! Reference and tolerance: exact (distance bit for bit, same triangle; the
//! occlusion answer equal to the brute force's hit or miss). The filter drops a
//! triangle only where its error bound proves the exact test would, so rays
//! aimed exactly at edges and vertices, grazing rays nearly in a facet's plane,
//! rays starting on a surface, ranges that end exactly at the hit, and origins
//! from millimetres to kilometres away, in a scene near the world origin and in
//! one at map coordinates (5,000 km out), must all get the exact answer.

mod common;

use common::{brute_force, random_unit as unit, Soup};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use scene_raycast::Scene;

/// Rays per scene.
const RAYS: usize = 1500;

fn scene(soup: &Soup) -> Scene {
    match Scene::new(&soup.vertices, &soup.triangles, &soup.ids) {
        Ok(s) => s,
        Err(e) => panic!("{e}"),
    }
}

/// A ray (origin, unit direction, range) through a point exactly on an edge or
/// a vertex of a random triangle, or nearly in its plane, or from its surface.
fn boundary_ray(soup: &Soup, rng: &mut Pcg64Mcg) -> (Point3<f64>, Vector3<f64>, f64) {
    let t = soup.triangles[rng.random_range(0..soup.triangles.len())];
    let [a, b, c] = t.map(|i| Point3::from(soup.vertices[i as usize]));
    let (e1, e2) = (b - a, c - a);
    let normal = e1.cross(&e2).normalize();
    let w: f64 = rng.random_range(0.0..1.0);
    let target = match rng.random_range(0..5) {
        0 => a + e1 * w,                  // edge ab (v = 0)
        1 => a + e2 * w,                  // edge ac (u = 0)
        2 => a + e1 * w + e2 * (1.0 - w), // edge bc (u + v = 1)
        3 => [a, b, c][rng.random_range(0..3)],
        _ => a + e1 * (0.5 * w) + e2 * (0.5 * (1.0 - w)),
    };
    let direction = match rng.random_range(0..3) {
        // Grazing: along an edge, tilted off the facet's plane by 1e-9 to 1e-3 rad.
        0 => {
            let along = (if rng.random_bool(0.5) { e1 } else { e2 - e1 }).normalize();
            let tilt = 10f64.powf(rng.random_range(-9.0..-3.0));
            (along + normal * tilt * if rng.random_bool(0.5) { 1.0 } else { -1.0 }).normalize()
        }
        1 => (-normal + unit(rng) * 0.5).normalize(),
        _ => unit(rng),
    };
    let distance = [0.0, 1e-3, 0.5, 20.0, 600.0, 4000.0][rng.random_range(0..6)];
    let origin = target - direction * distance;
    let range = match rng.random_range(0..3) {
        // Ends at the target itself (the filter's limit at the boundary).
        0 if distance > 0.0 => (target - origin).norm(),
        1 => rng.random_range(0.1..50.0),
        _ => f64::INFINITY,
    };
    (origin, direction, range)
}

fn check(soup: &Soup, seed: u64) {
    let scene = scene(soup);
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut hits = 0;
    for i in 0..RAYS {
        let (o, d, range) = boundary_ray(soup, &mut rng);
        let exact = brute_force(soup, &o, &d, range);
        let got = scene.cast_one(&o, &d, range);
        assert_eq!(
            got.map(|h| (h.distance, h.triangle)),
            exact,
            "ray {i} ({o}, {d}, range {range})"
        );
        assert_eq!(
            scene.occluded(&o, &d, range),
            exact.is_some(),
            "ray {i}: occlusion"
        );
        // The same ray inside a packet of rays from its origin.
        let mut dirs: Vec<Vector3<f64>> = (0..7).map(|_| unit(&mut rng)).collect();
        dirs.insert(3, d);
        let origins = vec![o; dirs.len()];
        let mut packet = vec![None; dirs.len()];
        assert_eq!(
            scene.cast_packet(&origins, &dirs, range, &mut packet),
            Ok(())
        );
        assert_eq!(packet[3], got, "ray {i}: in a packet");
        hits += usize::from(exact.is_some());
    }
    assert!(hits > RAYS / 2, "{hits} hits of {RAYS} rays");
}

#[test]
fn boundary_rays_match_brute_force_exactly() {
    check(&common::tower_like(150, 8), 21);
}

#[test]
fn boundary_rays_match_brute_force_exactly_at_map_coordinates() {
    let mut soup = common::tower_like(150, 8);
    for v in &mut soup.vertices {
        *v = [v[0] + 312_345.678, v[1] + 5_012_345.678, v[2] + 250.0];
    }
    check(&soup, 22);
}
