//! Insulator strings found in a tower-scale LiDAR cloud by geometry alone (no camera).
//!
//! The cloud (metres, any horizontal frame, `up` given) is thinned to one point per voxel;
//! every point gets the shape of its neighbourhood (`local_shape`); points whose neighbourhood
//! is line-like and as thick across as a shed stack (thicker than a wire or a brace, thinner
//! than a joint) are clustered with DBSCAN; each cluster is cut into straight runs of sheds
//! (`segments`: at rim gaps and point dips where fittings join two stacks or a stack and its
//! tip, by RANSAC where an arm and a string form an L), and each run becomes a segment (PCA
//! axis, the extent of its shed rims, its radius, its shed contrast). A segment is a string when
//! * it shows sheds: points bunched at a shed pitch along the axis (`sheds`); this is the test
//!   that rejects smooth cylinders of a string's size, legs, chords and struts;
//! * its stack is as long as a string (`min_length..=max_length`) and it is not a piece of a
//!   longer line (a leg cut at its joints);
//! * the shell round its middle is clear: not a chord webbed into an arm (`context`).
//!
//! Submodules: `cells` (voxels, cell buckets), `local_shape`, `segments`, `sheds`, `context`.
//! Nothing here knows of a camera, a simulator or a flight.
//!
//! Measured on the simulator's towers A (12 tension strings, doubled at each tip) and B (4
//! suspension strings) scanned along the exploration path: every string, no false find, at
//! 60k-820k points; strings score 19-50, everything else 5.4 at most.

mod cells;
mod context;
mod local_shape;
mod segments;
mod sheds;

use crate::dbscan::{dbscan, NOISE};
use crate::error::{check_positive, invalid, Result};
use crate::pca::canonical_sign;
use crate::points::{is_finite_point, PointCloud};

use cells::{cell_of, thin, Cells};
use local_shape::cell_shapes;
use segments::{dot, segments_of, Segment};

/// Most points one call takes: 5e7 (1.2 GB of f64 input). WHY a cap: a cloud of 1e8 points
/// is a day of flights, not one tower; refusing it at once beats minutes of work and gigabytes.
pub const MAX_POINTS: usize = 50_000_000;

/// m: side of the coarse cells whose 3x3x3 blocks give the local shape. The block (0.6 m)
/// must be long against a shed stack's diameter, or a stack of 0.14 m discs would not look
/// line-like: its linearity is 1 - 6 r^2 / side_of_block^2 at radius r (0.83 for r = 0.1 in
/// a 0.6 m block, 0.70 in a 0.45 m one).
const SHAPE_CELL: f64 = 0.2;
/// Fewest points in a block for its shape to mean anything.
const MIN_BLOCK_POINTS: usize = 6;
/// Least linearity of a string's neighbourhood (measured 0.84-0.90 on shed stacks; a plane or
/// a joint is below 0.5).
const MIN_LINEARITY: f64 = 0.7;
/// m: spread across the axis of a shed stack's neighbourhood: about half the shed radius
/// (0.05-0.06 m for sheds of 0.08-0.12 m; 0.09 allows discs of 0.18 m). Below it: wires
/// (0.015) and light braces (0.03); above it: joints.
const MIN_SHED_SPREAD: f64 = 0.04;
const MAX_SHED_SPREAD: f64 = 0.09;
/// DBSCAN of the shed-thick points: a radius that bridges the gap between two sheds seen
/// edge-on, and the core points it needs.
const CLUSTER_EPS: f64 = 0.15;
const CLUSTER_MIN_POINTS: usize = 5;
/// Fewest thinned points of a segment worth testing.
const MIN_SEGMENT_POINTS: usize = 20;

/// Tuning of [`find_insulator_strings`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StringParams {
    /// m: side of the thinning voxels (one point kept per voxel). Default 0.04: a quarter of a
    /// shed stack's diameter, half the finest shed pitch.
    pub voxel_size: f64,
    /// m: shortest shed stack reported (default 0.8: a 66 kV string).
    pub min_length: f64,
    /// m: longest shed stack reported, and longest line a stack may be a piece of (default 5).
    pub max_length: f64,
    /// Least shed contrast reported (default 10; strings measured 20-50, lattice 1-8).
    pub min_score: f64,
}

