//! DBSCAN on 3-D points with scikit-learn's semantics.
//!
//! Layout (no module imports its parent): `clustering` holds what every back end returns and
//! the merge of independent parts; `grid` is the near-linear uniform-grid DBSCAN that does the
//! work, handing sparse clouds to `sparse` (coarser cells, neighbour pairs listed once);
//! `kdtree` is kiddo's kd-tree version, for the one case the grid cannot take; this module
//! validates the arguments and splits the cloud.
//!
//! A far point must not cost more than a near one. The grid packs cell coordinates into 21
//! bits per axis, so a cloud whose bounding box needs more cells than that (60,000 dense points
//! plus ONE stray LiDAR return 1e7 m away) used to fall back to the kd-tree for the whole
//! cloud: 34 s and 6.4 GB. Now such a cloud is first cut at gaps: two points whose coordinates
//! differ by more than `eps` along an axis are never neighbours, so sorting along x (then y,
//! then z) and cutting wherever consecutive points are more than `eps` apart gives parts that
//! no neighbourhood crosses. Each part is clustered on its own grid and the labels are merged
//! in scikit-learn's numbering. This is exact (nothing is dropped; far points keep their true
//! labels: noise, or their own cluster) and costs one sort of the cloud on top of the grid.
//! The kd-tree remains only for a part that is one connected chain of points over more than
//! 2^21 cells per axis (about 360 km for eps = 0.3 m, which needs millions of points).

use crate::error::{check_positive, invalid, Result};
use crate::points::{collect_finite, PointCloud};

mod cells;
mod clustering;
mod grid;
mod kdtree;
mod sparse;

pub use clustering::NOISE;
use clustering::{merge, Clustering};
use grid::dbscan_grid;
use kdtree::dbscan_kdtree;

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

/// DBSCAN on points already known to be finite (validated arguments). Crate-internal so
/// localize can cluster its finite copy without re-scanning it.
pub(crate) fn dbscan_finite(coords: &[[f64; 3]], eps: f64, min_points: usize) -> Vec<i32> {
    cluster_finite(coords, eps, min_points).labels
}

/// The grid on the whole cloud when it fits; otherwise the cloud is cut at gaps wider than
/// `eps` (module docs) and every part is tried again, down to the kd-tree for a part that
/// cannot be cut.
fn cluster_finite(coords: &[[f64; 3]], eps: f64, min_points: usize) -> Clustering {
    if let Some(whole) = dbscan_grid(coords, eps, min_points) {
        return whole;
    }
    let mut done: Vec<(Vec<u32>, Clustering)> = Vec::new();
    // An explicit work list, not recursion: a hostile cloud could shed one point per cut.
    let mut todo: Vec<Vec<u32>> = Vec::new();
    let mut settle = |part: Vec<u32>, sub: &[[f64; 3]], todo: &mut Vec<Vec<u32>>| match cut_at_gaps(sub, eps) {
        // Each piece back in input order: a part's clusters are numbered by their first core
        // point in the order given, which must be the cloud's order for the merge to hold.
        Some(pieces) => todo.extend(pieces.into_iter().map(|mut p| {
            p.sort_unstable();
            p.into_iter().map(|k| part[k as usize]).collect()
        })),
        None => done.push((part, dbscan_kdtree(sub, eps, min_points))),
    };
    settle((0..coords.len() as u32).collect(), coords, &mut todo);
    let mut grid_parts = Vec::new();
    while let Some(part) = todo.pop() {
        let sub: Vec<[f64; 3]> = part.iter().map(|&i| coords[i as usize]).collect();
        match dbscan_grid(&sub, eps, min_points) {
            Some(c) => grid_parts.push((part, c)),
            None => settle(part, &sub, &mut todo),
        }
    }
    done.extend(grid_parts);
    merge(coords.len(), &done)
}

/// Cuts `coords` into parts along the first axis (x, y, z) that has a gap wider than `eps`
/// between consecutive sorted coordinates; `None` when no axis has one. Points of different
/// parts differ by more than `eps` along that axis, so they are never neighbours.
fn cut_at_gaps(coords: &[[f64; 3]], eps: f64) -> Option<Vec<Vec<u32>>> {
    for axis in 0..3 {
        let mut order: Vec<u32> = (0..coords.len() as u32).collect();
        order.sort_unstable_by(|&a, &b| coords[a as usize][axis].total_cmp(&coords[b as usize][axis]));
        let mut parts: Vec<Vec<u32>> = vec![Vec::new()];
        let mut last: Option<f64> = None;
        for &i in &order {
            let v = coords[i as usize][axis];
            // `v - prev` may overflow to +inf for points near +-f64::MAX: still a gap.
            if last.is_some_and(|prev| v - prev > eps) {
                parts.push(Vec::new());
            }
            last = Some(v);
            if let Some(p) = parts.last_mut() {
                p.push(i);
            }
        }
        if parts.len() > 1 {
            return Some(parts);
        }
    }
    None
}

