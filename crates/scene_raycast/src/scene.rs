//! A triangle scene in the world frame W and batched ray casting against it.
//!
//! The BVH is parry3d's (`Bvh`, PLOC-built, single precision) over slightly
//! loosened bounding boxes of the triangles, with coordinates taken relative to the
//! centre of the scene's bounds. parry3d 0.25 is f32 only, which would put hit
//! distances off by ~1e-5 m at tower scale, so the BVH only culls: each candidate
//! triangle is intersected in f64 (Moeller-Trumbore) from the original vertices.
//! Long thin triangles get several boxes (see [`BVH_SPLIT_EDGE`]); the triangle
//! itself is never cut, so the surface stays exactly the input's, without cracks.

use nalgebra::{Point3, Vector3};
use parry3d::bounding_volume::Aabb;
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhNode};
use rayon::prelude::*;
use std::cell::Cell;

use crate::error::RaycastError;

/// Triangles with a smaller area (m^2) are refused as degenerate.
pub const MIN_TRIANGLE_AREA: f64 = 1e-14;
/// Triangles get one BVH box per piece (longest edge halved, recursively) while
/// their longest edge exceeds this many metres and is also more than
/// [`BVH_SPLIT_ASPECT`] times the triangle's height over it: the single box of a
/// long thin facet (the side of a diagonal lattice member) is mostly empty space.
/// (On tower A the gain is small; 0.4 m / aspect 2 was no faster and built 4x slower.)
pub const BVH_SPLIT_EDGE: f64 = 1.0;
/// See [`BVH_SPLIT_EDGE`].
pub const BVH_SPLIT_ASPECT: f64 = 4.0;
/// Rays handed to one rayon task at a time.
const RAYS_PER_TASK: usize = 512;
/// Loosening of the f32 bounding boxes, m, so that rounding never culls a hit.
const AABB_MARGIN: f64 = 1e-5;
/// |det| below this (relative to the edge lengths) is a ray in the triangle's plane.
const PARALLEL_DETERMINANT: f64 = 1e-14;

/// The result of one ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance along the unit direction, m.
    pub distance: f64,
    /// Index of the triangle hit.
    pub triangle: u32,
    /// Instance id of that triangle.
    pub instance_id: i32,
    /// Unit geometric normal of the triangle in W, oriented by its winding
    /// (counter-clockwise = front); it may face away from the ray (a back face).
    pub normal: Vector3<f64>,
}

/// Hits of a batch of rays, one entry per ray (structure of arrays).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Hits {
    /// m; `f64::INFINITY` on a miss.
    pub distance: Vec<f64>,
    /// -1 on a miss.
    pub instance_id: Vec<i32>,
    /// -1 on a miss.
    pub triangle: Vec<i64>,
    /// Unit winding normal in W; zero on a miss.
    pub normal: Vec<[f64; 3]>,
}

impl Hits {
    fn from_options(hits: Vec<Option<Hit>>) -> Self {
        let n = hits.len();
        let mut out = Hits {
            distance: Vec::with_capacity(n),
            instance_id: Vec::with_capacity(n),
            triangle: Vec::with_capacity(n),
            normal: Vec::with_capacity(n),
        };
        for hit in hits {
            match hit {
                Some(h) => {
                    out.distance.push(h.distance);
                    out.instance_id.push(h.instance_id);
                    out.triangle.push(i64::from(h.triangle));
                    out.normal.push([h.normal.x, h.normal.y, h.normal.z]);
                }
                None => {
                    out.distance.push(f64::INFINITY);
                    out.instance_id.push(-1);
                    out.triangle.push(-1);
                    out.normal.push([0.0; 3]);
                }
            }
        }
        out
    }

    /// Number of rays.
    pub fn len(&self) -> usize {
        self.distance.len()
    }

    /// True when the batch held no ray.
    pub fn is_empty(&self) -> bool {
        self.distance.is_empty()
    }
}

/// A static triangle scene in W with one instance id per triangle.
pub struct Scene {
    bvh: Bvh,
    /// Triangle of each BVH leaf (a long thin triangle has several leaves). Leaf
    /// ids must be unique in parry's `Bvh`, hence this map.
    leaf_triangle: Vec<u32>,
    /// W coordinates of the origin of the BVH's (f32) frame.
    center: Vector3<f64>,
    vertices: Vec<Point3<f64>>,
    triangles: Vec<[u32; 3]>,
    normals: Vec<Vector3<f64>>,
    instance_ids: Vec<i32>,
}

