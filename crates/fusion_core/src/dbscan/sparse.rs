//! DBSCAN on coarse cells for sparse clouds: the same labels as the fine grid (module `grid`).
//!
//! On sparse tower-scale clouds (most fine cells, side eps/sqrt(3), hold one or two points)
//! the fine grid pays per cell, not per point: each cell's 5x5x5 neighbourhood is swept and
//! every cell pair is visited by five passes, for a few distance tests a point. Here cells
//! have side eps, so a point's neighbours lie in the 3x3x3 block, whose forward half is five
//! contiguous runs of sorted points found by four key cursors ([`ForwardRuns`]); every point
//! pair within eps is listed once as an edge (the same-cell pairs included: a coarse cell does
//! not make its points neighbours), and core flags, clusters (union-find on points) and border
//! labels are each one pass over the short edge list. Dense clouds keep the fine grid, where a
//! crowded cell is core wholesale and joined by one pair: listing their edges would cost
//! |a| x |b| per cell pair. This path runs where the fine cells' occupancy is low and its
//! own cost, the distance tests a point, estimated before any sort (`grid::CoarseTests`, a
//! count sketch of the coarse cells and a sample of points), is within `grid::SPARSE_GATE`;
//! the listing gives the cloud back (`None`) to the fine grid past [`TESTS_PER_POINT`],
//! should the estimate err.
//!
//! Measured (crate example, min of 20-150 calls, the build before session 24 alternated with
//! this one on the quiet 2-core box; the labels are the same): tower clouds 10k 1.58 -> 1.18
//! ms, 30k 5.57 -> 4.46 (now here; it took the fine grid), 65k 6.9 -> 6.6 (fine grid, faster
//! binning); 30k points uniform in a 9 m cube 7.5 -> 5.6, in a 6.8 m cube 21.8 -> 6.2 (it had
//! given up at 16 tests a point and paid both paths), in a 5.4 m cube 21.1 -> 19.2 (fine
//! grid); lines of 100 points in 2 m with noise (2.0 a fine cell, fine grid both times) 10k
//! 1.81 -> 1.82, 100k 21.5 -> 21.1; strings of 100 points in 1.5 m with noise 3k 0.36 ->
//! 0.38, 30k 4.93 -> 4.97. Through `ir.dbscan` and `benches/bench_core.py` side by side with
//! scikit-learn and Open3D: the README's table. Tried and dropped in session 22 (min of 200
//! calls): listing edges on the fine cells (the 5x5x5 sweep costs more); building the coarse
//! grid first for every cloud (a whole extra binning for the clouds that take the fine grid).
//! In session 24: an LSD radix sort of the cell bits (a third of std's sort's instructions at
//! 10k, but slower in time at 30k); the 13 forward cells by one cursor each (the five runs
//! need four); an occupancy gate alone at 3 points a fine cell (strings in noise, at 2.05,
//! took this path and ran 15 % slower); cells centred on multiples of the side (the same
//! guarantees, but the instruction guard's strings cloud fell differently on the cells: +15 %).
//! Session 26: the edge listing without a branch ([`EDGE_BATCH`]), 10k 1.15 -> 1.05 ms and
//! 30k 5.38 -> 4.62 (one thread, alternated builds); keeping a point's root through its run of
//! edges in the union was slower (4.6 -> 4.8 ms at 30k) and dropped.

use std::ops::Range;

use super::clustering::Clustering;
use super::cells::{dist2, rank_sets, Grid, Sets, AXIS_BITS, UNSET};

/// Most distance tests per point (pairs of points in neighbouring coarse cells) the edge
/// listing makes before it gives the cloud back: twice the largest gate on the estimate
/// (`grid::SPARSE_GATE`, doubled for lone points), a guard should the estimate err.
pub(crate) const TESTS_PER_POINT: usize = 64;

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

