//! SIMD path of the fused deskew + project + cull ([`super::deskew_points_in_boxes`]): the
//! results of the scalar reference ([`super::Motion::apply`], then
//! [`crate::projection::Projector::pixel`]) on tiles of [`TILE`] points, in f64 lanes.
//!
//! Crate: `pulp`, not `wide`. `pulp::Arch::new().dispatch` detects the CPU once and runs one
//! generic kernel compiled per instruction set behind `#[target_feature]` (AVX-512 with the
//! `x86-v4` feature, else AVX2 + FMA on x86-64, NEON on aarch64; other CPUs get the scalar
//! reference, see [`fused_chunk`]), with no hand-written dispatch and no `unsafe` here. `wide`
//! chooses its backend at compile time (`cfg(target_feature)`), so runtime dispatch with it
//! takes hand-written `#[target_feature]` wrappers per level.
//!
//! Why f64 lanes, not f32: f32's spacing is 3.8e-6 m at 40 m, so the 1e-6 m deskew parity
//! cannot hold at tower ranges, and 1.2e-4 px above u = 1024, so neither can 1e-4 px.
//!
//! No slerp per point (issue 23): slerp turns `R(q0)` about the fixed axis of `q1 q0*` at a
//! constant rate, so in a frame `Q` whose z is that axis the segment's rotation is
//! `Qᵀ Rz(omega (t - t0)) Q R(q0)` ([`super::Segment::omega`]). Per tile (a `sin_cos`, or an
//! earlier tile's turned by a series, see [`SinCosNear`]): the rotation at the centre angle
//! of the tile's times. Per point: a 3x3 rotation + offset, a
//! 2-D rotation by the small angle ε from the centre (Taylor series of sin/cos, exact to f64
//! rounding for |ε| <= [`EPS_MAX`]; 4 terms below [`EPS_SHORT`]), `Qᵀ`, and the translation,
//! linear in t. This is the exact slerp (no pose grid, no interpolation error), ~30 fused
//! multiply-adds a point where the per-point slerp took ~50.
//!
//! Exactness: the deskew differs from the scalar path by float rounding (< 1e-9 m to 150 m,
//! tested). The projection is `Projector::pixel`'s formula with fused multiply-adds: within a
//! few f64 ulps of the scalar pixel (tested to the 1e-4 px; the unfused, bit-identical
//! sequence cost a third more operations), so the culling of the SIMD cloud can differ from the
//! scalar culling only for a point within those ulps of a box edge (tested to 1e-4 px).
//!
//! Tiles whose times touch 2-3 segments (a pose knot inside the tile, or times out of order)
//! run the tile form of each and select lanes by time. Tiles that take the scalar reference
//! instead (same results, per point): times over more than 3 segments, or angles spreading more
//! than [`EPS_MAX`] from the centre (e.g. 128 ordered points over 0.64 ms past ~300 rad/s).

use std::ops::Range;

use pulp::{Arch, Simd, WithSimd};

use super::{Motion, Segment};
use crate::culling::simd::{PixelTile, UnionLanes};
use crate::culling::PixelBox;
use crate::points::PointCloud;
// Points per tile (TILE): staged into SoA arrays, deskewed and projected lane by lane, written
// back.
use crate::projection::lanes::{ProjLanes, TILE};
use crate::projection::Projector;

/// What to cull a chunk's deskewed points into (absent for a plain deskew).
#[derive(Clone, Copy)]
pub(super) struct Cull<'a> {
    pub projector: &'a Projector,
    pub boxes: &'a [PixelBox],
    /// The boxes' union clipped to the image, non-empty.
    pub union: &'a PixelBox,
}

/// One chunk of the fused kernel: deskew `range` of `points` (returned in order) and, with
/// `cull`, return per box the ascending global indices of the points inside it.
pub(super) struct FusedChunk<'a, P: ?Sized> {
    pub points: &'a P,
    pub times: &'a [f64],
    pub range: Range<usize>,
    pub motion: &'a Motion,
    pub cull: Option<Cull<'a>>,
}

/// A chunk's deskewed points and, per box, its points' global indices inside the box.
pub(super) type ChunkResult = (Vec<[f64; 3]>, Vec<Vec<usize>>);

/// Runs one chunk on the best instruction set of this CPU (the scalar reference where pulp
/// finds no SIMD level).
pub(super) fn fused_chunk<P: PointCloud + ?Sized>(chunk: FusedChunk<'_, P>) -> ChunkResult {
    Arch::new().dispatch(chunk)
}

