//! A cluster of shed-thick, line-like points made into a segment: its axis (PCA), the extent of
//! its shed stack, its radius and its shed contrast.

use crate::dbscan::{dbscan, NOISE};
use crate::pca::pca_of;
use crate::ransac::{ransac_line, RansacParams};

use super::sheds::shed_contrast;

/// Fraction of the points cut at each end of a sorted coordinate before an extent is read: a
/// stray return at 2 cm from the stack must not lengthen it.
const EXTENT_TRIM: f64 = 0.01;
/// A point counts as on a shed's rim when its distance from the axis is at least this fraction
/// of the segment's radius. WHY: the end fittings (rods of a third of the shed radius) are part
/// of the cluster but not of the stack; the stack's ends are where the rims stop.
const RIM_FRACTION: f64 = 0.5;
/// The segment's radius is this quantile of the points' distances from the axis (the rims,
/// not the core between sheds).
const RADIUS_QUANTILE: f64 = 0.9;

/// m: a cluster whose RADIUS_QUANTILE distance from its axis exceeds this is more than one
/// line (no shed is 0.25 m; an arm and the string under it, joined by the fitting, are).
const MAX_LINE_RADIUS: f64 = 0.25;
/// m: inlier distance of the RANSAC line that takes one line out of such a cluster: a shed's
/// radius with the range noise.
const LINE_INLIER: f64 = 0.2;
/// A piece is cut at its rim gaps only while it is about one line: this radius (m) allows two
/// strings 12 deg apart on one tip; the PCA axis of a fatter piece (an L) makes its rim gaps
/// meaningless.
const MAX_CUT_RADIUS: f64 = 0.4;
/// Pieces looked at in one cluster at most (a joint of the lattice meets five or six members,
/// each may be cut once or twice).
const MAX_PIECES_PER_CLUSTER: usize = 32;
/// RANSAC of one line in a cluster: hypotheses and the stop confidence (reproducible seed).
const LINE_RANSAC: RansacParams = RansacParams { threshold: LINE_INLIER, max_iterations: 300, confidence: 0.999, seed: 0 };

/// m: a gap this long between two rims along a segment's axis cuts it in two. Longer than the
/// gap between two sheds of any string (pitch at most 0.25 m less the shed's own thickness),
/// shorter than an end fitting with its clamp (0.25 m and more).
const RIM_GAP: f64 = 0.2;

/// A dense piece is also cut where its points thin out: at a DIP_BIN-long bin holding at most
/// DIP_FRACTION of the piece's median bin (a fitting between two stacks, where a dense scan
/// fills the rim gap with the tip's steel), when the median bin holds at least DIP_MIN_MEDIAN
/// points (fewer, and chance alone makes such dips inside a stack) and the bin is DIP_END_MARGIN
/// or more inside the piece's ends (the ends taper).
const DIP_BIN: f64 = 0.1;
const DIP_FRACTION: f64 = 0.3;
const DIP_MIN_MEDIAN: f64 = 25.0;
const DIP_END_MARGIN: f64 = 0.3;

/// One candidate segment, in the finder's local coordinates.
#[derive(Debug, Clone)]
pub(super) struct Segment {
    /// Centre of the shed stack.
    pub center: [f64; 3],
    /// Unit axis (PCA).
    pub axis: [f64; 3],
    /// m: length of the shed stack (between the outermost rims).
    pub length: f64,
    /// m: extent of all the cluster's points along the axis, fittings included, about `center`.
    pub extent: (f64, f64),
    /// m: RADIUS_QUANTILE of the distances from the axis.
    pub radius: f64,
    /// The cluster's point indices (into the thinned cloud).
    pub members: Vec<u32>,
    /// Shed contrast along the stack ([`shed_contrast`]).
    pub contrast: f64,
    /// m: where along the axis (about `center`) its rim-gap and dip cuts fall, ascending
    /// (empty: one run of sheds).
    pub cuts: Vec<f64>,
}

/// Value at quantile `q` of ascending `sorted` (nearest rank); `sorted` is not empty.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let k = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[k.min(sorted.len() - 1)]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub(super) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Axial coordinate and distance from the axis of `p` for the line through `c` along unit `a`.
#[inline]
pub(super) fn axial_radial(p: [f64; 3], c: [f64; 3], a: [f64; 3]) -> (f64, f64) {
    let d = sub(p, c);
    let t = dot(d, a);
    let r2 = dot(d, d) - t * t;
    (t, r2.max(0.0).sqrt())
}

