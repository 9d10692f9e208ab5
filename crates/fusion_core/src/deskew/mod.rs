//! Motion compensation ("deskew") of a LiDAR scan whose points carry their own times.
//!
//! A Livox Mid-360 frame spans 100 ms of flight: each point was measured from the body
//! pose of its own instant. Deskewing re-expresses every point in the LiDAR frame at one
//! reference time `t_ref`:
//!
//! `p_l(t_ref) = T_b_l^-1 · T_w_b(t_ref)^-1 · T_w_b(t_i) · T_b_l · p_l(t_i)`
//!
//! with `T_w_b(t)` interpolated in SE(3) from a pose stream: slerp of the rotation and
//! lerp of the translation between the two poses around `t` (what ROS' tf2 and most LIO
//! front ends do). [`deskew_points_in_boxes`] fuses the deskew with the projection and
//! the box culling of [`crate::points_in_boxes`] in one parallel pass over the cloud (per
//! chunk: deskew, then cull the chunk while it is in cache).
//!
//! [`deskew_points_in_boxes`] is what flies: the Python perception pipeline
//! (`perception/pipeline.py`) calls it once a paired scan for each camera frame, because it
//! returns both things a frame needs, every deskewed point (the tracks keep them) and the box
//! lists, in one pass where the two-step path made two (`deskew`, then `points_in_boxes` over
//! the frame's cloud). Same points to the bit, same lists but for a point within rounding of
//! a box edge (`tests/test_fused_perception.py`). The kernel time it saves a frame is small
//! beside the numpy pairing and the localization, so a frame costs the same within the noise
//! (`benches/bench_perception_frame.py`). [`deskew`] alone serves the obstacle map, which
//! takes every point of a scan and no box.
//!
//! Why the per-knot precomputation below is exact: quaternion slerp is bi-invariant
//! (`slerp(M q0 N, M q1 N, s) = M slerp(q0, q1, s) N`), so the rotation of
//! `A(t) = M · T_w_b(t) · N` (with `M = (T_w_b(t_ref) T_b_l)^-1`, `N = T_b_l`) is the slerp
//! of the knots' `A` rotations; its translation is `R_A(t) · R_N^T t_N + lerp(R_M t_k + t_M)`.

use std::ops::Range;

use nalgebra::{Isometry3, UnitQuaternion};
use rayon::prelude::*;

use crate::camera::CameraModel;
use crate::culling::{PixelBox, PARALLEL_MIN_POINTS};
use crate::error::{invalid, Result};
use crate::points::PointCloud;
use crate::projection::Projector;

mod simd;

/// Below this rotation between two knots (rad) slerp is replaced by a normalised lerp:
/// the two differ by O(θ³), far below f64 resolution of a point at 100 m.
const SMALL_ANGLE: f64 = 1e-6;
/// Below this rotation between two knots (rad) the slerp weights use the Taylor series of sin
/// instead of libm's `sin`: a Horner polynomial is a few ns where `sin` is tens, and it is exact
/// to f64 rounding there (the first omitted term, x^15/15!, is < 1e-20 at x = 0.3).
const SERIES_ANGLE: f64 = 0.3;
/// Smallest parallel chunk of points.
const MIN_CHUNK_POINTS: usize = 4096;

/// A validated pose stream: strictly increasing finite times with one rigid `T_w_b` each.
#[derive(Debug, Clone)]
pub struct PoseStream {
    times: Vec<f64>,
    poses: Vec<Isometry3<f64>>,
}

impl PoseStream {
    /// At least two poses; `times` finite and strictly increasing (errors name `pose_times`
    /// or `poses`).
    pub fn new(times: Vec<f64>, poses: Vec<Isometry3<f64>>) -> Result<Self> {
        if times.len() != poses.len() {
            return Err(invalid("poses", format!("{} poses for {} pose_times", poses.len(), times.len())));
        }
        if times.len() < 2 {
            return Err(invalid("pose_times", format!("needs at least 2 poses to interpolate, got {}", times.len())));
        }
        if let Some(i) = times.iter().position(|t| !t.is_finite()) {
            return Err(invalid("pose_times", format!("entry {i} is not finite")));
        }
        if let Some(i) = times.windows(2).position(|w| w[1] <= w[0]) {
            return Err(invalid(
                "pose_times",
                format!("must be strictly increasing: entry {} ({}) <= entry {} ({})", i + 1, times[i + 1], i, times[i]),
            ));
        }
        Ok(Self { times, poses })
    }