/// One chunk on the AVX2 + FMA kernel where the CPU has it (also under AVX-512), else as
/// [`fused_chunk`]: the tests' way to the path of CPUs without AVX-512.
#[cfg(test)]
pub(super) fn avx2_chunk<P: PointCloud + ?Sized>(chunk: FusedChunk<'_, P>) -> ChunkResult {
    #[cfg(target_arch = "x86_64")]
    if let Some(v3) = pulp::x86::V3::try_new() {
        return pulp::Simd::vectorize(v3, chunk);
    }
    fused_chunk(chunk)
}

/// The scalar reference for one chunk: [`Motion::apply`] per point, then the culling loop.
pub(super) fn scalar_chunk<P: PointCloud + ?Sized>(chunk: FusedChunk<'_, P>) -> ChunkResult {
    let FusedChunk { points, times, range, motion, cull } = chunk;
    let start = range.start;
    let mut out = Vec::with_capacity(range.len());
    let mut k = range.clone().next().map_or(0, |i| motion.start_segment(times[i]));
    points.for_each_point_in(range, |i, p| {
        out.push(motion.apply(p, times[i], &mut k));
    });
    let Some(c) = cull else { return (out, Vec::new()) };
    let mut lists = crate::culling::cull_range_scalar(&out, 0..out.len(), c.projector, c.boxes, c.union);
    for list in &mut lists {
        for i in list.iter_mut() {
            *i += start;
        }
    }
    (out, lists)
}

/// One tile's points (staged), deskewed points and pixels, structure of arrays.
struct Tile {
    x: [f64; TILE],
    y: [f64; TILE],
    z: [f64; TILE],
    /// The short last tile's times, padded (whole tiles read theirs in place).
    t: [f64; TILE],
    ox: [f64; TILE],
    oy: [f64; TILE],
    oz: [f64; TILE],
    /// The deskewed points' pixels and union mask.
    px: PixelTile,
}

impl Tile {
    fn new() -> Self {
        let a = [0.0; TILE];
        Self { x: a, y: a, z: a, t: a, ox: a, oy: a, oz: a, px: PixelTile::new() }
    }
}

/// Largest |ε| (rad) of a tile's points about its centre angle: the Taylor series of
/// `sin ε` to ε^7 and `cos ε` to ε^8 below are exact to f64 rounding there (first omitted
/// terms ε^9/9! < 3e-15, ε^10/10! < 3e-17, relative). A tile of time-ordered Mid-360 points
/// (128 points, 0.64 ms) stays under it up to ~300 rad/s.
const EPS_MAX: f64 = 0.1;
/// Below this |ε| (rad) the short series serve: `sin ε ≈ ε - ε³/6` (first omitted term
/// ε^5/120 < 3e-14, relative), `cos ε ≈ 1 - ε²/2 + ε^4/24` (ε^6/720 < 3e-17): 128 ordered
/// Mid-360 points up to ~15 rad/s.
const EPS_SHORT: f64 = 0.005;

/// One segment's motion about a tile's centre angle `phi_c`, broadcast to lanes:
/// `R_A(t) (p + d) = Qᵀ Rz(ε) [Rz(phi_c) b p + Rz(phi_c) f]`, `ε = omega (t - t_c)` (see
/// [`Segment::omega`]). Per point: a 3x3 rotation and offset, a 2-D rotation by the small ε
/// (sin/cos by series), the rotation back by `Qᵀ` and the translation, linear in t.
#[derive(Clone, Copy)]
struct TileLanes {
    /// `ε = t · omega + eps_off`.
    omega: f64,
    eps_off: f64,
    bt: [[f64; 3]; 3],
    ft: [f64; 3],
    qt: [[f64; 3]; 3],
    /// Translation `c0 + s (c1 - c0)` as `lin0 + t · lin1`.
    lin0: [f64; 3],
    lin1: [f64; 3],
    /// |ε| <= [`EPS_SHORT`]: the short series.
    short: bool,
}

/// Taylor coefficients of sin ε / ε and cos ε in ε².
const SIN_C: [f64; 4] = [1.0, -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0];
const COS_C: [f64; 5] = [1.0, -0.5, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40320.0];

