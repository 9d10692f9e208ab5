//! SIMD path of the fused deskew + project + cull ([`super::deskew_points_in_boxes`]): the
//! arithmetic of the scalar reference ([`super::Motion::apply`], then
//! [`crate::projection::Projector::pixel`]) on tiles of [`TILE`] points, in f64 lanes.
//!
//! Crate: `pulp`, not `wide`. `pulp::Arch::new().dispatch` detects the CPU once and runs one
//! generic kernel compiled per instruction set behind `#[target_feature]` (AVX2 + FMA on
//! x86-64, NEON on aarch64; other CPUs get the scalar reference, see [`fused_chunk`]), with no
//! hand-written dispatch and no `unsafe` here. `wide` chooses its backend at compile time
//! (`cfg(target_feature)`), so runtime dispatch with it takes hand-written `#[target_feature]`
//! wrappers per level, and wide's 256-bit types still run as SSE halves inside them.
//!
//! Why f64 lanes, not f32: f32's spacing is 3.8e-6 m at 40 m, so the 1e-6 m deskew parity
//! cannot hold at tower ranges, and 1.2e-4 px above u = 1024, so neither can 1e-4 px. The
//! pose knots, the interpolation parameter and the slerp are f64 as in the scalar path.
//!
//! Exactness: the deskew uses fused multiply-adds (it differs from the scalar path by float
//! rounding, ~1e-14 m). The projection keeps the scalar path's operations in its order,
//! unfused, so each deskewed point's pixel is bit-identical to `Projector::pixel` of it, and the
//! culling of the SIMD cloud is exactly the scalar culling of that cloud.
//!
//! Tiles that take the scalar reference instead (same results, per point): a tile whose times
//! straddle a pose knot (one segment per tile keeps the knots in broadcast registers), and a
//! segment rotating more than [`SERIES_ANGLE`] between knots (the scalar path's libm `sin`).

use std::ops::Range;

use pulp::{Arch, Simd, WithSimd};

use super::{Motion, Segment, SERIES_ANGLE, SERIES_TERMS};
use crate::camera::NEAR_LIMIT;
use crate::culling::PixelBox;
use crate::points::PointCloud;
use crate::projection::Projector;

/// Points per tile: staged into SoA arrays, deskewed and projected lane by lane, written back.
/// A multiple of every lane count (1, 2, 4, 8), so the lane loops have no tail.
pub(super) const TILE: usize = 64;

/// What to cull a chunk's deskewed points into (absent for a plain deskew).
#[derive(Clone, Copy)]
pub(super) struct Cull<'a> {
    pub projector: &'a Projector,
    pub boxes: &'a [PixelBox],
    /// The boxes' union clipped to the image, non-empty.
    pub union: &'a PixelBox,
}

/// One chunk of the fused kernel: deskew `range` of `points` into `out` (the chunk's slice)
/// and, with `cull`, return per box the ascending global indices of the points inside it.
pub(super) struct FusedChunk<'a, P: ?Sized> {
    pub points: &'a P,
    pub times: &'a [f64],
    pub range: Range<usize>,
    pub motion: &'a Motion,
    pub cull: Option<Cull<'a>>,
    pub out: &'a mut [[f64; 3]],
}

/// Runs one chunk on the best instruction set of this CPU (the scalar reference where pulp
/// finds no SIMD level).
pub(super) fn fused_chunk<P: PointCloud + ?Sized>(chunk: FusedChunk<'_, P>) -> Vec<Vec<usize>> {
    Arch::new().dispatch(chunk)
}

