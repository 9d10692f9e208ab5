//! Grid DBSCAN: the same labels as the kd-tree version (module `kdtree`), in near-linear time.
//!
//! Points are bucketed into cubic cells of side just under `eps / sqrt(3)`, so any two points
//! of one cell are within `eps` of each other. That gives, without listing neighbourhoods:
//! - core points: a cell holding at least `min_points` points makes all of them core with no
//!   distance test; a point of a sparser cell counts neighbours in the 5x5x5 block of cells
//!   around it and stops at `min_points`;
//! - clusters: all core points of a cell are connected, so union-find runs on cells; two cells
//!   are joined as soon as one pair of their core points is within `eps` (face/edge/corner
//!   neighbours first, so dense clouds are joined before the costlier far cells are tried);
//! - border points: the smallest cluster label among their core neighbours, which is the cluster
//!   that reaches them first in scikit-learn's expansion order (clusters are expanded one after
//!   another in the order of their first core point).
//!
//! Cells are found by sorting packed integer cell keys (21 bits per axis); a sweep finds the
//! occupied neighbour (x, y) columns once per column and the z window inside each with forward-only
//! cursors, so listing the neighbour cells of every cell costs O(1) amortised. Repeated points need
//! no deduplication: they share a cell, and a crowded cell is core wholesale. Worst case left: two
//! crowded cells whose points are all just over `eps` apart cost |A| x |B| distance tests once.
//! Clouds whose extent needs more than 2^21 cells per axis return `None` (the parent module
//! then cuts the cloud at gaps wider than eps and grids each part).
//!
//! Measured (criterion, loaded 2-core machine, same sitting): 3,000 line-cluster points 0.95 ms
//! (kd-tree 2.30 ms), 100,000 points 39 ms (kd-tree 161 ms), 1,000,000 points 0.37 s, 30,000
//! points in a 0.3 m cube 2.2 ms (kd-tree ~21 s).

use super::clustering::{Clustering, NOISE};

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
const UNSET: i32 = i32::MAX;

/// Packs cell coordinates (each < 2^21) into one key whose order is lexicographic (x, y, z).
#[inline]
fn pack(x: u64, y: u64, z: u64) -> u64 {
    (x << (2 * AXIS_BITS)) | (y << AXIS_BITS) | z
}

#[inline]
fn unpack(k: u64) -> [i64; 3] {
    let mask = (1u64 << AXIS_BITS) - 1;
    [(k >> (2 * AXIS_BITS)) as i64, ((k >> AXIS_BITS) & mask) as i64, (k & mask) as i64]
}

/// True when cell `key` is `here` or one of its 26 adjacent cells.
#[inline]
fn within_one(here: [i64; 3], key: u64) -> bool {
    let there = unpack(key);
    (0..3).all(|a| (here[a] - there[a]).abs() <= 1)
}

#[inline]
fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let (x, y, z) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    x * x + y * y + z * z
}

/// Points sorted by cell, with the cell table.
struct Grid {
    /// Coordinates in cell order.
    pts: Vec<[f64; 3]>,
    /// Input index of each sorted point.
    order: Vec<u32>,
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
}

impl Grid {
    /// Buckets finite points; `None` when the extent needs more than 2^21 cells per axis.
    fn build(coords: &[[f64; 3]], eps: f64) -> Option<Grid> {
        let side = eps / 3f64.sqrt() * SIDE_MARGIN;
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
        let cell = |v: f64, a: usize| ((v - lo[a]) * inv).floor() as u64 + PAD;
        let mut keyed: Vec<(u64, u32)> =
            coords.iter().enumerate().map(|(i, p)| (pack(cell(p[0], 0), cell(p[1], 1), cell(p[2], 2)), i as u32)).collect();
        keyed.sort_unstable();
        let mut keys = Vec::new();
        let mut starts = Vec::new();
        for (s, &(k, _)) in keyed.iter().enumerate() {
            if keys.last() != Some(&k) {
                keys.push(k);
                starts.push(s);
            }
        }
        starts.push(keyed.len());
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
        let pts = keyed.iter().map(|&(_, i)| coords[i as usize]).collect();
        let order = keyed.iter().map(|&(_, i)| i).collect();
        Some(Grid { pts, order, keys, starts, col_keys, col_starts, cell_col })
    }

    fn n_cells(&self) -> usize {
        self.keys.len()
    }
}

