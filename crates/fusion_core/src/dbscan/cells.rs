//! The cells both DBSCAN grids stand on: points bucketed by packed integer cell keys (21 bits
//! an axis) and sorted by cell, plus the union-find and the cluster numbering they share.
//!
//! Module `grid` (fine cells of side just under eps/sqrt(3), and the choice between the two
//! grids) and module `sparse` (coarse cells of side eps) both build on this one; neither
//! imports the other's internals, so `grid` -> `sparse` -> `cells` has no circle.

use super::clustering::{Clustering, NOISE};

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
pub(super) fn pack(x: u64, y: u64, z: u64) -> u64 {
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
pub(super) struct Frame {
    lo: [f64; 3],
    hi: [f64; 3],
    inv: f64,
}

impl Frame {
    /// `None` when the extent needs more than 2^21 cells per axis.
    #[inline(always)]
    pub(super) fn new(coords: &[[f64; 3]], side: f64) -> Option<Frame> {
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
    pub(super) fn cell(&self, p: &[f64; 3]) -> [u64; 3] {
        [self.cell_coord(p[0], 0), self.cell_coord(p[1], 1), self.cell_coord(p[2], 2)]
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
    pub(super) fn side(self, eps: f64) -> f64 {
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
    pub(super) keys: Vec<u64>,
    /// Cell `c` holds sorted points `starts[c]..starts[c + 1]`.
    starts: Vec<usize>,
    /// Sorted distinct (x, y) column keys (`key >> 21`); these three are empty on a grid of
    /// coarse cells, which is never swept.
    pub(super) col_keys: Vec<u64>,
    /// Column `k` holds cells `col_starts[k]..col_starts[k + 1]` (in increasing z).
    pub(super) col_starts: Vec<usize>,
    /// Column of each cell.
    pub(super) cell_col: Vec<u32>,
    /// Cells up to `reach` away on every axis can hold points within eps of each other.
    pub(super) reach: u64,
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