/// The scalar reference for one chunk: [`Motion::apply`] per point, then the culling loop.
pub(super) fn scalar_chunk<P: PointCloud + ?Sized>(chunk: FusedChunk<'_, P>) -> Vec<Vec<usize>> {
    let FusedChunk { points, times, range, motion, cull, out } = chunk;
    let start = range.start;
    let mut k = range.clone().next().map_or(0, |i| motion.start_segment(times[i]));
    points.for_each_point_in(range, |i, p| {
        out[i - start] = motion.apply(p, times[i], &mut k);
    });
    let Some(c) = cull else { return Vec::new() };
    let local: &[[f64; 3]] = out;
    let mut lists = crate::culling::cull_range(local, 0..local.len(), c.projector, c.boxes, c.union);
    for list in &mut lists {
        for i in list.iter_mut() {
            *i += start;
        }
    }
    lists
}

/// One tile's points (staged), deskewed points and pixels, structure of arrays.
struct Tile {
    x: [f64; TILE],
    y: [f64; TILE],
    z: [f64; TILE],
    t: [f64; TILE],
    ox: [f64; TILE],
    oy: [f64; TILE],
    oz: [f64; TILE],
    u: [f64; TILE],
    v: [f64; TILE],
}

impl Tile {
    fn new() -> Self {
        let a = [0.0; TILE];
        Self { x: a, y: a, z: a, t: a, ox: a, oy: a, oz: a, u: a, v: a }
    }
}

/// A segment of the motion, broadcast to lanes.
struct SegLanes<S: Simd> {
    t0: S::f64s,
    inv_dt: S::f64s,
    q0: [S::f64s; 4],
    q1: [S::f64s; 4],
    series: [S::f64s; SERIES_TERMS],
    /// Below `SMALL_ANGLE`: normalised lerp instead of slerp (the scalar path's `inv_sin == 0`).
    nlerp: bool,
    c0: [S::f64s; 3],
    c1: [S::f64s; 3],
    d: [S::f64s; 3],
    one: S::f64s,
    two: S::f64s,
}

impl<S: Simd> SegLanes<S> {
    #[inline(always)]
    fn new(simd: S, sg: &Segment, d: &[f64; 3]) -> Self {
        let sp = |v: f64| simd.splat_f64s(v);
        Self {
            t0: sp(sg.t0),
            inv_dt: sp(sg.inv_dt),
            q0: sg.q0.map(sp),
            q1: sg.q1.map(sp),
            series: sg.series.map(sp),
            nlerp: sg.inv_sin == 0.0,
            c0: sg.c0.map(sp),
            c1: sg.c1.map(sp),
            d: d.map(sp),
            one: sp(1.0),
            two: sp(2.0),
        }
    }

    #[inline(always)]
    fn horner(&self, simd: S, x2: S::f64s) -> S::f64s {
        let c = &self.series;
        let mut acc = c[SERIES_TERMS - 1];
        for v in c[..SERIES_TERMS - 1].iter().rev() {
            acc = simd.mul_add_e_f64s(acc, x2, *v);
        }
        acc
    }

