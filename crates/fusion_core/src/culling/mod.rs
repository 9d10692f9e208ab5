//! Box culling: which points of a LiDAR frame project inside each detection box.

pub(crate) mod simd;

use std::ops::Range;

use nalgebra::Isometry3;
use rayon::prelude::*;

use crate::camera::CameraModel;
use crate::error::{invalid, Result};
use crate::points::PointCloud;
use crate::projection::Projector;

/// An axis-aligned pixel box, half-open: x1 <= u < x2, y1 <= v < y2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelBox {
    pub x1: f64,
    pub y1: f64,
    pub x2: f64,
    pub y2: f64,
}

impl PixelBox {
    /// Validated constructor: finite corners with x2 > x1 and y2 > y1.
    pub fn new(x1: f64, y1: f64, x2: f64, y2: f64) -> Result<Self> {
        let b = Self { x1, y1, x2, y2 };
        b.validate("box")?;
        Ok(b)
    }

    pub(crate) fn validate(&self, name: &'static str) -> Result<()> {
        let c = [self.x1, self.y1, self.x2, self.y2];
        if c.iter().any(|v| !v.is_finite()) {
            return Err(invalid(name, format!("corners must be finite, got {c:?}")));
        }
        if self.x2 <= self.x1 || self.y2 <= self.y1 {
            return Err(invalid(name, format!("needs x2 > x1 and y2 > y1 (non-empty area), got {c:?}")));
        }
        Ok(())
    }

    /// True when the pixel is inside the half-open box.
    #[inline(always)]
    pub fn contains(&self, uv: [f64; 2]) -> bool {
        uv[0] >= self.x1 && uv[0] < self.x2 && uv[1] >= self.y1 && uv[1] < self.y2
    }
}

/// Clouds at least this large are culled in parallel chunks: below it rayon's
/// fork-join (a few µs) costs more than the second core saves.
pub const PARALLEL_MIN_POINTS: usize = 8192;
/// Smallest parallel chunk; otherwise one chunk per rayon thread (fewer, larger
/// chunks measured faster than 4096-point ones on 2 cores: less joining and waking).
const MIN_CHUNK_POINTS: usize = 4096;

/// For each box, the ascending indices of the points that are valid (in front of the
/// camera, inside the image) and project inside the box. One pass over the cloud,
/// split into chunks culled in parallel (rayon) for clouds of [`PARALLEL_MIN_POINTS`]
/// or more; the chunks' lists are joined in index order, so the result is the same.
///
/// A box partly outside the image is used as is; a box wholly outside gives an empty list.
/// Errors (naming `boxes`) on a non-finite, inverted or zero-area box, or `cam` on a bad camera.
pub fn points_in_boxes<P: PointCloud + Sync + ?Sized>(
    points: &P,
    t_c_l: &Isometry3<f64>,
    cam: &CameraModel,
    boxes: &[PixelBox],
) -> Result<Vec<Vec<usize>>> {
    cull(points, t_c_l, cam, boxes, Path::Simd)
}

/// [`points_in_boxes`] on the scalar loop only: the reference its SIMD path is tested and
/// benchmarked against (the same lists, bit for bit).
pub fn points_in_boxes_scalar<P: PointCloud + Sync + ?Sized>(
    points: &P,
    t_c_l: &Isometry3<f64>,
    cam: &CameraModel,
    boxes: &[PixelBox],
) -> Result<Vec<Vec<usize>>> {
    cull(points, t_c_l, cam, boxes, Path::Scalar)
}

/// Which loop culls the chunks.
#[derive(Clone, Copy)]
enum Path {
    /// SIMD lanes where pulp finds an instruction set (the scalar loop otherwise).
    Simd,
    Scalar,
    /// The AVX2 + FMA lanes even under AVX-512 (tests).
    #[cfg(test)]
    Avx2,
}

