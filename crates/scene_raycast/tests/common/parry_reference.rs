//! The previous ray caster (parry3d's PLOC BVH that culls in f32, f64
//! Moeller-Trumbore on the candidates), kept as the reference that the crate's
//! own BVH must match: the parity tests and the bench compare against it.
#![allow(dead_code)]

use nalgebra::{Point3, Vector3};
use parry3d::bounding_volume::Aabb;
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhNode};
use std::cell::Cell;

/// Loosening of the f32 bounding boxes, m, so that rounding never culls a hit.
const AABB_MARGIN: f64 = 1e-5;
/// |det| below this (relative to the edge lengths) is a ray in the triangle's plane.
const PARALLEL_DETERMINANT: f64 = 1e-14;

/// The reference scene (no validation, no instance ids).
pub struct ParryScene {
    bvh: Bvh,
    /// Triangle of each BVH leaf (a long thin triangle has several leaves). Leaf
    /// ids must be unique in parry's `Bvh`, hence this map.
    leaf_triangle: Vec<u32>,
    /// W coordinates of the origin of the BVH's (f32) frame.
    center: Vector3<f64>,
    vertices: Vec<Point3<f64>>,
    triangles: Vec<[u32; 3]>,
}

impl ParryScene {
    /// Builds the reference over already validated input.
    pub fn new(vertices: &[[f64; 3]], triangles: &[[u32; 3]]) -> Self {
        let points: Vec<Point3<f64>> = vertices
            .iter()
            .map(|v| Point3::new(v[0], v[1], v[2]))
            .collect();
        let (lo, hi) = points.iter().fold(
            (
                Vector3::repeat(f64::INFINITY),
                Vector3::repeat(f64::NEG_INFINITY),
            ),
            |(lo, hi), p| (lo.inf(&p.coords), hi.sup(&p.coords)),
        );
        let center = 0.5 * (lo + hi);
        let (leaf_triangle, boxes) = leaf_boxes(&points, triangles, &center);
        // PLOC: slower to build than binned SAH, better trees for heavy ray casting.
        let bvh = Bvh::from_leaves(BvhBuildStrategy::Ploc, &boxes);
        Self {
            bvh,
            leaf_triangle,
            center,
            vertices: points,
            triangles: triangles.to_vec(),
        }
    }

    /// Casts one ray; `direction` must be a unit vector, `max_range` > 0 (may be
    /// infinite). Returns the nearest hit with distance in [0, max_range].
    pub fn cast_one(
        &self,
        origin: &Point3<f64>,
        direction: &Vector3<f64>,
        max_range: f64,
    ) -> Option<(f64, u32)> {
        let local = origin.coords - self.center;
        let slab = Slab::new(&local, direction);
        // A little slack so that f32 rounding cannot lose a hit right at max_range.
        let bvh_max = if max_range.is_finite() {
            (max_range * (1.0 + 1e-5) + 1e-3) as f32
        } else {
            f32::MAX
        };
        // The BVH compares f32 distances; the f64 answer is kept beside it.
        let best: Cell<Option<(f64, u32)>> = Cell::new(None);
        // Best-first search of parry's BVH, with a slab test on the precomputed
        // inverse direction (parry's own `Bvh::cast_ray` runs its general AABB ray
        // cast at every node).
        self.bvh.find_best(
            bvh_max,
            |node, best| slab.entry(node, best),
            |leaf, _| {
                let tri = *self.leaf_triangle.get(leaf as usize)?;
                let t = self.intersect(tri, origin, direction)?;
                if t <= max_range && best.get().is_none_or(|(b, _)| t < b) {
                    best.set(Some((t, tri)));
                }
                Some(t as f32)
            },
        );
        best.get()
    }

    /// Distance along the unit `direction` at which the ray meets triangle `t`
    /// (either side), f64 Moeller-Trumbore; None if it does not.
    fn intersect(&self, t: u32, origin: &Point3<f64>, direction: &Vector3<f64>) -> Option<f64> {
        let [ia, ib, ic] = *self.triangles.get(t as usize)?;
        let a = self.vertices[ia as usize];
        let e1 = self.vertices[ib as usize] - a;
        let e2 = self.vertices[ic as usize] - a;
        let p = direction.cross(&e2);
        let det = e1.dot(&p);
        if det.abs() < PARALLEL_DETERMINANT * e1.norm() * e2.norm() {
            return None;
        }
        let inv = 1.0 / det;
        let s = origin - a;
        let u = s.dot(&p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(&e1);
        let v = direction.dot(&q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let distance = e2.dot(&q) * inv;
        (distance >= 0.0).then_some(distance)
    }
}

/// The BVH's leaves: (triangle of each leaf, loosened f32 box of each leaf relative
/// to `center`), one per triangle. (The shipped caster had one leaf per piece of a
/// long thin triangle; that only changed which boxes culled, never a hit.)
fn leaf_boxes(
    points: &[Point3<f64>],
    triangles: &[[u32; 3]],
    center: &Vector3<f64>,
) -> (Vec<u32>, Vec<Aabb>) {
    let pad = |v: &Vector3<f64>| v.map(|x| AABB_MARGIN + 1e-6 * x.abs());
    let boxes = triangles
        .iter()
        .map(|tri| {
            let c = tri.map(|i| points[i as usize].coords - center);
            let lo = c[0].inf(&c[1]).inf(&c[2]);
            let hi = c[0].sup(&c[1]).sup(&c[2]);
            Aabb::new(
                Point3::from((lo - pad(&lo)).map(|x| x as f32)),
                Point3::from((hi + pad(&hi)).map(|x| x as f32)),
            )
        })
        .collect();
    ((0..triangles.len() as u32).collect(), boxes)
}

/// A ray in the BVH's f32 frame, ready for slab tests against node boxes.
struct Slab {
    origin: Vector3<f32>,
    inv_dir: Vector3<f32>,
}

impl Slab {
    fn new(local_origin: &Vector3<f64>, direction: &Vector3<f64>) -> Self {
        Self {
            origin: local_origin.map(|c| c as f32),
            // Infinite for a ray parallel to an axis (handled in `entry`).
            inv_dir: direction.map(|c| 1.0 / c as f32),
        }
    }

    /// Distance at which the ray enters `node`'s box (0 from inside), or
    /// `f32::MAX` when it misses it or enters beyond `best`.
    #[inline]
    fn entry(&self, node: &BvhNode, best: f32) -> f32 {
        let (mins, maxs) = (node.mins(), node.maxs());
        let mut t_in = 0.0f32;
        let mut t_out = best;
        for k in 0..3 {
            if self.inv_dir[k].is_infinite() {
                // Parallel to this slab: inside it for ever, or never.
                if self.origin[k] < mins[k] || self.origin[k] > maxs[k] {
                    return f32::MAX;
                }
                continue;
            }
            let t1 = (mins[k] - self.origin[k]) * self.inv_dir[k];
            let t2 = (maxs[k] - self.origin[k]) * self.inv_dir[k];
            t_in = t_in.max(t1.min(t2));
            t_out = t_out.min(t1.max(t2));
        }
        if t_in <= t_out {
            t_in
        } else {
            f32::MAX
        }
    }
}
