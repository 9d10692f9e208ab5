//! Grid DBSCAN: the same labels as the kd-tree version (module `kdtree`), in near-linear time.
//!
//! Points are bucketed into cubic cells of side just under `eps / sqrt(3)`, so any two points
//! of one cell are within `eps` of each other. That gives, without listing neighbourhoods:
//! - core points: a cell holding at least `min_points` points makes all of them core with no
//!   distance test; a point of a sparser cell counts neighbours in the 5x5x5 block of cells
//!   around it (adjacent cells first) and stops at `min_points`;
//! - clusters: all core points of a cell are connected, so union-find runs on cells; two cells
//!   are joined as soon as one pair of their core points is within `eps` (adjacent cells
//!   first, so dense clouds are joined before the costlier outer-shell pairs are tried);
//! - border points: the smallest cluster label among their core neighbours, which is the cluster
//!   that reaches them first in scikit-learn's expansion order (clusters are expanded one after
//!   another in the order of their first core point).
//!
//! Cells are found by sorting packed integer cell keys (21 bits per axis; module `cells`, which
//! the coarse cells of module `sparse` stand on too). One sweep over the
//! sorted cells lists every pair of occupied cells within two cells of each other once (struct
//! `Sweep`: forward-only cursors, so empty space costs nothing), and every pass below walks
//! that pair table: the cost follows the occupied cells and their occupied neighbours, never
//! the volume. (Each pass used to re-run a 25-cursor sweep over the 5x5x5 block, five sweeps
//! in all; on sparse tower-scale clouds, where most cells hold a point or three,
//! that was most of the time: 630 ns a point at 10k points over 60 m.) Core counting goes
//! through each pair once and credits both sides. Repeated points need no deduplication: they
//! share a cell, and a crowded cell is core wholesale. Worst case left: two crowded cells whose
//! points are all just over `eps` apart cost |A| x |B| distance tests once.
//! Clouds whose extent needs more than 2^21 cells per axis return `None` (the parent module
//! then cuts the cloud at gaps wider than eps and grids each part).
//!
//! Sparse clouds (at most `SPARSE_OCCUPANCY` points per occupied cell, and at most
//! `SPARSE_GATE` distance tests a point on coarse cells, both estimated before any sort)
//! go to module `sparse` first: cells
//! of side eps, each point pair within eps listed once. There the per-cell work above (a
//! 5x5x5 sweep, five passes over the pair table) costs more than the few distance tests a
//! point needs.
//!
//! Measured on the sparse tower clouds of `benches/dbscan_tower.rs` (eps 0.3, min_points 5,
//! best of 60 calls, old and new build alternated in one sitting on the loaded 2-core
//! machine): 10k / 30k / 65k points 518 / 292 / 180 ns a point with the per-pass sweeps,
//! 232 / 177 / 121 with the pair table. Dense clouds got faster too (same way, best of 30:
//! the kernels bench's line clusters at 3k / 10k / 100k points 263 / 307 / 552 ns a point
//! before, 141 / 173 / 401 after; 30,000 points in a 0.3 m cube 1.63 ms before, 0.64 ms
//! after, where the kd-tree took ~21 s).

use super::cells::{dist2, pack, rank_sets, Cells, Frame, Grid, Sets, AXIS_BITS, UNSET};
use super::clustering::{Clustering, NOISE};
use super::sparse::dbscan_sparse;

/// Points the cost estimate of the coarse-cell path samples (every point of smaller clouds).
const SAMPLED_POINTS: usize = 256;

/// Distance tests a point the coarse-cell path (module `sparse`) would make, estimated
/// before any sort: each point's coarse cell is counted in a hashed table of 4 counters a
/// point (a count sketch), and for a sample of points the counts of their own cell and its
/// 13 forward neighbours are summed, less the expected count that hash collisions add to a
/// lookup (n / table size each). Both paths give the same labels; only the time depends on
/// it. `None` when the extent does not fit the cells (the fine grid's binning says so too).
struct CoarseTests<'a> {
    coords: &'a [[f64; 3]],
    eps: f64,
}

