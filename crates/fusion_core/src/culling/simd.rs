//! SIMD lanes of the box culling, shared by [`super::points_in_boxes`] and the fused
//! deskew + project + cull ([`crate::deskew::deskew_points_in_boxes`]): the boxes' union on
//! lanes of a tile's pixels ([`ProjLanes`]), and the per-box lists built from the lanes whose
//! pixel is inside the union. `points_in_boxes` projects with [`ProjLanes::pixel_exact`], so its
//! lists are the scalar loop's exactly (edges included); the fused kernel with
//! [`ProjLanes::pixel_fused`].
//!
//! Dispatch is pulp's, as in `deskew::simd` (AVX-512, AVX2 + FMA, NEON; the scalar loop on
//! other CPUs).

use std::ops::Range;

use pulp::{Arch, Simd, WithSimd};

use super::PixelBox;
use crate::points::PointCloud;
use crate::projection::lanes::{lanes, stage, ProjLanes, TILE};
use crate::projection::Projector;

/// The boxes' union: `PixelBox::contains` as a lane mask (edges splat where used, as in
/// [`ProjLanes`]).
pub(crate) struct UnionLanes(pub PixelBox);

impl UnionLanes {
    /// 1.0 where `valid` and `(u, v)` is inside (same comparisons as `PixelBox::contains`),
    /// else 0.0; and whether any lane is.
    #[inline(always)]
    fn contains<S: Simd>(&self, simd: S, u: S::f64s, v: S::f64s, valid: S::m64s) -> (S::f64s, bool) {
        let sp = |v: f64| simd.splat_f64s(v);
        let b = &self.0;
        let inside = simd.and_m64s(
            simd.and_m64s(simd.greater_than_or_equal_f64s(u, sp(b.x1)), simd.less_than_f64s(u, sp(b.x2))),
            simd.and_m64s(simd.greater_than_or_equal_f64s(v, sp(b.y1)), simd.less_than_f64s(v, sp(b.y2))),
        );
        let inside = simd.and_m64s(inside, valid);
        let any = simd.first_true_m64s(inside) < lanes::<S>();
        (simd.select_f64s(inside, sp(1.0), sp(0.0)), any)
    }
}

/// One tile's pixels and union mask, structure of arrays.
pub(crate) struct PixelTile {
    pub u: [f64; TILE],
    pub v: [f64; TILE],
    /// 1.0 where the pixel is inside the boxes' union, else 0.0.
    pub m: [f64; TILE],
    /// Per lane vector (at most [`TILE`] of them): whether any of its `m` is 1.0.
    pub any: [bool; TILE],
}

impl PixelTile {
    pub(crate) fn new() -> Self {
        let a = [0.0; TILE];
        Self { u: a, v: a, m: a, any: [false; TILE] }
    }

    /// Projects the tile's first `n` points `(x, y, z)` and marks those inside the union,
    /// with [`ProjLanes::pixel_fused`] (`FUSED`) or [`ProjLanes::pixel_exact`]: a constant,
    /// so each caller's loop has one form and no branch. Lane vectors past the `n`-th point
    /// are not computed (a 10-point call projects one or two vectors, not the whole tile);
    /// the lanes of the last one past `n` must hold finite points (padding).
    #[inline(always)]
    pub(crate) fn project<S: Simd, const FUSED: bool>(
        &mut self,
        simd: S,
        proj: &ProjLanes,
        union: &UnionLanes,
        [x, y, z]: [&[f64; TILE]; 3],
        n: usize,
    ) {
        let (xs, _) = S::as_simd_f64s(x);
        let (ys, _) = S::as_simd_f64s(y);
        let (zs, _) = S::as_simd_f64s(z);
        let (us, _) = S::as_mut_simd_f64s(&mut self.u);
        let (vs, _) = S::as_mut_simd_f64s(&mut self.v);
        let (ms, _) = S::as_mut_simd_f64s(&mut self.m);
        let rows = (xs.iter().zip(ys).zip(zs)).zip(us.iter_mut().zip(vs.iter_mut()).zip(ms.iter_mut()).zip(self.any.iter_mut()));
        for (((x, y), z), (((u, v), m), any)) in rows.take(n.div_ceil(lanes::<S>())) {
            let p = [*x, *y, *z];
            let ([pu, pv], valid) = if FUSED { proj.pixel_fused(simd, p) } else { proj.pixel_exact(simd, p) };
            (*u, *v) = (pu, pv);
            (*m, *any) = union.contains(simd, pu, pv, valid);
        }
    }