fn cull<P: PointCloud + Sync + ?Sized>(
    points: &P,
    t_c_l: &Isometry3<f64>,
    cam: &CameraModel,
    boxes: &[PixelBox],
    path: Path,
) -> Result<Vec<Vec<usize>>> {
    cam.validate()?;
    for b in boxes {
        b.validate("boxes")?;
    }
    if boxes.is_empty() {
        return Ok(Vec::new());
    }
    // Union of the boxes clipped to the image: a cheap reject before the per-box tests.
    let union = PixelBox {
        x1: boxes.iter().map(|b| b.x1).fold(f64::INFINITY, f64::min).max(0.0),
        y1: boxes.iter().map(|b| b.y1).fold(f64::INFINITY, f64::min).max(0.0),
        x2: boxes.iter().map(|b| b.x2).fold(f64::NEG_INFINITY, f64::max).min(f64::from(cam.width)),
        y2: boxes.iter().map(|b| b.y2).fold(f64::NEG_INFINITY, f64::max).min(f64::from(cam.height)),
    };
    if union.x2 <= union.x1 || union.y2 <= union.y1 {
        return Ok(vec![Vec::new(); boxes.len()]);
    }
    let projector = Projector::new(t_c_l, cam);
    let cull_one = |range: Range<usize>| {
        let chunk = simd::CullChunk { points, range, projector: &projector, boxes, union: &union };
        match path {
            Path::Simd => simd::cull_chunk(chunk),
            Path::Scalar => cull_range_scalar(points, chunk.range, &projector, boxes, &union),
            #[cfg(test)]
            Path::Avx2 => simd::avx2_cull_chunk(chunk),
        }
    };
    let n = points.len();
    if n < PARALLEL_MIN_POINTS {
        return Ok(cull_one(0..n));
    }
    let chunk = n.div_ceil(rayon::current_num_threads()).max(MIN_CHUNK_POINTS);
    let chunks: Vec<Vec<Vec<usize>>> =
        (0..n.div_ceil(chunk)).into_par_iter().map(|c| cull_one(c * chunk..((c + 1) * chunk).min(n))).collect();
    let mut out: Vec<Vec<usize>> = (0..boxes.len())
        .map(|k| Vec::with_capacity(chunks.iter().map(|c| c[k].len()).sum()))
        .collect();
    for chunk in chunks {
        for (list, part) in out.iter_mut().zip(chunk) {
            list.extend(part);
        }
    }
    Ok(out)
}