/// The segment of the points `members` of `points`, or None when they are too few for a PCA.
pub(super) fn segment(points: &[[f64; 3]], members: Vec<u32>) -> Option<Segment> {
    let pca = pca_of(members.iter().map(|&i| points[i as usize])).ok()?;
    let axis = pca.axis();
    let mean = pca.mean;
    let (mut ts, mut rs): (Vec<f64>, Vec<f64>) = members.iter().map(|&i| axial_radial(points[i as usize], mean, axis)).unzip();
    let mut sorted_r = rs.clone();
    sorted_r.sort_by(f64::total_cmp);
    let radius = quantile(&sorted_r, RADIUS_QUANTILE);
    let mut rim: Vec<f64> = ts.iter().zip(&rs).filter(|(_, &r)| r >= RIM_FRACTION * radius).map(|(&t, _)| t).collect();
    if rim.len() < 2 {
        return None;
    }
    rim.sort_by(f64::total_cmp);
    let (lo, hi) = (quantile(&rim, EXTENT_TRIM), quantile(&rim, 1.0 - EXTENT_TRIM));
    let mid = 0.5 * (lo + hi);
    let cuts: Vec<f64> = rim.windows(2).filter(|w| w[1] - w[0] > RIM_GAP).map(|w| 0.5 * (w[0] + w[1]) - mid).collect();
    let center = [mean[0] + mid * axis[0], mean[1] + mid * axis[1], mean[2] + mid * axis[2]];
    ts.iter_mut().for_each(|t| *t -= mid);
    let contrast = shed_contrast(&ts, lo - mid, hi - mid);
    ts.sort_by(f64::total_cmp);
    let extent = (quantile(&ts, EXTENT_TRIM), quantile(&ts, 1.0 - EXTENT_TRIM));
    let mut cuts = cuts;
    cuts.extend(dips(&ts, extent));
    cuts.sort_by(f64::total_cmp);
    rs.clear();
    Some(Segment { center, axis, length: hi - lo, extent, radius, members, contrast, cuts })
}

/// Centres (m) of the bins of ascending `ts` that are dips (see DIP_FRACTION), the lowest bin
/// of each run of dip bins.
fn dips(ts: &[f64], extent: (f64, f64)) -> Vec<f64> {
    let (lo, hi) = (extent.0 + DIP_END_MARGIN, extent.1 - DIP_END_MARGIN);
    if hi - lo < DIP_BIN {
        return Vec::new();
    }
    let n = ((extent.1 - extent.0) / DIP_BIN).ceil() as usize;
    let mut counts = vec![0.0f64; n];
    for &t in ts {
        let k = ((t - extent.0) / DIP_BIN).floor();
        if k >= 0.0 && (k as usize) < n {
            counts[k as usize] += 1.0;
        }
    }
    let mut sorted = counts.clone();
    sorted.sort_by(f64::total_cmp);
    let median = quantile(&sorted, 0.5);
    if median < DIP_MIN_MEDIAN {
        return Vec::new();
    }
    let mut cuts = Vec::new();
    let mut run: Option<(f64, f64)> = None; // (lowest count, its bin centre) of the current run
    for (k, &count) in counts.iter().enumerate() {
        let centre = extent.0 + (k as f64 + 0.5) * DIP_BIN;
        if count <= DIP_FRACTION * median && centre >= lo && centre <= hi {
            run = Some(match run {
                Some((c, at)) if c <= count => (c, at),
                _ => (count, centre),
            });
        } else if let Some((_, at)) = run.take() {
            cuts.push(at);
        }
    }
    if let Some((_, at)) = run {
        cuts.push(at);
    }
    cuts
}