    /// The scalar reference for lane `j`: `pixel` of the point (None: no pixel) and whether
    /// it is inside `union`; for tiles the lanes do not take.
    #[inline]
    pub(crate) fn set_scalar(&mut self, j: usize, pixel: Option<[f64; 2]>, union: &PixelBox) {
        [self.u[j], self.v[j]] = pixel.unwrap_or([f64::NAN; 2]);
        self.m[j] = if pixel.is_some_and(|uv| union.contains(uv)) { 1.0 } else { 0.0 };
    }

    /// Appends to each box's list the indices `start + j` (j < `n`, ascending) of the tile's
    /// points inside that box. Lane vectors with no pixel in the union are skipped whole.
    #[inline(always)]
    pub(crate) fn push_members<S: Simd>(&self, n: usize, start: usize, boxes: &[PixelBox], lists: &mut [Vec<usize>]) {
        let w = lanes::<S>();
        for g in (0..n.div_ceil(w)).filter(|&g| self.any[g]) {
            for j in g * w..((g + 1) * w).min(n) {
                if self.m[j] != 0.0 {
                    let uv = [self.u[j], self.v[j]];
                    for (b, list) in boxes.iter().zip(lists.iter_mut()) {
                        if b.contains(uv) {
                            list.push(start + j);
                        }
                    }
                }
            }
        }
    }
}

/// One range of a cloud to cull: per box, the ascending indices of its points inside.
pub(super) struct CullChunk<'a, P: ?Sized> {
    pub points: &'a P,
    pub range: Range<usize>,
    pub projector: &'a Projector,
    pub boxes: &'a [PixelBox],
    /// The boxes' union clipped to the image, non-empty.
    pub union: &'a PixelBox,
}

/// Culls one range on the best instruction set of this CPU (the scalar loop where pulp
/// finds no SIMD level): the same lists as [`super::cull_range_scalar`], bit for bit.
pub(super) fn cull_chunk<P: PointCloud + ?Sized>(chunk: CullChunk<'_, P>) -> Vec<Vec<usize>> {
    Arch::new().dispatch(chunk)
}

/// One range on the AVX2 + FMA kernel where the CPU has it (also under AVX-512), else as
/// [`cull_chunk`]: the tests' way to the path of CPUs without AVX-512.
#[cfg(test)]
pub(super) fn avx2_cull_chunk<P: PointCloud + ?Sized>(chunk: CullChunk<'_, P>) -> Vec<Vec<usize>> {
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        return pulp::Simd::vectorize(v3, chunk);
    }
    cull_chunk(chunk)
}

impl<P: PointCloud + ?Sized> WithSimd for CullChunk<'_, P> {
    type Output = Vec<Vec<usize>>;

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> Self::Output {
        let CullChunk { points, range, projector, boxes, union } = self;
        if S::IS_SCALAR {
            return super::cull_range_scalar(points, range, projector, boxes, union);
        }
        let mut lists: Vec<Vec<usize>> = vec![Vec::new(); boxes.len()];
        let proj = ProjLanes::new(projector);
        let union = UnionLanes(*union);
        let (mut x, mut y, mut z) = ([0.0; TILE], [0.0; TILE], [0.0; TILE]);
        let mut px = PixelTile::new();
        let mut start = range.start;
        while start < range.end {
            let n = TILE.min(range.end - start);
            stage::<S, P>(points, start, n, [&mut x, &mut y, &mut z]);
            px.project::<S, false>(simd, &proj, &union, [&x, &y, &z], n);
            px.push_members::<S>(n, start, boxes, &mut lists);
            start += n;
        }
        lists
    }
}