    /// First and last time covered.
    pub fn span(&self) -> (f64, f64) {
        (self.times[0], self.times[self.times.len() - 1])
    }

    /// `T_w_b(t)` by slerp + lerp between the bracketing poses; error (naming `name`)
    /// outside the stream.
    pub fn interpolate(&self, t: f64, name: &'static str) -> Result<Isometry3<f64>> {
        self.check_time(t, name)?;
        let k = self.segment(t);
        let (t0, t1) = (self.times[k], self.times[k + 1]);
        let s = (t - t0) / (t1 - t0);
        let (a, b) = (&self.poses[k], &self.poses[k + 1]);
        let rotation = a.rotation.slerp(&b.rotation, s);
        let translation = a.translation.vector.lerp(&b.translation.vector, s);
        Ok(Isometry3::from_parts(translation.into(), rotation))
    }

    fn check_time(&self, t: f64, name: &'static str) -> Result<()> {
        let (lo, hi) = self.span();
        if !(t >= lo && t <= hi) {
            return Err(invalid(name, format!("time {t} is outside the pose stream [{lo}, {hi}]")));
        }
        Ok(())
    }

    /// Index k of the segment `[times[k], times[k+1]]` holding `t` (t inside the span).
    fn segment(&self, t: f64) -> usize {
        let upper = self.times.partition_point(|&x| x <= t);
        upper.saturating_sub(1).min(self.times.len() - 2)
    }
}

/// One segment of the relative motion `A(t)`, unpacked for the per-point loop.
#[derive(Debug, Clone, Copy)]
struct Segment {
    t0: f64,
    inv_dt: f64,
    /// Rotation quaternions (w, x, y, z) of A at both ends, same hemisphere.
    q0: [f64; 4],
    q1: [f64; 4],
    theta: f64,
    inv_sin: f64,
    /// sin(s θ) series coefficients, divided by sin θ (so they give the slerp weight directly).
    series: [f64; SERIES_TERMS],
    /// Translation part `R_M t_k + t_M` at both ends.
    c0: [f64; 3],
    c1: [f64; 3],
    /// The same segment in axis-angle form, for the SIMD tiles ([`simd`]): slerp turns
    /// `R(q0)` about the fixed unit axis `a` of `q1 q0*` at the constant rate `omega`, so
    /// `R_A(t) = Qᵀ Rz(omega (t - t0)) Q R(q0)` with `Q` the rotation whose rows are
    /// `(e1, e2, a)`. `b = Q R(q0)`, `f = b d`, `qt = Qᵀ`, `dc = c1 - c0`.
    omega: f64,
    b: [[f64; 3]; 3],
    f: [f64; 3],
    qt: [[f64; 3]; 3],
    dc: [f64; 3],
    /// End time of the segment (the next knot).
    t1: f64,
}

/// Axis-angle form of one segment (see [`Segment::omega`]): `(omega, b, f, qt)` for knot
/// rotations `q0`, `q1` (same hemisphere), `inv_dt` and the offset `d`.
#[allow(clippy::type_complexity)]
fn axis_angle_form(q0: [f64; 4], q1: [f64; 4], inv_dt: f64, d: [f64; 3]) -> (f64, [[f64; 3]; 3], [f64; 3], [[f64; 3]; 3]) {
    use nalgebra::{Quaternion, Vector3};
    let (w0, v0) = (q0[0], Vector3::new(q0[1], q0[2], q0[3]));
    let (w1, v1) = (q1[0], Vector3::new(q1[1], q1[2], q1[3]));
    // r = q1 ⊗ conj(q0): scalar part = dot >= 0, vector part = sin θ · axis.
    let rw = w1 * w0 + v1.dot(&v0);
    let rv = w0 * v1 - w1 * v0 - v1.cross(&v0);
    let sin_half = rv.norm();
    let (a, omega) = if sin_half > 0.0 {
        (rv / sin_half, 2.0 * sin_half.atan2(rw) * inv_dt)
    } else {
        (Vector3::z(), 0.0)
    };
    // e1 ⊥ a, e2 = a × e1: rows (e1, e2, a) form a rotation taking a to +z.
    let helper = if a.x.abs() < 0.6 { Vector3::x() } else { Vector3::y() };
    let e1 = helper.cross(&a).normalize();
    let e2 = a.cross(&e1);
    let q = nalgebra::Matrix3::from_rows(&[e1.transpose(), e2.transpose(), a.transpose()]);
    let r0 = UnitQuaternion::new_unchecked(Quaternion::new(q0[0], q0[1], q0[2], q0[3])).to_rotation_matrix();
    let b = q * r0.matrix();
    let f = b * Vector3::from(d);
    let qt = q.transpose();
    let rows = |m: &nalgebra::Matrix3<f64>| [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]]);
    (omega, rows(&b), [f[0], f[1], f[2]], rows(&qt))
}