    /// [`Motion::apply`] on lanes of points (x, y, z) measured at `t`, all in this segment.
    #[inline(always)]
    fn apply(&self, simd: S, x: S::f64s, y: S::f64s, z: S::f64s, t: S::f64s) -> [S::f64s; 3] {
        let s = simd.mul_f64s(simd.sub_f64s(t, self.t0), self.inv_dt);
        let r = simd.sub_f64s(self.one, s);
        let (w0, w1) = if self.nlerp {
            (r, s)
        } else {
            (
                simd.mul_f64s(r, self.horner(simd, simd.mul_f64s(r, r))),
                simd.mul_f64s(s, self.horner(simd, simd.mul_f64s(s, s))),
            )
        };
        let mut q = [self.one; 4];
        for (j, v) in q.iter_mut().enumerate() {
            *v = simd.mul_add_e_f64s(w1, self.q1[j], simd.mul_f64s(w0, self.q0[j]));
        }
        if self.nlerp {
            let n2 = simd.mul_add_e_f64s(
                q[3],
                q[3],
                simd.mul_add_e_f64s(q[2], q[2], simd.mul_add_e_f64s(q[1], q[1], simd.mul_f64s(q[0], q[0]))),
            );
            let n = simd.div_f64s(self.one, simd.sqrt_f64s(n2));
            q = q.map(|v| simd.mul_f64s(v, n));
        }
        let [w, qx, qy, qz] = q;
        let v = [simd.add_f64s(x, self.d[0]), simd.add_f64s(y, self.d[1]), simd.add_f64s(z, self.d[2])];
        // v + 2w(u×v) + 2u×(u×v), u = (qx, qy, qz), as in the scalar path.
        let cross = |a: [S::f64s; 3]| {
            [
                simd.negate_mul_add_e_f64s(qz, a[1], simd.mul_f64s(qy, a[2])),
                simd.negate_mul_add_e_f64s(qx, a[2], simd.mul_f64s(qz, a[0])),
                simd.negate_mul_add_e_f64s(qy, a[0], simd.mul_f64s(qx, a[1])),
            ]
        };
        let c = cross(v);
        let cc = cross(c);
        let mut out = v;
        for j in 0..3 {
            let rot = simd.mul_add_e_f64s(self.two, simd.mul_add_e_f64s(w, c[j], cc[j]), v[j]);
            out[j] = simd.mul_add_e_f64s(s, self.c1[j], simd.mul_add_e_f64s(r, self.c0[j], rot));
        }
        out
    }
}

/// The projector, broadcast to lanes.
struct ProjLanes<S: Simd> {
    rot: [[S::f64s; 3]; 3],
    trans: [S::f64s; 3],
    fx: S::f64s,
    fy: S::f64s,
    cx: S::f64s,
    cy: S::f64s,
    k: [S::f64s; 5],
    near: S::f64s,
    inf: S::f64s,
    nan: S::f64s,
    one: S::f64s,
    two: S::f64s,
}

impl<S: Simd> ProjLanes<S> {
    #[inline(always)]
    fn new(simd: S, p: &Projector) -> Self {
        let sp = |v: f64| simd.splat_f64s(v);
        Self {
            rot: p.rotation.map(|row| row.map(sp)),
            trans: p.translation.map(sp),
            fx: sp(p.cam.fx),
            fy: sp(p.cam.fy),
            cx: sp(p.cam.cx),
            cy: sp(p.cam.cy),
            k: p.cam.dist.map(sp),
            near: sp(NEAR_LIMIT),
            inf: sp(f64::INFINITY),
            nan: sp(f64::NAN),
            one: sp(1.0),
            two: sp(2.0),
        }
    }

    /// `Projector::pixel` on lanes, operation for operation (unfused, same order, so the
    /// same bits); NaN pixels where it gives `None`'s reasons (depth, non-finite input).
    #[inline(always)]
    fn pixel(&self, simd: S, p: [S::f64s; 3]) -> [S::f64s; 2] {
        let (m, a) = (|x, y| simd.mul_f64s(x, y), |x, y| simd.add_f64s(x, y));
        let row = |r: &[S::f64s; 3], t| a(a(a(m(r[0], p[0]), m(r[1], p[1])), m(r[2], p[2])), t);
        let z = row(&self.rot[2], self.trans[2]);
        let x = row(&self.rot[0], self.trans[0]);
        let y = row(&self.rot[1], self.trans[1]);
        let valid = simd.and_m64s(
            simd.and_m64s(simd.greater_than_f64s(z, self.near), simd.less_than_f64s(z, self.inf)),
            simd.and_m64s(
                simd.less_than_f64s(simd.abs_f64s(x), self.inf),
                simd.less_than_f64s(simd.abs_f64s(y), self.inf),
            ),
        );
        let inv_z = simd.div_f64s(self.one, z);
        let xp = m(x, inv_z);
        let yp = m(y, inv_z);
        let [k1, k2, p1, p2, k3] = self.k;
        let r2 = a(m(xp, xp), m(yp, yp));
        let radial = a(self.one, m(r2, a(k1, m(r2, a(k2, m(r2, k3))))));
        let two_xp = m(self.two, xp);
        let xy2 = m(two_xp, yp);
        let xpp = a(a(m(xp, radial), m(p1, xy2)), m(p2, a(r2, m(two_xp, xp))));
        let ypp = a(a(m(yp, radial), m(p1, a(r2, m(m(self.two, yp), yp)))), m(p2, xy2));
        let u = a(m(self.fx, xpp), self.cx);
        let v = a(m(self.fy, ypp), self.cy);
        [simd.select_f64s(valid, u, self.nan), simd.select_f64s(valid, v, self.nan)]
    }
}