/// Number of clusters in a label vector (largest label + 1).
pub fn n_clusters(labels: &[i32]) -> usize {
    labels.iter().copied().max().map_or(0, |m| usize::try_from(m + 1).unwrap_or(0))
}

/// The benches' tower-scale cloud generator, shared so tests check what the benches time.
#[cfg(test)]
#[path = "../../benches/tower.rs"]
mod tower;

#[cfg(test)]
mod tests {
    use super::*;
    use grid::{dbscan_grid_with, Budgets, BUDGETS};
    use kdtree::{dbscan_with_budget, NEIGHBOUR_BUDGET};
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
        assert_eq!(dbscan(&sparse, 0.3, 5).unwrap(), dbscan_kdtree(&sparse, 0.3, 5).labels);
    }

    #[test]
    fn huge_extent_is_cut_at_gaps() {
        // 1e12 m apart needs more cells than the packed keys hold: the cloud is cut at its gaps
        // and each part gridded; the kd-tree gives the same answer on the whole cloud.
        let pts = vec![[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [1e12, 0.0, 0.0], [1e12, 0.1, 0.0], [-1e300, 0.0, 0.0],
                       [f64::MAX, f64::MAX, 0.0], [-f64::MAX, 0.0, f64::MAX]];
        assert!(dbscan_grid(&pts, 0.3, 2).is_none());
        assert_eq!(dbscan(&pts, 0.3, 2).unwrap(), vec![0, 0, 1, 1, -1, -1, -1]);
        assert_eq!(cluster_finite(&pts, 0.3, 2), dbscan_kdtree(&pts, 0.3, 2));
        assert_equivalent(&pts, 0.3, 2);
        assert_equivalent(&pts, 0.3, 1);
    }

    #[test]
    fn wide_cloud_sorts_key_index_pairs() {
        // Clumps at the corners of a 250 km cube: 21 bits of cell coordinate per axis, so the
        // keys and the index no longer fit one u64 and the grid sorts (key, index) pairs; no
        // gap along an axis is cut since the clumps are chained by points on the diagonals.
        let mut pts = Vec::new();
        for k in 0..64u32 {
            let t = f64::from(k) / 63.0 * 2.5e5;
            for corner in [[t, t, t], [t, 2.5e5 - t, t], [0.0, 0.0, t]] {
                pts.extend((0..4).map(|j| [corner[0] + 0.05 * f64::from(j), corner[1], corner[2]]));
            }
        }
        for (eps, mp) in [(0.3, 3), (0.3, 5), (0.5, 1)] {
            let grid = dbscan_grid(&pts, eps, mp).expect("fits the grid's 21-bit keys");
            assert_eq!(grid, dbscan_kdtree(&pts, eps, mp));
        }
        assert_equivalent(&pts, 0.3, 3);
    }

    #[test]
    fn one_far_point_changes_nothing_else() {
        // A dense clump (cells far above min_points) plus one stray return 1e7 m away: the same
        // labels as without it (that cloud used to take the kd-tree: 34 s at 60,000 points).
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let near: Vec<[f64; 3]> = (0..20_000).map(|_| [next() * 2.0, next() * 0.5, next() * 0.5]).collect();
        let alone = dbscan(&near, 0.3, 10).unwrap();
        for far in [[1e7, 0.0, 0.0], [0.0, -1e7, 3.0], [5.0, 5.0, 1e12], [-1e300, 0.0, 0.0]] {
            let mut pts = near.clone();
            pts.insert(1234, far);
            let labels = dbscan(&pts, 0.3, 10).unwrap();
            assert_eq!(labels[1234], NOISE);
            assert_eq!([&labels[..1234], &labels[1235..]].concat(), alone);
        }
    }

    #[test]
    fn merge_numbers_clusters_by_first_core_point() {
        // Part B's border point comes first in index order, then part A's core, then B's cores:
        // A's cluster is 0 (its core comes first), B's is 1, as scikit-learn numbers them.
        let pts = vec![[1e6, 0.0, 0.0], [0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [1e6 + 0.15, 0.0, 0.0],
                       [1e6 + 0.2, 0.0, 0.0], [1e6 + 0.25, 0.0, 0.0]];
        assert_eq!(dbscan(&pts, 0.1, 2).unwrap(), vec![-1, 0, 0, 1, 1, 1]);
        assert_eq!(dbscan(&pts, 0.16, 3).unwrap(), vec![0, -1, -1, 0, 0, 0]);
        assert_equivalent(&pts, 0.16, 3);
        let pts = vec![[1e6, 0.0, 0.0], [0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.1, 0.0, 0.0],
                       [1e6 + 0.1, 0.0, 0.0], [1e6 + 0.2, 0.0, 0.0], [1e6 + 0.3, 0.0, 0.0]];
        // eps 0.1, min 3: B's first point (index 0) is a border point of B's cluster.
        assert_eq!(dbscan(&pts, 0.1 + 1e-9, 3).unwrap(), vec![1, 0, 0, 0, 1, 1, 1]);
        assert_equivalent(&pts, 0.1 + 1e-9, 3);
    }

    /// Budgets that force the fine grid (never the coarse cells), and the coarse cells always.
    const FINE: Budgets = Budgets { sparse_occupancy: 0.0, ..BUDGETS };
    const COARSE: Budgets =
        Budgets { sparse_occupancy: f64::INFINITY, sparse_gate: f64::INFINITY, sparse_tests: usize::MAX, ..BUDGETS };

    /// The bench's sparse tower-scale clouds (lattice + conductors over ~60 m, most cells holding
    /// fewer than 5 points): the grid gives the kd-tree's labels exactly, as chosen, on the fine
    /// grid with the pair table stored and over budget (every pass re-sweeps), and on coarse
    /// cells, at eps 0.3 and localize's 0.5.
    #[test]
    fn tower_clouds_match_kdtree_stored_and_swept() {
        for (n, seed) in [(10_000, 7), (3_000, 1)] {
            let pts = tower::tower_cloud(n, seed);
            for (eps, mp) in [(0.3, 5), (0.5, 5), (0.15, 3), (0.3, 1)] {
                let want = dbscan_kdtree(&pts, eps, mp);
                assert!(n_clusters(&want.labels) > 1 && (mp == 1 || want.labels.contains(&NOISE)));
                assert_eq!(dbscan_grid(&pts, eps, mp).as_ref(), Some(&want), "n {n} eps {eps} min {mp}");
                for budgets in [FINE, Budgets { table: 0, ..FINE }, COARSE] {
                    assert_eq!(dbscan_grid_with(&pts, eps, mp, budgets).as_ref(), Some(&want), "{budgets:?}");
                }
            }
        }
        assert_equivalent(&tower::tower_cloud(1_500, 3), 0.3, 5);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Sparse tower-like clouds of any size and seed, any eps/min_points: grid (stored pair
        /// table, and a table budget that runs out part-way; fine grid, coarse cells as chosen,
        /// always, or given up part-way) equals the kd-tree exactly.
        #[test]
        fn tower_clouds_grid_matches_kdtree(
            n in 0usize..2_500, seed in 0u64..1_000, eps in 0.05f64..1.0, min_points in 1usize..12,
            table in prop::sample::select(vec![0usize, 100, 5_000, grid::TABLE_BUDGET]),
            sparse in prop::sample::select(vec![FINE, BUDGETS, COARSE, Budgets { sparse_tests: 1, ..COARSE }]),
        ) {
            let pts = tower::tower_cloud(n, seed);
            let want = dbscan_kdtree(&pts, eps, min_points);
            prop_assert_eq!(dbscan_grid_with(&pts, eps, min_points, Budgets { table, ..sparse }), Some(want));
        }

        /// The grid and the kd-tree give identical labels (border rule included) on clouds with
        /// clumps denser than min_points per cell, ties and duplicates; on the fine grid (also
        /// with the pair table over budget: every pass re-sweeps) and on coarse cells.
        #[test]
        fn grid_matches_kdtree(
            pts in prop::collection::vec(prop::array::uniform3(0i32..40), 0..400),
            scale in prop::sample::select(vec![0.01, 0.05, 0.1, 0.25]),
            eps in prop::sample::select(vec![0.1, 0.2, 0.3, 0.5]), min_points in 1usize..12,
        ) {
            let pts: Vec<[f64; 3]> = pts.iter().map(|p| p.map(|v| f64::from(v) * scale)).collect();
            let want = Some(dbscan_kdtree(&pts, eps, min_points));
            prop_assert_eq!(&dbscan_grid(&pts, eps, min_points), &want);
            for budgets in [FINE, Budgets { table: 50, ..FINE }, COARSE, Budgets { sparse_tests: 2, ..COARSE }] {
                prop_assert_eq!(&dbscan_grid_with(&pts, eps, min_points, budgets), &want);
            }
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

        /// Clumps of which some are moved 1e9 m (or 1e300 m) away along a random axis: the cloud is
        /// cut at its gaps and merged; labels as the brute force, and as the kd-tree exactly.
        #[test]
        fn far_parts_match_brute_force_and_kdtree(
            pts in prop::collection::vec((prop::array::uniform3(0i32..10), 0usize..4), 1..200),
            axis in 0usize..3, far in prop::sample::select(vec![1e9, -1e9, 1e300]),
            eps_steps in 1i32..4, min_points in 1usize..6,
        ) {
            let pts: Vec<[f64; 3]> = pts.iter().map(|(p, group)| {
                let mut q = p.map(|v| f64::from(v) * 0.1);
                if *group > 0 {
                    q[axis] += far * *group as f64;
                }
                q
            }).collect();
            let eps = f64::from(eps_steps) * 0.1 + 1e-9;
            assert_equivalent(&pts, eps, min_points);
            prop_assert_eq!(cluster_finite(&pts, eps, min_points), dbscan_kdtree(&pts, eps, min_points));
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
