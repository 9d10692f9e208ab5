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

use super::clustering::{Clustering, NOISE};
use super::sparse::dbscan_sparse;

/// Bits per axis in a packed cell key.
pub(super) const AXIS_BITS: u32 = 21;
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
    /// The points' keys by `cell(p)` (each coordinate at most `max_cell(axis)`), in input
    /// order: [`ByCell::sort`] sorts them.
    #[inline(always)]
    fn keys(coords: &[[f64; 3]], cell: impl Fn(&[f64; 3]) -> [u64; 3], max_cell: impl Fn(usize) -> u64) -> ByCell {
        let bits = |v: u64| u64::BITS - v.leading_zeros();
        let axis_bits = [bits(max_cell(0)), bits(max_cell(1)), bits(max_cell(2))];
        let index_bits = bits(coords.len() as u64);
        if axis_bits.iter().sum::<u32>() + index_bits > u64::BITS {
            let keyed: Vec<(u64, u32)> = coords
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let [x, y, z] = cell(p);
                    (pack(x, y, z), i as u32)
                })
                .collect();
            return ByCell::Pairs(keyed);
        }
        let [_, by, bz] = axis_bits;
        // A plain loop over a filled vector, not a collect: it inlines into the caller's
        // SIMD dispatch (`Grid::bin`) and vectorises there, where the collect stayed a
        // baseline-x86 call of ~70 instructions a point.
        let mut sorted = vec![0u64; coords.len()];
        for (i, (s, p)) in sorted.iter_mut().zip(coords).enumerate() {
            let [x, y, z] = cell(p);
            *s = ((((x << by) | y) << bz | z) << index_bits) | i as u64;
        }
        ByCell::Packed { sorted, index_bits, by, bz }
    }

    fn sort(&mut self) {
        match self {
            ByCell::Packed { sorted, .. } => sorted.sort_unstable(),
            ByCell::Pairs(keyed) => keyed.sort_unstable(),
        }
    }

    /// Occupied cells, estimated by linear counting (Whang, Vander-Zanden and Taylor, 1990):
    /// each point's cell hashed into a bitmap of 8 bits a point, then `m ln(m / empty bits)`.
    /// Standard error about 1 % at these loads; the keys in any order.
    fn estimated_cells(&self) -> f64 {
        let n = match self {
            ByCell::Packed { sorted, .. } => sorted.len(),
            ByCell::Pairs(keyed) => keyed.len(),
        };
        let bits = (8 * n).next_power_of_two().max(64);
        let shift = u64::BITS - bits.trailing_zeros();
        let mut bitmap = vec![0u64; bits / 64];
        let mut mark = |cell: u64| {
            // Fibonacci hashing: the top bits of the product index the bitmap.
            let h = (cell.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> shift) as usize;
            bitmap[h / 64] |= 1 << (h % 64);
        };
        match self {
            ByCell::Packed { sorted, index_bits, .. } => sorted.iter().for_each(|&v| mark(v >> index_bits)),
            ByCell::Pairs(keyed) => keyed.iter().for_each(|&(k, _)| mark(k)),
        }
        let empty = bitmap.iter().map(|w| w.count_zeros()).sum::<u32>();
        if empty == 0 {
            return f64::INFINITY;
        }
        bits as f64 * (bits as f64 / f64::from(empty)).ln()
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

/// The points' cell keys, before they are sorted and the cell table is built: enough to
/// estimate how many cells are occupied.
pub(super) struct Binned {
    by_cell: ByCell,
    reach: u64,
}

impl Binned {
    /// Occupied cells, estimated (see [`ByCell::estimated_cells`]).
    pub fn estimated_cells(&self) -> f64 {
        self.by_cell.estimated_cells()
    }

    /// The cell table: the points sorted by cell.
    pub fn into_grid(mut self, coords: &[[f64; 3]]) -> Grid {
        self.by_cell.sort();
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
        // Columns serve the sweep of the fine cells' 5x5x5 blocks; the coarse cells' path
        // (module `sparse`) finds its neighbours by key cursors and skips building them.
        let columns = if self.reach == Cells::Fine.reach() { keys.as_slice() } else { &[] };
        for (c, &k) in columns.iter().enumerate() {
            if col_keys.last() != Some(&(k >> AXIS_BITS)) {
                col_keys.push(k >> AXIS_BITS);
                col_starts.push(c);
            }
            cell_col.push((col_keys.len() - 1) as u32);
        }
        col_starts.push(columns.len());
        Grid { pts, order, keys, starts, col_keys, col_starts, cell_col, reach: self.reach }
    }
}

/// [`Grid::bin`] as a pulp operation: its body inlined into each instruction set's
/// `#[target_feature]` function (a closure there stayed a baseline-x86 call).
struct BinOp<'a> {
    coords: &'a [[f64; 3]],
    eps: f64,
    cells: Cells,
}

