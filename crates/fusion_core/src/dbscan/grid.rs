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
//! Cells are found by sorting packed integer cell keys (21 bits per axis). One sweep over the
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
//! Sparse clouds (at most `SPARSE_OCCUPANCY` points per occupied cell, counted on the sorted
//! keys before the cell table is built) go to module `sparse` instead: cells of side eps, each
//! point pair within eps listed once. There the per-cell work above (a 5x5x5 sweep, five passes
//! over the pair table) cost more than the two or three distance tests a point needs.
//!
//! Measured on the sparse tower clouds of `benches/dbscan_tower.rs` (eps 0.3, min_points 5,
//! best of 60 calls, old and new build alternated in one sitting on the loaded 2-core
//! machine): 10k / 30k / 65k points 518 / 292 / 180 ns a point with the per-pass sweeps,
//! 232 / 177 / 121 with the pair table. Dense clouds got faster too (same way, best of 30:
//! the kernels bench's line clusters at 3k / 10k / 100k points 263 / 307 / 552 ns a point
//! before, 141 / 173 / 401 after; 30,000 points in a 0.3 m cube 1.63 ms before, 0.64 ms
//! after, where the kd-tree took ~21 s).

use super::clustering::{Clustering, NOISE};
use super::sparse::dbscan_sparse;

/// Bits per axis in a packed cell key.
const AXIS_BITS: u32 = 21;
/// Empty cells kept on each side of the occupied range, so key offsets of +-2 never wrap.
const PAD: u64 = 2;
/// Largest usable cell coordinate (occupied cells stay in PAD..=MAX_CELL - PAD).
const MAX_CELL: u64 = (1 << AXIS_BITS) - 1;
/// Cell side = eps / sqrt(3) shrunk by this factor, so rounding in the cell assignment can
/// never put two points more than eps apart into one cell.
const SIDE_MARGIN: f64 = 1.0 - 1e-6;
/// Sentinel for "no cluster yet".
pub(super) const UNSET: i32 = i32::MAX;

/// Packs cell coordinates (each < 2^21) into one key whose order is lexicographic (x, y, z).
#[inline]
fn pack(x: u64, y: u64, z: u64) -> u64 {
    (x << (2 * AXIS_BITS)) | (y << AXIS_BITS) | z
}

#[inline]
pub(super) fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let (x, y, z) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    x * x + y * y + z * z
}

/// Points sorted by cell and, inside a cell, by input index.
///
/// When the cell coordinates (each at most `max_cell(axis)`) and the index fit one u64
/// together, which they do for any cloud a UAV scans (a 100 m cloud at eps 0.3 needs 10 bits
/// an axis), the sort runs on plain u64s: faster than on (key, index) pairs and half the
/// memory, and on sparse clouds the sort and the fresh pages it touches were the largest
/// single cost. Otherwise it sorts the pairs. (radsort, the radix sort crate, was measured
/// here: slower than std's sort on 64-bit keys at these sizes, 15 against 10 ns an element.)
enum ByCell {
    /// (cell coordinates, input index) packed into one u64: the index in the low
    /// `index_bits`, then z and y in `bz` and `by` bits, then x.
    Packed { sorted: Vec<u64>, index_bits: u32, by: u32, bz: u32 },
    /// (packed key, input index) pairs, when the cell coordinates and the index need more.
    Pairs(Vec<(u64, u32)>),
}

