//! Integer cells over a cloud: the thinning voxels and the coarse cells whose moments give
//! every point's local shape. Keys are plain `[i64; 3]` cell coordinates in a hash map, so a
//! cloud of any extent (a stray return kilometres away included) costs only its occupied cells.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// A multiply-xor hasher for cell keys (three i64 words): the standard SipHash costs more than
/// the rest of the thinning pass, and keys come from our own arithmetic, not from an adversary.
#[derive(Default)]
pub(super) struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }
    #[inline]
    fn write_i64(&mut self, v: i64) {
        self.write_u64(v as u64);
    }
    #[inline]
    fn write_u64(&mut self, v: u64) {
        // FxHash's step: rotate, xor, multiply by a large odd constant.
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    #[inline]
    fn write_usize(&mut self, v: usize) {
        self.write_u64(v as u64);
    }
}

pub(super) type CellMap<V> = HashMap<[i64; 3], V, BuildHasherDefault<CellHasher>>;

/// The cell of side `side` holding `p` (coordinates already relative to the cloud's origin,
/// so they stay far inside i64).
#[inline]
pub(super) fn cell_of(p: &[f64; 3], side: f64) -> [i64; 3] {
    [(p[0] / side).floor() as i64, (p[1] / side).floor() as i64, (p[2] / side).floor() as i64]
}

/// One point per occupied voxel of side `voxel` (the first in input order), as coordinates
/// relative to `origin`.
///
/// WHY: an exploration leaves tens of returns per square centimetre where it flew close and a
/// few where it flew far; every later statistic (local shape, extents, shed spectrum) should
/// weigh the surface, not the dwell time.
pub(super) fn thin<F: FnMut(&mut dyn FnMut([f64; 3]))>(mut walk: F, origin: [f64; 3], voxel: f64) -> Vec<[f64; 3]> {
    let mut seen: CellMap<()> = CellMap::default();
    let mut kept = Vec::new();
    walk(&mut |p| {
        let local = [p[0] - origin[0], p[1] - origin[1], p[2] - origin[2]];
        if seen.insert(cell_of(&local, voxel), ()).is_none() {
            kept.push(local);
        }
    });
    kept
}

/// Points bucketed by coarse cells, for range queries.
pub(super) struct Cells {
    pub side: f64,
    /// Cell key -> indices of the points in it.
    pub members: CellMap<Vec<u32>>,
}

impl Cells {
    pub fn new(points: &[[f64; 3]], side: f64) -> Cells {
        let mut members: CellMap<Vec<u32>> = CellMap::default();
        for (i, p) in points.iter().enumerate() {
            // Indices fit u32: the caller caps clouds far below u32::MAX points.
            members.entry(cell_of(p, side)).or_default().push(i as u32);
        }
        Cells { side, members }
    }

    /// Calls `f(i)` for every point in the cells that the axis-aligned box `lo..hi` touches.
    pub fn for_each_in_box(&self, lo: [f64; 3], hi: [f64; 3], mut f: impl FnMut(usize)) {
        let a = cell_of(&lo, self.side);
        let b = cell_of(&hi, self.side);
        // A box spanning more cells than are occupied is walked by the occupied cells instead.
        let span = (0..3).map(|k| b[k].saturating_sub(a[k]).saturating_add(1).max(0) as u128).product::<u128>();
        if span > self.members.len() as u128 {
            for (key, idx) in &self.members {
                if (0..3).all(|k| key[k] >= a[k] && key[k] <= b[k]) {
                    idx.iter().for_each(|&i| f(i as usize));
                }
            }
            return;
        }
        for x in a[0]..=b[0] {
            for y in a[1]..=b[1] {
                for z in a[2]..=b[2] {
                    if let Some(idx) = self.members.get(&[x, y, z]) {
                        idx.iter().for_each(|&i| f(i as usize));
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thinning_keeps_one_point_per_voxel_in_input_order() {
        let pts = [[0.01, 0.01, 0.01], [0.02, 0.03, 0.01], [0.5, 0.0, 0.0], [-0.01, 0.0, 0.0]];
        let kept = thin(|f| pts.iter().for_each(|p| f(*p)), [0.0; 3], 0.04);
        assert_eq!(kept, vec![[0.01, 0.01, 0.01], [0.5, 0.0, 0.0], [-0.01, 0.0, 0.0]]);
    }

    #[test]
    fn box_query_visits_exactly_the_touched_cells() {
        let pts: Vec<[f64; 3]> = (0..100).map(|i| [f64::from(i) * 0.1, 0.0, 0.0]).collect();
        let cells = Cells::new(&pts, 0.15);
        let mut got = Vec::new();
        cells.for_each_in_box([1.0, -0.1, -0.1], [2.0, 0.1, 0.1], |i| got.push(i));
        got.sort_unstable();
        // Cells are whole: the query may return neighbours of the box, never miss a point in it.
        for i in 10..=20 {
            assert!(got.contains(&i), "{i} missing");
        }
        assert!(got.iter().all(|&i| (8..=22).contains(&i)));
        // A huge box (more cells than occupied) falls back to the occupied cells.
        let mut all = 0;
        cells.for_each_in_box([-1e6; 3], [1e6; 3], |_| all += 1);
        assert_eq!(all, 100);
    }
}