impl pulp::WithSimd for CoarseTests<'_> {
    type Output = Option<f64>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> Option<f64> {
        let (coords, n) = (self.coords, self.coords.len());
        let frame = Frame::new(coords, Cells::Coarse.side(self.eps))?;
        let mut keys = vec![0u64; n];
        for (k, p) in keys.iter_mut().zip(coords) {
            let [x, y, z] = frame.cell(p);
            *k = pack(x, y, z);
        }
        let slots = (4 * n).next_power_of_two().max(64);
        let shift = u64::BITS - slots.trailing_zeros();
        // Fibonacci hashing: the top bits of the product index the table.
        let slot = |key: u64| (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> shift) as usize;
        let mut counts = vec![0u16; slots];
        for &k in &keys {
            let c = &mut counts[slot(k)];
            *c = c.saturating_add(1);
        }
        // The forward half of the 3x3x3 block and the own cell, as key offsets written as
        // (dx, dy, dz) + (1, 1, 1) less (1, 1, 1), so no step goes negative (PAD keeps the
        // fields apart).
        let at = |dx: u64, dy: u64, dz: u64| (dx << (2 * AXIS_BITS)) + (dy << AXIS_BITS) + dz;
        let mut block = [0u64; 14];
        let mut m = 0;
        for dx in 0..=2u64 {
            for dy in 0..=2u64 {
                for dz in 0..=2u64 {
                    if (dx, dy, dz) >= (1, 1, 1) {
                        block[m] = at(dx, dy, dz) - at(1, 1, 1);
                        m += 1;
                    }
                }
            }
        }
        let stride = (n / SAMPLED_POINTS).max(1);
        let sampled = keys.iter().step_by(stride);
        let total: u64 = sampled.clone().map(|&k| block.iter().map(|&d| u64::from(counts[slot(k + d)])).sum::<u64>()).sum();
        let phantom = block.len() as f64 * n as f64 / slots as f64;
        Some(total as f64 / sampled.count() as f64 - phantom)
    }
}

/// The largest `Grid::reach`.
const MAX_REACH: usize = 2;

/// Lists, for cells in increasing order, their forward neighbours (occupied cells with a
/// larger index within `Grid::reach` cells on every axis), adjacent ones (the 26 around the cell)
/// first. Cells come in increasing (x, y, z) key order, so the forward neighbours of a cell in
/// column (x, y) lie in columns (x, y..=y+2) and (x+1..=x+2, y-2..=y+2): a window of one
/// sorted-column row per dx. One forward-only cursor per row finds the occupied columns of
/// its window, and inside each a forward-only z cursor finds the cells of the z window, so a
/// sweep costs O(occupied cells + occupied columns): empty space costs nothing. (The sweep
/// used to keep one cursor per (dx, dy) column of the 5x5 block, 25 of them: on sparse
/// clouds, where nearly every cell is its own column, stepping them was most of the time.)
pub(super) struct Sweep {
    /// Forward-only cursors into `Grid::col_keys` for the rows x+1 and x+2.
    row_cursors: [usize; MAX_REACH],
    /// Column of the previous call, if any.
    column: Option<usize>,
    /// Occupied neighbour columns of `column`: (column key, z cursor into cells, column end,
    /// whether the column is adjacent: |dx| <= 1 and |dy| <= 1).
    near: Vec<(u64, usize, usize, bool)>,
}

impl Sweep {
    pub fn new() -> Sweep {
        Sweep { row_cursors: [0; MAX_REACH], column: None, near: Vec::new() }
    }

    /// Collects the occupied columns with keys up to `last`, from cursor `cur` on; `mid` is
    /// the key of the window's middle column (dy = 0) and `dx` the window's row offset.
    fn columns_in(&mut self, grid: &Grid, cur: usize, last: u64, mid: u64, dx: u64) {
        let n = grid.col_keys.len();
        let mut q = cur;
        while q < n && grid.col_keys[q] <= last {
            let ck = grid.col_keys[q];
            let adjacent = dx <= 1 && ck.abs_diff(mid) <= 1;
            self.near.push((ck, grid.col_starts[q], grid.col_starts[q + 1], adjacent));
            q += 1;
        }
    }