impl ByCell {
    /// Sorts the points by `cell(p)` (each coordinate at most `max_cell(axis)`).
    fn sort(coords: &[[f64; 3]], cell: impl Fn(&[f64; 3]) -> [u64; 3], max_cell: impl Fn(usize) -> u64) -> ByCell {
        let bits = |v: u64| u64::BITS - v.leading_zeros();
        let axis_bits = [bits(max_cell(0)), bits(max_cell(1)), bits(max_cell(2))];
        let index_bits = bits(coords.len() as u64);
        if axis_bits.iter().sum::<u32>() + index_bits > u64::BITS {
            let mut keyed: Vec<(u64, u32)> = coords
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let [x, y, z] = cell(p);
                    (pack(x, y, z), i as u32)
                })
                .collect();
            keyed.sort_unstable();
            return ByCell::Pairs(keyed);
        }
        let [_, by, bz] = axis_bits;
        let mut sorted: Vec<u64> = coords
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let [x, y, z] = cell(p);
                ((((x << by) | y) << bz | z) << index_bits) | i as u64
            })
            .collect();
        sorted.sort_unstable();
        ByCell::Packed { sorted, index_bits, by, bz }
    }

    /// Number of occupied cells.
    fn n_cells(&self) -> usize {
        let distinct = |cells: &mut dyn Iterator<Item = u64>| {
            let mut last = None;
            cells.filter(|&c| last.replace(c) != Some(c)).count()
        };
        match self {
            ByCell::Packed { sorted, index_bits, .. } => distinct(&mut sorted.iter().map(|&v| v >> index_bits)),
            ByCell::Pairs(keyed) => distinct(&mut keyed.iter().map(|&(k, _)| k)),
        }
    }

    /// Calls `f(packed cell key, input index)` for every point in sorted order.
    fn for_each(self, mut f: impl FnMut(u64, u32)) {
        match self {
            ByCell::Pairs(keyed) => keyed.into_iter().for_each(|(k, i)| f(k, i)),
            ByCell::Packed { sorted, index_bits, by, bz } => {
                let low = |v: u64, b: u32| v & ((1u64 << b) - 1);
                for v in sorted {
                    let (i, c) = (low(v, index_bits), v >> index_bits);
                    f(pack(c >> (by + bz), low(c >> bz, by), low(c, bz)), i as u32);
                }
            }
        }
    }
}

/// Points sorted by cell, before the cell table is built: enough to count occupied cells.
pub(super) struct Binned {
    by_cell: ByCell,
    reach: u64,
}

impl Binned {
    pub fn n_cells(&self) -> usize {
        self.by_cell.n_cells()
    }

    /// The cell table over the sorted points.
    pub fn into_grid(self, coords: &[[f64; 3]]) -> Grid {
        let n = coords.len();
        let (mut pts, mut order) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let mut keys: Vec<u64> = Vec::new();
        let mut starts = Vec::new();
        self.by_cell.for_each(|k, i| {
            if keys.last() != Some(&k) {
                keys.push(k);
                starts.push(order.len());
            }
            pts.push(coords[i as usize]);
            order.push(i);
        });
        starts.push(n);
        let mut col_keys = Vec::new();
        let mut col_starts = Vec::new();
        let mut cell_col = Vec::with_capacity(keys.len());
        for (c, &k) in keys.iter().enumerate() {
            if col_keys.last() != Some(&(k >> AXIS_BITS)) {
                col_keys.push(k >> AXIS_BITS);
                col_starts.push(c);
            }
            cell_col.push((col_keys.len() - 1) as u32);
        }
        col_starts.push(keys.len());
        Grid { pts, order, keys, starts, col_keys, col_starts, cell_col, reach: self.reach }
    }
}

/// Cell size against eps.
#[derive(Clone, Copy)]
pub(super) enum Cells {
    /// Side just under eps / sqrt(3): any two points of a cell are within eps; neighbours
    /// lie up to 2 cells away on each axis (the 5x5x5 block).
    Fine,
    /// Side just over eps: neighbours lie up to 1 cell away on each axis (the 3x3x3 block),
    /// but two points of a cell may be up to eps sqrt(3) apart.
    Coarse,
}

/// Points sorted by cell, with the cell table.
pub(super) struct Grid {
    /// Coordinates in cell order.
    pub pts: Vec<[f64; 3]>,
    /// Input index of each sorted point.
    pub order: Vec<u32>,
    /// Sorted distinct cell keys.
    keys: Vec<u64>,
    /// Cell `c` holds sorted points `starts[c]..starts[c + 1]`.
    starts: Vec<usize>,
    /// Sorted distinct (x, y) column keys (`key >> 21`).
    col_keys: Vec<u64>,
    /// Column `k` holds cells `col_starts[k]..col_starts[k + 1]` (in increasing z).
    col_starts: Vec<usize>,
    /// Column of each cell.
    cell_col: Vec<u32>,
    /// Cells up to `reach` away on every axis can hold points within eps of each other.
    reach: u64,
}

impl Grid {
    /// Buckets finite points; `None` when the extent needs more than 2^21 cells per axis.
    pub(super) fn build(coords: &[[f64; 3]], eps: f64, cells: Cells) -> Option<Grid> {
        Grid::bin(coords, eps, cells).map(|b| b.into_grid(coords))
    }

