//! DBSCAN on 3-D points with scikit-learn's semantics.
//!
//! The work is done on a uniform grid (module `dbscan_grid`: near-linear, no neighbour lists);
//! clouds too wide for its packed cell keys fall back to kiddo's ImmutableKdTree here. The
//! immutable tree is used on purpose: kiddo's mutable tree panics when a bucket fills with
//! equal coordinates, which LiDAR scan lines produce routinely. Both give identical labels.

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;

use crate::dbscan_grid::dbscan_grid;
use crate::error::{check_positive, invalid, Result};
use crate::points::{collect_finite, PointCloud};

/// Label of points that belong to no cluster.
pub const NOISE: i32 = -1;

/// Points per kd-tree leaf bucket (kiddo's default).
const BUCKET: usize = 32;
type Tree = ImmutableKdTree<f64, u32, 3, BUCKET>;

/// Labels each point with its cluster (0, 1, ...) or [`NOISE`].
///
/// scikit-learn semantics: a point is core when at least `min_points` points (itself
/// included) lie within distance `eps` (inclusive, compared as squared distances like
/// sklearn's trees); clusters are the connected components of core points plus the
/// border points they reach, numbered in the order of their first core point (index
/// order); a border point joins the lowest-numbered cluster with a core point within `eps`
/// (the one that reaches it first in scikit-learn's expansion). Non-finite points are
/// labelled [`NOISE`] and take no part.
/// Errors: `eps` not finite and > 0, `min_points` < 1, more than `u32::MAX` points.
pub fn dbscan<P: PointCloud + ?Sized>(points: &P, eps: f64, min_points: usize) -> Result<Vec<i32>> {
    check_positive("eps", eps)?;
    if min_points < 1 {
        return Err(invalid("min_points", "must be >= 1"));
    }
    let n = points.len();
    if u32::try_from(n).is_err() {
        return Err(invalid("points", format!("at most {} points are supported, got {n}", u32::MAX)));
    }
    let finite = collect_finite(points);
    let local = dbscan_finite(&finite.coords, eps, min_points);
    let mut labels = vec![NOISE; n];
    for (&i, &l) in finite.indices.iter().zip(&local) {
        labels[i] = l;
    }
    Ok(labels)
}

/// Most neighbour indices kept between the two passes (u32 each: 64 MiB). Beyond it the
/// neighbourhoods of core points are queried again while expanding, so memory stays O(N).
const NEIGHBOUR_BUDGET: usize = 16 << 20;

/// DBSCAN on points already known to be finite (validated arguments). Crate-internal so
/// localize can cluster its finite copy without re-scanning it.
pub(crate) fn dbscan_finite(coords: &[[f64; 3]], eps: f64, min_points: usize) -> Vec<i32> {
    dbscan_grid(coords, eps, min_points).unwrap_or_else(|| dbscan_kdtree(coords, eps, min_points))
}

/// The kd-tree version (for clouds wider than the grid's cell keys allow, and as a cross-check).
fn dbscan_kdtree(coords: &[[f64; 3]], eps: f64, min_points: usize) -> Vec<i32> {
    dbscan_with_budget(coords, eps, min_points, NEIGHBOUR_BUDGET)
}

/// Groups exactly equal points: returns the distinct points, their multiplicities and,
/// for each input point, the index of its distinct point. Many LiDARs report every missing
/// return as (0, 0, 0), so without this a cloud could hold one neighbourhood of N points.
fn deduplicate(coords: &[[f64; 3]]) -> (Vec<[f64; 3]>, Vec<usize>, Vec<u32>) {
    // +0.0 turns -0.0 into 0.0 so equal coordinates share a bit pattern.
    let key = |p: &[f64; 3]| [(p[0] + 0.0).to_bits(), (p[1] + 0.0).to_bits(), (p[2] + 0.0).to_bits()];
    let mut order: Vec<u32> = (0..coords.len() as u32).collect();
    order.sort_unstable_by_key(|&i| key(&coords[i as usize]));
    let mut unique: Vec<[f64; 3]> = Vec::with_capacity(coords.len());
    let mut weight: Vec<usize> = Vec::with_capacity(coords.len());
    let mut rep = vec![0u32; coords.len()];
    let mut last: Option<[u64; 3]> = None;
    for &i in &order {
        let k = key(&coords[i as usize]);
        if last != Some(k) {
            unique.push(coords[i as usize]);
            weight.push(0);
            last = Some(k);
        }
        let u = unique.len() - 1;
        weight[u] += 1;
        rep[i as usize] = u as u32;
    }
    (unique, weight, rep)
}