impl<P: PointCloud + ?Sized> WithSimd for FusedChunk<'_, P> {
    type Output = Vec<Vec<usize>>;

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> Self::Output {
        if S::IS_SCALAR {
            return scalar_chunk(self);
        }
        let FusedChunk { points, times, range, motion, cull, out } = self;
        let mut lists: Vec<Vec<usize>> = vec![Vec::new(); cull.map_or(0, |c| c.boxes.len())];
        let proj = cull.map(|c| ProjLanes::new(simd, c.projector));
        let mut tile = Tile::new();
        let last = motion.segments.len() - 1;
        let mut start = range.start;
        while start < range.end {
            let n = TILE.min(range.end - start);
            let end = start + n;
            let tl = &mut tile;
            points.for_each_point_in(start..end, |i, p| {
                let k = i - start;
                tl.x[k] = p[0];
                tl.y[k] = p[1];
                tl.z[k] = p[2];
            });
            tl.t[..n].copy_from_slice(&times[start..end]);
            if n < TILE {
                // Padding lanes: a valid time and point, computed and dropped.
                let t0 = tl.t[0];
                tl.t[n..].fill(t0);
                tl.x[n..].fill(0.0);
                tl.y[n..].fill(0.0);
                tl.z[n..].fill(0.0);
            }
            let (tmin, tmax) = tl.t[..n].iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &t| (lo.min(t), hi.max(t)));
            let k = motion.start_segment(tmin);
            let sg = &motion.segments[k];
            let one_segment = k == last || tmax < motion.segments[k + 1].t0;
            if one_segment && sg.theta <= SERIES_ANGLE {
                let seg = SegLanes::new(simd, sg, &motion.d);
                let (xs, _) = S::as_simd_f64s(&tl.x);
                let (ys, _) = S::as_simd_f64s(&tl.y);
                let (zs, _) = S::as_simd_f64s(&tl.z);
                let (ts, _) = S::as_simd_f64s(&tl.t);
                let (ox, _) = S::as_mut_simd_f64s(&mut tl.ox);
                let (oy, _) = S::as_mut_simd_f64s(&mut tl.oy);
                let (oz, _) = S::as_mut_simd_f64s(&mut tl.oz);
                for ((((((x, y), z), t), ox), oy), oz) in
                    xs.iter().zip(ys).zip(zs).zip(ts).zip(ox.iter_mut()).zip(oy.iter_mut()).zip(oz.iter_mut())
                {
                    [*ox, *oy, *oz] = seg.apply(simd, *x, *y, *z, *t);
                }
                if let Some(pl) = &proj {
                    let (ox, _) = S::as_simd_f64s(&tl.ox);
                    let (oy, _) = S::as_simd_f64s(&tl.oy);
                    let (oz, _) = S::as_simd_f64s(&tl.oz);
                    let (us, _) = S::as_mut_simd_f64s(&mut tl.u);
                    let (vs, _) = S::as_mut_simd_f64s(&mut tl.v);
                    for ((((x, y), z), u), v) in ox.iter().zip(oy).zip(oz).zip(us.iter_mut()).zip(vs.iter_mut()) {
                        [*u, *v] = pl.pixel(simd, [*x, *y, *z]);
                    }
                }
            } else {
                let mut cursor = k;
                for j in 0..n {
                    let p = motion.apply([tl.x[j], tl.y[j], tl.z[j]], tl.t[j], &mut cursor);
                    [tl.ox[j], tl.oy[j], tl.oz[j]] = p;
                    if let Some(c) = cull {
                        [tl.u[j], tl.v[j]] = c.projector.pixel(p).unwrap_or([f64::NAN; 2]);
                    }
                }
            }
            let dst = &mut out[start - range.start..end - range.start];
            for (j, d) in dst.iter_mut().enumerate() {
                *d = [tl.ox[j], tl.oy[j], tl.oz[j]];
            }
            if let Some(c) = cull {
                for j in 0..n {
                    let uv = [tl.u[j], tl.v[j]];
                    if c.union.contains(uv) {
                        for (b, list) in c.boxes.iter().zip(lists.iter_mut()) {
                            if b.contains(uv) {
                                list.push(start + j);
                            }
                        }
                    }
                }
            }
            start = end;
        }
        lists
    }
}

