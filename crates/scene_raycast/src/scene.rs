//! A triangle scene in the world frame W and batched ray casting against it.
//!
//! The triangles sit in the crate's own BVH ([`crate::bvh`]: binned SAH, f32
//! node boxes that only cull, exact f64 Moeller-Trumbore triangle tests), built
//! once per scene; batches of rays are cast in parallel (rayon).

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::bvh::{Bvh, RayQuery, MAX_PACKET};
use crate::error::RaycastError;

/// Triangles with a smaller area (m^2) are refused as degenerate.
pub const MIN_TRIANGLE_AREA: f64 = 1e-14;
/// Rays handed to one rayon task at a time.
const RAYS_PER_TASK: usize = 512;
/// Rows one rayon task validates at a time.
const CHECK_ROWS_PER_TASK: usize = 16_384;
/// A batch's consecutive rays that share their origin (a camera's pixels, a LiDAR's
/// shots) are cast in packets of this many ([`Scene::cast_packet`]).
const BATCH_PACKET: usize = 64;
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
        let hit = self.bvh.cast(origin, direction, max_range, false)?;
        Some(self.hit(hit))
    }

    /// True when the ray meets any triangle within [0, `max_range`] (the same
    /// test as `cast_one(..).is_some()`, stopping at the first triangle found);
    /// `direction` must be a unit vector.
    pub fn occluded(&self, origin: &Point3<f64>, direction: &Vector3<f64>, max_range: f64) -> bool {
        self.bvh.cast(origin, direction, max_range, true).is_some()
    }

    /// Casts up to [`Scene::PACKET`] rays together, a packet (rays beyond are
    /// cast in further packets): for coherent rays, neighbouring pixels of a camera
    /// or shadow rays toward the sun, each BVH node is fetched once for all the rays
    /// that enter its box. `out[i]` gets exactly what `cast_one` gives ray `i`
    /// (unit `directions[i]` from `origins[i]`).
    ///
    /// Returns an error naming the argument when `directions` or `out` does not
    /// have one row per origin.
    pub fn cast_packet(
        &self,
        origins: &[Point3<f64>],
        directions: &[Vector3<f64>],
        max_range: f64,
        out: &mut [Option<Hit>],
    ) -> Result<(), RaycastError> {
        check_packet(origins, directions, out.len())?;
        self.each_packet(origins, directions, max_range, false, |slot, best| {
            out[slot] = best.map(|hit| self.hit(hit));
        });
        Ok(())
    }

    /// [`Scene::occluded`] of a packet of rays cast together (see
    /// [`Scene::cast_packet`]): `out[i]` is true when ray `i` meets a triangle
    /// within [0, `max_range`].
    pub fn occluded_packet(
        &self,
        origins: &[Point3<f64>],
        directions: &[Vector3<f64>],
        max_range: f64,
        out: &mut [bool],
    ) -> Result<(), RaycastError> {
        check_packet(origins, directions, out.len())?;
        self.each_packet(origins, directions, max_range, true, |slot, best| {
            out[slot] = best.is_some();
        });
        Ok(())
    }

    /// Casts the rays in packets of [`MAX_PACKET`] (with `any`, occlusion tests)
    /// and hands `answer` each ray's index and BVH answer, misses included.
    fn each_packet(
        &self,
        origins: &[Point3<f64>],
        directions: &[Vector3<f64>],
        max_range: f64,
        any: bool,
        mut answer: impl FnMut(usize, Option<(f64, u32)>),
    ) {
        let mut rays = Vec::with_capacity(MAX_PACKET.min(origins.len()));
        let mut slots = Vec::with_capacity(rays.capacity());
        for start in (0..origins.len()).step_by(MAX_PACKET) {
            let end = (start + MAX_PACKET).min(origins.len());
            self.queries(
                &origins[start..end],
                &directions[start..end],
                max_range,
                &mut rays,
                &mut slots,
            );
            self.bvh.cast_packet(&mut rays, any);
            let mut cast = rays.iter().zip(&slots).peekable();
            for slot in 0..end - start {
                let best = match cast.next_if(|(_, &s)| s == slot) {
                    Some((ray, _)) => ray.best(),
                    None => None,
                };
                answer(start + slot, best);
            }
        }
    }

    /// Most rays one packet of [`Scene::cast_packet`] traverses together.
    pub const PACKET: usize = MAX_PACKET;

    /// The traversal states of the rays that can meet the scene (into `rays`) and
    /// their indices (into `slots`).
    fn queries(
        &self,
        origins: &[Point3<f64>],
        directions: &[Vector3<f64>],
        max_range: f64,
        rays: &mut Vec<RayQuery>,
        slots: &mut Vec<usize>,
    ) {
        rays.clear();
        slots.clear();
        for (slot, (origin, direction)) in origins.iter().zip(directions).enumerate() {
            if let Some(ray) = self.bvh.query(origin, direction, max_range) {
                rays.push(ray);
                slots.push(slot);
            }
        }
    }

    /// The [`Hit`] of (distance, triangle) found by the BVH.
    fn hit(&self, (distance, triangle): (f64, u32)) -> Hit {
        let t = triangle as usize;
        Hit {
            distance,
            triangle,
            instance_id: self.instance_ids[t],
            normal: self.normals[t],
        }
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
        // Zeroed allocations (pages mapped lazily, then written by the parallel
        // tasks, misses included): no serial pass over the outputs.
        let mut out = Hits {
            distance: vec![0.0; n],
            instance_id: vec![0; n],
            triangle: vec![0; n],
            normal: vec![[0.0; 3]; n],
        };
        // Written in place, chunk by chunk: no per-ray result list to gather.
        out.distance
            .par_chunks_mut(RAYS_PER_TASK)
            .zip(out.instance_id.par_chunks_mut(RAYS_PER_TASK))
            .zip(out.triangle.par_chunks_mut(RAYS_PER_TASK))
            .zip(out.normal.par_chunks_mut(RAYS_PER_TASK))
            .enumerate()
            .try_for_each(|(chunk, (((distance, instance_id), triangle), normal))| {
                let start = chunk * RAYS_PER_TASK;
                let mut packet_origins = Vec::with_capacity(BATCH_PACKET);
                let mut packet_directions = Vec::with_capacity(BATCH_PACKET);
                let mut packet_hits = vec![None; BATCH_PACKET];
                for first in (0..distance.len()).step_by(BATCH_PACKET) {
                    let rows = start + first..start + (first + BATCH_PACKET).min(distance.len());
                    packet_origins.clear();
                    packet_directions.clear();
                    for (o, d) in origins[rows.clone()].iter().zip(&directions[rows.clone()]) {
                        packet_origins.push(Point3::new(o[0], o[1], o[2]));
                        packet_directions.push(unit(d));
                    }
                    let hits = &mut packet_hits[..rows.len()];
                    // Rays from one point are coherent; others are cast one by one.
                    if origins[rows.clone()]
                        .iter()
                        .all(|o| *o == origins[rows.start])
                    {
                        self.cast_packet(&packet_origins, &packet_directions, max_range, hits)?;
                    } else {
                        for (hit, (o, d)) in hits
                            .iter_mut()
                            .zip(packet_origins.iter().zip(&packet_directions))
                        {
                            *hit = self.cast_one(o, d, max_range);
                        }
                    }
                    for (k, hit) in hits.iter().enumerate() {
                        let k = first + k;
                        match hit {
                            Some(hit) => {
                                distance[k] = hit.distance;
                                instance_id[k] = hit.instance_id;
                                triangle[k] = i64::from(hit.triangle);
                                normal[k] = [hit.normal.x, hit.normal.y, hit.normal.z];
                            }
                            None => {
                                distance[k] = f64::INFINITY;
                                instance_id[k] = -1;
                                triangle[k] = -1;
                            }
                        }
                    }
                }
                Ok(())
            })?;
        Ok(out)
    }
}