/// The relative motion `A(t)` of the module docstring over a whole pose stream.
#[derive(Debug, Clone)]
struct Motion {
    segments: Vec<Segment>,
    /// `R_N^T t_N`: added to every point before the rotation.
    d: [f64; 3],
}

/// sin(x) by its Taylor series to x^13 (|x| <= [`SERIES_ANGLE`]); reference for the
/// per-segment coefficients below.
#[cfg(test)]
fn sin_series(x: f64) -> f64 {
    let c = series_coefficients(1.0);
    let x2 = x * x;
    x * horner(&c, x2)
}

/// Terms of the series: sin(s θ) = s · Σ_n c_n s^(2n), c_n = (-1)^n θ^(2n+1) / (2n+1)!.
const SERIES_TERMS: usize = 7;

fn series_coefficients(theta: f64) -> [f64; SERIES_TERMS] {
    let mut c = [0.0; SERIES_TERMS];
    let mut term = theta;
    for (n, v) in c.iter_mut().enumerate() {
        *v = term;
        let k = (2 * n + 2) as f64;
        term *= -theta * theta / (k * (k + 1.0));
    }
    c
}

#[inline(always)]
fn horner(c: &[f64; SERIES_TERMS], x2: f64) -> f64 {
    let mut acc = c[SERIES_TERMS - 1];
    for v in c[..SERIES_TERMS - 1].iter().rev() {
        acc = acc * x2 + v;
    }
    acc
}

fn quat(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.w, q.i, q.j, q.k]
}

impl Motion {
    fn new(stream: &PoseStream, t_ref: f64, t_b_l: &Isometry3<f64>) -> Result<Self> {
        let m = (stream.interpolate(t_ref, "t_ref")? * t_b_l).inverse();
        let rn = t_b_l.rotation;
        let d = rn.inverse() * t_b_l.translation.vector;
        let knots: Vec<([f64; 4], [f64; 3])> = stream
            .poses
            .iter()
            .map(|p| {
                let q = m.rotation * p.rotation * rn;
                let c = m.rotation * p.translation.vector + m.translation.vector;
                (quat(&q), [c[0], c[1], c[2]])
            })
            .collect();
        let segments = (0..knots.len() - 1)
            .map(|k| {
                let (q0, c0) = knots[k];
                let (mut q1, c1) = knots[k + 1];
                let mut dot: f64 = q0.iter().zip(&q1).map(|(a, b)| a * b).sum();
                if dot < 0.0 {
                    q1 = q1.map(|v| -v);
                    dot = -dot;
                }
                let theta = dot.min(1.0).acos();
                let inv_sin = if theta < SMALL_ANGLE { 0.0 } else { 1.0 / theta.sin() };
                let t0 = stream.times[k];
                let series = series_coefficients(theta).map(|v| v * inv_sin);
                let t1 = stream.times[k + 1];
                let inv_dt = 1.0 / (t1 - t0);
                let (omega, b, f, qt) = axis_angle_form(q0, q1, inv_dt, [d[0], d[1], d[2]]);
                let dc = [c1[0] - c0[0], c1[1] - c0[1], c1[2] - c0[2]];
                Segment { t0, inv_dt, q0, q1, theta, inv_sin, series, c0, c1, omega, b, f, qt, dc, t1 }
            })
            .collect();
        Ok(Self { segments, d: [d[0], d[1], d[2]] })
    }