/// sin and cos of a segment's tile angles: libm's `sin_cos` at an anchor angle, then for
/// angles within [`EPS_MAX`] of it the anchor turned by the difference δ (the series above,
/// within 3e-15; never chained, so the error does not grow tile by tile). Ordered
/// tiles in one segment then share one `sin_cos` up to the rate at which a tile's angle
/// span reaches `EPS_MAX`, where one `sin_cos` a tile took about 2 % of the kernel.
struct SinCosNear {
    /// Segment of the anchor (`usize::MAX`: none yet); angles are per segment.
    segment: usize,
    phi: f64,
    sin: f64,
    cos: f64,
}

impl SinCosNear {
    fn new() -> Self {
        Self { segment: usize::MAX, phi: f64::NAN, sin: f64::NAN, cos: f64::NAN }
    }

    #[inline(always)]
    fn get(&mut self, segment: usize, phi: f64) -> (f64, f64) {
        let d = phi - self.phi;
        if segment == self.segment && d.abs() <= EPS_MAX {
            let d2 = d * d;
            let sd = d * (SIN_C[0] + d2 * (SIN_C[1] + d2 * (SIN_C[2] + d2 * SIN_C[3])));
            let cd = COS_C[0] + d2 * (COS_C[1] + d2 * (COS_C[2] + d2 * (COS_C[3] + d2 * COS_C[4])));
            return (self.sin * cd + self.cos * sd, self.cos * cd - self.sin * sd);
        }
        (self.sin, self.cos) = phi.sin_cos();
        (self.segment, self.phi) = (segment, phi);
        (self.sin, self.cos)
    }
}

impl TileLanes {
    /// The tile form for the points of segment `sg` with times in `[lo, hi]`, with `angles`
    /// giving sin and cos of the segment's angle at their centre; `None` when their angles
    /// spread more than `EPS_MAX` either side of the centre.
    #[inline(always)]
    fn new(sg: &Segment, lo: f64, hi: f64, angles: impl FnOnce(f64) -> (f64, f64)) -> Option<Self> {
        let tc = 0.5 * (lo + hi);
        let eps_max = sg.omega.abs() * 0.5 * (hi - lo);
        if eps_max.is_nan() || eps_max > EPS_MAX {
            return None;
        }
        let (sn, cs) = angles(sg.omega * (tc - sg.t0));
        let b = &sg.b;
        let row0 = [0, 1, 2].map(|j| cs * b[0][j] - sn * b[1][j]);
        let row1 = [0, 1, 2].map(|j| sn * b[0][j] + cs * b[1][j]);
        let ft = [cs * sg.f[0] - sn * sg.f[1], sn * sg.f[0] + cs * sg.f[1], sg.f[2]];
        let lin1 = sg.dc.map(|v| v * sg.inv_dt);
        let lin0 = [0, 1, 2].map(|j| sg.c0[j] - sg.t0 * lin1[j]);
        Some(Self {
            omega: sg.omega,
            eps_off: -sg.omega * tc,
            bt: [row0, row1, b[2]],
            ft,
            qt: sg.qt,
            lin0,
            lin1,
            short: eps_max <= EPS_SHORT,
        })
    }

    /// [`Motion::apply`] on lanes of points (x, y, z) measured at `t`, all in this segment
    /// and tile.
    #[inline(always)]
    fn apply<S: Simd>(&self, simd: S, x: S::f64s, y: S::f64s, z: S::f64s, t: S::f64s) -> [S::f64s; 3] {
        let sp = |v: f64| simd.splat_f64s(v);
        let fma = |a, b, c| simd.mul_add_e_f64s(a, b, c);
        let one = sp(1.0);
        let eps = fma(t, sp(self.omega), sp(self.eps_off));
        let e2 = simd.mul_f64s(eps, eps);
        let (sc, cc) = (SIN_C.map(sp), COS_C.map(sp));
        let (sin_e, cos_e) = if self.short {
            (simd.mul_f64s(eps, fma(e2, sc[1], one)), fma(e2, fma(e2, cc[2], cc[1]), one))
        } else {
            (
                simd.mul_f64s(eps, fma(e2, fma(e2, fma(e2, sc[3], sc[2]), sc[1]), one)),
                fma(e2, fma(e2, fma(e2, fma(e2, cc[4], cc[3]), cc[2]), cc[1]), one),
            )
        };
        let row = |r: &[f64; 3], o: f64| fma(sp(r[2]), z, fma(sp(r[1]), y, fma(sp(r[0]), x, sp(o))));
        let y0 = row(&self.bt[0], self.ft[0]);
        let y1 = row(&self.bt[1], self.ft[1]);
        let y2 = row(&self.bt[2], self.ft[2]);
        let z0 = simd.negate_mul_add_e_f64s(sin_e, y1, simd.mul_f64s(cos_e, y0));
        let z1 = fma(cos_e, y1, simd.mul_f64s(sin_e, y0));
        let mut out = [one; 3];
        for (j, o) in out.iter_mut().enumerate() {
            let q = &self.qt[j];
            let lin = fma(t, sp(self.lin1[j]), sp(self.lin0[j]));
            *o = fma(sp(q[2]), y2, fma(sp(q[1]), z1, fma(sp(q[0]), z0, lin)));
        }
        out
    }
}

