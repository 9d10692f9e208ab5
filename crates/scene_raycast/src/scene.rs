//! A triangle scene in the world frame W and batched ray casting against it.
//!
//! The triangles sit in the crate's own BVH ([`crate::bvh`]: binned SAH, f32
//! node boxes that only cull, exact f64 Moeller-Trumbore triangle tests), built
//! once per scene; batches of rays are cast in parallel (rayon).

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::bvh::Bvh;
use crate::error::RaycastError;

/// Triangles with a smaller area (m^2) are refused as degenerate.
pub const MIN_TRIANGLE_AREA: f64 = 1e-14;
/// Rays handed to one rayon task at a time.
const RAYS_PER_TASK: usize = 512;
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
    n_vertices: usize,
    n_triangles: usize,
    normals: Vec<Vector3<f64>>,
    instance_ids: Vec<i32>,
}

impl std::fmt::Debug for Scene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene")
            .field("n_vertices", &self.n_vertices)
            .field("n_triangles", &self.n_triangles)
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
        let bvh = Bvh::build(&points, triangles);
        Ok(Self {
            bvh,
            n_vertices: points.len(),
            n_triangles: triangles.len(),
            normals,
            instance_ids: instance_ids.to_vec(),
        })
    }

    /// Number of triangles.
    pub fn n_triangles(&self) -> usize {
        self.n_triangles
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
        let (distance, tri) = self.bvh.cast(origin, direction, max_range, false)?;
        let t = tri as usize;
        Some(Hit {
            distance,
            triangle: tri,
            instance_id: self.instance_ids[t],
            normal: self.normals[t],
        })
    }

    /// True when the ray meets any triangle within [0, `max_range`] (the same
    /// test as `cast_one(..).is_some()`, stopping at the first triangle found);
    /// `direction` must be a unit vector.
    pub fn occluded(&self, origin: &Point3<f64>, direction: &Vector3<f64>, max_range: f64) -> bool {
        self.bvh.cast(origin, direction, max_range, true).is_some()
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
        check_directions("directions", directions)?;
        check_finite_rows("origins", origins)?;
        let n = origins.len();
        let mut out = Hits {
            distance: vec![f64::INFINITY; n],
            instance_id: vec![-1; n],
            triangle: vec![-1; n],
            normal: vec![[0.0; 3]; n],
        };
        // Written in place, chunk by chunk: no per-ray result list to gather.
        out.distance
            .par_chunks_mut(RAYS_PER_TASK)
            .zip(out.instance_id.par_chunks_mut(RAYS_PER_TASK))
            .zip(out.triangle.par_chunks_mut(RAYS_PER_TASK))
            .zip(out.normal.par_chunks_mut(RAYS_PER_TASK))
            .enumerate()
            .for_each(|(chunk, (((distance, instance_id), triangle), normal))| {
                let start = chunk * RAYS_PER_TASK;
                for (k, (o, d)) in origins[start..start + distance.len()]
                    .iter()
                    .zip(&directions[start..start + distance.len()])
                    .enumerate()
                {
                    let origin = Point3::new(o[0], o[1], o[2]);
                    if let Some(hit) = self.cast_one(&origin, &unit(d), max_range) {
                        distance[k] = hit.distance;
                        instance_id[k] = hit.instance_id;
                        triangle[k] = i64::from(hit.triangle);
                        normal[k] = [hit.normal.x, hit.normal.y, hit.normal.z];
                    }
                }
            });
        Ok(out)
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

/// Refuses non-finite and zero-length (or overflowing) direction rows.
pub(crate) fn check_directions(
    name: &'static str,
    directions: &[[f64; 3]],
) -> Result<(), RaycastError> {
    check_finite_rows(name, directions)?;
    match directions.iter().position(|d| {
        let norm = Vector3::new(d[0], d[1], d[2]).norm();
        !(norm > 0.0 && norm.is_finite())
    }) {
        Some(index) => Err(RaycastError::ZeroDirection { name, index }),
        None => Ok(()),
    }
}

/// The unit vector along a direction row that [`check_directions`] accepted.
#[inline]
pub(crate) fn unit(d: &[f64; 3]) -> Vector3<f64> {
    let v = Vector3::new(d[0], d[1], d[2]);
    v / v.norm()
}
