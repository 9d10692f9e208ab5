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
/// Lines taken out of one cluster at most (a joint of the lattice meets five or six members).
const MAX_LINES_PER_CLUSTER: usize = 8;
/// RANSAC of one line in a cluster: hypotheses and the stop confidence (reproducible seed).
const LINE_RANSAC: RansacParams = RansacParams { threshold: LINE_INLIER, max_iterations: 300, confidence: 0.999, seed: 0 };

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
    let center = [mean[0] + mid * axis[0], mean[1] + mid * axis[1], mean[2] + mid * axis[2]];
    ts.iter_mut().for_each(|t| *t -= mid);
    let contrast = shed_contrast(&ts, lo - mid, hi - mid);
    ts.sort_by(f64::total_cmp);
    let extent = (quantile(&ts, EXTENT_TRIM), quantile(&ts, 1.0 - EXTENT_TRIM));
    rs.clear();
    Some(Segment { center, axis, length: hi - lo, extent, radius, members, contrast })
}

/// The segments of a cluster (`members` of `points`): the cluster itself when it is one line,
/// else the lines RANSAC takes out of it one by one, each cut at its gaps of more than `eps`
/// (m) into runs of at least `min_points` points.
///
/// WHY: the fitting between an arm tip and a string's first shed is a short thin rod; where the
/// LiDAR sees it well, the shed-thick points of the arm, the fitting and the string touch and
/// DBSCAN returns one L-shaped cluster whose PCA is neither.
pub(super) fn segments_of(points: &[[f64; 3]], members: Vec<u32>, eps: f64, min_points: usize) -> Vec<Segment> {
    let mut found = Vec::new();
    let mut rest = members;
    for _ in 0..MAX_LINES_PER_CLUSTER {
        if rest.len() < min_points {
            break;
        }
        if let Some(seg) = segment(points, rest.clone()) {
            if seg.radius <= MAX_LINE_RADIUS {
                found.push(seg);
                break;
            }
        }
        let coords: Vec<[f64; 3]> = rest.iter().map(|&i| points[i as usize]).collect();
        let Ok(line) = ransac_line(coords.as_slice(), &LINE_RANSAC) else { break };
        if line.inliers.len() < min_points {
            break;
        }
        let on_line: Vec<[f64; 3]> = line.inliers.iter().map(|&k| coords[k]).collect();
        if let Ok(runs) = dbscan(on_line.as_slice(), eps, 1) {
            let n_runs = runs.iter().copied().max().map_or(0, |m| (m + 1).max(0) as usize);
            let mut by_run: Vec<Vec<u32>> = vec![Vec::new(); n_runs];
            for (k, &run) in runs.iter().enumerate() {
                if run != NOISE {
                    by_run[run as usize].push(rest[line.inliers[k]]);
                }
            }
            found.extend(by_run.into_iter().filter(|r| r.len() >= min_points).filter_map(|r| segment(points, r)));
        }
        let mut taken = vec![false; rest.len()];
        line.inliers.iter().for_each(|&k| taken[k] = true);
        rest = rest.into_iter().zip(taken).filter(|(_, t)| !t).map(|(i, _)| i).collect();
    }
    found
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
        let s = segment(&pts, members).unwrap();
        assert!((s.length - 1.5).abs() < 0.05, "{s:?}");
        assert!((s.center[2] - 0.75).abs() < 0.03, "{s:?}");
        assert!((s.radius - 0.1).abs() < 0.01);
        assert!(s.axis[2].abs() > 0.99);
        assert!(s.extent.0 < -1.1, "the rod is in the extent: {:?}", s.extent);
        assert!(s.contrast > 10.0, "{}", s.contrast);
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