impl pulp::WithSimd for BinOp<'_> {
    type Output = Option<Binned>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> Option<Binned> {
        Grid::bin_here(self.coords, self.eps, self.cells)
    }
}

/// A cloud's bounds and cell side: each point's cell coordinates.
struct Frame {
    lo: [f64; 3],
    hi: [f64; 3],
    inv: f64,
}

impl Frame {
    /// `None` when the extent needs more than 2^21 cells per axis.
    #[inline(always)]
    fn new(coords: &[[f64; 3]], side: f64) -> Option<Frame> {
        // Plain comparisons (the points are finite): they vectorise, f64::min's NaN rule
        // did not.
        let mut lo = coords.first().copied().unwrap_or([0.0; 3]);
        let mut hi = lo;
        for p in coords {
            for a in 0..3 {
                lo[a] = if p[a] < lo[a] { p[a] } else { lo[a] };
                hi[a] = if p[a] > hi[a] { p[a] } else { hi[a] };
            }
        }
        let inv = 1.0 / side;
        // A cell of margin below the packed range, on top of PAD.
        let limit = (MAX_CELL - 2 * PAD - 1) as f64;
        let fits = (0..3).all(|a| ((hi[a] - lo[a]) * inv).is_finite() && (hi[a] - lo[a]) * inv < limit);
        fits.then_some(Frame { lo, hi, inv })
    }

    /// Cell coordinate on axis `a`: floor((v - lo) / side) + PAD, computed as the nearest
    /// integer to (v - lo) / side + PAD - 1/2 by adding 2^52 (the sum's low mantissa bits are
    /// the rounded value, for 0 <= x < 2^51, checked in `new`): an add and a mask in any
    /// vector unit, where `as u64` (or `as i32`) is a saturating conversion, scalar here.
    /// Exact integers (a point on a cell boundary) round to the even neighbour, so such a
    /// point may land in the cell below: every cell still spans one side, so the guarantees
    /// hold (two points of a fine cell within eps, neighbours within `reach` cells).
    #[inline(always)]
    fn cell_coord(&self, v: f64, a: usize) -> u64 {
        round_small((v - self.lo[a]) * self.inv + (PAD as f64 - 0.5))
    }

    #[inline(always)]
    fn cell(&self, p: &[f64; 3]) -> [u64; 3] {
        [self.cell_coord(p[0], 0), self.cell_coord(p[1], 1), self.cell_coord(p[2], 2)]
    }
}

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

/// `x` rounded to the nearest integer (ties to even), for `0 <= x < 2^51`: the low 52
/// bits of `x + 2^52`, whose unit in the last place is 1.
#[inline(always)]
fn round_small(x: f64) -> u64 {
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    (x + TWO_52).to_bits() & ((1 << 52) - 1)
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

impl Cells {
    /// Side of a cell.
    fn side(self, eps: f64) -> f64 {
        match self {
            Cells::Fine => eps / 3f64.sqrt() * SIDE_MARGIN,
            Cells::Coarse => eps / SIDE_MARGIN,
        }
    }

    /// Cells up to this far away on every axis can hold points within eps of each other.
    const fn reach(self) -> u64 {
        match self {
            Cells::Fine => 2,
            Cells::Coarse => 1,
        }
    }
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
    /// Sorted distinct (x, y) column keys (`key >> 21`); these three are empty on a grid of
    /// coarse cells, which is never swept.
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

    /// The finite points' cell keys; `None` when the extent needs more than 2^21 cells per
    /// axis. Compiled for the CPU's widest vectors (pulp's dispatch): the bounds and the keys
    /// are a pass of arithmetic a point, which took a third of a sparse cloud's binning at
    /// baseline x86-64.
    pub(super) fn bin(coords: &[[f64; 3]], eps: f64, cells: Cells) -> Option<Binned> {
        pulp::Arch::new().dispatch(BinOp { coords, eps, cells })
    }

    #[inline(always)]
    fn bin_here(coords: &[[f64; 3]], eps: f64, cells: Cells) -> Option<Binned> {
        let frame = Frame::new(coords, cells.side(eps))?;
        let by_cell = ByCell::keys(coords, |p| frame.cell(p), |a| frame.cell_coord(frame.hi[a], a));
        Some(Binned { by_cell, reach: cells.reach() })
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

    /// Sorted distinct packed cell keys (x, y, z; `AXIS_BITS` each).
    pub(super) fn keys(&self) -> &[u64] {
        &self.keys
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

/// Union-find over cells or points (path halving; the smaller index becomes the root).
pub(super) struct Sets(Vec<u32>);

impl Sets {
    pub fn new(n: usize) -> Sets {
        Sets((0..n as u32).collect())
    }

    #[inline]
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
    #[inline]
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