/// Visits, for cells in increasing order, the occupied cells within `reach` cells on every
/// axis (the cell itself included). The occupied neighbour (x, y) columns are found once per
/// column with one forward-only cursor per (dx, dy); inside each of them a forward-only z
/// cursor finds the cells of the z window, so empty columns cost nothing per cell.
struct Sweep {
    reach: i64,
    /// Column-key offsets of the (dx, dy) neighbour columns.
    offsets: Vec<i64>,
    /// Forward-only cursors into `Grid::col_keys`, one per offset.
    col_cursors: Vec<usize>,
    /// Column of the previous call, if any.
    column: Option<usize>,
    /// Occupied neighbour columns of `column`: (column key, z cursor into cells, column end).
    near: Vec<(u64, usize, usize)>,
}

impl Sweep {
    fn new(reach: i64) -> Sweep {
        let mut offsets = Vec::new();
        for dx in -reach..=reach {
            for dy in -reach..=reach {
                offsets.push((dx << AXIS_BITS) + dy);
            }
        }
        let col_cursors = vec![0; offsets.len()];
        Sweep { reach, offsets, col_cursors, column: None, near: Vec::new() }
    }

    /// Neighbour cells of `cell` into `out`; calls must come in increasing `cell` order.
    fn neighbours(&mut self, grid: &Grid, cell: usize, out: &mut Vec<usize>) {
        out.clear();
        let col = grid.cell_col[cell] as usize;
        if self.column != Some(col) {
            self.column = Some(col);
            self.near.clear();
            let key = grid.col_keys[col] as i64;
            let n = grid.col_keys.len();
            for (off, cur) in self.offsets.iter().zip(self.col_cursors.iter_mut()) {
                // PAD keeps x + dx and y + dy in range: no carries between the fields.
                let want = (key + off) as u64;
                while *cur < n && grid.col_keys[*cur] < want {
                    *cur += 1;
                }
                if *cur < n && grid.col_keys[*cur] == want {
                    self.near.push((want, grid.col_starts[*cur], grid.col_starts[*cur + 1]));
                }
            }
        }
        let z = (grid.keys[cell] & ((1 << AXIS_BITS) - 1)) as i64;
        for (ck, zc, end) in &mut self.near {
            let lo = (*ck << AXIS_BITS) | (z - self.reach) as u64;
            let hi = (*ck << AXIS_BITS) | (z + self.reach) as u64;
            while *zc < *end && grid.keys[*zc] < lo {
                *zc += 1;
            }
            let mut q = *zc;
            while q < *end && grid.keys[q] <= hi {
                out.push(q);
                q += 1;
            }
        }
    }
}

/// Union-find over cells (path halving; the smaller index becomes the root).
struct Sets(Vec<u32>);

impl Sets {
    fn find(&mut self, mut i: usize) -> usize {
        while self.0[i] as usize != i {
            let parent = self.0[i] as usize;
            self.0[i] = self.0[parent];
            i = parent;
        }
        i
    }
}