impl<P: PointCloud + ?Sized> WithSimd for FusedChunk<'_, P> {
    type Output = ChunkResult;

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> Self::Output {
        if S::IS_SCALAR {
            return scalar_chunk(self);
        }
        let FusedChunk { points, times, range, motion, cull } = self;
        let mut out = Vec::with_capacity(range.len());
        let mut lists: Vec<Vec<usize>> = vec![Vec::new(); cull.map_or(0, |c| c.boxes.len())];
        let proj = cull.map(|c| ProjLanes::new(c.projector));
        let union = cull.map(|c| UnionLanes(*c.union));
        let mut tile = Tile::new();
        let mut angles = SinCosNear::new();
        let mut cursor = range.clone().next().map_or(0, |i| motion.start_segment(times[i]));
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
            // A whole tile reads its times where they are; the last, short one from the
            // tile's copy. (Copying every tile's took 3 us of the fused kernel's 85.)
            let tile_times: &[f64; TILE] = match times[start..end].try_into() {
                Ok(whole) => whole,
                Err(_) => {
                    tl.t[..n].copy_from_slice(&times[start..end]);
                    // Padding lanes: a valid time, computed and dropped.
                    let t0 = tl.t[0];
                    tl.t[n..].fill(t0);
                    &tl.t
                }
            };
            if n < TILE {
                // Padding lanes: a valid point, computed and dropped.
                tl.x[n..].fill(0.0);
                tl.y[n..].fill(0.0);
                tl.z[n..].fill(0.0);
            }
            // Lane-wise min / max, then across lanes: a scalar fold is one chain of 2 x 128
            // dependent min/max (about a tenth of the kernel's time).
            let (tmin, tmax) = {
                let (ts, _) = S::as_simd_f64s(tile_times);
                let (lo, hi) = ts.iter().fold((ts[0], ts[0]), |(lo, hi), &t| (simd.min_f64s(lo, t), simd.max_f64s(hi, t)));
                (simd.reduce_min_f64s(lo), simd.reduce_max_f64s(hi))
            };
            let k_lo = motion.seek(tmin, &mut cursor);
            let k_hi = if tmax < motion.segments[k_lo].t1 { k_lo } else { motion.seek(tmax, &mut k_lo.clone()) };
            // One tile form per segment the tile's times touch (one for ordered times but
            // at a knot), each about the centre of the tile's times inside its segment.
            let mut segs: [Option<(TileLanes, f64)>; MAX_TILE_SEGMENTS] = [None; MAX_TILE_SEGMENTS];
            let mut fast = k_hi - k_lo < MAX_TILE_SEGMENTS;
            if fast {
                for (slot, k) in segs.iter_mut().zip(k_lo..=k_hi) {
                    let sg = &motion.segments[k];
                    let Some(form) = TileLanes::new(sg, tmin.max(sg.t0), tmax.min(sg.t1), |phi| angles.get(k, phi)) else {
                        fast = false;
                        break;
                    };
                    *slot = Some((form, sg.t0));
                }
            }
            if fast {
                let (xs, _) = S::as_simd_f64s(&tl.x);
                let (ys, _) = S::as_simd_f64s(&tl.y);
                let (zs, _) = S::as_simd_f64s(&tl.z);
                let (ts, _) = S::as_simd_f64s(tile_times);
                let (ox, _) = S::as_mut_simd_f64s(&mut tl.ox);
                let (oy, _) = S::as_mut_simd_f64s(&mut tl.oy);
                let (oz, _) = S::as_mut_simd_f64s(&mut tl.oz);
                let first = segs[0].as_ref();
                // Two passes over the tile (deskew, then project): short loop bodies whose
                // iterations are independent, so the core overlaps many of them.
                let lanes = (xs.iter().zip(ys).zip(zs).zip(ts)).zip(ox.iter_mut().zip(oy.iter_mut()).zip(oz.iter_mut()));
                for ((((x, y), z), t), ((ox, oy), oz)) in lanes {
                    let mut p = match first {
                        Some((seg, _)) => seg.apply(simd, *x, *y, *z, *t),
                        None => [*x; 3],
                    };
                    for (seg, t0) in segs[1..].iter().flatten() {
                        // Lanes at or past this segment's first knot take its motion.
                        let q = seg.apply(simd, *x, *y, *z, *t);
                        let later = simd.greater_than_or_equal_f64s(*t, simd.splat_f64s(*t0));
                        p = [0, 1, 2].map(|j| simd.select_f64s(later, q[j], p[j]));
                    }
                    [*ox, *oy, *oz] = p;
                }
                if let (Some(pl), Some(un)) = (&proj, &union) {
                    tl.px.project::<S, true>(simd, pl, un, [&tl.ox, &tl.oy, &tl.oz], n);
                }
            } else {
                let mut k = k_lo;
                for (j, &t) in tile_times[..n].iter().enumerate() {
                    let p = motion.apply([tl.x[j], tl.y[j], tl.z[j]], t, &mut k);
                    [tl.ox[j], tl.oy[j], tl.oz[j]] = p;
                    if let Some(c) = cull {
                        tl.px.set_scalar(j, c.projector.pixel(p), c.union);
                    }
                }
                tl.px.any.fill(true);
            }
            // SoA to AoS straight into the output (an exact-size iterator: no capacity check
            // a point). Through a fixed tile and a copy it took 8 % more.
            out.extend((0..n).map(|j| [tl.ox[j], tl.oy[j], tl.oz[j]]));
            if let Some(c) = cull {
                tl.px.push_members::<S>(n, start, c.boxes, &mut lists);
            }
            start = end;
        }
        (out, lists)
    }
}