/// A packet's rows: one direction and one output per origin.
fn check_packet(
    origins: &[Point3<f64>],
    directions: &[Vector3<f64>],
    outputs: usize,
) -> Result<(), RaycastError> {
    for (name, got) in [("directions", directions.len()), ("out", outputs)] {
        if got != origins.len() {
            return Err(RaycastError::LengthMismatch {
                name,
                expected: origins.len(),
                got,
            });
        }
    }
    Ok(())
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
    match first_bad_row(rows, |r| !r.iter().all(|c| c.is_finite())) {
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
    match first_bad_row(directions, |d| {
        let norm = Vector3::new(d[0], d[1], d[2]).norm();
        !(norm > 0.0 && norm.is_finite())
    }) {
        Some(index) => Err(RaycastError::ZeroDirection { name, index }),
        None => Ok(()),
    }
}

/// The index of the first row for which `bad` holds. In parallel, chunk by
/// chunk (a batch's serial share bounds its speed-up), each chunk scanned in
/// one tight loop.
fn first_bad_row(rows: &[[f64; 3]], bad: impl Fn(&[f64; 3]) -> bool + Sync) -> Option<usize> {
    let chunk = rows
        .par_chunks(CHECK_ROWS_PER_TASK)
        .position_first(|chunk| chunk.iter().any(&bad))?;
    let start = chunk * CHECK_ROWS_PER_TASK;
    rows[start..].iter().position(&bad).map(|k| start + k)
}

/// The unit vector along a direction row that [`check_directions`] accepted.
#[inline]
pub(crate) fn unit(d: &[f64; 3]) -> Vector3<f64> {
    let v = Vector3::new(d[0], d[1], d[2]);
    v / v.norm()
}