fn dbscan_with_budget(coords: &[[f64; 3]], eps: f64, min_points: usize, budget: usize) -> Vec<i32> {
    let m = coords.len();
    if m == 0 {
        return Vec::new();
    }
    let (unique, weight, rep) = deduplicate(coords);
    let u_count = unique.len();
    let tree = Tree::new_from_slice(&unique);
    let eps2 = eps * eps;
    let query = |q: &[f64; 3]| tree.within_unsorted::<SquaredEuclidean>(q, eps2);

    // Pass 1: weighted neighbour count of every distinct point; the neighbourhoods of core
    // points (the only ones expanded) are kept in one flat buffer while it fits the budget.
    let mut is_core = vec![false; u_count];
    let mut starts = vec![0usize; u_count + 1];
    let mut neighbours: Vec<u32> = Vec::with_capacity(u_count * min_points.min(32));
    let mut stored = true;
    for (k, q) in unique.iter().enumerate() {
        let found = query(q);
        let count: usize = found.iter().map(|nn| weight[nn.item as usize]).sum();
        if count >= min_points {
            is_core[k] = true;
            if stored {
                if neighbours.len() + found.len() > budget {
                    stored = false;
                    neighbours = Vec::new();
                } else {
                    neighbours.extend(found.iter().map(|nn| nn.item));
                }
            }
        }
        if stored {
            starts[k + 1] = neighbours.len();
        }
    }

    // Pass 2: expand clusters from core points in input index order (sklearn's dbscan_inner).
    let mut labels = vec![NOISE; u_count];
    let mut stack: Vec<u32> = Vec::new();
    let mut next_label: i32 = 0;
    for &seed in &rep {
        if labels[seed as usize] != NOISE || !is_core[seed as usize] {
            continue;
        }
        stack.push(seed);
        while let Some(i) = stack.pop() {
            let i = i as usize;
            if labels[i] != NOISE {
                continue;
            }
            labels[i] = next_label;
            if !is_core[i] {
                continue;
            }
            if stored {
                stack.extend(neighbours[starts[i]..starts[i + 1]].iter().filter(|&&j| labels[j as usize] == NOISE));
            } else {
                stack.extend(query(&unique[i]).iter().map(|nn| nn.item).filter(|&j| labels[j as usize] == NOISE));
            }
        }
        next_label += 1;
    }
    rep.iter().map(|&u| labels[u as usize]).collect()
}

