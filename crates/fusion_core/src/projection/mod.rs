//! Projection of a LiDAR-frame cloud straight into pixels (paper eqs. 1-2, plus distortion).

pub(crate) mod lanes;

use std::ops::Range;

use nalgebra::{Isometry3, Matrix3, Vector3};

use crate::camera::{CameraModel, NEAR_LIMIT};
use crate::points::PointCloud;

/// Per-point projection result.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Projection {
    /// Pixel (u, v) of each point; NaN for points behind/near the camera or non-finite.
    pub uv: Vec<[f64; 2]>,
    /// True when the point is in front of the camera and lands inside the image.
    pub valid: Vec<bool>,
}

/// `T_c_l` and the camera, unpacked once for the per-point loop.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Projector {
    /// Rotation C <- L, row-major plain f64s (no matrix indexing in the hot loop).
    pub(crate) rotation: [[f64; 3]; 3],
    pub(crate) translation: [f64; 3],
    /// A copy, so the hot loop reads its fields from the stack, not through a pointer.
    pub(crate) cam: CameraModel,
}

impl Projector {
    pub(crate) fn new(t_c_l: &Isometry3<f64>, cam: &CameraModel) -> Self {
        let r: Matrix3<f64> = t_c_l.rotation.to_rotation_matrix().into_inner();
        let t: Vector3<f64> = t_c_l.translation.vector;
        Self {
            rotation: [
                [r[(0, 0)], r[(0, 1)], r[(0, 2)]],
                [r[(1, 0)], r[(1, 1)], r[(1, 2)]],
                [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
            ],
            translation: [t[0], t[1], t[2]],
            cam: *cam,
        }
    }

    /// Pixel of an L-frame point, or `None` when behind/near the camera or non-finite.
    #[inline(always)]
    pub(crate) fn pixel(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        let z = self.depth(p);
        // Depth first: most of a 360-degree frame is behind the camera and stops here.
        if z.is_nan() || z <= NEAR_LIMIT {
            return None;
        }
        let [x, y] = self.lateral(p);
        self.cam.project_xyz(x, y, z)
    }

    /// Camera-frame depth z of an L-frame point.
    #[inline(always)]
    fn depth(&self, p: [f64; 3]) -> f64 {
        let r2 = &self.rotation[2];
        r2[0] * p[0] + r2[1] * p[1] + r2[2] * p[2] + self.translation[2]
    }

    /// Camera-frame x, y of an L-frame point.
    #[inline(always)]
    fn lateral(&self, p: [f64; 3]) -> [f64; 2] {
        let [r0, r1, _] = &self.rotation;
        let t = &self.translation;
        [r0[0] * p[0] + r0[1] * p[1] + r0[2] * p[2] + t[0], r1[0] * p[0] + r1[1] * p[1] + r1[2] * p[2] + t[1]]
    }

    #[inline(always)]
    pub(crate) fn in_image(&self, uv: [f64; 2]) -> bool {
        self.cam.contains(uv)
    }
}

/// Projects every point of an L-frame cloud through `t_c_l` and `cam`.
///
/// `uv` is NaN where the point is behind/near the camera ([`crate::camera::NEAR_LIMIT`])
/// or non-finite; `valid` is true where it is in front and inside the image. SIMD lanes
/// (`projection/lanes.rs`) compute the scalar formula operation for operation: the same bits
/// as the point-by-point loop.
pub fn project_points<P: PointCloud + ?Sized>(points: &P, t_c_l: &Isometry3<f64>, cam: &CameraModel) -> Projection {
    project(points, t_c_l, cam, lanes::project_chunk)
}

/// [`project_points`] through `run` (the SIMD dispatch, or a fixed path in the tests).
fn project<P: PointCloud + ?Sized>(
    points: &P,
    t_c_l: &Isometry3<f64>,
    cam: &CameraModel,
    run: fn(lanes::ProjectChunk<'_, P>, &mut Projection),
) -> Projection {
    let projector = Projector::new(t_c_l, cam);
    let n = points.len();
    let mut out = Projection { uv: Vec::with_capacity(n), valid: Vec::with_capacity(n) };
    run(lanes::ProjectChunk { points, range: 0..n, projector: &projector }, &mut out);
    out
}

/// The pixels of the points in `range`, one point at a time, appended to `out`: the scalar
/// reference of the lanes, and their path on CPUs without SIMD.
pub(crate) fn project_range_scalar<P: PointCloud + ?Sized>(
    points: &P,
    range: Range<usize>,
    projector: &Projector,
    out: &mut Projection,
) {
    points.for_each_point_in(range, #[inline(always)] |_, p| match projector.pixel(p) {
        Some(uv) => {
            out.uv.push(uv);
            out.valid.push(projector.in_image(uv));
        }
        None => {
            out.uv.push([f64::NAN; 2]);
            out.valid.push(false);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Translation3, UnitQuaternion};

    #[test]
    fn projects_through_pose_by_hand() {
        // L frame = FLU-like (x forward); camera optical: z_c = x_l, x_c = -y_l, y_c = -z_l, camera 0.1 m ahead.
        let r = Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
        let q = UnitQuaternion::from_matrix(&r);
        let t = Isometry3::from_parts(Translation3::new(0.0, 0.0, -0.1), q);
        let cam = CameraModel::new(500.0, 500.0, 320.0, 240.0, 640, 480, [0.0; 5]).unwrap();
        let pts = vec![[2.1, -0.4, 0.2], [-1.0, 0.0, 0.0], [2.1, 5.0, 0.0], [f64::NAN, 0.0, 0.0]];
        let pr = project_points(&pts, &t, &cam);
        // Point 0 in C: (0.4, -0.2, 2.0) -> u = 500*0.2+320 = 420, v = 500*(-0.1)+240 = 190.
        assert!((pr.uv[0][0] - 420.0).abs() < 1e-9 && (pr.uv[0][1] - 190.0).abs() < 1e-9);
        assert_eq!(pr.valid, vec![true, false, false, false]);
        assert!(pr.uv[1][0].is_nan() && pr.uv[3][1].is_nan());
        // Point 2 is in front but far left of the image: finite uv, not valid.
        assert!(pr.uv[2][0].is_finite() && pr.uv[2][0] < 0.0);
        // Same as transforming by hand with nalgebra and calling the camera.
        let pc = t * Point3::new(2.1, -0.4, 0.2);
        let uv = cam.project_camera_point(&pc.coords).unwrap();
        assert!((uv[0] - pr.uv[0][0]).abs() < 1e-9);
    }

    /// The lanes (the CPU's level, and AVX2 + FMA where the CPU has it) against the scalar
    /// loop: the same pixels to the bit (NaN in the same places) and the same `valid`, on
    /// clouds ending mid-tile, with non-finite points, points at the near limit and behind
    /// the camera, under strong distortion.
    #[test]
    fn lanes_give_the_scalar_pixels_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let cam = CameraModel::new(300.0, 280.0, 160.0, 120.0, 320, 240, [-0.35, 0.12, 1e-3, -2e-3, -0.03]).unwrap();
        let t = Isometry3::new(Vector3::new(0.1, 0.0, -0.2), Vector3::new(0.1, -0.05, 0.03));
        for n in [0, 1, 5, 127, 128, 129, 2000] {
            let mut pts: Vec<[f64; 3]> =
                (0..n).map(|_| [rng.random_range(-4.0..4.0), rng.random_range(-4.0..4.0), rng.random_range(-2.0..8.0)]).collect();
            let bad = [[f64::NAN, 0.0, 2.0], [f64::INFINITY, 0.0, 2.0], [0.0, f64::NEG_INFINITY, 2.0], [0.0, 0.0, f64::INFINITY], [1e300, 0.0, 2.0]];
            for (i, p) in bad.into_iter().enumerate() {
                if let Some(slot) = pts.get_mut(2 * i + 1) {
                    *slot = p;
                }
            }
            if n > 20 {
                let near = t.inverse() * Point3::new(0.0, 0.0, NEAR_LIMIT);
                pts[15] = [near.x, near.y, near.z];
            }
            let projector = Projector::new(&t, &cam);
            let mut want = Projection::default();
            project_range_scalar(&pts, 0..n, &projector, &mut want);
            // Bits, with every NaN as one value (its payload is not the scalar loop's concern).
            let bits = |p: &Projection| -> Vec<[u64; 2]> {
                p.uv.iter().map(|uv| uv.map(|x| if x.is_nan() { u64::MAX } else { x.to_bits() })).collect()
            };
            for got in [project_points(&pts, &t, &cam), project(&pts, &t, &cam, lanes::avx2_project_chunk)] {
                assert_eq!(bits(&got), bits(&want), "n = {n}");
                assert_eq!(got.valid, want.valid, "n = {n}");
            }
            assert!(n < 20 || (want.valid.iter().any(|&v| v) && want.valid.iter().any(|&v| !v)));
        }
    }

    #[test]
    fn empty_cloud() {
        let cam = CameraModel::new(500.0, 500.0, 320.0, 240.0, 640, 480, [0.0; 5]).unwrap();
        let empty: Vec<[f64; 3]> = vec![];
        let pr = project_points(&empty, &Isometry3::identity(), &cam);
        assert!(pr.uv.is_empty() && pr.valid.is_empty());
    }
}