/// The per-box lists of the points in `range` (ascending), one point at a time: the scalar
/// reference of the SIMD lanes ([`simd::CullChunk`]), and their path on CPUs without SIMD.
pub(crate) fn cull_range_scalar<P: PointCloud + ?Sized>(
    points: &P,
    range: Range<usize>,
    projector: &Projector,
    boxes: &[PixelBox],
    union: &PixelBox,
) -> Vec<Vec<usize>> {
    let mut out: Vec<Vec<usize>> = vec![Vec::new(); boxes.len()];
    // Slice walk (no per-point index arithmetic for contiguous clouds); the depth test
    // comes before x, y and distortion are computed (see `Projector::pixel`).
    points.for_each_point_in(
        range,
        #[inline(always)]
        |i, p| {
            let Some(uv) = projector.pixel(p) else { return };
            if !union.contains(uv) {
                return;
            }
            for (b, list) in boxes.iter().zip(out.iter_mut()) {
                if b.contains(uv) {
                    list.push(i);
                }
            }
        },
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::projection::project_points;
    use nalgebra::Vector3;
    use proptest::prelude::*;

    fn brute(points: &[[f64; 3]], t: &Isometry3<f64>, cam: &CameraModel, boxes: &[PixelBox]) -> Vec<Vec<usize>> {
        let pr = project_points(points, t, cam);
        boxes
            .iter()
            .map(|b| (0..points.len()).filter(|&i| pr.valid[i] && b.contains(pr.uv[i])).collect())
            .collect()
    }

    #[test]
    fn hand_made_scene() {
        let cam = CameraModel::new(100.0, 100.0, 50.0, 50.0, 100, 100, [0.0; 5]).unwrap();
        let t = Isometry3::identity();
        // Pixels: (50,50), (60,50), (5,5), behind, (150, 50) outside the image.
        let pts = vec![[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [-0.45, -0.45, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 1.0]];
        let boxes = [
            PixelBox::new(40.0, 40.0, 70.0, 70.0).unwrap(),
            PixelBox::new(0.0, 0.0, 10.0, 10.0).unwrap(),
            PixelBox::new(40.0, 40.0, 200.0, 60.0).unwrap(), // partly outside: point 4 must not appear
            PixelBox::new(300.0, 300.0, 400.0, 400.0).unwrap(), // wholly outside
            PixelBox::new(60.0, 0.0, 61.0, 100.0).unwrap(),  // u = 60 is on the inclusive edge
        ];
        let got = points_in_boxes(&pts, &t, &cam, &boxes).unwrap();
        assert_eq!(got, vec![vec![0, 1], vec![2], vec![0, 1], vec![], vec![1]]);
        assert_eq!(got, brute(&pts, &t, &cam, &boxes));
        assert_eq!(points_in_boxes(&pts, &t, &cam, &[]).unwrap(), Vec::<Vec<usize>>::new());
    }

    #[test]
    fn parallel_chunks_match_brute_force_on_a_large_cloud() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let cam = CameraModel::new(900.0, 910.0, 640.0, 480.0, 1280, 960, [-0.2, 0.05, 1e-3, -1e-3, 0.01]).unwrap();
        let t = Isometry3::new(Vector3::new(0.1, -0.2, 0.3), Vector3::new(0.05, -0.1, 0.02));
        // Not a multiple of the chunk size, so the last chunk is short.
        let n = 3 * PARALLEL_MIN_POINTS + 123;
        let pts: Vec<[f64; 3]> =
            (0..n).map(|_| [rng.random_range(-8.0..8.0), rng.random_range(-6.0..6.0), rng.random_range(-2.0..20.0)]).collect();
        let boxes = [
            PixelBox::new(100.0, 100.0, 700.0, 500.0).unwrap(),
            PixelBox::new(600.0, 400.0, 1300.0, 1000.0).unwrap(),
            PixelBox::new(-50.0, -50.0, 30.0, 30.0).unwrap(),
        ];
        let got = points_in_boxes(&pts, &t, &cam, &boxes).unwrap();
        assert!(got.iter().all(|l| !l.is_empty()));
        assert_eq!(got, brute(&pts, &t, &cam, &boxes));
        let f32s: Vec<[f32; 3]> = pts.iter().map(|p| p.map(|v| v as f32)).collect();
        let wide: Vec<[f64; 3]> = f32s.iter().map(|p| p.map(f64::from)).collect();
        assert_eq!(points_in_boxes(&f32s[..], &t, &cam, &boxes).unwrap(), brute(&wide, &t, &cam, &boxes));
    }

    /// The SIMD lanes (the CPU's level, and AVX2 + FMA where the CPU has it) against the
    /// scalar loop and the brute-force filter of `project_points`: the same lists, exactly
    /// (bit-identical pixels), on clouds ending mid-tile, with points on box edges, at the
    /// near limit and non-finite ones, under strong distortion.
    #[test]
    fn simd_lanes_give_the_scalar_lists_exactly() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        let cam = CameraModel::new(100.0, 120.0, 50.0, 40.0, 100, 80, [-0.3, 0.1, 2e-3, -1e-3, -0.02]).unwrap();
        let t = Isometry3::new(Vector3::new(0.05, -0.1, 0.2), Vector3::new(0.02, -0.03, 0.01));
        let boxes = [
            PixelBox::new(10.0, 10.0, 60.0, 50.0).unwrap(),
            PixelBox::new(50.0, 0.0, 100.0, 80.0).unwrap(),
            PixelBox::new(-20.0, 30.0, 20.0, 90.0).unwrap(),
        ];
        for n in [0, 1, 7, 127, 128, 129, 1000, 3 * PARALLEL_MIN_POINTS + 5] {
            let mut pts: Vec<[f64; 3]> =
                (0..n).map(|_| [rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), rng.random_range(-1.0..6.0)]).collect();
            for (i, bad) in [[f64::NAN, 0.0, 2.0], [f64::INFINITY, 0.0, 2.0], [0.0, f64::NEG_INFINITY, 2.0], [0.0, 0.0, f64::INFINITY]]
                .into_iter()
                .enumerate()
            {
                if let Some(p) = pts.get_mut(3 * i) {
                    *p = bad;
                }
            }
            if n > 20 {
                // Placed in C and mapped back to L (so to rounding): a point at the near limit,
                // and one at the principal point (50, 40), on the second box's left edge.
                let inv = t.inverse();
                let near = inv * nalgebra::Point3::new(0.0, 0.0, crate::camera::NEAR_LIMIT);
                pts[13] = [near.x, near.y, near.z];
                let edge = inv * nalgebra::Point3::new(0.0, 0.0, 2.0);
                pts[17] = [edge.x, edge.y, edge.z];
            }
            let want = brute(&pts, &t, &cam, &boxes);
            assert_eq!(points_in_boxes_scalar(&pts, &t, &cam, &boxes).unwrap(), want, "scalar, n = {n}");
            assert_eq!(points_in_boxes(&pts, &t, &cam, &boxes).unwrap(), want, "SIMD, n = {n}");
            assert_eq!(cull(&pts, &t, &cam, &boxes, Path::Avx2).unwrap(), want, "AVX2, n = {n}");
        }
    }

    #[test]
    fn bad_boxes_are_rejected() {
        assert!(PixelBox::new(10.0, 0.0, 10.0, 5.0).is_err());
        assert!(PixelBox::new(10.0, 0.0, 5.0, 5.0).is_err());
        assert!(PixelBox::new(0.0, f64::NAN, 5.0, 5.0).is_err());
        let cam = CameraModel::new(100.0, 100.0, 50.0, 50.0, 100, 100, [0.0; 5]).unwrap();
        let inverted = PixelBox { x1: 5.0, y1: 0.0, x2: 1.0, y2: 4.0 };
        match points_in_boxes(&vec![[0.0, 0.0, 1.0]], &Isometry3::identity(), &cam, &[inverted]) {
            Err(crate::FusionError::InvalidArgument { name, .. }) => assert_eq!(name, "boxes"),
            other => panic!("expected InvalidArgument, got {other:?}"),
        }
    }

    proptest! {
        /// Culling equals the brute-force filter of project_points for random intrinsics,
        /// distortion, poses and boxes (including boxes partly or wholly off the image).
        #[test]
        fn culling_matches_brute_force(
            fx in 50.0f64..2000.0, fy in 50.0f64..2000.0, w in 1u32..2000, h in 1u32..2000,
            cxf in -0.2f64..1.2, cyf in -0.2f64..1.2,
            k1 in -0.5f64..0.5, k2 in -0.2f64..0.2, p1 in -0.01f64..0.01, p2 in -0.01f64..0.01, k3 in -0.1f64..0.1,
            rot in prop::array::uniform3(-3.1f64..3.1), trans in prop::array::uniform3(-5.0f64..5.0),
            pts in prop::collection::vec(prop::array::uniform3(-20.0f64..20.0), 0..300),
            raw_boxes in prop::collection::vec((-500.0f64..2500.0, -500.0f64..2500.0, 1.0f64..1500.0, 1.0f64..1500.0), 0..5),
        ) {
            let cam = CameraModel::new(fx, fy, cxf * f64::from(w), cyf * f64::from(h), w, h, [k1, k2, p1, p2, k3]).unwrap();
            let t = Isometry3::new(Vector3::from(trans), Vector3::from(rot));
            let boxes: Vec<PixelBox> = raw_boxes.iter()
                .map(|&(x, y, bw, bh)| PixelBox::new(x, y, x + bw, y + bh).unwrap()).collect();
            let got = points_in_boxes(&pts, &t, &cam, &boxes).unwrap();
            prop_assert_eq!(got, brute(&pts, &t, &cam, &boxes));
        }
    }
}