impl std::fmt::Debug for Scene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene")
            .field("n_vertices", &self.vertices.len())
            .field("n_triangles", &self.triangles.len())
            .finish()
    }
}

impl Scene {
    /// Builds a scene, validating every input.
    ///
    /// `vertices` in W (m), `triangles` as vertex indices, `instance_ids` one
    /// non-negative id per triangle.
    pub fn new(
        vertices: &[[f64; 3]],
        triangles: &[[u32; 3]],
        instance_ids: &[i32],
    ) -> Result<Self, RaycastError> {
        if triangles.is_empty() {
            return Err(RaycastError::EmptyScene);
        }
        if instance_ids.len() != triangles.len() {
            return Err(RaycastError::InstanceCountMismatch {
                expected: triangles.len(),
                got: instance_ids.len(),
            });
        }
        if let Some(index) = vertices
            .iter()
            .position(|v| !v.iter().all(|c| c.is_finite()))
        {
            return Err(RaycastError::NonFiniteVertex { index });
        }
        if let Some((triangle, &id)) = instance_ids.iter().enumerate().find(|(_, &id)| id < 0) {
            return Err(RaycastError::NegativeInstanceId { triangle, id });
        }
        let points: Vec<Point3<f64>> = vertices
            .iter()
            .map(|v| Point3::new(v[0], v[1], v[2]))
            .collect();
        let mut normals = Vec::with_capacity(triangles.len());
        for (t, tri) in triangles.iter().enumerate() {
            for &vertex in tri {
                if vertex as usize >= points.len() {
                    return Err(RaycastError::IndexOutOfRange {
                        triangle: t,
                        vertex,
                        n_vertices: points.len(),
                    });
                }
            }
            let [a, b, c] = tri.map(|i| points[i as usize]);
            let cross = (b - a).cross(&(c - a));
            let area = 0.5 * cross.norm();
            // `!(area >= MIN)` also catches a NaN area from overflowing coordinates.
            if area.is_nan() || area < MIN_TRIANGLE_AREA {
                return Err(RaycastError::DegenerateTriangle { triangle: t, area });
            }
            normals.push(cross / (2.0 * area));
        }
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
        Ok(Self {
            bvh,
            leaf_triangle,
            center,
            vertices: points,
            triangles: triangles.to_vec(),
            normals,
            instance_ids: instance_ids.to_vec(),
        })
    }

    /// Number of triangles.
    pub fn n_triangles(&self) -> usize {
        self.triangles.len()
    }

    /// Unit winding normal of triangle `t` in W (None if out of range).
    pub fn triangle_normal(&self, t: usize) -> Option<Vector3<f64>> {
        self.normals.get(t).copied()
    }

    /// Instance id of triangle `t` (None if out of range).
    pub fn triangle_instance(&self, t: usize) -> Option<i32> {
        self.instance_ids.get(t).copied()
    }