    /// Forward neighbours of `cell` into `out` (cleared), adjacent cells first; returns how
    /// many are adjacent. Calls must come in increasing `cell` order.
    pub fn neighbours(&mut self, grid: &Grid, cell: usize, out: &mut Vec<u32>) -> usize {
        out.clear();
        let col = grid.cell_col[cell] as usize;
        if self.column != Some(col) {
            self.column = Some(col);
            self.near.clear();
            let key = grid.col_keys[col];
            // Own row: this column and the next two y's (y + 2 stays inside the row by PAD).
            let reach = grid.reach;
            self.columns_in(grid, col, key + reach, key, 0);
            let n = grid.col_keys.len();
            for dx in 1..=reach {
                // PAD keeps x + dx and y - 2 in range: no borrow between the fields.
                let first = key + (dx << AXIS_BITS) - reach;
                let mut cur = self.row_cursors[dx as usize - 1];
                while cur < n && grid.col_keys[cur] < first {
                    cur += 1;
                }
                self.row_cursors[dx as usize - 1] = cur;
                self.columns_in(grid, cur, first + 2 * reach, first + reach, dx);
            }
        }
        let z = grid.keys[cell] & ((1 << AXIS_BITS) - 1);
        let mut far_from = out.len();
        for (ck, zc, end, adjacent) in &mut self.near {
            let lo = (*ck << AXIS_BITS) | (z - grid.reach);
            let hi = (*ck << AXIS_BITS) | (z + grid.reach);
            while *zc < *end && grid.keys[*zc] < lo {
                *zc += 1;
            }
            let mut q = *zc;
            while q < *end && grid.keys[q] <= hi {
                if q > cell {
                    out.push(q as u32);
                    // Keep adjacent cells in front: swap this one into the adjacent block.
                    if *adjacent && (grid.keys[q] & ((1 << AXIS_BITS) - 1)).abs_diff(z) <= 1 {
                        let last = out.len() - 1;
                        out.swap(far_from, last);
                        far_from += 1;
                    }
                }
                q += 1;
            }
        }
        far_from
    }
}

/// Most forward-neighbour entries kept in the table (u32 each: 64 MiB). Real scans (surfaces
/// and wires) have a dozen or so per cell; a solid volume with one point per cell has up to 62.
/// Beyond the budget the sweep is re-run for each pass instead, so memory stays O(N).
pub(crate) const TABLE_BUDGET: usize = 16 << 20;

/// Points per occupied fine cell (estimated) above which a cloud takes the fine grid with
/// no further estimate: the tower clouds have 1.4 (10k points), 2.35 (30k) and 4.2 (65k), the
/// kernels bench's line clusters 3.6. (The cost estimate below scatters a counter a point
/// over a table of 8 bytes a point: 1.4 ms of 8 on the 65k cloud, so dense clouds skip it.)
pub(crate) const SPARSE_OCCUPANCY: f64 = 3.0;

/// Estimated distance tests a point (`CoarseTests`) up to which the coarse cells (module
/// `sparse`) are used. The estimates: tower clouds 4.8 (10k points), 14 (30k), 29 (65k);
/// strings of 100 points in 1.5 m with 20 % uniform noise (instruction guard's `dbscan_3k`)
/// 29, lines of 100 points in 2 m with noise (2.0 points a fine cell) 21: there the fine
/// grid was faster (1.8 against 2.7 ms at 10k), at the towers' 14 the coarse cells (4.2
/// against 5.2 ms at 30k; crate example, min of 60).
pub(crate) const SPARSE_GATE: f64 = 16.0;

/// Points per occupied fine cell (estimated) at or below which the gate doubles: uniform
/// volumes, where the fine grid spent about 600 ns a point (30k points in a 9 m cube, 1.1 a
/// cell, estimate 16: 19.3 ms on the fine grid, 5.9 on coarse cells; in a 6.8 m cube, 1.3 a
/// cell, estimate 30: 18.3 ms fine, 6.2 on coarse cells; crate example, min of 20).
const LONE_OCCUPANCY: f64 = 1.5;

