//! The crate's BVH against the previous caster (parry3d's BVH culling in f32,
//! f64 Moeller-Trumbore on its candidates: `common::parry_reference`), ray for
//! ray, on lattice towers like the simulator's and a dense thicket.
//!
//! Reference and tolerance: the same nearest hit (both miss, or both hit within
//! 1e-6 m, on the same triangle unless the ray crosses an edge two triangles
//! share at the same distance), for random rays from outside and inside the
//! scene, rays starting inside node boxes (on member surfaces), grazing rays in
//! the plane of the ground and of facets, axis-parallel rays, and finite ranges.
//! Where the two disagree, an exact f64 Moeller-Trumbore over every triangle
//! settles it, and the crate's answer must be that one (to 1e-12 m relative): the
//! reference culls in f32 from the ray's own origin, which loses hits by a few
//! 1e-5 m from origins hundreds of metres off, and it keeps the first of two
//! triangles that meet the ray 1e-10 m apart at a shared edge.
//! The occlusion test agrees with `cast_one(..).is_some()` on every ray.

mod common;

use common::parry_reference::ParryScene;
use common::{brute_force, random_unit as unit, Soup};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use scene_raycast::Scene;

const TOL: f64 = 1e-6;

fn scenes(soup: &Soup) -> (Scene, ParryScene) {
    match Scene::new(&soup.vertices, &soup.triangles, &soup.ids) {
        Ok(s) => (s, ParryScene::new(&soup.vertices, &soup.triangles)),
        Err(e) => panic!("test scene refused: {e}"),
    }
}

/// Rays of every kind the simulator and the edge cases produce.
fn rays(soup: &Soup, rng: &mut Pcg64Mcg, n: usize) -> Vec<(Point3<f64>, Vector3<f64>, f64)> {
    let mut out = Vec::with_capacity(n);
    let vertex = |rng: &mut Pcg64Mcg| {
        let v = soup.vertices[rng.random_range(0..soup.vertices.len())];
        Point3::from(v)
    };
    let axes = [
        Vector3::x(),
        Vector3::y(),
        Vector3::z(),
        -Vector3::x(),
        -Vector3::y(),
        -Vector3::z(),
    ];
    for k in 0..n {
        let ray = match k % 8 {
            // From around the tower (camera / LiDAR standpoints) toward it.
            0 => {
                let o = Point3::new(
                    rng.random_range(-40.0..40.0),
                    rng.random_range(-40.0..40.0),
                    rng.random_range(0.5..45.0),
                );
                let target = vertex(rng);
                ((o), (target - o).normalize(), f64::INFINITY)
            }
            // Anywhere inside the tower's volume, any direction.
            1 => {
                let o = Point3::new(
                    rng.random_range(-8.0..8.0),
                    rng.random_range(-8.0..8.0),
                    rng.random_range(0.0..35.0),
                );
                (o, unit(rng), f64::INFINITY)
            }
            // Starting on (or just off) a surface vertex, inside the leaf boxes.
            2 => {
                let o = vertex(rng) + unit(rng) * rng.random_range(0.0..0.01);
                (o, unit(rng), f64::INFINITY)
            }
            // Grazing the ground plane z = 0 (in its plane or nearly).
            3 => {
                let o = Point3::new(
                    rng.random_range(-60.0..60.0),
                    rng.random_range(-60.0..60.0),
                    [0.0, 1e-9, -1e-9, 1e-4][rng.random_range(0..4)],
                );
                let mut d = unit(rng);
                d.z = [0.0, 1e-7, -1e-7][rng.random_range(0..3)];
                (o, d.normalize(), f64::INFINITY)
            }
            // Along a facet: from one vertex of a triangle through another.
            4 => {
                let t = soup.triangles[rng.random_range(0..soup.triangles.len())];
                let a = Point3::from(soup.vertices[t[0] as usize]);
                let b = Point3::from(soup.vertices[t[1] as usize]);
                let o = a - (b - a) * rng.random_range(0.0..3.0);
                (o, (b - a).normalize(), f64::INFINITY)
            }
            // Axis-parallel from anywhere.
            5 => {
                let o = Point3::new(
                    rng.random_range(-30.0..30.0),
                    rng.random_range(-30.0..30.0),
                    rng.random_range(-5.0..50.0),
                );
                (o, axes[rng.random_range(0..6)], f64::INFINITY)
            }
            // Finite ranges, ending near hits.
            6 => {
                let o = Point3::new(
                    rng.random_range(-20.0..20.0),
                    rng.random_range(-20.0..20.0),
                    rng.random_range(0.5..40.0),
                );
                let target = vertex(rng);
                let d = target - o;
                (o, d.normalize(), d.norm() * rng.random_range(0.9..1.1))
            }
            // From far away (a camera hundreds of metres off).
            _ => {
                let o = Point3::from(unit(rng) * 600.0) + Vector3::new(0.0, 0.0, 300.0);
                let target = vertex(rng);
                (o, (target - o).normalize(), f64::INFINITY)
            }
        };
        out.push(ray);
    }
    out
}