impl Default for StringParams {
    fn default() -> Self {
        StringParams { voxel_size: 0.04, min_length: 0.8, max_length: 5.0, min_score: 10.0 }
    }
}

impl StringParams {
    fn validate(&self) -> Result<()> {
        check_positive("voxel_size", self.voxel_size)?;
        if self.voxel_size > SHAPE_CELL {
            return Err(invalid("voxel_size", format!("must be <= {SHAPE_CELL} m (the shape cell), got {}", self.voxel_size)));
        }
        check_positive("min_length", self.min_length)?;
        check_positive("max_length", self.max_length)?;
        if self.max_length < self.min_length {
            return Err(invalid("max_length", format!("must be >= min_length ({}), got {}", self.min_length, self.max_length)));
        }
        if !(self.min_score.is_finite() && self.min_score >= 0.0) {
            return Err(invalid("min_score", format!("must be finite and >= 0, got {}", self.min_score)));
        }
        Ok(())
    }
}

/// One insulator string found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InsulatorString {
    /// Centre of the shed stack (m, the input's frame).
    pub center: [f64; 3],
    /// Unit axis, sign canonical (largest-|component| positive).
    pub axis: [f64; 3],
    /// m: length of the shed stack.
    pub length: f64,
    /// m: radius of the sheds (the 90 % quantile of the points' distance from the axis).
    pub radius: f64,
    /// Thinned points (one per voxel) in the segment.
    pub n_points: usize,
    /// Shed contrast (dimensionless, >= `min_score`): how clearly the points bunch at a shed
    /// pitch along the axis.
    pub score: f64,
    /// rad: angle of the axis above the plane normal to `up` (pi/2: a suspension string; near
    /// 0: a tension string).
    pub elevation: f64,
}