/// Where the grid switches strategy; a parameter so the tests can force every path.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Budgets {
    /// Most entries of the cell-pair table (`Pairs`), else every pass sweeps again.
    pub table: usize,
    /// Points per occupied fine cell up to which the coarse-cell path's cost is estimated.
    pub sparse_occupancy: f64,
    /// Estimated tests a point up to which the coarse-cell path is tried.
    pub sparse_gate: f64,
    /// Most distance tests per point the coarse-cell path may make before it gives up.
    pub sparse_tests: usize,
}

/// The budgets `dbscan_grid` runs with.
pub(crate) const BUDGETS: Budgets =
    Budgets {
    table: TABLE_BUDGET,
    sparse_occupancy: SPARSE_OCCUPANCY,
    sparse_gate: SPARSE_GATE,
    sparse_tests: super::sparse::TESTS_PER_POINT,
};

/// The pairs of neighbour cells, each once (from the lower-index cell), adjacent pairs
/// apart from the outer-shell ones. Built by one sweep and kept while it fits the budget; the
/// passes of the clustering then cost one step per pair instead of a sweep each.
enum Pairs {
    /// `list[start[c]..near_end[c]]` are c's adjacent forward neighbours,
    /// `list[near_end[c]..start[c + 1]]` its outer-shell ones.
    Stored { start: Vec<u32>, near_end: Vec<u32>, list: Vec<u32> },
    /// Over budget: each pass sweeps again.
    Swept,
}

/// Which pairs a pass visits: adjacent cells, outer-shell cells, or all.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Shell {
    Adjacent,
    Outer,
    All,
}

impl Pairs {
    fn build(grid: &Grid, budget: usize) -> Pairs {
        let n_cells = grid.n_cells();
        let mut sweep = Sweep::new();
        let mut buf = Vec::new();
        let mut start = Vec::with_capacity(n_cells + 1);
        let mut near_end = Vec::with_capacity(n_cells);
        let mut list = Vec::new();
        for c in 0..n_cells {
            start.push(list.len() as u32);
            let adjacent = sweep.neighbours(grid, c, &mut buf);
            if list.len() + buf.len() > budget {
                return Pairs::Swept;
            }
            near_end.push((list.len() + adjacent) as u32);
            list.extend_from_slice(&buf);
        }
        start.push(list.len() as u32);
        Pairs::Stored { start, near_end, list }
    }

    /// Calls `f(a, b)` for every pair of neighbour cells in `shell`, `a < b`, in increasing `a`.
    fn visit(&self, grid: &Grid, shell: Shell, mut f: impl FnMut(usize, usize)) {
        match self {
            Pairs::Stored { start, near_end, list } => {
                for a in 0..grid.n_cells() {
                    let (s, m, e) = (start[a] as usize, near_end[a] as usize, start[a + 1] as usize);
                    let range = match shell {
                        Shell::Adjacent => s..m,
                        Shell::Outer => m..e,
                        Shell::All => s..e,
                    };
                    for &b in &list[range] {
                        f(a, b as usize);
                    }
                }
            }
            Pairs::Swept => {
                let mut sweep = Sweep::new();
                let mut buf = Vec::new();
                for a in 0..grid.n_cells() {
                    let adjacent = sweep.neighbours(grid, a, &mut buf);
                    let range = match shell {
                        Shell::Adjacent => 0..adjacent,
                        Shell::Outer => adjacent..buf.len(),
                        Shell::All => 0..buf.len(),
                    };
                    for &b in &buf[range] {
                        f(a, b as usize);
                    }
                }
            }
        }
    }
}

/// The core points of each cell, contiguous (sorted indices; cells are small unless dense, and
/// dense cells are all core, so this is cheap).
struct CoreCells {
    pts: Vec<u32>,
    starts: Vec<usize>,
}

impl CoreCells {
    fn new(grid: &Grid, core: &[bool]) -> CoreCells {
        let mut pts = Vec::new();
        let mut starts = Vec::with_capacity(grid.n_cells() + 1);
        for c in 0..grid.n_cells() {
            starts.push(pts.len());
            pts.extend(grid.cell_pts(c).filter(|&i| core[i]).map(|i| i as u32));
        }
        starts.push(pts.len());
        CoreCells { pts, starts }
    }

