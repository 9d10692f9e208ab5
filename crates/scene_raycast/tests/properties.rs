//! Property tests: scene validation never panics and names the fault; casting
//! random triangle soups agrees with a brute-force f64 Moeller-Trumbore over
//! every triangle (reference), to 1e-6 m relative, away from triangle edges.

mod common;

use nalgebra::{Point3, Vector3};
use proptest::prelude::*;
use scene_raycast::{RaycastError, Scene};

/// (distance, barycentric margin) of the nearest hit, brute force.
fn brute_force(
    v: &[[f64; 3]],
    tris: &[[u32; 3]],
    o: Vector3<f64>,
    d: Vector3<f64>,
) -> Option<(f64, f64)> {
    let mut best: Option<(f64, f64)> = None;
    for t in tris {
        let [a, b, c] = t.map(|i| Vector3::from(v[i as usize]));
        let (e1, e2) = (b - a, c - a);
        let p = d.cross(&e2);
        let det = e1.dot(&p);
        if det.abs() < 1e-12 {
            continue;
        }
        let s = o - a;
        let u = s.dot(&p) / det;
        let q = s.cross(&e1);
        let w = d.dot(&q) / det;
        let dist = e2.dot(&q) / det;
        let margin = u.min(w).min(1.0 - u - w);
        if margin >= 0.0 && dist >= 0.0 && best.is_none_or(|(bd, _)| dist < bd) {
            best = Some((dist, margin));
        }
    }
    best
}

/// Smallest barycentric coordinate of the ray's crossing of the one triangle, if it is ahead.
fn brute_force_margin(
    v: &[[f64; 3]],
    tris: &[[u32; 3]],
    o: Vector3<f64>,
    d: Vector3<f64>,
) -> Option<f64> {
    let [a, b, c] = tris[0].map(|i| Vector3::from(v[i as usize]));
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(&e2);
    let det = e1.dot(&p);
    let s = o - a;
    let q = s.cross(&e1);
    let (u, w, t) = (s.dot(&p) / det, d.dot(&q) / det, e2.dot(&q) / det);
    (t >= 0.0).then_some(u.min(w).min(1.0 - u - w))
}

fn coord() -> impl Strategy<Value = f64> {
    -5.0..5.0f64
}

/// A coordinate that is now and then NaN or infinite.
fn maybe_bad() -> BoxedStrategy<f64> {
    prop_oneof![8 => -5.0..5.0f64, 1 => Just(f64::NAN), 1 => Just(f64::INFINITY)].boxed()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn random_soups_match_brute_force(
        verts in prop::collection::vec([coord(), coord(), coord()], 3..60),
        rays in prop::collection::vec(([coord(), coord(), coord()], [coord(), coord(), coord()]), 1..40),
    ) {
        let n_tris = verts.len() / 3;
        let tris: Vec<[u32; 3]> = (0..n_tris as u32).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        let ids: Vec<i32> = (0..n_tris as i32).collect();
        let scene = match Scene::new(&verts, &tris, &ids) {
            Ok(s) => s,
            // Random triangles can be degenerate; that is reported, never a panic.
            Err(RaycastError::DegenerateTriangle { .. }) => return Ok(()),
            Err(e) => return Err(TestCaseError::fail(format!("unexpected error {e}"))),
        };
        for (o, d) in rays {
            let o = Vector3::from(o);
            let d = Vector3::from(d);
            let Some(d) = d.try_normalize(1e-6) else { continue };
            let hit = scene.cast_one(&Point3::from(o), &d, f64::INFINITY);
            match brute_force(&verts, &tris, o, d) {
                Some((_, margin)) if margin < 1e-4 => {} // through an edge: either answer is fine
                Some((t, _)) => {
                    let got = hit.map(|h| h.distance);
                    prop_assert!(got.is_some_and(|g| (g - t).abs() <= 1e-6 * (1.0 + t)), "{got:?} vs {t}");
                }
                None => {
                    // A hit the reference does not see must be on an edge (f32 BVH rounding):
                    // the reference then finds it with a slightly negative margin.
                    if let Some(h) = hit {
                        let tri = [tris[h.triangle as usize]];
                        let widened = brute_force_margin(&verts, &tri, o, d);
                        prop_assert!(widened.is_some_and(|m| m > -1e-4), "hit {h:?} missed by the reference");
                    }
                }
            }
        }
    }

    #[test]
    fn validation_never_panics_and_names_the_argument(
        verts in prop::collection::vec([maybe_bad(), maybe_bad(), maybe_bad()], 0..12),
        tris in prop::collection::vec([0u32..15, 0u32..15, 0u32..15], 0..8),
        ids in prop::collection::vec(-2i32..5, 0..8),
    ) {
        match Scene::new(&verts, &tris, &ids) {
            Ok(scene) => {
                prop_assert_eq!(scene.n_triangles(), tris.len());
                prop_assert!(verts.iter().all(|v| v.iter().all(|c| c.is_finite())));
                prop_assert!(ids.iter().all(|&i| i >= 0));
            }
            Err(e) => {
                let text = e.to_string();
                prop_assert!(
                    text.starts_with("vertices:") || text.starts_with("triangles:") || text.starts_with("instance_ids:"),
                    "{}", text
                );
            }
        }
    }

    #[test]
    fn cast_results_are_in_range_and_consistent(
        origins in prop::collection::vec([coord(), coord(), coord()], 0..30),
        max_range in 0.01..20.0f64,
    ) {
        let mut soup = common::aabb([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], 3);
        soup.add(common::plane_z(-2.0, 50.0, 0));
        let scene = Scene::new(&soup.vertices, &soup.triangles, &soup.ids).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let dirs: Vec<[f64; 3]> = origins.iter().map(|o| [-o[0] + 0.1, -o[1] + 0.2, -o[2] - 0.3]).collect();
        let hits = scene.cast(&origins, &dirs, max_range).map_err(|e| TestCaseError::fail(e.to_string()))?;
        prop_assert_eq!(hits.len(), origins.len());
        for i in 0..hits.len() {
            if hits.instance_id[i] < 0 {
                prop_assert!(hits.distance[i].is_infinite() && hits.triangle[i] == -1);
            } else {
                prop_assert!(hits.distance[i] >= 0.0 && hits.distance[i] <= max_range);
                let t = usize::try_from(hits.triangle[i]).map_err(|e| TestCaseError::fail(e.to_string()))?;
                prop_assert_eq!(scene.triangle_instance(t), Some(hits.instance_id[i]));
                let n = Vector3::from(hits.normal[i]);
                prop_assert!((n.norm() - 1.0).abs() < 1e-12);
            }
        }
    }
}