    /// Sorts finite points by cell; `None` when the extent needs more than 2^21 cells per axis.
    pub(super) fn bin(coords: &[[f64; 3]], eps: f64, cells: Cells) -> Option<Binned> {
        let (side, reach) = match cells {
            Cells::Fine => (eps / 3f64.sqrt() * SIDE_MARGIN, 2),
            Cells::Coarse => (eps / SIDE_MARGIN, 1),
        };
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in coords {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let inv = 1.0 / side;
        let limit = (MAX_CELL - 2 * PAD) as f64;
        if !(0..3).all(|a| ((hi[a] - lo[a]) * inv).is_finite() && (hi[a] - lo[a]) * inv < limit) {
            return None;
        }
        // Cell coordinate: floor((x - lo) / side) + PAD, in range by the check above.
        // v >= lo, so truncation is floor (and avoids a libm call per coordinate).
        let cell = |v: f64, a: usize| ((v - lo[a]) * inv) as u64 + PAD;
        let cell_of = |p: &[f64; 3]| [cell(p[0], 0), cell(p[1], 1), cell(p[2], 2)];
        let by_cell = ByCell::sort(coords, cell_of, |a| ((hi[a] - lo[a]) * inv) as u64 + PAD);
        Some(Binned { by_cell, reach })
    }

    pub fn n_cells(&self) -> usize {
        self.keys.len()
    }

    /// Labels and core flags from sorted order back to input order (UNSET becomes NOISE).
    pub(super) fn unsort(&self, labels: &[i32], core: &[bool]) -> Clustering {
        let mut out = vec![NOISE; labels.len()];
        let mut core_out = vec![false; labels.len()];
        for (s, &i) in self.order.iter().enumerate() {
            out[i as usize] = if labels[s] == UNSET { NOISE } else { labels[s] };
            core_out[i as usize] = core[s];
        }
        Clustering { labels: out, core: core_out }
    }

    /// Sorted indices of the points of cell `c`.
    pub fn cell_pts(&self, c: usize) -> std::ops::Range<usize> {
        self.starts[c]..self.starts[c + 1]
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

/// Points per occupied fine cell at or below which a cloud is clustered on coarse cells
/// (module `sparse`). The tower clouds have 1.4 (10k points), 2.4 (30k) and 4.1 (65k).
pub(crate) const SPARSE_OCCUPANCY: f64 = 2.0;

/// Where the grid switches strategy; a parameter so the tests can force every path.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Budgets {
    /// Most entries of the cell-pair table (`Pairs`), else every pass sweeps again.
    pub table: usize,
    /// Points per occupied fine cell up to which the coarse-cell path is tried.
    pub sparse_occupancy: f64,
    /// Most distance tests per point the coarse-cell path may make before it gives up.
    pub sparse_tests: usize,
}

/// The budgets `dbscan_grid` runs with.
pub(crate) const BUDGETS: Budgets =
    Budgets { table: TABLE_BUDGET, sparse_occupancy: SPARSE_OCCUPANCY, sparse_tests: super::sparse::TESTS_PER_POINT };

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

/// Union-find over cells or points (path halving; the smaller index becomes the root).
pub(super) struct Sets(Vec<u32>);

impl Sets {
    pub fn new(n: usize) -> Sets {
        Sets((0..n as u32).collect())
    }

    pub fn find(&mut self, mut i: usize) -> usize {
        while self.0[i] as usize != i {
            let parent = self.0[i] as usize;
            self.0[i] = self.0[parent];
            i = parent;
        }
        i
    }

    /// Joins the sets of `a` and `b` when `linked()` says so; it is asked only when they are
    /// apart (it may cost distance tests).
    pub fn union_if(&mut self, a: usize, b: usize, linked: impl FnOnce() -> bool) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb && linked() {
            self.0[ra.max(rb)] = ra.min(rb) as u32;
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
    // Sparse clouds are clustered on coarse cells (module `sparse`), chosen by the occupancy
    // of the fine cells: counting them costs one pass over the sorted keys.
    let fine = Grid::bin(coords, eps, Cells::Fine)?;
    if coords.len() as f64 <= budgets.sparse_occupancy * fine.n_cells() as f64 {
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

/// Labels sets by their first core point in input order: `first[root]` is the earliest input
/// index among a set's core points (u32::MAX where no set has that root); returns the label
/// of each root, UNSET elsewhere.
pub(super) fn rank_sets(first: &[u32]) -> Vec<i32> {
    let mut ranked: Vec<(u32, u32)> =
        first.iter().enumerate().filter(|&(_, &f)| f != u32::MAX).map(|(root, &f)| (f, root as u32)).collect();
    ranked.sort_unstable();
    let mut root_label = vec![UNSET; first.len()];
    for (label, &(_, root)) in ranked.iter().enumerate() {
        root_label[root as usize] = label as i32;
    }
    root_label
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