    fn of(&self, c: usize) -> &[u32] {
        &self.pts[self.starts[c]..self.starts[c + 1]]
    }
}

/// Grid DBSCAN on finite points (see the module docs); `None` when the extent is too large
/// for the grid. Labels follow the public `dbscan`'s contract exactly.
pub(crate) fn dbscan_grid(coords: &[[f64; 3]], eps: f64, min_points: usize) -> Option<Clustering> {
    dbscan_grid_with(coords, eps, min_points, BUDGETS)
}

/// [`dbscan_grid`] with the budgets given (tests force the re-sweeping and the sparse paths).
pub(crate) fn dbscan_grid_with(coords: &[[f64; 3]], eps: f64, min_points: usize, budgets: Budgets) -> Option<Clustering> {
    if coords.is_empty() {
        return Some(Clustering::empty());
    }
    if min_points > coords.len() {
        // No point has that many neighbours: all noise (and min_points fits a u32 below).
        return Some(Clustering { labels: vec![NOISE; coords.len()], core: vec![false; coords.len()] });
    }
    // Sparse clouds are clustered on coarse cells (module `sparse`). Two estimates on
    // unsorted keys choose them: the fine cells' occupancy (linear counting: a bitmap of a
    // byte a point), which sends dense clouds to the fine grid at once, then that path's own
    // cost, its distance tests a point (`CoarseTests`), which tells a sparse tower from
    // strings of dense points in sparse noise (their mean occupancy is as low, but their
    // tests follow the dense part). Only the time depends on them; both paths give the same
    // labels. A cloud that goes the sparse way is sorted once, on the coarse cells.
    let fine = Grid::bin(coords, eps, Cells::Fine)?;
    let occupancy = coords.len() as f64 / fine.estimated_cells();
    // Nearly a cell a point: there the fine grid pays its per-cell work for almost every
    // point, so the coarse cells win at twice the tests.
    let gate = if occupancy <= LONE_OCCUPANCY { 2.0 * budgets.sparse_gate } else { budgets.sparse_gate };
    if occupancy <= budgets.sparse_occupancy
        && pulp::Arch::new().dispatch(CoarseTests { coords, eps }).is_some_and(|tests| tests <= gate)
    {
        let sparse = Grid::build(coords, eps, Cells::Coarse).and_then(|g| dbscan_sparse(&g, eps, min_points, budgets.sparse_tests));
        if sparse.is_some() {
            return sparse;
        }
    }
    let grid = fine.into_grid(coords);
    let pairs = Pairs::build(&grid, budgets.table);
    let eps2 = eps * eps;
    // Counts stop at min_points, which is at most the number of points (checked above): a u32.
    let core = core_by_cells(&grid, &pairs, eps2, min_points as u32);
    let cores = CoreCells::new(&grid, &core);
    let mut sets = Sets::new(grid.n_cells());
    join_by_cells(&grid, &pairs, &cores, eps2, &mut sets);
    // Every point starts with its cell's label (UNSET without core points there: same-cell
    // points are within eps); border points then take the smallest label among their core
    // neighbours (scikit-learn's expansion order).
    let cell_label = number_clusters(&grid, &cores, &mut sets);
    let mut labels = vec![UNSET; grid.pts.len()];
    for (c, &l) in cell_label.iter().enumerate() {
        labels[grid.cell_pts(c)].fill(l);
    }
    borders_by_cells(&grid, &pairs, &cores, &cell_label, &core, eps2, &mut labels);
    Some(grid.unsort(&labels, &core))
}