#[cfg(test)]
mod tests {
    use super::super::{deskew_points_in_boxes, deskew_points_in_boxes_scalar, PoseStream};
    use super::*;
    use crate::camera::CameraModel;
    use nalgebra::{Isometry3, Vector3};
    use proptest::prelude::*;
    use proptest::test_runner::RngSeed;

    /// Deskewed points: SIMD path against the scalar reference (metres).
    const DESKEW_TOL_M: f64 = 1e-6;
    /// Projected pixels: SIMD against scalar (px). The design gives equal bits; this is the
    /// issue's bound, asserted beside exact equality.
    const PIXEL_TOL_PX: f64 = 1e-4;
    /// Cull membership may differ only for points this close to a box or image edge (px).
    const EDGE_TOL_PX: f64 = 1e-4;
    /// Fixed proptest seed: the same cases every run, in CI and here (STYLE 21).
    const SEED: u64 = 23;

    fn config() -> ProptestConfig {
        ProptestConfig { cases: 64, rng_seed: RngSeed::Fixed(SEED), ..ProptestConfig::default() }
    }

    /// `Projector::pixel` of each point through the SIMD lanes (ProjLanes::pixel).
    struct PixelOp<'a> {
        projector: &'a Projector,
        pts: &'a [[f64; 3]],
    }

    impl WithSimd for PixelOp<'_> {
        type Output = Vec<[f64; 2]>;
        fn with_simd<S: Simd>(self, simd: S) -> Self::Output {
            let lanes = ProjLanes::new(simd, self.projector);
            let mut out = Vec::with_capacity(self.pts.len());
            for block in self.pts.chunks(TILE) {
                let mut t = Tile::new();
                for (j, p) in block.iter().enumerate() {
                    [t.x[j], t.y[j], t.z[j]] = *p;
                }
                let (xs, _) = S::as_simd_f64s(&t.x);
                let (ys, _) = S::as_simd_f64s(&t.y);
                let (zs, _) = S::as_simd_f64s(&t.z);
                let (us, _) = S::as_mut_simd_f64s(&mut t.u);
                let (vs, _) = S::as_mut_simd_f64s(&mut t.v);
                for ((((x, y), z), u), v) in xs.iter().zip(ys).zip(zs).zip(us.iter_mut()).zip(vs.iter_mut()) {
                    [*u, *v] = lanes.pixel(simd, [*x, *y, *z]);
                }
                out.extend((0..block.len()).map(|j| [t.u[j], t.v[j]]));
            }
            out
        }
    }

    fn pose(t: [f64; 3], r: [f64; 3]) -> Isometry3<f64> {
        Isometry3::new(Vector3::from(t), Vector3::from(r))
    }

    /// Distance (px) from `uv` to the nearest edge of `b` or of the image.
    fn edge_distance(uv: [f64; 2], b: &PixelBox, cam: &CameraModel) -> f64 {
        let (w, h) = (f64::from(cam.width), f64::from(cam.height));
        [uv[0] - b.x1, uv[0] - b.x2, uv[1] - b.y1, uv[1] - b.y2, uv[0], uv[0] - w, uv[1], uv[1] - h]
            .iter()
            .fold(f64::INFINITY, |m, d| m.min(d.abs()))
    }

    #[allow(clippy::too_many_arguments)]
    fn check_parity(
        pts: &[[f64; 3]],
        times: &[f64],
        s: &PoseStream,
        t_ref: f64,
        t_b_l: &Isometry3<f64>,
        t_c_l: &Isometry3<f64>,
        cam: &CameraModel,
        boxes: &[PixelBox],
    ) -> std::result::Result<(), TestCaseError> {
        let (cloud, lists) = deskew_points_in_boxes(pts, times, s, t_ref, t_b_l, t_c_l, cam, boxes).unwrap();
        let (cloud_ref, lists_ref) = deskew_points_in_boxes_scalar(pts, times, s, t_ref, t_b_l, t_c_l, cam, boxes).unwrap();
        for (a, b) in cloud.iter().zip(&cloud_ref) {
            for j in 0..3 {
                prop_assert_eq!(a[j].is_nan(), b[j].is_nan(), "{:?} vs {:?}", a, b);
                prop_assert!(a[j].is_nan() || (a[j] - b[j]).abs() < DESKEW_TOL_M, "{:?} vs {:?}", a, b);
            }
        }
        let projector = Projector::new(t_c_l, cam);
        let simd_px = Arch::new().dispatch(PixelOp { projector: &projector, pts: &cloud });
        for (p, got) in cloud.iter().zip(&simd_px) {
            let want = projector.pixel(*p).unwrap_or([f64::NAN; 2]);
            for j in 0..2 {
                prop_assert_eq!(got[j].to_bits(), want[j].to_bits(), "{:?}: {:?} vs {:?}", p, got, want);
                prop_assert!(want[j].is_nan() || (got[j] - want[j]).abs() <= PIXEL_TOL_PX);
            }
        }
        prop_assert_eq!(lists.len(), lists_ref.len());
        for ((a, b), bx) in lists.iter().zip(&lists_ref).zip(boxes) {
            prop_assert!(a.windows(2).all(|w| w[0] < w[1]));
            for &i in a.iter().filter(|i| b.binary_search(i).is_err()).chain(b.iter().filter(|i| a.binary_search(i).is_err())) {
                let uv = projector.pixel(cloud_ref[i]);
                prop_assert!(uv.is_some_and(|uv| edge_distance(uv, bx, cam) < EDGE_TOL_PX), "point {} differs: {:?}", i, uv);
            }
        }
        Ok(())
    }

    #[test]
    fn non_finite_points_stay_nan_and_out_of_every_box() {
        let s = PoseStream::new(vec![0.0, 0.1], vec![pose([0.0; 3], [0.0; 3]), pose([0.3, 0.0, 0.0], [0.0, 0.0, 0.05])]).unwrap();
        let cam = CameraModel::new(500.0, 500.0, 320.0, 240.0, 640, 480, [-0.1, 0.01, 0.0, 0.0, 0.0]).unwrap();
        let boxes = [PixelBox::new(0.0, 0.0, 640.0, 480.0).unwrap()];
        let mut pts: Vec<[f64; 3]> = (0..150).map(|i| [0.01 * f64::from(i) - 0.75, 0.2, 5.0]).collect();
        pts[3] = [f64::NAN, 0.0, 5.0];
        pts[70] = [0.0, f64::INFINITY, 5.0];
        pts[100] = [0.0, 0.0, f64::INFINITY];
        let times: Vec<f64> = (0..pts.len()).map(|i| 0.1 * i as f64 / pts.len() as f64).collect();
        let (cloud, lists) =
            deskew_points_in_boxes(&pts, &times, &s, 0.05, &Isometry3::identity(), &Isometry3::identity(), &cam, &boxes).unwrap();
        assert!(cloud[3][0].is_nan() && !cloud[70][1].is_finite() && !cloud[100][2].is_finite());
        assert!(lists[0].len() > 100 && [3, 70, 100].iter().all(|i| !lists[0].contains(i)));
        let (cloud_ref, lists_ref) = deskew_points_in_boxes_scalar(
            &pts,
            &times,
            &s,
            0.05,
            &Isometry3::identity(),
            &Isometry3::identity(),
            &cam,
            &boxes,
        )
        .unwrap();
        assert_eq!(lists, lists_ref);
        assert_eq!(cloud.len(), cloud_ref.len());
    }

    proptest! {
        #![proptest_config(config())]

        /// Parity of the SIMD path with the scalar reference (`deskew_points_in_boxes_scalar`):
        /// deskewed points within DESKEW_TOL_M (1e-6 m), pixels bit-equal (so within
        /// PIXEL_TOL_PX, 1e-4 px), and the same box members except points within EDGE_TOL_PX
        /// (1e-4 px) of an edge. Random pose streams whose knots turn by ~1e-8 rad (nlerp),
        /// up to 0.15 rad (the series slerp) or up to 1 rad (libm slerp, the scalar tiles),
        /// points out to tower ranges (120 m), times in order (SIMD tiles) or shuffled
        /// (tiles across knots), random cameras with distortion, poses and boxes.
        #[test]
        fn simd_matches_scalar(
            n_knots in 2usize..6,
            base in prop::array::uniform3(-3.0f64..3.0),
            step_scale in prop_oneof![Just(1e-8f64), Just(0.15f64), Just(1.0f64)],
            steps in prop::collection::vec((prop::array::uniform3(-50.0f64..50.0), prop::array::uniform3(-1.0f64..1.0)), 6),
            pts in prop::collection::vec((prop::array::uniform3(-120.0f64..120.0), 0.0f64..0.1), 1..400),
            sorted in any::<bool>(),
            tref in 0.0f64..0.1,
            lt in prop::array::uniform3(-0.5f64..0.5), lr in prop::array::uniform3(-3.0f64..3.0),
            fx in 50.0f64..2000.0, fy in 50.0f64..2000.0, w in 1u32..2000, h in 1u32..2000,
            k1 in -0.5f64..0.5, k2 in -0.2f64..0.2, p1 in -0.01f64..0.01, p2 in -0.01f64..0.01, k3 in -0.1f64..0.1,
            crot in prop::array::uniform3(-3.1f64..3.1), ctrans in prop::array::uniform3(-1.0f64..1.0),
            raw_boxes in prop::collection::vec((-500.0f64..2500.0, -500.0f64..2500.0, 1.0f64..1500.0, 1.0f64..1500.0), 0..4),
        ) {
            let times: Vec<f64> = (0..n_knots).map(|i| 0.1 * i as f64 / (n_knots - 1) as f64).collect();
            let poses: Vec<Isometry3<f64>> = (0..n_knots).map(|i| {
                let (t, r) = steps[i];
                let k = i as f64 * step_scale;
                pose(t, [base[0] + k * r[0], base[1] + k * r[1], base[2] + k * r[2]])
            }).collect();
            let s = PoseStream::new(times, poses).unwrap();
            let p: Vec<[f64; 3]> = pts.iter().map(|x| x.0).collect();
            let mut t: Vec<f64> = pts.iter().map(|x| x.1).collect();
            if sorted {
                t.sort_by(f64::total_cmp);
            }
            let cam = CameraModel::new(fx, fy, 0.5 * f64::from(w), 0.5 * f64::from(h), w, h, [k1, k2, p1, p2, k3]).unwrap();
            let boxes: Vec<PixelBox> = raw_boxes.iter()
                .map(|&(x, y, bw, bh)| PixelBox::new(x, y, x + bw, y + bh).unwrap()).collect();
            check_parity(&p, &t, &s, tref, &pose(lt, lr), &pose(ctrans, crot), &cam, &boxes)?;
        }
    }
}