fn check(soup: &Soup, n: usize, seed: u64) {
    let (scene, reference) = scenes(soup);
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let (mut hits, mut misses, mut disagreements) = (0, 0, 0);
    for (i, (o, d, range)) in rays(soup, &mut rng, n).into_iter().enumerate() {
        let got = scene.cast_one(&o, &d, range);
        let want = reference.cast_one(&o, &d, range);
        let same = match (got, want) {
            (None, None) => true,
            // Another triangle at the same distance: an edge or vertex they share.
            (Some(g), Some((t, tri))) => {
                (g.triangle == tri && (g.distance - t).abs() <= TOL)
                    || (g.distance - t).abs() <= 1e-12 * (1.0 + t)
            }
            _ => false,
        };
        if !same {
            disagreements += 1;
            let exact = brute_force(soup, &o, &d, range);
            let agree = match (got, exact) {
                (None, None) => true,
                (Some(g), Some((t, _))) => (g.distance - t).abs() <= 1e-12 * (1.0 + t),
                _ => false,
            };
            assert!(
                agree,
                "ray {i} ({o}, {d}, range {range}): {got:?}, reference {want:?}, exact {exact:?}"
            );
        }
        match got {
            Some(_) => hits += 1,
            None => misses += 1,
        }
        assert_eq!(
            scene.occluded(&o, &d, range),
            got.is_some(),
            "ray {i}: occlusion"
        );
    }
    // The rays must exercise both outcomes.
    assert!(
        hits > n / 10 && misses > n / 20,
        "{hits} hits, {misses} misses"
    );
    // Disagreements are the reference's rare f32 losses, never more.
    assert!(
        disagreements * 100 < n,
        "{disagreements} disagreements in {n} rays"
    );
    println!("{n} rays: {hits} hits, {misses} misses, {disagreements} settled by brute force");
}

#[test]
fn lattice_tower_matches_the_parry_reference() {
    check(&common::lattice_tower(), 40_000, 1);
}

#[test]
fn dense_thicket_matches_the_parry_reference() {
    check(&common::tower_like(2000, 8), 20_000, 2);
}

#[test]
fn batch_cast_matches_one_by_one() {
    let soup = common::lattice_tower();
    let (scene, _) = scenes(&soup);
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let rays = rays(&soup, &mut rng, 5000);
    let origins: Vec<[f64; 3]> = rays.iter().map(|(o, _, _)| [o.x, o.y, o.z]).collect();
    let dirs: Vec<[f64; 3]> = rays.iter().map(|(_, d, _)| [d.x, d.y, d.z]).collect();
    let hits = match scene.cast(&origins, &dirs, 30.0) {
        Ok(h) => h,
        Err(e) => panic!("{e}"),
    };
    for (i, (o, d, _)) in rays.iter().enumerate() {
        // The batch normalises the directions again, as here.
        let one = scene.cast_one(o, &(d / d.norm()), 30.0);
        assert_eq!(
            one.map_or(f64::INFINITY, |h| h.distance),
            hits.distance[i],
            "ray {i}"
        );
        assert_eq!(
            one.map_or(-1, |h| i64::from(h.triangle)),
            hits.triangle[i],
            "ray {i}"
        );
    }
}