/// Core flags (sorted order) by cell pairs. Same-cell points are all within eps, so every
/// point starts with its cell's size; each pair of cells then adds its pairs within eps to
/// both sides, adjacent cells first so most points are settled before the outer shell is
/// tried. A point stops counting at min_points, a cell once all its points have (`pending`).
fn core_by_cells(grid: &Grid, pairs: &Pairs, eps2: f64, min_points: u32) -> Vec<bool> {
    let mut count: Vec<u32> = vec![0; grid.pts.len()];
    let mut pending: Vec<u32> = vec![0; grid.n_cells()];
    for (c, p) in pending.iter_mut().enumerate() {
        let own = grid.cell_pts(c);
        let size = own.len() as u32;
        count[own].fill(size);
        if size < min_points {
            *p = size;
        }
    }
    for shell in [Shell::Adjacent, Shell::Outer] {
        pairs.visit(grid, shell, |a, b| {
            if pending[a] == 0 && pending[b] == 0 {
                return;
            }
            for i in grid.cell_pts(a) {
                let p = &grid.pts[i];
                for j in grid.cell_pts(b) {
                    let open_i = count[i] < min_points;
                    let open_j = count[j] < min_points;
                    if !(open_i || open_j) || dist2(p, &grid.pts[j]) > eps2 {
                        continue;
                    }
                    if open_i {
                        count[i] += 1;
                        pending[a] -= u32::from(count[i] == min_points);
                    }
                    if open_j {
                        count[j] += 1;
                        pending[b] -= u32::from(count[j] == min_points);
                    }
                }
                if pending[a] == 0 && pending[b] == 0 {
                    return;
                }
            }
        });
    }
    count.iter().map(|&k| k >= min_points).collect()
}

/// Clusters by cell pairs: all core points of a cell are connected, so cells are joined when
/// a pair of their core points is within eps. Adjacent cells first: in dense clouds they join
/// almost everything, so the costlier outer-shell pairs mostly find their cells already in one
/// set and are not tested.
fn join_by_cells(grid: &Grid, pairs: &Pairs, cores: &CoreCells, eps2: f64, sets: &mut Sets) {
    let linked = |a: usize, b: usize| {
        cores.of(a).iter().any(|&i| {
            let p = &grid.pts[i as usize];
            cores.of(b).iter().any(|&j| dist2(p, &grid.pts[j as usize]) <= eps2)
        })
    };
    for shell in [Shell::Adjacent, Shell::Outer] {
        pairs.visit(grid, shell, |a, b| {
            if !cores.of(a).is_empty() && !cores.of(b).is_empty() {
                sets.union_if(a, b, || linked(a, b));
            }
        });
    }
}

/// Numbers clusters by their first core point in input order; returns each cell's label
/// (UNSET for a cell without core points). Points of a cell are sorted by input index, so a
/// cell's first core point is its earliest; each set takes the earliest of its cells' and the
/// sets are ranked by it. (Walking all points in input order instead was a random access per
/// point.)
fn number_clusters(grid: &Grid, cores: &CoreCells, sets: &mut Sets) -> Vec<i32> {
    let n_cells = grid.n_cells();
    let mut first = vec![u32::MAX; n_cells];
    for c in 0..n_cells {
        if let Some(&s) = cores.of(c).first() {
            let root = sets.find(c);
            first[root] = first[root].min(grid.order[s as usize]);
        }
    }
    let root_label = rank_sets(&first);
    (0..n_cells).map(|c| if cores.of(c).is_empty() { UNSET } else { root_label[sets.find(c)] }).collect()
}

/// Border labels by cell pairs: each pair of cells offers each side's label to the other
/// side's non-core points within eps of one of its core points.
fn borders_by_cells(
    grid: &Grid,
    pairs: &Pairs,
    cores: &CoreCells,
    cell_label: &[i32],
    core: &[bool],
    eps2: f64,
    labels: &mut [i32],
) {
    let all_core = |c: usize| cores.of(c).len() == grid.cell_pts(c).len();
    let offer = |from: usize, to: usize, labels: &mut [i32]| {
        let l = cell_label[from];
        if l == UNSET || all_core(to) {
            return;
        }
        for i in grid.cell_pts(to) {
            if !core[i] && l < labels[i] && cores.of(from).iter().any(|&j| dist2(&grid.pts[i], &grid.pts[j as usize]) <= eps2) {
                labels[i] = l;
            }
        }
    };
    pairs.visit(grid, Shell::All, |a, b| {
        offer(a, b, labels);
        offer(b, a, labels);
    });
}