/// A coarse cell's forward neighbours (the half of its 3x3x3 block with larger keys) as
/// contiguous runs of sorted points: the next cell of its own column, and three
/// z-consecutive cells in each of four columns, (x, y+1), (x+1, y-1), (x+1, y) and
/// (x+1, y+1). Cells of one column are consecutive in the sorted order, so each is one run,
/// and one forward-only cursor per column finds it (keys ascend with the cells, and so does a
/// key plus a fixed offset): four cursors a cell, no neighbour list. The grid's padding keeps
/// every coordinate of a neighbour in range, so no key field borrows from the next.
struct ForwardRuns<'a> {
    grid: &'a Grid,
    /// Offsets of the packed key to (x, y+1, z-1), (x+1, y-1, z-1), (x+1, y, z-1) and
    /// (x+1, y+1, z-1): the first cell of each forward column's three.
    offsets: [u64; 4],
    cursors: [usize; 4],
}

impl<'a> ForwardRuns<'a> {
    fn new(grid: &'a Grid) -> Self {
        let at = |dx: u64, dy: u64, dz: u64| (dx << (2 * AXIS_BITS)) + (dy << AXIS_BITS) + dz;
        // Written as (dx, dy, dz) + (1, 1, 1) less (1, 1, 1), so no step goes negative.
        let base = at(1, 1, 1);
        let offsets = [at(1, 2, 0) - base, at(2, 0, 0) - base, at(2, 1, 0) - base, at(2, 2, 0) - base];
        ForwardRuns { grid, offsets, cursors: [0; 4] }
    }

    /// The forward runs of cell `c`: the next cell up its column (empty when there is none),
    /// then the four other columns'. Calls must come in increasing `c`.
    fn at(&mut self, c: usize) -> [Range<usize>; 5] {
        let keys = self.grid.keys();
        let key = keys[c];
        let own_end = self.grid.cell_pts(c).end;
        let up_end = if keys.get(c + 1) == Some(&(key + 1)) { self.grid.cell_pts(c + 1).end } else { own_end };
        let mut runs = [own_end..up_end, 0..0, 0..0, 0..0, 0..0];
        for ((run, cur), &d) in runs[1..].iter_mut().zip(&mut self.cursors).zip(&self.offsets) {
            // Cells (dx, dy, z - 1 ..= z + 1) of this column.
            let lo = key + d;
            while *cur < keys.len() && keys[*cur] < lo {
                *cur += 1;
            }
            let mut end = *cur;
            while end < keys.len() && keys[end] <= lo + 2 {
                end += 1;
            }
            if end > *cur {
                *run = self.grid.cell_pts(*cur).start..self.grid.cell_pts(end - 1).end;
            }
        }
        runs
    }
}

/// Every pair of points within eps, once, as sorted indices (i, j) with i < j; `None` once
/// more than `budget` distance tests would be made.
fn edges(grid: &Grid, eps2: f64, budget: usize) -> Option<Vec<[u32; 2]>> {
    let mut forward = ForwardRuns::new(grid);
    // Sparse clouds have a few edges a point: room for two each saves the regrowths.
    let mut list = Vec::with_capacity(2 * grid.pts.len());
    let mut tests = 0usize;
    let mut pending = [[0u32; 2]; EDGE_BATCH];
    let mut held = 0;
    for c in 0..grid.n_cells() {
        let own = grid.cell_pts(c);
        let runs = forward.at(c);
        tests += own.len() * (own.len() + runs.iter().map(ExactSizeIterator::len).sum::<usize>());
        if tests > budget {
            return None;
        }
        for i in own.clone() {
            let p = grid.pts[i];
            let mut test_run = |run: Range<usize>| {
                for (j, q) in (run.start..).zip(&grid.pts[run]) {
                    // Written whatever the test says and kept by advancing the count: the
                    // test is true for about 4 pairs in 10, which a branch mispredicts.
                    pending[held] = [i as u32, j as u32];
                    held += usize::from(dist2(&p, q) <= eps2);
                    if held == EDGE_BATCH {
                        list.extend_from_slice(&pending);
                        held = 0;
                    }
                }
            };
            // The rest of the own cell and the first run (which continues it up the column)
            // in one, then the other columns'.
            test_run(i + 1..runs[0].end);
            for run in &runs[1..] {
                test_run(run.clone());
            }
        }
    }
    list.extend_from_slice(&pending[..held]);
    Some(list)
}

/// Edges held back before they join the list: every pair tested is written to the batch and
/// kept by advancing its count (see [`edges`]).
const EDGE_BATCH: usize = 256;

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
