//! DBSCAN on coarse cells for sparse clouds: the same labels as the fine grid (module `grid`).
//!
//! On sparse tower-scale clouds (most fine cells, side eps/sqrt(3), hold one or two points)
//! the fine grid pays per cell, not per point: each cell's 5x5x5 neighbourhood is swept and
//! every cell pair is visited by five passes, for two or three distance tests a point. Here
//! cells have side eps, so neighbours are found in the 3x3x3 block (a sweep window of 5
//! columns instead of 13), every point pair within eps is listed once as an edge (the few
//! same-cell pairs included: a coarse cell does not make its points neighbours), and
//! core flags, clusters (union-find on points) and border labels are each one pass over the
//! short edge list. Dense clouds keep the fine grid, where a crowded cell is core wholesale
//! and joined by one pair: listing their edges would cost |a| x |b| per cell pair. Which path
//! runs is chosen after the fine binning by its occupancy, and this path gives the cloud back
//! (`None`) once it would make more than a budget of distance tests.
//!
//! Measured on the 10k-point tower cloud (eps 0.3, min_points 5; `ir.dbscan` through
//! `benches/bench_core.py`, old and new builds alternated in one sitting on the loaded 2-core
//! box): 2.10 ms before, 1.32 ms after (best of ~450 calls); callgrind on the guard's sparse
//! kernel (`dbscan_sparse_10k`) 13.2M instructions before, 10.9M after. Tried and dropped
//! (min of 200 calls on the crate's own 10k/65k tower clouds): listing edges on the fine cells
//! (1.86 ms at 10k against about 1.55 here: the 5x5x5 sweep stays); building the coarse grid
//! first and choosing by its occupancy (10k in 1.40 ms, but a whole extra binning for the
//! clouds that then take the fine grid: 65k from 6.5 to 9.2 ms); taking the edge path up to
//! 24 tests a point (30k and 65k slower, 65k twice as slow: there the fine grid settles
//! crowded cells with no distance test at all); listing the neighbour cells before any test,
//! so a cloud over budget is given back sooner (4 % slower at 10k).
//!
//! The cost of giving up: a uniform volume with about one point per fine cell passes the
//! occupancy gate and then needs far more than 16 tests a point, so it pays the coarse binning
//! and up to 16 tests a point before the fine grid: through `ir.dbscan`, 30k points in a
//! 5.4 m or 6.8 m cube 21.5-21.9 ms before, 23.4-24.1 after (min of 40, alternated, loaded
//! box); a sparser volume (30k in a 9 m cube) runs here and went from 18.0 to 6.9 ms. The
//! bench's line clusters (1k-100k points, fine grid) are unchanged.

use super::clustering::Clustering;
use super::grid::{dist2, rank_sets, Grid, Sets, Sweep, UNSET};

/// Most distance tests per point (pairs of points in neighbouring coarse cells) before the
/// coarse path gives up. The bench's tower clouds need about 4 (10k points), 12 (30k) and
/// 25 (65k); only the 10k one is sparse enough to come here.
pub(crate) const TESTS_PER_POINT: usize = 16;

/// Coarse-cell DBSCAN (module docs) on a grid built with `Cells::Coarse`; `None` when the
/// cloud is denser than `tests_per_point` allows.
pub(super) fn dbscan_sparse(grid: &Grid, eps: f64, min_points: usize, tests_per_point: usize) -> Option<Clustering> {
    let n = grid.pts.len();
    let edges = edges(grid, eps * eps, tests_per_point.saturating_mul(n))?;
    // Every point is its own neighbour; counts stay below n + 1, a u32 for any cloud we take.
    let mut count = vec![1u32; n];
    for &[i, j] in &edges {
        count[i as usize] += 1;
        count[j as usize] += 1;
    }
    let core: Vec<bool> = count.iter().map(|&k| k as usize >= min_points).collect();
    let mut sets = Sets::new(n);
    for &[i, j] in &edges {
        if core[i as usize] && core[j as usize] {
            sets.union_if(i as usize, j as usize, || true);
        }
    }
    let labels = label_points(grid, &core, &mut sets, &edges);
    Some(grid.unsort(&labels, &core))
}

/// Every pair of points within eps, once, as sorted indices (i, j) with i < j; `None` once
/// more than `budget` distance tests would be made.
fn edges(grid: &Grid, eps2: f64, budget: usize) -> Option<Vec<[u32; 2]>> {
    let mut sweep = Sweep::new();
    let mut near = Vec::new();
    let mut list = Vec::new();
    let mut tests = 0usize;
    for c in 0..grid.n_cells() {
        // Forward neighbours only (larger cell index, so larger sorted point index).
        sweep.neighbours(grid, c, &mut near);
        let own = grid.cell_pts(c);
        tests += own.len() * (own.len() + near.iter().map(|&b| grid.cell_pts(b as usize).len()).sum::<usize>());
        if tests > budget {
            return None;
        }
        for i in own.clone() {
            let p = &grid.pts[i];
            let mut keep = |j: usize| {
                if dist2(p, &grid.pts[j]) <= eps2 {
                    list.push([i as u32, j as u32]);
                }
            };
            (i + 1..own.end).for_each(&mut keep);
            for &b in &near {
                grid.cell_pts(b as usize).for_each(&mut keep);
            }
        }
    }
    Some(list)
}

/// Labels in sorted order: clusters (sets of core points) numbered by their first core point
/// in input order, border points the smallest label among their core neighbours (the cluster
/// that reaches them first in scikit-learn's expansion), UNSET for noise.
fn label_points(grid: &Grid, core: &[bool], sets: &mut Sets, edges: &[[u32; 2]]) -> Vec<i32> {
    let n = core.len();
    let mut first = vec![u32::MAX; n];
    for s in (0..n).filter(|&s| core[s]) {
        let root = sets.find(s);
        first[root] = first[root].min(grid.order[s]);
    }
    let root_label = rank_sets(&first);
    let mut labels: Vec<i32> = (0..n).map(|s| if core[s] { root_label[sets.find(s)] } else { UNSET }).collect();
    for &[i, j] in edges {
        let (i, j) = (i as usize, j as usize);
        match (core[i], core[j]) {
            (true, false) => labels[j] = labels[j].min(labels[i]),
            (false, true) => labels[i] = labels[i].min(labels[j]),
            _ => {}
        }
    }
    labels
}