/// The segments of a cluster (`members` of `points`), each one line and one run of sheds.
///
/// A piece (the cluster first) is
/// * cut at its rim gaps ([`RIM_GAP`]) and its dips (DIP_FRACTION) when it is about one line
///   (radius at most MAX_CUT_RADIUS), each part taken again on its own axis;
/// * kept as a segment when it is one line without a gap (radius at most MAX_LINE_RADIUS);
/// * else split by RANSAC: the best line's inliers, cut at their gaps of more than `eps` (m),
///   and the rest, each taken again.
///
/// Pieces under `min_points` are dropped; at most MAX_PIECES_PER_CLUSTER pieces are looked at.
///
/// WHY the line split: the fitting between an arm tip and a string's first shed is a short
/// thin rod; where the LiDAR sees it well, the shed-thick points of the arm, the fitting and
/// the string touch and DBSCAN returns one L-shaped cluster whose PCA is neither.
/// WHY the rim cut: the two strings of a tension tip hang 12 deg apart from the same tip;
/// their fittings and the tip join them into one slightly bent 5.5 m line, not fat enough for
/// the line split and no string. No shed stands on a fitting: the rims stop there.
pub(super) fn segments_of(points: &[[f64; 3]], members: Vec<u32>, eps: f64, min_points: usize) -> Vec<Segment> {
    let mut found = Vec::new();
    let mut pending = vec![members];
    let mut budget = MAX_PIECES_PER_CLUSTER;
    while let Some(piece) = pending.pop() {
        if piece.len() < min_points || budget == 0 {
            continue;
        }
        budget -= 1;
        let Some(seg) = segment(points, piece.clone()) else { continue };
        if seg.radius <= MAX_CUT_RADIUS && !seg.cuts.is_empty() {
            let mut parts: Vec<Vec<u32>> = vec![Vec::new(); seg.cuts.len() + 1];
            for i in piece {
                let (t, _) = axial_radial(points[i as usize], seg.center, seg.axis);
                parts[seg.cuts.partition_point(|&c| c < t)].push(i);
            }
            pending.extend(parts);
        } else if seg.radius <= MAX_LINE_RADIUS {
            found.push(seg);
        } else {
            pending.extend(split_off_a_line(points, piece, eps));
        }
    }
    found
}

