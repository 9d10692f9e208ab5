//! The projector on SIMD lanes (pulp: AVX-512, AVX2 + FMA, NEON; the scalar loop on other
//! CPUs), for tiles of points staged as structure of arrays. Two forms of the pixel:
//! - [`ProjLanes::pixel_exact`]: `Projector::pixel`'s operations in its order, unfused, so every
//!   pixel is the scalar one to the bit: [`super::project_points`] and
//!   [`crate::culling::points_in_boxes`] give exactly the scalar loop's results.
//! - [`ProjLanes::pixel_fused`]: the same formula with fused multiply-adds and the tangential
//!   terms regrouped, a third fewer operations, within a few f64 ulps of the scalar pixel: the
//!   fused deskew + project + cull's, whose parity bound is the 1e-4 px.

use std::ops::Range;

use pulp::{Arch, Simd, WithSimd};

use super::{Projection, Projector};
use crate::camera::NEAR_LIMIT;
use crate::points::PointCloud;

/// Points per tile: staged into SoA arrays, projected lane by lane, culled. A multiple of
/// every lane count (1, 2, 4, 8), so the lane loops have no tail.
pub(crate) const TILE: usize = 128;

/// f64 lanes of `S`.
#[inline(always)]
pub(crate) const fn lanes<S: Simd>() -> usize {
    std::mem::size_of::<S::f64s>() / std::mem::size_of::<f64>()
}

/// Stages points `start..start + n` of `points` (n <= [`TILE`]) into a tile's `x, y, z`, and
/// fills the lanes of the last lane vector past them with the origin (a finite point,
/// computed and dropped; the vectors after it are not computed at all).
#[inline(always)]
pub(crate) fn stage<S: Simd, P: PointCloud + ?Sized>(points: &P, start: usize, n: usize, [x, y, z]: [&mut [f64; TILE]; 3]) {
    points.for_each_point_in(start..start + n, |i, p| {
        let k = i - start;
        [x[k], y[k], z[k]] = p;
    });
    let end = (n.div_ceil(lanes::<S>()) * lanes::<S>()).min(TILE);
    for a in [x, y, z] {
        a[n..end].fill(0.0);
    }
}

/// The projector's constants for the lanes. Kept as scalars and splat where used: the
/// compiler folds each into its instruction as a broadcast memory operand, where 26
/// broadcast registers crowded the 32 vector registers and spilled in the loop.
#[derive(Clone, Copy)]
pub(crate) struct ProjLanes {
    rot: [[f64; 3]; 3],
    trans: [f64; 3],
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    k: [f64; 5],
}

impl ProjLanes {
    pub(crate) fn new(p: &Projector) -> Self {
        Self { rot: p.rotation, trans: p.translation, fx: p.cam.fx, fy: p.cam.fy, cx: p.cam.cx, cy: p.cam.cy, k: p.cam.dist }
    }

    /// The mask of lanes whose depth is finite and past the near limit. Other lanes' pixels
    /// are meaningless; lanes with a non-finite x or y (or a pixel past f64's range) come out
    /// non-finite, so every box test (finite edges, `>=` and `<`) rejects them as the scalar
    /// `None` does.
    #[inline(always)]
    fn in_front<S: Simd>(simd: S, z: S::f64s) -> S::m64s {
        let sp = |v: f64| simd.splat_f64s(v);
        simd.and_m64s(simd.greater_than_f64s(z, sp(NEAR_LIMIT)), simd.less_than_f64s(z, sp(f64::INFINITY)))
    }

    /// x' = x / z and y' = y / z of the camera-frame point whose coordinate `i` is `row(i)`
    /// (z first, as the scalar `pixel`), the division as the scalar's (`1 / z`, then products),
    /// and the mask of [`Self::in_front`].
    #[inline(always)]
    fn normalized<S: Simd>(simd: S, row: impl Fn(usize) -> S::f64s) -> ([S::f64s; 2], S::m64s) {
        let z = row(2);
        let (x, y) = (row(0), row(1));
        let inv_z = simd.div_f64s(simd.splat_f64s(1.0), z);
        ([simd.mul_f64s(x, inv_z), simd.mul_f64s(y, inv_z)], Self::in_front(simd, z))
    }