    /// The point `p` (measured at time `t`, inside the stream) in L at `t_ref`. `k` is the
    /// caller's segment cursor: points come nearly time-ordered, so it rarely moves far.
    #[inline(always)]
    fn apply(&self, p: [f64; 3], t: f64, k: &mut usize) -> [f64; 3] {
        let last = self.segments.len() - 1;
        while *k < last && t >= self.segments[*k + 1].t0 {
            *k += 1;
        }
        while *k > 0 && t < self.segments[*k].t0 {
            *k -= 1;
        }
        let sg = &self.segments[*k];
        let s = (t - sg.t0) * sg.inv_dt;
        let (w0, w1) = if sg.inv_sin == 0.0 {
            (1.0 - s, s)
        } else if sg.theta <= SERIES_ANGLE {
            let r = 1.0 - s;
            (r * horner(&sg.series, r * r), s * horner(&sg.series, s * s))
        } else {
            (((1.0 - s) * sg.theta).sin() * sg.inv_sin, (s * sg.theta).sin() * sg.inv_sin)
        };
        let mut q = [0.0; 4];
        for (j, v) in q.iter_mut().enumerate() {
            *v = w0 * sg.q0[j] + w1 * sg.q1[j];
        }
        if sg.inv_sin == 0.0 {
            let n = 1.0 / (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
            q = q.map(|v| v * n);
        }
        let [w, x, y, z] = q;
        let v = [p[0] + self.d[0], p[1] + self.d[1], p[2] + self.d[2]];
        // Rotation of v by the unit quaternion q: v + 2w(u×v) + 2u×(u×v), u = (x, y, z).
        let c = [y * v[2] - z * v[1], z * v[0] - x * v[2], x * v[1] - y * v[0]];
        let cc = [y * c[2] - z * c[1], z * c[0] - x * c[2], x * c[1] - y * c[0]];
        let mut out = [0.0; 3];
        for j in 0..3 {
            out[j] = v[j] + 2.0 * (w * c[j] + cc[j]) + (1.0 - s) * sg.c0[j] + s * sg.c1[j];
        }
        out
    }

    /// Index of the segment holding `t` (as [`Self::start_segment`]), walked from the
    /// caller's cursor `k` (left there): nearly ordered times move it a step at most.
    #[inline(always)]
    fn seek(&self, t: f64, k: &mut usize) -> usize {
        let last = self.segments.len() - 1;
        while *k < last && t >= self.segments[*k + 1].t0 {
            *k += 1;
        }
        while *k > 0 && t < self.segments[*k].t0 {
            *k -= 1;
        }
        *k
    }

    /// Segment cursor to start a chunk from.
    fn start_segment(&self, t: f64) -> usize {
        self.segments.partition_point(|sg| sg.t0 <= t).saturating_sub(1)
    }
}

fn check_inputs<P: PointCloud + ?Sized>(points: &P, times: &[f64], stream: &PoseStream) -> Result<()> {
    if times.len() != points.len() {
        return Err(invalid("times", format!("{} times for {} points", times.len(), points.len())));
    }
    let (lo, hi) = stream.span();
    // Branch-free scan first (vectorises); the position only on failure.
    let inside = |c: &[f64]| c.iter().fold(true, |ok, &t| ok & (t >= lo) & (t <= hi));
    // Compiled for the CPU's widest vectors (pulp's dispatch): the baseline SSE2 build of
    // this scan took a twentieth of the fused kernel's time on 20k points.
    if !pulp::Arch::new().dispatch(#[inline(always)] || times.chunks(512).all(inside)) {
        let i = times.iter().position(|&t| !(t >= lo && t <= hi)).unwrap_or(0);
        return Err(invalid(
            "times",
            format!("point {i} at time {} is outside the pose stream [{lo}, {hi}] (NaN or not covered)", times[i]),
        ));
    }
    Ok(())
}

/// Chunk ranges for a cloud of `n` points (one chunk below [`PARALLEL_MIN_POINTS`]).
fn chunks(n: usize) -> Vec<Range<usize>> {
    if n < PARALLEL_MIN_POINTS {
        return std::iter::once(0..n).collect();
    }
    let chunk = n.div_ceil(rayon::current_num_threads()).max(MIN_CHUNK_POINTS);
    (0..n.div_ceil(chunk)).map(|c| c * chunk..((c + 1) * chunk).min(n)).collect()
}

/// Every point of `points` (L, measured at `times`) re-expressed in L at `t_ref`, with
/// `T_w_b(t)` interpolated from `stream` (module docstring). Non-finite points stay NaN.
/// Runs the SIMD path where the CPU has one (the `simd` module), the scalar reference otherwise.
///
/// Errors (naming the argument) when `times` and `points` differ in length, or a point
/// time or `t_ref` lies outside the pose stream (no extrapolation).
pub fn deskew<P: PointCloud + Sync + ?Sized>(
    points: &P,
    times: &[f64],
    stream: &PoseStream,
    t_ref: f64,
    t_b_l: &Isometry3<f64>,
) -> Result<Vec<[f64; 3]>> {
    Ok(fused(points, times, stream, t_ref, t_b_l, None, Path::Simd)?.0)
}

/// Deskew (as [`deskew`]) fused with projection and box culling (as
/// [`crate::points_in_boxes`] on the deskewed cloud) in one pass: returns the deskewed
/// cloud and, per box, the ascending indices of the points inside it. Runs the SIMD path
/// where the CPU has one (the `simd` module), the scalar reference otherwise.
#[allow(clippy::too_many_arguments)]
pub fn deskew_points_in_boxes<P: PointCloud + Sync + ?Sized>(
    points: &P,
    times: &[f64],
    stream: &PoseStream,
    t_ref: f64,
    t_b_l: &Isometry3<f64>,
    t_c_l: &Isometry3<f64>,
    cam: &CameraModel,
    boxes: &[PixelBox],
) -> Result<CloudAndLists> {
    fused(points, times, stream, t_ref, t_b_l, Some((t_c_l, cam, boxes)), Path::Simd)
}

/// [`deskew_points_in_boxes`] on the scalar reference path only, whatever the CPU: the
/// reference of the SIMD path's parity tests and the other side of its benchmark.
#[allow(clippy::too_many_arguments)]
pub fn deskew_points_in_boxes_scalar<P: PointCloud + Sync + ?Sized>(
    points: &P,
    times: &[f64],
    stream: &PoseStream,
    t_ref: f64,
    t_b_l: &Isometry3<f64>,
    t_c_l: &Isometry3<f64>,
    cam: &CameraModel,
    boxes: &[PixelBox],
) -> Result<CloudAndLists> {
    fused(points, times, stream, t_ref, t_b_l, Some((t_c_l, cam, boxes)), Path::Scalar)
}

/// The deskewed cloud and, per box, the ascending indices of its points inside the box.
type CloudAndLists = (Vec<[f64; 3]>, Vec<Vec<usize>>);

/// Which implementation of the per-chunk kernel to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Path {
    /// [`simd::fused_chunk`]: SIMD where pulp finds an instruction set, scalar otherwise.
    Simd,
    /// [`simd::scalar_chunk`] only.
    Scalar,
    /// The AVX2 + FMA kernel even where the CPU has AVX-512 (tests: the path of CPUs without
    /// it); the dispatched one on other CPUs.
    #[cfg(test)]
    Avx2,
}