/// Most segments one tile's times may touch on the SIMD path (more: the scalar reference).
const MAX_TILE_SEGMENTS: usize = 3;

#[cfg(test)]
mod tests {
    use super::super::{deskew_points_in_boxes, deskew_points_in_boxes_avx2, deskew_points_in_boxes_scalar, Motion, PoseStream};
    use super::*;
    use crate::camera::CameraModel;
    use nalgebra::{Isometry3, Vector3};
    use proptest::prelude::*;
    use proptest::test_runner::RngSeed;

    /// Deskewed points: SIMD path against the scalar reference (metres).
    const DESKEW_TOL_M: f64 = 1e-6;
    /// Projected pixels: SIMD (fused multiply-adds) against the scalar path, px: the issue's
    /// bound, for pixels where a box can be.
    const PIXEL_TOL_PX: f64 = 1e-4;
    /// Pixels far off the image (points near the camera plane): relative bound.
    const RELATIVE_TOL: f64 = 1e-9;
    /// Cull membership may differ only for points this close to a box or image edge (px).
    const EDGE_TOL_PX: f64 = 1e-4;
    /// Fixed proptest seed: the same cases every run, in CI and here (STYLE 21).
    const SEED: u64 = 23;

    fn config() -> ProptestConfig {
        ProptestConfig { cases: 64, rng_seed: RngSeed::Fixed(SEED), ..ProptestConfig::default() }
    }