    /// `Projector::pixel` on lanes, with fused multiply-adds (within a few f64 ulps of the
    /// scalar pixel, far inside the 1e-4 px), and the mask of [`Self::in_front`].
    #[inline(always)]
    pub(crate) fn pixel_fused<S: Simd>(&self, simd: S, p: [S::f64s; 3]) -> ([S::f64s; 2], S::m64s) {
        let sp = |v: f64| simd.splat_f64s(v);
        let m = |x, y| simd.mul_f64s(x, y);
        let fma = |a, b, c| simd.mul_add_e_f64s(a, b, c);
        let row = |i: usize| {
            let (r, t) = (&self.rot[i], self.trans[i]);
            fma(sp(r[2]), p[2], fma(sp(r[1]), p[1], fma(sp(r[0]), p[0], sp(t))))
        };
        let ([xp, yp], valid) = Self::normalized(simd, row);
        let [k1, k2, p1, p2, k3] = self.k;
        let r2 = fma(xp, xp, m(yp, yp));
        let radial = fma(r2, fma(r2, fma(r2, sp(k3), sp(k2)), sp(k1)), sp(1.0));
        // The tangential terms regrouped: x'' = x' w + p2 r², y'' = y' w + p1 r² with
        // w = radial + 2 p1 y' + 2 p2 x' (the same polynomial in 7 operations, not 11).
        let w = simd.add_f64s(radial, fma(sp(2.0 * p1), yp, m(sp(2.0 * p2), xp)));
        let xpp = fma(xp, w, m(sp(p2), r2));
        let ypp = fma(yp, w, m(sp(p1), r2));
        ([fma(sp(self.fx), xpp, sp(self.cx)), fma(sp(self.fy), ypp, sp(self.cy))], valid)
    }

    /// `Projector::pixel` on lanes, operation for operation (`Projector::depth`, `lateral`
    /// and `CameraModel::project_xyz`, same order, no fused multiply-add): each lane's pixel
    /// is the scalar one to the bit, and the mask of [`Self::in_front`].
    #[inline(always)]
    pub(crate) fn pixel_exact<S: Simd>(&self, simd: S, p: [S::f64s; 3]) -> ([S::f64s; 2], S::m64s) {
        let sp = |v: f64| simd.splat_f64s(v);
        let m = |x, y| simd.mul_f64s(x, y);
        let a = |x, y| simd.add_f64s(x, y);
        // r[0] p[0] + r[1] p[1] + r[2] p[2] + t, left to right as the scalar sum.
        let row = |i: usize| {
            let (r, t) = (&self.rot[i], self.trans[i]);
            a(a(a(m(sp(r[0]), p[0]), m(sp(r[1]), p[1])), m(sp(r[2]), p[2])), sp(t))
        };
        let ([xp, yp], valid) = Self::normalized(simd, row);
        let [k1, k2, p1, p2, k3] = self.k;
        let r2 = a(m(xp, xp), m(yp, yp));
        let radial = a(sp(1.0), m(r2, a(sp(k1), m(r2, a(sp(k2), m(r2, sp(k3)))))));
        let two = sp(2.0);
        let xy2 = m(m(two, xp), yp);
        let xpp = a(a(m(xp, radial), m(sp(p1), xy2)), m(sp(p2), a(r2, m(m(two, xp), xp))));
        let ypp = a(a(m(yp, radial), m(sp(p1), a(r2, m(m(two, yp), yp)))), m(sp(p2), xy2));
        ([a(m(sp(self.fx), xpp), sp(self.cx)), a(m(sp(self.fy), ypp), sp(self.cy))], valid)
    }
}