/// Grid DBSCAN on finite points (see the module docs); `None` when the extent is too large
/// for the grid. Labels follow the public `dbscan`'s contract exactly.
pub(crate) fn dbscan_grid(coords: &[[f64; 3]], eps: f64, min_points: usize) -> Option<Clustering> {
    if coords.is_empty() {
        return Some(Clustering::empty());
    }
    let grid = Grid::build(coords, eps)?;
    let eps2 = eps * eps;
    let n_cells = grid.n_cells();
    let cell_pts = |c: usize| grid.starts[c]..grid.starts[c + 1];
    let mut buf: Vec<usize> = Vec::new();

    // 1. Core points (flags in sorted order). Same-cell points are all within eps; the other
    // neighbours are counted in the 27 adjacent cells first, then the outer shell, stopping
    // at min_points.
    let mut core = vec![false; grid.pts.len()];
    let mut count: Vec<usize> = (0..n_cells).flat_map(|c| std::iter::repeat_n(cell_pts(c).len(), cell_pts(c).len())).collect();
    for reach in [1i64, 2] {
        let mut sweep = Sweep::new(reach);
        for c in 0..n_cells {
            let own = cell_pts(c);
            if own.len() >= min_points {
                core[own].fill(true);
                continue;
            }
            if own.clone().all(|i| core[i]) {
                continue;
            }
            sweep.neighbours(&grid, c, &mut buf);
            let here = unpack(grid.keys[c]);
            for i in own {
                if count[i] >= min_points {
                    core[i] = true;
                    continue;
                }
                let p = &grid.pts[i];
                'cells: for &nb in &buf {
                    if nb == c || (reach == 2 && within_one(here, grid.keys[nb])) {
                        continue;
                    }
                    for q in &grid.pts[cell_pts(nb)] {
                        if dist2(p, q) <= eps2 {
                            count[i] += 1;
                            if count[i] >= min_points {
                                break 'cells;
                            }
                        }
                    }
                }
                core[i] = count[i] >= min_points;
            }
        }
    }
    // Core points of each cell, contiguous (cells are small unless dense, and dense cells are
    // all core, so this is cheap).
    let mut core_pts: Vec<u32> = Vec::new();
    let mut core_starts = Vec::with_capacity(n_cells + 1);
    for c in 0..n_cells {
        core_starts.push(core_pts.len());
        core_pts.extend(cell_pts(c).filter(|&i| core[i]).map(|i| i as u32));
    }
    core_starts.push(core_pts.len());
    let cores_of = |c: usize| &core_pts[core_starts[c]..core_starts[c + 1]];

    // 2. Clusters: union cells with a pair of core points within eps. Near cells first.
    let linked = |a: usize, b: usize| {
        cores_of(a).iter().any(|&i| {
            let p = &grid.pts[i as usize];
            cores_of(b).iter().any(|&j| dist2(p, &grid.pts[j as usize]) <= eps2)
        })
    };
    let mut sets = Sets((0..n_cells as u32).collect());
    for reach in [1i64, 2] {
        let mut sweep = Sweep::new(reach);
        for c in 0..n_cells {
            if cores_of(c).is_empty() {
                continue;
            }
            sweep.neighbours(&grid, c, &mut buf);
            let here = unpack(grid.keys[c]);
            for &nb in &buf {
                if nb <= c || cores_of(nb).is_empty() {
                    continue;
                }
                if reach == 2 && within_one(here, grid.keys[nb]) {
                    continue; // done in the reach-1 pass
                }
                let (ra, rb) = (sets.find(c), sets.find(nb));
                if ra != rb && linked(c, nb) {
                    let (lo, hi) = (ra.min(rb), ra.max(rb));
                    sets.0[hi] = lo as u32;
                }
            }
        }
    }

    // 3. Number clusters by their first core point in input order.
    let mut labels = vec![NOISE; grid.pts.len()];
    let mut cell_of = vec![0u32; grid.pts.len()];
    for c in 0..n_cells {
        cell_of[cell_pts(c)].fill(c as u32);
    }
    let mut sorted_pos = vec![0u32; grid.pts.len()];
    for (s, &i) in grid.order.iter().enumerate() {
        sorted_pos[i as usize] = s as u32;
    }
    let mut root_label = vec![UNSET; n_cells];
    let mut next = 0i32;
    for &s in &sorted_pos {
        let s = s as usize;
        if !core[s] {
            continue;
        }
        let root = sets.find(cell_of[s] as usize);
        if root_label[root] == UNSET {
            root_label[root] = next;
            next += 1;
        }
        labels[s] = root_label[root];
    }
    let mut cell_label = vec![UNSET; n_cells];
    for (c, l) in cell_label.iter_mut().enumerate() {
        if !cores_of(c).is_empty() {
            *l = root_label[sets.find(c)];
        }
    }

    // 4. Border points: smallest label among core neighbours (scikit-learn's expansion order).
    let mut sweep = Sweep::new(2);
    for c in 0..n_cells {
        let own = cell_pts(c);
        if own.clone().all(|i| core[i]) {
            continue;
        }
        sweep.neighbours(&grid, c, &mut buf);
        for i in own {
            if core[i] {
                continue;
            }
            let p = &grid.pts[i];
            let mut best = cell_label[c]; // UNSET when the cell has no core point
            for &nb in &buf {
                if cell_label[nb] < best
                    && nb != c
                    && cores_of(nb).iter().any(|&j| dist2(p, &grid.pts[j as usize]) <= eps2)
                {
                    best = cell_label[nb];
                }
            }
            if best != UNSET {
                labels[i] = best;
            }
        }
    }

    let mut out = vec![NOISE; labels.len()];
    let mut core_out = vec![false; labels.len()];
    for (s, &i) in grid.order.iter().enumerate() {
        out[i as usize] = labels[s];
        core_out[i as usize] = core[s];
    }
    Some(Clustering { labels: out, core: core_out })
}