    /// Casts one ray; `direction` must be a unit vector, `max_range` > 0 (may be
    /// infinite). Returns the nearest hit with distance in [0, max_range].
    pub fn cast_one(
        &self,
        origin: &Point3<f64>,
        direction: &Vector3<f64>,
        max_range: f64,
    ) -> Option<Hit> {
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
        let (distance, tri) = best.get()?;
        let t = tri as usize;
        Some(Hit {
            distance,
            triangle: tri,
            instance_id: self.instance_ids[t],
            normal: self.normals[t],
        })
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

    /// Casts a batch of rays in parallel.
    ///
    /// `origins` and `directions` in W, one row per ray; directions need not be
    /// unit (they are normalised; distances are in metres along them).
    /// `max_range` > 0 (m), `f64::INFINITY` allowed.
    pub fn cast(
        &self,
        origins: &[[f64; 3]],
        directions: &[[f64; 3]],
        max_range: f64,
    ) -> Result<Hits, RaycastError> {
        validate_max_range(max_range)?;
        if directions.len() != origins.len() {
            return Err(RaycastError::LengthMismatch {
                name: "directions",
                expected: origins.len(),
                got: directions.len(),
            });
        }
        let units = unit_directions("directions", directions)?;
        check_finite_rows("origins", origins)?;
        let hits: Vec<Option<Hit>> = origins
            .par_iter()
            .zip(units.par_iter())
            .with_min_len(RAYS_PER_TASK)
            .map(|(o, d)| self.cast_one(&Point3::new(o[0], o[1], o[2]), d, max_range))
            .collect();
        Ok(Hits::from_options(hits))
    }
}

/// The BVH's leaves: (triangle of each leaf, loosened f32 box of each leaf relative
/// to `center`); one leaf per triangle, or one per piece of a long thin triangle
/// (see [`BVH_SPLIT_EDGE`]).
fn leaf_boxes(
    points: &[Point3<f64>],
    triangles: &[[u32; 3]],
    center: &Vector3<f64>,
) -> (Vec<u32>, Vec<Aabb>) {
    let boxed = |c: &[Point3<f64>; 3]| {
        let lo = c
            .iter()
            .fold(Vector3::repeat(f64::INFINITY), |m, p| m.inf(&p.coords))
            - center;
        let hi = c
            .iter()
            .fold(Vector3::repeat(f64::NEG_INFINITY), |m, p| m.sup(&p.coords))
            - center;
        let pad = |v: &Vector3<f64>| v.map(|x| AABB_MARGIN + 1e-6 * x.abs());
        Aabb::new(
            Point3::from((lo - pad(&lo)).map(|x| x as f32)),
            Point3::from((hi + pad(&hi)).map(|x| x as f32)),
        )
    };
    let mut leaf_triangle = Vec::with_capacity(triangles.len());
    let mut leaves = Vec::with_capacity(triangles.len());
    let mut stack: Vec<[Point3<f64>; 3]> = Vec::new();
    for (t, tri) in triangles.iter().enumerate() {
        stack.push(tri.map(|i| points[i as usize]));
        while let Some(c) = stack.pop() {
            if needs_split(&c) {
                // Halve the longest edge (a, b); o is the corner opposite it.
                let k = (0..3)
                    .max_by(|&i, &j| edge(&c, i).total_cmp(&edge(&c, j)))
                    .unwrap_or(0);
                let (a, b, o) = (c[(k + 1) % 3], c[(k + 2) % 3], c[k]);
                let m = Point3::from((a.coords + b.coords) * 0.5);
                stack.push([o, a, m]);
                stack.push([o, m, b]);
            } else {
                leaf_triangle.push(t as u32);
                leaves.push(boxed(&c));
            }
        }
    }
    (leaf_triangle, leaves)
}

/// Length of the edge opposite corner `k`.
fn edge(c: &[Point3<f64>; 3], k: usize) -> f64 {
    (c[(k + 1) % 3] - c[(k + 2) % 3]).norm()
}

fn needs_split(c: &[Point3<f64>; 3]) -> bool {
    let longest = (0..3).map(|k| edge(c, k)).fold(0.0, f64::max);
    let twice_area = (c[1] - c[0]).cross(&(c[2] - c[0])).norm();
    let height = twice_area / longest;
    longest > BVH_SPLIT_EDGE && longest > BVH_SPLIT_ASPECT * height
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

/// `max_range` must be > 0 (infinity allowed), never NaN.
pub(crate) fn validate_max_range(max_range: f64) -> Result<(), RaycastError> {
    if max_range.is_nan() || max_range <= 0.0 {
        return Err(RaycastError::BadParameter {
            name: "max_range",
            reason: "must be > 0",
            value: max_range,
        });
    }
    Ok(())
}

pub(crate) fn check_finite_rows(name: &'static str, rows: &[[f64; 3]]) -> Result<(), RaycastError> {
    match rows.iter().position(|r| !r.iter().all(|c| c.is_finite())) {
        Some(index) => Err(RaycastError::NonFiniteRay { name, index }),
        None => Ok(()),
    }
}

/// Normalises ray directions, refusing non-finite and zero-length rows.
pub(crate) fn unit_directions(
    name: &'static str,
    directions: &[[f64; 3]],
) -> Result<Vec<Vector3<f64>>, RaycastError> {
    check_finite_rows(name, directions)?;
    directions
        .iter()
        .enumerate()
        .map(|(index, d)| {
            let v = Vector3::new(d[0], d[1], d[2]);
            let norm = v.norm();
            if norm > 0.0 && norm.is_finite() {
                Ok(v / norm)
            } else {
                Err(RaycastError::ZeroDirection { name, index })
            }
        })
        .collect()
}