/// [`deskew_points_in_boxes`] on the AVX2 kernel (see [`Path::Avx2`]).
#[cfg(test)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn deskew_points_in_boxes_avx2<P: PointCloud + Sync + ?Sized>(
    points: &P,
    times: &[f64],
    stream: &PoseStream,
    t_ref: f64,
    t_b_l: &Isometry3<f64>,
    t_c_l: &Isometry3<f64>,
    cam: &CameraModel,
    boxes: &[PixelBox],
) -> Result<CloudAndLists> {
    fused(points, times, stream, t_ref, t_b_l, Some((t_c_l, cam, boxes)), Path::Avx2)
}

/// The camera, its pose and the boxes of a fused call.
type CullArgs<'a> = (&'a Isometry3<f64>, &'a CameraModel, &'a [PixelBox]);

fn fused<P: PointCloud + Sync + ?Sized>(
    points: &P,
    times: &[f64],
    stream: &PoseStream,
    t_ref: f64,
    t_b_l: &Isometry3<f64>,
    cull: Option<CullArgs<'_>>,
    path: Path,
) -> Result<CloudAndLists> {
    let mut setup = None;
    if let Some((t_c_l, cam, boxes)) = cull {
        cam.validate()?;
        for b in boxes {
            if !(b.x1.is_finite() && b.y1.is_finite() && b.x2.is_finite() && b.y2.is_finite())
                || b.x2 <= b.x1
                || b.y2 <= b.y1
            {
                return Err(invalid("boxes", format!("needs finite corners with x2 > x1 and y2 > y1, got {b:?}")));
            }
        }
        let union = PixelBox {
            x1: boxes.iter().map(|b| b.x1).fold(f64::INFINITY, f64::min).max(0.0),
            y1: boxes.iter().map(|b| b.y1).fold(f64::INFINITY, f64::min).max(0.0),
            x2: boxes.iter().map(|b| b.x2).fold(f64::NEG_INFINITY, f64::max).min(f64::from(cam.width)),
            y2: boxes.iter().map(|b| b.y2).fold(f64::NEG_INFINITY, f64::max).min(f64::from(cam.height)),
        };
        setup = Some((Projector::new(t_c_l, cam), boxes, union));
    }
    check_inputs(points, times, stream)?;
    let motion = Motion::new(stream, t_ref, t_b_l)?;
    let n_boxes = setup.as_ref().map_or(0, |s| s.1.len());
    // Per chunk: deskew, project and cull the chunk while it is in cache. Each chunk returns
    // its own points (no NaN prefill of the whole cloud); one chunk is the cloud as it is.
    let parts: Vec<simd::ChunkResult> = chunks(points.len())
        .into_par_iter()
        .map(|range| {
            let cull = setup.as_ref().and_then(|(projector, boxes, union)| {
                (union.x2 > union.x1 && union.y2 > union.y1).then_some(simd::Cull { projector, boxes, union })
            });
            let chunk = simd::FusedChunk { points, times, range, motion: &motion, cull };
            let (cloud, lists) = match path {
                Path::Simd => simd::fused_chunk(chunk),
                Path::Scalar => simd::scalar_chunk(chunk),
                #[cfg(test)]
                Path::Avx2 => simd::avx2_chunk(chunk),
            };
            // No box on the image: every list empty.
            if lists.len() == n_boxes {
                (cloud, lists)
            } else {
                (cloud, vec![Vec::new(); n_boxes])
            }
        })
        .collect();
    let (mut clouds, lists): (Vec<_>, Vec<_>) = parts.into_iter().unzip();
    let out = if clouds.len() == 1 {
        clouds.pop().unwrap_or_default()
    } else {
        let mut out = Vec::with_capacity(points.len());
        for c in &clouds {
            out.extend_from_slice(c);
        }
        out
    };
    let mut merged: Vec<Vec<usize>> =
        (0..n_boxes).map(|k| Vec::with_capacity(lists.iter().map(|c| c[k].len()).sum())).collect();
    for part in lists {
        for (list, chunk) in merged.iter_mut().zip(part) {
            list.extend(chunk);
        }
    }
    Ok((out, merged))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::culling::points_in_boxes;
    use nalgebra::{Point3, Translation3, Vector3};
    use proptest::prelude::*;

    fn pose(t: [f64; 3], r: [f64; 3]) -> Isometry3<f64> {
        Isometry3::new(Vector3::from(t), Vector3::from(r))
    }

    /// The textbook form: interpolate T_w_b(t_i), chain the four transforms with nalgebra.
    fn reference(pts: &[[f64; 3]], times: &[f64], s: &PoseStream, t_ref: f64, t_b_l: &Isometry3<f64>) -> Vec<[f64; 3]> {
        let m = (s.interpolate(t_ref, "t_ref").unwrap() * t_b_l).inverse();
        pts.iter()
            .zip(times)
            .map(|(p, &t)| {
                let a = m * s.interpolate(t, "t").unwrap() * t_b_l;
                let q = a * Point3::from(*p);
                [q.x, q.y, q.z]
            })
            .collect()
    }

    fn stream() -> PoseStream {
        let times = vec![0.0, 0.02, 0.04, 0.06, 0.08, 0.1];
        let poses = times
            .iter()
            .map(|&t| pose([3.0 * t, -1.0 + 0.5 * t, 10.0 + t], [0.1 * t, -0.3 * t, 1.0 + 2.0 * t]))
            .collect();
        PoseStream::new(times, poses).unwrap()
    }

    #[test]
    fn static_vehicle_leaves_points_alone() {
        let p = pose([1.0, 2.0, 3.0], [0.1, 0.2, 0.3]);
        let s = PoseStream::new(vec![0.0, 1.0], vec![p, p]).unwrap();
        let pts = vec![[1.0, -2.0, 5.0], [0.5, 0.5, 0.5]];
        let t_b_l = pose([0.1, 0.0, -0.05], [0.0, 0.3, 0.0]);
        let out = deskew(&pts, &[0.2, 0.9], &s, 0.5, &t_b_l).unwrap();
        for (a, b) in out.iter().zip(&pts) {
            for j in 0..3 {
                assert!((a[j] - b[j]).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn pure_translation_moves_points_by_the_displacement() {
        // Body flies +x at 10 m/s, LiDAR = body: a point seen 0.05 s before t_ref moved
        // 0.5 m backwards in the frame of t_ref.
        let s = PoseStream::new(vec![0.0, 0.1], vec![pose([0.0; 3], [0.0; 3]), pose([1.0, 0.0, 0.0], [0.0; 3])]).unwrap();
        let out = deskew(&vec![[5.0, 0.0, 0.0]], &[0.05], &s, 0.1, &Isometry3::identity()).unwrap();
        assert!((out[0][0] - 4.5).abs() < 1e-12 && out[0][1].abs() < 1e-12);
    }

    #[test]
    fn matches_the_textbook_chain_and_the_culling_of_the_deskewed_cloud() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let s = stream();
        let n = 2 * PARALLEL_MIN_POINTS + 77;
        let pts: Vec<[f64; 3]> =
            (0..n).map(|_| [rng.random_range(2.0..20.0), rng.random_range(-8.0..8.0), rng.random_range(-5.0..5.0)]).collect();
        // Nearly sorted times, as a Livox frame, with some out of order.
        let times: Vec<f64> = (0..n).map(|i| (i as f64 / n as f64 * 0.1 + rng.random_range(-0.003..0.003)).clamp(0.0, 0.1)).collect();
        let t_b_l = pose([0.1, 0.0, -0.1], [0.0, 0.1, 0.0]);
        let expected = reference(&pts, &times, &s, 0.1, &t_b_l);
        let got = deskew(&pts, &times, &s, 0.1, &t_b_l).unwrap();
        for (a, b) in got.iter().zip(&expected) {
            for j in 0..3 {
                assert!((a[j] - b[j]).abs() < 1e-9, "{a:?} vs {b:?}");
            }
        }
        let cam = CameraModel::new(900.0, 910.0, 640.0, 480.0, 1280, 960, [-0.2, 0.05, 1e-3, -1e-3, 0.01]).unwrap();
        // Camera looks along L's +x.
        let t_c_l = Isometry3::from_parts(
            Translation3::new(0.0, 0.05, 0.0),
            UnitQuaternion::from_matrix(&nalgebra::Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0)),
        );
        let boxes = [
            PixelBox::new(100.0, 100.0, 700.0, 500.0).unwrap(),
            PixelBox::new(600.0, 400.0, 1300.0, 1000.0).unwrap(),
            PixelBox::new(-50.0, -50.0, 30.0, 30.0).unwrap(),
        ];
        let (cloud, lists) = deskew_points_in_boxes(&pts, &times, &s, 0.1, &t_b_l, &t_c_l, &cam, &boxes).unwrap();
        assert_eq!(cloud, got);
        assert!(lists.iter().take(2).all(|l| !l.is_empty()));
        assert_eq!(lists, points_in_boxes(&got, &t_c_l, &cam, &boxes).unwrap());
    }

    #[test]
    fn bad_inputs_name_the_argument() {
        let s = stream();
        let name = |r: Result<Vec<[f64; 3]>>| match r {
            Err(crate::FusionError::InvalidArgument { name, .. }) => name,
            other => panic!("expected InvalidArgument, got {other:?}"),
        };
        let p = vec![[1.0, 0.0, 0.0]];
        let id = Isometry3::identity();
        assert_eq!(name(deskew(&p, &[0.2], &s, 0.05, &id)), "times");
        assert_eq!(name(deskew(&p, &[f64::NAN], &s, 0.05, &id)), "times");
        assert_eq!(name(deskew(&p, &[0.01, 0.02], &s, 0.05, &id)), "times");
        assert_eq!(name(deskew(&p, &[0.01], &s, 0.5, &id)), "t_ref");
        assert!(PoseStream::new(vec![0.0, 0.0], vec![id, id]).is_err());
        assert!(PoseStream::new(vec![0.0], vec![id]).is_err());
        assert!(PoseStream::new(vec![0.0, f64::NAN], vec![id, id]).is_err());
        assert!(PoseStream::new(vec![0.0, 1.0], vec![id]).is_err());
        // A NaN point stays NaN and is never culled into a box.
        let out = deskew(&vec![[f64::NAN, 0.0, 0.0]], &[0.01], &s, 0.05, &id).unwrap();
        assert!(out[0][0].is_nan());
    }

    #[test]
    fn sine_series_is_exact_to_rounding() {
        for k in 0..=3000 {
            let x = SERIES_ANGLE * k as f64 / 3000.0;
            assert!((sin_series(x) - x.sin()).abs() <= 4.0 * f64::EPSILON * x.max(1e-300), "{x}");
        }
    }

    proptest! {
        /// Random pose streams (large rotations between knots included) and points: the
        /// fused per-knot form equals the textbook chain to 1e-9 m.
        #[test]
        fn deskew_matches_reference(
            knots in prop::collection::vec((prop::array::uniform3(-50.0f64..50.0), prop::array::uniform3(-3.0f64..3.0)), 2..6),
            pts in prop::collection::vec((prop::array::uniform3(-30.0f64..30.0), 0.0f64..1.0), 1..60),
            tref in 0.0f64..1.0,
            lt in prop::array::uniform3(-0.5f64..0.5), lr in prop::array::uniform3(-3.0f64..3.0),
        ) {
            let k = knots.len();
            let times: Vec<f64> = (0..k).map(|i| i as f64 / (k - 1) as f64).collect();
            let s = PoseStream::new(times, knots.iter().map(|(t, r)| pose(*t, *r)).collect()).unwrap();
            let p: Vec<[f64; 3]> = pts.iter().map(|x| x.0).collect();
            let t: Vec<f64> = pts.iter().map(|x| x.1).collect();
            let t_b_l = pose(lt, lr);
            let got = deskew(&p, &t, &s, tref, &t_b_l).unwrap();
            let want = reference(&p, &t, &s, tref, &t_b_l);
            for (a, b) in got.iter().zip(&want) {
                for j in 0..3 {
                    prop_assert!((a[j] - b[j]).abs() < 1e-9, "{:?} vs {:?}", a, b);
                }
            }
        }

        /// Small rotations between knots (a multirotor's 20 Hz odometry): the series path.
        #[test]
        fn deskew_matches_reference_small_steps(
            base in prop::array::uniform3(-3.0f64..3.0), step in prop::array::uniform3(-0.15f64..0.15),
            pts in prop::collection::vec((prop::array::uniform3(-30.0f64..30.0), 0.0f64..0.1), 1..60),
            tref in 0.0f64..0.1,
        ) {
            let times: Vec<f64> = (0..6).map(|i| 0.02 * i as f64).collect();
            let s = PoseStream::new(times.clone(), times.iter().enumerate().map(|(i, &t)| {
                let k = i as f64;
                pose([3.0 * t, 1.0, 10.0], [base[0] + k * step[0], base[1] + k * step[1], base[2] + k * step[2]])
            }).collect()).unwrap();
            let p: Vec<[f64; 3]> = pts.iter().map(|x| x.0).collect();
            let t: Vec<f64> = pts.iter().map(|x| x.1).collect();
            let t_b_l = pose([0.1, 0.0, -0.1], [0.0, 0.1, 0.0]);
            let got = deskew(&p, &t, &s, tref, &t_b_l).unwrap();
            let want = reference(&p, &t, &s, tref, &t_b_l);
            for (a, b) in got.iter().zip(&want) {
                for j in 0..3 {
                    prop_assert!((a[j] - b[j]).abs() < 1e-9, "{:?} vs {:?}", a, b);
                }
            }
        }
    }
}