    /// `Projector::pixel` of each point through the SIMD lanes (ProjLanes::pixel_fused).
    struct PixelOp<'a> {
        projector: &'a Projector,
        pts: &'a [[f64; 3]],
    }

    impl WithSimd for PixelOp<'_> {
        type Output = Vec<[f64; 2]>;
        fn with_simd<S: Simd>(self, simd: S) -> Self::Output {
            let lanes = ProjLanes::new(self.projector);
            let mut out = Vec::with_capacity(self.pts.len());
            for block in self.pts.chunks(TILE) {
                let mut t = Tile::new();
                for (j, p) in block.iter().enumerate() {
                    [t.x[j], t.y[j], t.z[j]] = *p;
                }
                let (xs, _) = S::as_simd_f64s(&t.x);
                let (ys, _) = S::as_simd_f64s(&t.y);
                let (zs, _) = S::as_simd_f64s(&t.z);
                let (us, _) = S::as_mut_simd_f64s(&mut t.px.u);
                let (vs, _) = S::as_mut_simd_f64s(&mut t.px.v);
                for ((((x, y), z), u), v) in xs.iter().zip(ys).zip(zs).zip(us.iter_mut()).zip(vs.iter_mut()) {
                    let ([pu, pv], valid) = lanes.pixel_fused(simd, [*x, *y, *z]);
                    let nan = simd.splat_f64s(f64::NAN);
                    [*u, *v] = [simd.select_f64s(valid, pu, nan), simd.select_f64s(valid, pv, nan)];
                }
                out.extend((0..block.len()).map(|j| [t.px.u[j], t.px.v[j]]));
            }
            out
        }
    }

    /// `SinCosNear` against libm's `sin_cos` (the reference) along ordered and jumping
    /// angles in two segments: within 4e-15 absolute (the series' first omitted term, δ^9/9!,
    /// is 2.8e-15 at δ = EPS_MAX; 1e-13 m at 40 m, against the deskew's 1e-6 m).
    #[test]
    fn sin_cos_near_matches_libm() {
        let mut near = SinCosNear::new();
        let mut phis: Vec<(usize, f64)> = (0..400).map(|i| (0, -3.0 + 0.013 * f64::from(i))).collect();
        phis.extend([(0, 2.0), (0, 2.0999), (0, 1.9), (1, 1.9), (1, -40.0), (1, -40.1), (1, 1e3)]);
        for (segment, phi) in phis {
            let (s, c) = near.get(segment, phi);
            let (s_ref, c_ref) = phi.sin_cos();
            assert!((s - s_ref).abs() <= 4e-15 && (c - c_ref).abs() <= 4e-15, "{phi}: {s} {c} vs {s_ref} {c_ref}");
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
        let (cloud_ref, lists_ref) = deskew_points_in_boxes_scalar(pts, times, s, t_ref, t_b_l, t_c_l, cam, boxes).unwrap();
        // The dispatched kernel (AVX-512 here where the CPU has it) and the AVX2 one.
        let dispatched = deskew_points_in_boxes(pts, times, s, t_ref, t_b_l, t_c_l, cam, boxes).unwrap();
        let avx2 = deskew_points_in_boxes_avx2(pts, times, s, t_ref, t_b_l, t_c_l, cam, boxes).unwrap();
        for (cloud, lists) in [dispatched, avx2] {
            check_against(&cloud, &lists, &cloud_ref, &lists_ref, t_c_l, cam, boxes)?;
        }
        Ok(())
    }

    /// One SIMD result against the scalar reference (see [`check_parity`]).
    #[allow(clippy::too_many_arguments)]
    fn check_against(
        cloud: &[[f64; 3]],
        lists: &[Vec<usize>],
        cloud_ref: &[[f64; 3]],
        lists_ref: &[Vec<usize>],
        t_c_l: &Isometry3<f64>,
        cam: &CameraModel,
        boxes: &[PixelBox],
    ) -> std::result::Result<(), TestCaseError> {
        prop_assert_eq!(cloud.len(), cloud_ref.len());
        for (a, b) in cloud.iter().zip(cloud_ref) {
            for j in 0..3 {
                prop_assert_eq!(a[j].is_nan(), b[j].is_nan(), "{:?} vs {:?}", a, b);
                prop_assert!(a[j].is_nan() || (a[j] - b[j]).abs() < DESKEW_TOL_M, "{:?} vs {:?}", a, b);
            }
        }
        let projector = Projector::new(t_c_l, cam);
        let simd_px = Arch::new().dispatch(PixelOp { projector: &projector, pts: cloud });
        let reach = f64::from(cam.width.max(cam.height));
        for (p, got) in cloud.iter().zip(&simd_px) {
            match projector.pixel(*p) {
                // No pixel: the lanes give a non-finite one, which every box test rejects.
                None => prop_assert!(!(got[0].is_finite() && got[1].is_finite()), "{:?}: {:?} for no pixel", p, got),
                Some(want) => {
                    for j in 0..2 {
                        // The bound where a box can be (the image and as far again
                        // around it); past that, the same relative rounding of larger values.
                        let tol = if want[j].abs() <= 2.0 * reach { PIXEL_TOL_PX } else { RELATIVE_TOL * want[j].abs() };
                        prop_assert!((got[j] - want[j]).abs() <= tol, "{:?}: {:?} vs {:?}", p, got, want);
                    }
                }
            }
        }
        prop_assert_eq!(lists.len(), lists_ref.len());
        for ((a, b), bx) in lists.iter().zip(lists_ref).zip(boxes) {
            prop_assert!(a.windows(2).all(|w| w[0] < w[1]));
            for &i in a.iter().filter(|i| b.binary_search(i).is_err()).chain(b.iter().filter(|i| a.binary_search(i).is_err())) {
                let uv = projector.pixel(cloud_ref[i]);
                prop_assert!(uv.is_some_and(|uv| edge_distance(uv, bx, cam) < EDGE_TOL_PX), "point {} differs: {:?}", i, uv);
            }
        }
        Ok(())
    }

    /// The dispatch takes a SIMD level wherever the CPU has one, so the parity tests of this
    /// module compare that path (AVX-512 or AVX2 on x86-64, NEON on aarch64, where it is
    /// architectural), not the scalar fallback, with the reference. Under qemu-aarch64
    /// (`scripts/test-aarch64.sh`) this is the NEON kernel's proof of being tested.
    #[test]
    fn dispatch_takes_the_cpus_simd_level() {
        struct Level;
        impl WithSimd for Level {
            type Output = (bool, usize);
            fn with_simd<S: Simd>(self, _simd: S) -> (bool, usize) {
                (S::IS_SCALAR, crate::projection::lanes::lanes::<S>())
            }
        }
        let (scalar, lanes) = Arch::new().dispatch(Level);
        eprintln!("{}: {} f64 lanes (scalar: {scalar})", std::env::consts::ARCH, lanes);
        #[cfg(target_arch = "aarch64")]
        assert!(!scalar && lanes == 2, "aarch64 must take NEON's 2 f64 lanes, got scalar {scalar}, {lanes} lanes");
        #[cfg(target_arch = "x86_64")]
        if pulp::x86::V3::try_new().is_some() {
            assert!(!scalar && lanes >= 4, "an AVX2 CPU must take 4 or 8 f64 lanes, got scalar {scalar}, {lanes} lanes");
        }
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

    /// The per-tile axis-angle lanes (`TileLanes`) against the scalar slerp (`Motion::apply`)
    /// on time-ordered tiles: returns the largest deviation (m) and how many tiles took the
    /// SIMD form (the rest would take the scalar reference).
    struct TileCheck<'a> {
        motion: &'a Motion,
        pts: &'a [[f64; 3]],
        times: &'a [f64],
    }

    impl WithSimd for TileCheck<'_> {
        type Output = (f64, usize, usize);
        fn with_simd<S: Simd>(self, simd: S) -> Self::Output {
            let (mut worst, mut fast, mut total) = (0.0f64, 0, 0);
            for (block, tblock) in self.pts.chunks(TILE).zip(self.times.chunks(TILE)) {
                total += 1;
                let (lo, hi) = (tblock[0], tblock[tblock.len() - 1]);
                let k = self.motion.start_segment(lo);
                if self.motion.start_segment(hi) != k {
                    continue;
                }
                let sg = &self.motion.segments[k];
                let Some(lanes) = TileLanes::new(sg, lo, hi, f64::sin_cos) else { continue };
                fast += 1;
                let mut t = Tile::new();
                for (j, (p, &tt)) in block.iter().zip(tblock).enumerate() {
                    [t.x[j], t.y[j], t.z[j]] = *p;
                    t.t[j] = tt;
                }
                t.t[block.len()..].fill(lo);
                let (xs, _) = S::as_simd_f64s(&t.x);
                let (ys, _) = S::as_simd_f64s(&t.y);
                let (zs, _) = S::as_simd_f64s(&t.z);
                let (ts, _) = S::as_simd_f64s(&t.t);
                let (ox, _) = S::as_mut_simd_f64s(&mut t.ox);
                let (oy, _) = S::as_mut_simd_f64s(&mut t.oy);
                let (oz, _) = S::as_mut_simd_f64s(&mut t.oz);
                for ((((((x, y), z), tt), ox), oy), oz) in
                    xs.iter().zip(ys).zip(zs).zip(ts).zip(ox.iter_mut()).zip(oy.iter_mut()).zip(oz.iter_mut())
                {
                    [*ox, *oy, *oz] = lanes.apply(simd, *x, *y, *z, *tt);
                }
                let mut cursor = k;
                for (j, (p, &tt)) in block.iter().zip(tblock).enumerate() {
                    let want = self.motion.apply(*p, tt, &mut cursor);
                    for (g, w) in [t.ox[j], t.oy[j], t.oz[j]].iter().zip(want) {
                        worst = worst.max((g - w).abs());
                    }
                }
            }
            (worst, fast, total)
        }
    }

    /// A Mid-360-like frame: `n` time-ordered points over 0.1 s out to `range` m, pose knots
    /// at `rate_hz` turning at `omega` rad/s about a tilted axis (plus a wobble) and flying
    /// at 12 m/s.
    fn fast_turn(n: usize, range: f64, omega: f64, rate_hz: f64, seed: u64) -> (Vec<[f64; 3]>, Vec<f64>, PoseStream) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        let pts = (0..n)
            .map(|_| {
                let (az, el) = (rng.random_range(-std::f64::consts::PI..std::f64::consts::PI), rng.random_range(-0.12..0.9f64));
                let r = rng.random_range(0.5..range);
                [r * el.cos() * az.cos(), r * el.cos() * az.sin(), r * el.sin()]
            })
            .collect();
        let times: Vec<f64> = (0..n).map(|i| 0.1 * i as f64 / n as f64).collect();
        let m = (0.1 * rate_hz).ceil() as usize;
        let knots: Vec<f64> = (0..=m).map(|k| 0.1 * k as f64 / m as f64).collect();
        let axis = Vector3::new(0.3, -0.5, 1.0).normalize();
        let poses = knots
            .iter()
            .map(|&t| {
                let wobble = Vector3::new((40.0 * t).sin(), (30.0 * t).cos(), 0.0) * 0.05;
                Isometry3::new(Vector3::new(12.0 * t, -3.0 * t, 20.0), axis * (omega * t) + wobble)
            })
            .collect();
        (pts, times, PoseStream::new(knots, poses).unwrap())
    }

    /// High angular rates (to 12 rad/s, 20-200 Hz odometry), points to 150 m, 20k and 2k
    /// points a frame: every time-ordered tile inside one segment takes the SIMD form,
    /// within 1e-9 m of the per-point slerp (the parity bound is 1e-6 m).
    #[test]
    fn tile_form_matches_slerp_at_high_angular_rate() {
        let t_b_l = pose([0.1, 0.0, -0.1], [0.0, 0.1, 0.0]);
        // 20k points a frame: |ε| <= 0.004 rad, the short series; 2k points: up to 0.04 rad.
        for (seed, (&omega, n)) in [0.5, 3.0, 6.0, 12.0].iter().flat_map(|w| [(w, 20_000), (w, 2_000)]).enumerate() {
            for rate_hz in [20.0, 50.0, 200.0] {
                let (pts, times, s) = fast_turn(n, 150.0, omega, rate_hz, seed as u64);
                let motion = Motion::new(&s, 0.1, &t_b_l).unwrap();
                let (worst, fast, total) = Arch::new().dispatch(TileCheck { motion: &motion, pts: &pts, times: &times });
                assert!(worst < 1e-9, "omega {omega} rad/s, {rate_hz} Hz: {worst} m");
                // Tiles across a knot take the per-segment selects in the kernel, not this check.
                assert!(fast + s.times.len() >= total, "omega {omega}: {fast} of {total} tiles");
            }
        }
    }

    /// The fused call at high angular rate against the scalar reference (points, pixels,
    /// boxes), time-ordered Mid-360-like frames.
    #[test]
    fn simd_matches_scalar_at_high_angular_rate() {
        let cam = CameraModel::new(1000.0, 1000.0, 640.0, 360.0, 1280, 720, [-0.1, 0.02, 0.001, -0.001, 0.0]).unwrap();
        // Optical z = L's x, x = -y, y = -z (the bench's camera).
        let r = nalgebra::Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
        let t_c_l = Isometry3::from_parts(
            nalgebra::Translation3::new(0.0, -0.05, 0.0),
            nalgebra::UnitQuaternion::from_matrix(&r),
        );
        let boxes = [
            PixelBox::new(500.0, 200.0, 700.0, 500.0).unwrap(),
            PixelBox::new(0.0, 0.0, 1280.0, 720.0).unwrap(),
            PixelBox::new(100.0, 100.0, 400.0, 250.0).unwrap(),
        ];
        let t_b_l = pose([0.1, 0.0, -0.1], [0.0, 0.1, 0.0]);
        for (seed, &omega) in [2.0, 8.0, 12.0].iter().enumerate() {
            let (pts, times, s) = fast_turn(20_000, 120.0, omega, 20.0, 100 + seed as u64);
            check_parity(&pts, &times, &s, 0.05, &t_b_l, &t_c_l, &cam, &boxes).unwrap();
            let (_, lists) = deskew_points_in_boxes(&pts, &times, &s, 0.05, &t_b_l, &t_c_l, &cam, &boxes).unwrap();
            assert!(lists[1].len() > 500, "{}", lists[1].len());
        }
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