/// Number of clusters in a label vector (largest label + 1).
pub fn n_clusters(labels: &[i32]) -> usize {
    labels.iter().copied().max().map_or(0, |m| usize::try_from(m + 1).unwrap_or(0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::HashMap;

    /// Independent O(N^2) DBSCAN, written straight from the definition.
    fn brute_dbscan(pts: &[[f64; 3]], eps: f64, min_points: usize) -> Vec<i32> {
        let n = pts.len();
        let ok = |p: &[f64; 3]| p.iter().all(|v| v.is_finite());
        let d2 = |a: &[f64; 3], b: &[f64; 3]| {
            let (x, y, z) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
            x * x + y * y + z * z
        };
        let nb: Vec<Vec<usize>> = (0..n)
            .map(|i| if ok(&pts[i]) { (0..n).filter(|&j| ok(&pts[j]) && d2(&pts[i], &pts[j]) <= eps * eps).collect() } else { vec![] })
            .collect();
        let core: Vec<bool> = nb.iter().map(|v| v.len() >= min_points).collect();
        let mut labels = vec![-1; n];
        let mut c = 0;
        for s in 0..n {
            if !core[s] || labels[s] != -1 {
                continue;
            }
            let mut queue = std::collections::VecDeque::from([s]);
            labels[s] = c;
            while let Some(i) = queue.pop_front() {
                if !core[i] {
                    continue;
                }
                for &j in &nb[i] {
                    if labels[j] == -1 {
                        labels[j] = c;
                        queue.push_back(j);
                    }
                }
            }
            c += 1;
        }
        labels
    }

    /// Same noise, identical core labels (both number clusters by first core point), and every
    /// border point carries the label of some core neighbour.
    fn assert_equivalent(pts: &[[f64; 3]], eps: f64, min_points: usize) {
        let got = dbscan(pts, eps, min_points).unwrap();
        let want = brute_dbscan(pts, eps, min_points);
        let ok = |p: &[f64; 3]| p.iter().all(|v| v.is_finite());
        let d2 = |a: &[f64; 3], b: &[f64; 3]| (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum::<f64>();
        let n = pts.len();
        let core: Vec<bool> = (0..n)
            .map(|i| ok(&pts[i]) && (0..n).filter(|&j| ok(&pts[j]) && d2(&pts[i], &pts[j]) <= eps * eps).count() >= min_points)
            .collect();
        for i in 0..n {
            assert_eq!(got[i] == -1, want[i] == -1, "noise differs at {i}");
            if core[i] {
                assert_eq!(got[i], want[i], "core label differs at {i}");
            } else if got[i] != -1 {
                let has_core_nb =
                    (0..n).any(|j| core[j] && got[j] == got[i] && d2(&pts[i], &pts[j]) <= eps * eps);
                assert!(has_core_nb, "border point {i} not adjacent to a core of its cluster");
            }
        }
    }

    #[test]
    fn two_blobs_and_noise() {
        let mut pts = Vec::new();
        for k in 0..20 {
            pts.push([f64::from(k) * 0.05, 0.0, 0.0]);
        }
        for k in 0..10 {
            pts.push([10.0, f64::from(k) * 0.05, 0.0]);
        }
        pts.push([5.0, 5.0, 5.0]);
        let labels = dbscan(&pts, 0.11, 3).unwrap();
        assert!(labels[..20].iter().all(|&l| l == 0));
        assert!(labels[20..30].iter().all(|&l| l == 1));
        assert_eq!(labels[30], NOISE);
        assert_eq!(n_clusters(&labels), 2);
        assert_equivalent(&pts, 0.11, 3);
    }

    #[test]
    fn min_points_one_makes_every_point_a_cluster() {
        let pts = vec![[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.05, 0.0, 0.0]];
        assert_eq!(dbscan(&pts, 0.1, 1).unwrap(), vec![0, 1, 0]);
    }

    #[test]
    fn border_point_and_inclusive_eps() {
        // Points at 0, 1, 2 with eps = 1 (exactly representable): distances of exactly eps count.
        let pts = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
        assert_eq!(dbscan(&pts, 1.0, 3).unwrap(), vec![0, 0, 0]);
        assert_eq!(dbscan(&pts, 0.999, 2).unwrap(), vec![-1, -1, -1]);
    }

    #[test]
    fn many_equal_coordinates_like_scan_lines() {
        // 4000 points on 8 scan lines with heavy duplication (same x, same z per line).
        let mut pts = Vec::new();
        for line in 0..8 {
            for k in 0..500 {
                pts.push([f64::from(k / 10) * 0.02, 0.0, f64::from(line) * 0.5]);
            }
        }
        let labels = dbscan(&pts, 0.3, 5).unwrap();
        assert_eq!(n_clusters(&labels), 8);
        // 10 000 identical points.
        let same = vec![[1.0, 2.0, 3.0]; 10_000];
        assert!(dbscan(&same, 0.3, 5).unwrap().iter().all(|&l| l == 0));
        assert_equivalent(&pts[..600], 0.3, 5);
    }

    #[test]
    fn requery_path_matches_stored_path() {
        let mut pts = Vec::new();
        for k in 0..300 {
            let t = f64::from(k);
            pts.push([(t * 0.37).sin() * 2.0, (t * 0.11).cos() * 2.0, (t * 0.05) % 1.0]);
        }
        pts.extend(vec![[0.5, 0.5, 0.5]; 50]);
        for (eps, mp) in [(0.3, 5), (0.6, 12), (0.1, 2)] {
            let a = dbscan_with_budget(&pts, eps, mp, NEIGHBOUR_BUDGET);
            let b = dbscan_with_budget(&pts, eps, mp, 10);
            assert_eq!(a, b);
            assert_equivalent(&pts, eps, mp);
        }
    }

    #[test]
    fn larger_cloud_matches_brute_force_and_requery() {
        // 1600 points; the small budget overflows part-way through pass 1.
        let mut pts = Vec::new();
        for k in 0..1600 {
            let t = f64::from(k);
            pts.push([(t * 0.37).sin() * 3.0, (t * 0.11).cos() * 3.0, (t * 0.013) % 2.0]);
        }
        assert_equivalent(&pts, 0.25, 6);
        assert_eq!(dbscan_with_budget(&pts, 0.25, 6, NEIGHBOUR_BUDGET), dbscan_with_budget(&pts, 0.25, 6, 5000));
    }

    #[test]
    fn duplicates_count_towards_core_and_signed_zero_is_equal() {
        // Three copies of one point make it core for min_points = 3; -0.0 equals 0.0.
        let pts = vec![[0.0, 0.0, 0.0], [-0.0, 0.0, -0.0], [0.0, 0.0, 0.0], [0.25, 0.0, 0.0], [9.0, 9.0, 9.0]];
        assert_eq!(dbscan(&pts, 0.3, 3).unwrap(), vec![0, 0, 0, 0, -1]);
        assert_equivalent(&pts, 0.3, 3);
        assert_equivalent(&pts, 0.3, 4);
    }

    #[test]
    fn non_finite_points_are_noise_and_ignored() {
        let pts = vec![
            [0.0, 0.0, 0.0],
            [f64::NAN, 0.0, 0.0],
            [0.01, 0.0, 0.0],
            [f64::INFINITY, f64::INFINITY, f64::INFINITY],
            [0.02, 0.0, 0.0],
        ];
        assert_eq!(dbscan(&pts, 0.05, 3).unwrap(), vec![0, -1, 0, -1, 0]);
        let all_nan = vec![[f64::NAN; 3]; 4];
        assert_eq!(dbscan(&all_nan, 0.05, 1).unwrap(), vec![-1; 4]);
        assert_equivalent(&pts, 0.05, 3);
    }

    #[test]
    fn bad_arguments() {
        let pts = vec![[0.0; 3]];
        let name = |r: Result<Vec<i32>>| match r {
            Err(crate::FusionError::InvalidArgument { name, .. }) => name,
            _ => "ok",
        };
        assert_eq!(name(dbscan(&pts, 0.0, 1)), "eps");
        assert_eq!(name(dbscan(&pts, -1.0, 1)), "eps");
        assert_eq!(name(dbscan(&pts, f64::NAN, 1)), "eps");
        assert_eq!(name(dbscan(&pts, f64::INFINITY, 1)), "eps");
        assert_eq!(name(dbscan(&pts, 1.0, 0)), "min_points");
        assert_eq!(dbscan(&Vec::<[f64; 3]>::new(), 1.0, 1).unwrap(), Vec::<i32>::new());
    }

    #[test]
    fn relabelling_free_cluster_order() {
        // Cluster of the lowest index core point comes first even if spatially later.
        let pts = vec![[9.0, 0.0, 0.0], [0.0, 0.0, 0.0], [9.01, 0.0, 0.0], [0.01, 0.0, 0.0]];
        assert_eq!(dbscan(&pts, 0.05, 2).unwrap(), vec![0, 1, 0, 1]);
        let counts: HashMap<i32, usize> = dbscan(&pts, 0.05, 2).unwrap().iter().fold(HashMap::new(), |mut m, &l| {
            *m.entry(l).or_default() += 1;
            m
        });
        assert_eq!(counts.len(), 2);
    }

    #[test]
    fn dense_cube_is_one_cluster_quickly() {
        // 30 000 points in a 0.3 m cube: every point has thousands of neighbours within eps,
        // which the grid never lists (the kd-tree version took ~20 s here).
        let mut rng_state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            rng_state ^= rng_state << 13;
            rng_state ^= rng_state >> 7;
            rng_state ^= rng_state << 17;
            (rng_state >> 11) as f64 / (1u64 << 53) as f64
        };
        let pts: Vec<[f64; 3]> = (0..30_000).map(|_| [next() * 0.3, next() * 0.3, next() * 0.3]).collect();
        let labels = dbscan(&pts, 0.3, 5).unwrap();
        assert!(labels.iter().all(|&l| l == 0));
        // A sparser cube where cells are below min_points: still matches the kd-tree.
        let sparse: Vec<[f64; 3]> = pts[..2000].iter().map(|p| [p[0] * 20.0, p[1] * 20.0, p[2] * 20.0]).collect();
        assert_eq!(dbscan(&sparse, 0.3, 5).unwrap(), dbscan_kdtree(&sparse, 0.3, 5));
    }

    #[test]
    fn huge_extent_falls_back_to_the_tree() {
        // 1e12 m apart needs more cells than the packed keys hold: the kd-tree answers.
        let pts = vec![[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [1e12, 0.0, 0.0], [1e12, 0.1, 0.0], [-1e300, 0.0, 0.0]];
        assert!(crate::dbscan_grid::dbscan_grid(&pts, 0.3, 2).is_none());
        assert_eq!(dbscan(&pts, 0.3, 2).unwrap(), vec![0, 0, 1, 1, -1]);
        assert_equivalent(&pts[..4], 0.3, 2);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// The grid and the kd-tree give identical labels (border rule included) on clouds with
        /// clumps denser than min_points per cell, ties and duplicates.
        #[test]
        fn grid_matches_kdtree(
            pts in prop::collection::vec(prop::array::uniform3(0i32..40), 0..400),
            scale in prop::sample::select(vec![0.01, 0.05, 0.1, 0.25]),
            eps in prop::sample::select(vec![0.1, 0.2, 0.3, 0.5]), min_points in 1usize..12,
        ) {
            let pts: Vec<[f64; 3]> = pts.iter().map(|p| p.map(|v| f64::from(v) * scale)).collect();
            let grid = crate::dbscan_grid::dbscan_grid(&pts, eps, min_points);
            prop_assert_eq!(grid, Some(dbscan_kdtree(&pts, eps, min_points)));
        }

        /// Random clouds on a coarse grid (exact ties and duplicates) and continuous ones.
        #[test]
        fn matches_brute_force_on_grid(
            pts in prop::collection::vec(prop::array::uniform3(0i32..12), 0..250),
            eps_steps in 1i32..5, min_points in 1usize..8,
        ) {
            let pts: Vec<[f64; 3]> = pts.iter().map(|p| [f64::from(p[0]) * 0.1, f64::from(p[1]) * 0.1, f64::from(p[2]) * 0.1]).collect();
            assert_equivalent(&pts, f64::from(eps_steps) * 0.1 + 1e-9, min_points);
        }

        #[test]
        fn matches_brute_force_continuous(
            pts in prop::collection::vec(prop::array::uniform3(-2.0f64..2.0), 0..300),
            eps in 0.05f64..0.8, min_points in 1usize..10,
        ) {
            assert_equivalent(&pts, eps, min_points);
        }
    }
}