/// One range of a cloud to project: per point its pixel (NaN where there is none) and
/// whether it lands inside the image.
pub(super) struct ProjectChunk<'a, P: ?Sized> {
    pub points: &'a P,
    pub range: Range<usize>,
    pub projector: &'a Projector,
}

/// Projects one range on the best instruction set of this CPU (the scalar loop where pulp
/// finds no SIMD level): the same pixels as [`super::project_range_scalar`], bit for bit.
pub(super) fn project_chunk<P: PointCloud + ?Sized>(chunk: ProjectChunk<'_, P>, out: &mut Projection) {
    Arch::new().dispatch(ProjectInto { chunk, out });
}

/// One range on the AVX2 + FMA lanes where the CPU has them (also under AVX-512), else as
/// [`project_chunk`]: the tests' way to the path of CPUs without AVX-512.
#[cfg(test)]
pub(super) fn avx2_project_chunk<P: PointCloud + ?Sized>(chunk: ProjectChunk<'_, P>, out: &mut Projection) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        return pulp::Simd::vectorize(v3, ProjectInto { chunk, out });
    }
    project_chunk(chunk, out)
}

struct ProjectInto<'a, 'o, P: ?Sized> {
    chunk: ProjectChunk<'a, P>,
    out: &'o mut Projection,
}

impl<P: PointCloud + ?Sized> WithSimd for ProjectInto<'_, '_, P> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let ProjectInto { chunk: ProjectChunk { points, range, projector }, out } = self;
        if S::IS_SCALAR {
            return super::project_range_scalar(points, range, projector, out);
        }
        let proj = ProjLanes::new(projector);
        let sp = |v: f64| simd.splat_f64s(v);
        let (width, height) = (f64::from(projector.cam.width), f64::from(projector.cam.height));
        let (mut x, mut y, mut z) = ([0.0; TILE], [0.0; TILE], [0.0; TILE]);
        let (mut u, mut v, mut inside) = ([0.0; TILE], [0.0; TILE], [0.0; TILE]);
        let mut start = range.start;
        while start < range.end {
            let n = TILE.min(range.end - start);
            stage::<S, P>(points, start, n, [&mut x, &mut y, &mut z]);
            let (xs, _) = S::as_simd_f64s(&x);
            let (ys, _) = S::as_simd_f64s(&y);
            let (zs, _) = S::as_simd_f64s(&z);
            let (us, _) = S::as_mut_simd_f64s(&mut u);
            let (vs, _) = S::as_mut_simd_f64s(&mut v);
            let (ins, _) = S::as_mut_simd_f64s(&mut inside);
            let rows = (xs.iter().zip(ys).zip(zs)).zip(us.iter_mut().zip(vs.iter_mut()).zip(ins.iter_mut()));
            for (((x, y), z), ((u, v), inside)) in rows.take(n.div_ceil(lanes::<S>())) {
                let ([pu, pv], front) = proj.pixel_exact(simd, [*x, *y, *z]);
                // The scalar `None`: behind or at the near limit, or a non-finite pixel.
                let finite = |w| simd.less_than_f64s(simd.abs_f64s(w), sp(f64::INFINITY));
                let some = simd.and_m64s(front, simd.and_m64s(finite(pu), finite(pv)));
                let nan = sp(f64::NAN);
                (*u, *v) = (simd.select_f64s(some, pu, nan), simd.select_f64s(some, pv, nan));
                // `Projector::in_image` (NaN fails every comparison).
                let in_image = simd.and_m64s(
                    simd.and_m64s(simd.greater_than_or_equal_f64s(*u, sp(0.0)), simd.less_than_f64s(*u, sp(width))),
                    simd.and_m64s(simd.greater_than_or_equal_f64s(*v, sp(0.0)), simd.less_than_f64s(*v, sp(height))),
                );
                *inside = simd.select_f64s(in_image, sp(1.0), sp(0.0));
            }
            out.uv.extend((0..n).map(|j| [u[j], v[j]]));
            out.valid.extend(inside[..n].iter().map(|&m| m != 0.0));
            start += n;
        }
    }
}