/// The insulator strings in `points` (N x 3, metres; `up`: the vertical, any length > 0),
/// strongest shed contrast first. An empty or flat cloud gives no strings.
///
/// Errors (naming the argument): a non-finite coordinate, more than [`MAX_POINTS`] points, a
/// zero or non-finite `up`, bad `params`.
pub fn find_insulator_strings<P: PointCloud + ?Sized>(points: &P, up: [f64; 3], params: &StringParams) -> Result<Vec<InsulatorString>> {
    params.validate()?;
    let up_norm = dot(up, up).sqrt();
    if !(up_norm.is_finite() && up_norm > 0.0) {
        return Err(invalid("up", format!("must be a finite non-zero vector, got {up:?}")));
    }
    let up = [up[0] / up_norm, up[1] / up_norm, up[2] / up_norm];
    let n = points.len();
    if n > MAX_POINTS {
        return Err(invalid("points", format!("at most {MAX_POINTS} points are taken, got {n}")));
    }
    let mut bad = None;
    points.for_each_point(|i, p| {
        if bad.is_none() && !is_finite_point(&p) {
            bad = Some(i);
        }
    });
    if let Some(i) = bad {
        return Err(invalid("points", format!("row {i} is not finite")));
    }
    if n == 0 {
        return Ok(Vec::new());
    }
    // Work relative to the first point: projected coordinates (5e6 m) keep their millimetres.
    let origin = points.point(0);
    let cloud = thin(|f| points.for_each_point(|_, p| f(p)), origin, params.voxel_size);
    let cells = Cells::new(&cloud, SHAPE_CELL);
    let shapes = cell_shapes(&cloud, &cells);
    let shape_of = |i: usize| shapes.get(&cell_of(&cloud[i], SHAPE_CELL)).copied();

    let shed_like: Vec<u32> = (0..cloud.len())
        .filter(|&i| {
            shape_of(i).is_some_and(|s| {
                s.count >= MIN_BLOCK_POINTS && s.linearity >= MIN_LINEARITY && (MIN_SHED_SPREAD..=MAX_SHED_SPREAD).contains(&s.spread)
            })
        })
        .map(|i| i as u32)
        .collect();
    let thick: Vec<[f64; 3]> = shed_like.iter().map(|&i| cloud[i as usize]).collect();
    let labels = dbscan(thick.as_slice(), CLUSTER_EPS, CLUSTER_MIN_POINTS)?;
    let n_clusters = labels.iter().copied().max().map_or(0, |m| (m + 1).max(0) as usize);
    let mut clusters: Vec<Vec<u32>> = vec![Vec::new(); n_clusters];
    for (k, &l) in labels.iter().enumerate() {
        if l != NOISE {
            clusters[l as usize].push(shed_like[k]);
        }
    }
    let segments: Vec<Segment> =
        clusters.into_iter().flat_map(|m| segments_of(&cloud, m, CLUSTER_EPS, MIN_SEGMENT_POINTS)).collect();

    // Which segment (if any) shows sheds, per thinned point: the shell test ignores those
    // points, so strings side by side (doubled, V pairs) do not count as each other's structure.
    const NONE: u32 = u32::MAX;
    let mut owner = vec![NONE; cloud.len()];
    for (s, seg) in segments.iter().enumerate() {
        if seg.contrast >= params.min_score {
            seg.members.iter().for_each(|&i| owner[i as usize] = s as u32);
        }
    }
    let line_lengths = context::line_lengths(&segments, params.min_length);

    let mut found: Vec<InsulatorString> = segments
        .iter()
        .zip(&line_lengths)
        .filter(|(seg, &line)| {
            seg.contrast >= params.min_score
                && (params.min_length..=params.max_length).contains(&seg.length)
                && line <= params.max_length
                && context::shell_is_clear(seg, &cloud, &cells, |i| owner[i] == NONE)
        })
        .map(|(seg, _)| InsulatorString {
            center: [seg.center[0] + origin[0], seg.center[1] + origin[1], seg.center[2] + origin[2]],
            axis: canonical_sign(seg.axis),
            length: seg.length,
            radius: seg.radius,
            n_points: seg.members.len(),
            score: seg.contrast,
            elevation: dot(seg.axis, up).abs().min(1.0).asin(),
        })
        .collect();
    found.sort_by(|a, b| b.score.total_cmp(&a.score));
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    /// Points on a shed stack: `sheds` cones (root 0.03 m, skirt `radius`) at a 0.08 m pitch
    /// from `top` down along `axis`, plus its core rod; 2 cm of range noise.
    fn shed_stack(rng: &mut Pcg64, top: [f64; 3], axis: [f64; 3], sheds: usize, radius: f64, out: &mut Vec<[f64; 3]>) {
        let (u, v) = perpendiculars(axis);
        for k in 0..sheds {
            let s = 0.04 + 0.08 * k as f64;
            let skirt = if k % 2 == 0 { radius } else { 0.7 * radius };
            for _ in 0..120 {
                let f: f64 = rng.random();
                let r = 0.03 + f * (skirt - 0.03);
                let along = s + 0.02 * f; // the cone slopes toward its skirt
                let phi = rng.random::<f64>() * std::f64::consts::TAU;
                out.push(noisy(rng, around(top, axis, u, v, along, r, phi)));
            }
        }
        let length = 0.08 * sheds as f64;
        for _ in 0..(300.0 * length) as usize {
            let along = rng.random::<f64>() * length;
            let phi = rng.random::<f64>() * std::f64::consts::TAU;
            out.push(noisy(rng, around(top, axis, u, v, along, 0.025, phi)));
        }
    }

    /// Points on a square tube (a lattice angle, a leg) of side `side` from `a` to `b`.
    fn member(rng: &mut Pcg64, a: [f64; 3], b: [f64; 3], side: f64, per_m: f64, out: &mut Vec<[f64; 3]>) {
        let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let len = dot(d, d).sqrt();
        let axis = [d[0] / len, d[1] / len, d[2] / len];
        let (u, v) = perpendiculars(axis);
        for _ in 0..(per_m * len) as usize {
            let along = rng.random::<f64>() * len;
            let face = rng.random_range(0..4);
            let w = (rng.random::<f64>() - 0.5) * side;
            let h = 0.5 * side;
            let (x, y) = [(h, w), (-h, w), (w, h), (w, -h)][face];
            let p = [0, 1, 2].map(|k| a[k] + along * axis[k] + x * u[k] + y * v[k]);
            out.push(noisy(rng, p));
        }
    }

    fn perpendiculars(a: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let t = if a[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        let u = [a[1] * t[2] - a[2] * t[1], a[2] * t[0] - a[0] * t[2], a[0] * t[1] - a[1] * t[0]];
        let n = dot(u, u).sqrt();
        let u = [u[0] / n, u[1] / n, u[2] / n];
        let v = [a[1] * u[2] - a[2] * u[1], a[2] * u[0] - a[0] * u[2], a[0] * u[1] - a[1] * u[0]];
        (u, v)
    }

    fn around(top: [f64; 3], axis: [f64; 3], u: [f64; 3], v: [f64; 3], along: f64, r: f64, phi: f64) -> [f64; 3] {
        [0, 1, 2].map(|k| top[k] + along * axis[k] + r * (phi.cos() * u[k] + phi.sin() * v[k]))
    }

    fn noisy(rng: &mut Pcg64, p: [f64; 3]) -> [f64; 3] {
        p.map(|x| x + 0.01 * (rng.random::<f64>() - 0.5))
    }

    /// A leg (10 m), an arm to its tip, a suspension string (1.48 m) on a 0.25 m fitting under
    /// the tip (close enough for the arm and the stack to form one cluster), a conductor (thin)
    /// through its clamp, a lone 2 m panel of leg; all shifted by `offset`.
    fn scene(offset: [f64; 3]) -> (Vec<[f64; 3]>, [f64; 3]) {
        let mut rng = Pcg64::seed_from_u64(7);
        let mut pts = Vec::new();
        member(&mut rng, [0.0, 0.0, 0.0], [0.0, 0.0, 10.0], 0.14, 3000.0, &mut pts);
        member(&mut rng, [0.0, 0.0, 9.0], [3.0, 0.0, 9.0], 0.14, 3000.0, &mut pts);
        member(&mut rng, [3.0, 0.0, 9.0], [3.0, 0.0, 8.75], 0.03, 400.0, &mut pts); // fitting
        shed_stack(&mut rng, [3.0, 0.0, 8.75], [0.0, 0.0, -1.0], 19, 0.11, &mut pts);
        member(&mut rng, [3.0, -10.0, 6.9], [3.0, 10.0, 6.9], 0.015, 300.0, &mut pts); // conductor
        member(&mut rng, [-3.0, 0.0, 2.0], [-3.0, 0.0, 4.0], 0.14, 3000.0, &mut pts); // a lone panel
        let pts = pts.into_iter().map(|p| [p[0] + offset[0], p[1] + offset[1], p[2] + offset[2]]).collect();
        // The stack spans 8.75 - 0.04 .. 8.75 - 1.46 - 0.02: centre ~8.0.
        (pts, [3.0 + offset[0], offset[1], 8.0 + offset[2]])
    }

    #[test]
    fn finds_the_string_and_nothing_else() {
        let (pts, truth) = scene([0.0; 3]);
        let found = find_insulator_strings(pts.as_slice(), [0.0, 0.0, 1.0], &StringParams::default()).unwrap();
        assert_eq!(found.len(), 1, "{found:?}");
        let s = found[0];
        let err = dot([0, 1, 2].map(|k| s.center[k] - truth[k]), [0, 1, 2].map(|k| s.center[k] - truth[k])).sqrt();
        assert!(err < 0.08, "{s:?}");
        assert!(s.axis[2] > 0.99 && (s.elevation - std::f64::consts::FRAC_PI_2).abs() < 0.05, "{s:?}");
        // The stack is 1.48 m; its end sheds, whose neighbourhoods hold the arm or the conductor
        // clamp, may be left out of the cluster.
        assert!((s.length - 1.48).abs() < 0.25 && (s.radius - 0.11).abs() < 0.03, "{s:?}");
        assert!(s.score >= StringParams::default().min_score);
    }

    #[test]
    fn projected_coordinates_and_another_up_give_the_same_string() {
        let (pts, truth) = scene([512_345.0, 5_612_345.0, 300.0]);
        let found = find_insulator_strings(pts.as_slice(), [0.0, 0.0, 1.0], &StringParams::default()).unwrap();
        assert_eq!(found.len(), 1, "{found:?}");
        assert!((0..3).all(|k| (found[0].center[k] - truth[k]).abs() < 0.08), "{found:?}");
        // The same scene with y as the vertical: only the elevation changes meaning.
        let swapped: Vec<[f64; 3]> = pts.iter().map(|p| [p[0], p[2], -p[1]]).collect();
        let f2 = find_insulator_strings(swapped.as_slice(), [0.0, 1.0, 0.0], &StringParams::default()).unwrap();
        assert_eq!(f2.len(), 1);
        assert!((f2[0].elevation - std::f64::consts::FRAC_PI_2).abs() < 0.05);
    }

    #[test]
    fn empty_and_flat_clouds_give_nothing() {
        let none: Vec<[f64; 3]> = Vec::new();
        assert!(find_insulator_strings(none.as_slice(), [0.0, 0.0, 1.0], &StringParams::default()).unwrap().is_empty());
        let mut rng = Pcg64::seed_from_u64(1);
        let plane: Vec<[f64; 3]> = (0..50_000).map(|_| [rng.random::<f64>() * 20.0, rng.random::<f64>() * 20.0, 0.0]).collect();
        assert!(find_insulator_strings(plane.as_slice(), [0.0, 0.0, 1.0], &StringParams::default()).unwrap().is_empty());
    }

    #[test]
    fn extreme_coordinates_neither_panic_nor_hang() {
        let (mut pts, _) = scene([0.0; 3]);
        pts.push([1e300, -1e300, 1e300]);
        pts.push([-1e300, 1e300, -1e300]);
        let found = find_insulator_strings(pts.as_slice(), [0.0, 0.0, 1.0], &StringParams::default()).unwrap();
        assert!(found.len() <= 1);
        let far: Vec<[f64; 3]> = (0..100).map(|k| [1e300 * f64::from(k % 2), -1e299, f64::from(k)]).collect();
        assert!(find_insulator_strings(far.as_slice(), [0.0, 0.0, 1.0], &StringParams::default()).unwrap().is_empty());
    }

    /// A cloud that claims more points than MAX_POINTS without holding them.
    struct Huge;
    impl PointCloud for Huge {
        fn len(&self) -> usize {
            MAX_POINTS + 1
        }
        fn point(&self, _i: usize) -> [f64; 3] {
            [0.0; 3]
        }
    }

    #[test]
    fn bad_input_is_refused_by_name() {
        let p = StringParams::default();
        let err = |r: Result<Vec<InsulatorString>>| r.unwrap_err().to_string();
        assert!(err(find_insulator_strings(&Huge, [0.0, 0.0, 1.0], &p)).starts_with("points: at most"));
        let nan = [[0.0, 0.0, 0.0], [f64::NAN, 0.0, 0.0]];
        assert_eq!(err(find_insulator_strings(nan.as_slice(), [0.0, 0.0, 1.0], &p)), "points: row 1 is not finite");
        let ok = [[0.0; 3]];
        assert!(err(find_insulator_strings(ok.as_slice(), [0.0; 3], &p)).starts_with("up:"));
        assert!(err(find_insulator_strings(ok.as_slice(), [f64::NAN, 0.0, 1.0], &p)).starts_with("up:"));
        for (bad, name) in [
            (StringParams { voxel_size: 0.0, ..p }, "voxel_size"),
            (StringParams { voxel_size: 0.5, ..p }, "voxel_size"),
            (StringParams { min_length: -1.0, ..p }, "min_length"),
            (StringParams { max_length: 0.5, ..p }, "max_length"),
            (StringParams { min_score: f64::NAN, ..p }, "min_score"),
        ] {
            assert!(err(find_insulator_strings(ok.as_slice(), [0.0, 0.0, 1.0], &bad)).starts_with(name), "{name}");
        }
    }
}