/// The inliers of the best RANSAC line of `piece`, cut at their gaps of more than `eps`, and
/// the rest (all as point sets; nothing when no line is found).
fn split_off_a_line(points: &[[f64; 3]], piece: Vec<u32>, eps: f64) -> Vec<Vec<u32>> {
    let coords: Vec<[f64; 3]> = piece.iter().map(|&i| points[i as usize]).collect();
    let Ok(line) = ransac_line(coords.as_slice(), &LINE_RANSAC) else { return Vec::new() };
    let on_line: Vec<[f64; 3]> = line.inliers.iter().map(|&k| coords[k]).collect();
    let Ok(runs) = dbscan(on_line.as_slice(), eps, 1) else { return Vec::new() };
    let n_runs = runs.iter().copied().max().map_or(0, |m| (m + 1).max(0) as usize);
    let mut parts: Vec<Vec<u32>> = vec![Vec::new(); n_runs + 1];
    for (k, &run) in runs.iter().enumerate() {
        if run != NOISE {
            parts[run as usize].push(piece[line.inliers[k]]);
        }
    }
    let mut taken = vec![false; piece.len()];
    line.inliers.iter().for_each(|&k| taken[k] = true);
    parts[n_runs] = piece.into_iter().zip(taken).filter(|(_, t)| !t).map(|(i, _)| i).collect();
    parts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shed_stack_on_a_thin_rod_gives_the_stack_not_the_rod() {
        // Stack: rings of radius 0.1 every 0.1 m from z = 0 to 1.5; rod of radius 0.02 from
        // z = -0.4 to 0 (an end fitting).
        let mut pts = Vec::new();
        for k in 0..=15 {
            for j in 0..24 {
                let a = f64::from(j) * std::f64::consts::TAU / 24.0;
                pts.push([0.1 * a.cos(), 0.1 * a.sin(), f64::from(k) * 0.1]);
            }
        }
        for k in 0..40 {
            pts.push([0.02, 0.0, -0.01 * f64::from(k)]);
        }
        let members: Vec<u32> = (0..pts.len() as u32).collect();
        let s = segment(&pts, members.clone()).unwrap();
        assert!((s.length - 1.5).abs() < 0.05, "{s:?}");
        assert!(s.cuts.is_empty(), "{s:?}");
        assert_eq!(segments_of(&pts, members, 0.15, 20).len(), 1);
        assert!((s.center[2] - 0.75).abs() < 0.03, "{s:?}");
        assert!((s.radius - 0.1).abs() < 0.01);
        assert!(s.axis[2].abs() > 0.99);
        assert!(s.extent.0 < -1.1, "the rod is in the extent: {:?}", s.extent);
        assert!(s.contrast > 10.0, "{}", s.contrast);
    }

    #[test]
    fn two_stacks_joined_by_a_rod_are_cut_at_the_rod() {
        // Two 1.5 m stacks of rings along x, 12 deg apart, joined by 0.7 m of thin rod.
        let mut pts = Vec::new();
        let (s, c) = (6f64.to_radians().sin(), 6f64.to_radians().cos());
        for (sign, start) in [(-1.0, -0.35), (1.0, 0.35)] {
            let axis = [sign * c, 0.0, -s];
            for k in 0..=15 {
                let along = f64::from(k) * 0.1;
                for j in 0..24 {
                    let a = f64::from(j) * std::f64::consts::TAU / 24.0;
                    let base = [start + sign * 0.0 + axis[0] * along, axis[1] * along, axis[2] * along];
                    pts.push([base[0], base[1] + 0.1 * a.cos(), base[2] + 0.1 * a.sin()]);
                }
            }
        }
        for k in 0..70 {
            pts.push([-0.35 + 0.01 * f64::from(k), 0.0, 0.0]);
        }
        let members: Vec<u32> = (0..pts.len() as u32).collect();
        let segs = segments_of(&pts, members, 0.15, 20);
        let stacks: Vec<&Segment> = segs.iter().filter(|g| g.length > 1.0).collect();
        assert_eq!(stacks.len(), 2, "{segs:?}");
        for g in stacks {
            assert!((g.length - 1.5).abs() < 0.1 && (g.axis[2].abs() - s).abs() < 0.02, "{g:?}");
        }
    }

    #[test]
    fn a_dense_piece_is_cut_where_its_points_thin_out() {
        // 2 m at 60 points per 0.1 m, but 6 in the bin at 1.0..1.1 m (a fitting).
        let mut ts = Vec::new();
        for k in 0..2000 {
            let t = f64::from(k) * 0.001;
            if !(1.0..1.1).contains(&t) || k % 10 == 0 {
                ts.push(t);
                ts.push(t + 0.0005);
            }
        }
        ts.sort_by(f64::total_cmp);
        let cuts = dips(&ts, (0.0, 2.0));
        assert_eq!(cuts.len(), 1, "{cuts:?}");
        assert!((cuts[0] - 1.05).abs() < 1e-9);
        // The same shape at a tenth of the density: too sparse to tell a dip from chance.
        let sparse: Vec<f64> = ts.iter().step_by(10).copied().collect();
        assert!(dips(&sparse, (0.0, 2.0)).is_empty());
        // A dip within DIP_END_MARGIN of an end is the end tapering, not a cut.
        assert!(dips(&ts, (0.85, 2.0)).is_empty());
    }

    #[test]
    fn an_l_shaped_cluster_is_cut_into_its_two_lines() {
        // A 3 m horizontal bar (radius 0.05) and a 1.5 m vertical one 0.2 m below its end.
        let mut pts = Vec::new();
        for k in 0..300 {
            let a = f64::from(k) * 2.4;
            pts.push([f64::from(k) * 0.01, 0.05 * a.cos(), 0.05 * a.sin()]);
        }
        for k in 0..150 {
            let a = f64::from(k) * 2.4;
            pts.push([3.0 + 0.05 * a.cos(), 0.05 * a.sin(), -0.2 - f64::from(k) * 0.01]);
        }
        let members: Vec<u32> = (0..pts.len() as u32).collect();
        let mut segs = segments_of(&pts, members, 0.15, 20);
        segs.sort_by(|a, b| a.length.total_cmp(&b.length));
        assert_eq!(segs.len(), 2, "{segs:?}");
        assert!(segs[0].axis[2].abs() > 0.99 && (segs[0].length - 1.5).abs() < 0.1, "{:?}", segs[0]);
        assert!(segs[1].axis[0].abs() > 0.99 && (segs[1].length - 3.0).abs() < 0.1, "{:?}", segs[1]);
    }
}
