//! The local shape round every point: the covariance of the points in the 3x3x3 block of
//! coarse cells round its cell (a cube of three cell sides), reduced to how
//! line-like it is and how thick across.
//!
//! WHY per cell and not per point: the block's moments are the sum of 27 cells' moments, so
//! the whole cloud costs one pass plus 27 additions per occupied cell, where a ball query per
//! point costs a thousand distance tests on a 500k-point tower. Every point of a cell shares
//! its cell's shape.

use super::cells::{CellMap, Cells};

/// Shape of the neighbourhood of one cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct LocalShape {
    /// Points in the block.
    pub count: usize,
    /// (l1 - l2) / l1 of the block's covariance eigenvalues l1 >= l2 >= l3: 1 on a line.
    pub linearity: f64,
    /// sqrt((l2 + l3) / 2), m: the spread across the block's main axis (a wire's is its
    /// radius plus range noise, a shed stack's about half its shed radius).
    pub spread: f64,
}

/// Count, first and second moments of a cell's points about the cell's own corner (small
/// numbers, so a cloud kilometres from its origin loses no precision in the covariance).
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    n: f64,
    s1: [f64; 3],
    s2: [[f64; 3]; 3],
}

impl Moments {
    fn add(&mut self, d: [f64; 3]) {
        self.n += 1.0;
        for r in 0..3 {
            self.s1[r] += d[r];
            for c in 0..3 {
                self.s2[r][c] += d[r] * d[c];
            }
        }
    }

    /// Adds `other`, whose moments are about a corner `delta` (m) from this one's.
    fn add_shifted(&mut self, other: &Moments, delta: [f64; 3]) {
        // sum (d + delta)(d + delta)^T = S2 + S1 delta^T + delta S1^T + n delta delta^T
        self.n += other.n;
        for r in 0..3 {
            self.s1[r] += other.s1[r] + other.n * delta[r];
            for c in 0..3 {
                self.s2[r][c] += other.s2[r][c]
                    + other.s1[r] * delta[c]
                    + delta[r] * other.s1[c]
                    + other.n * delta[r] * delta[c];
            }
        }
    }

    fn covariance(&self) -> [[f64; 3]; 3] {
        let mut cov = [[0.0; 3]; 3];
        let mean = [self.s1[0] / self.n, self.s1[1] / self.n, self.s1[2] / self.n];
        for r in 0..3 {
            for c in 0..3 {
                cov[r][c] = self.s2[r][c] / self.n - mean[r] * mean[c];
            }
        }
        cov
    }
}

/// Eigenvalues of a symmetric 3x3, descending (closed form, Smith 1961): a million of these
/// must cost less than the iterative solver's setup.
pub(super) fn symmetric_eigenvalues(a: &[[f64; 3]; 3]) -> [f64; 3] {
    let p1 = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    let mut e = if p1 <= 0.0 {
        [a[0][0], a[1][1], a[2][2]]
    } else {
        let q = (a[0][0] + a[1][1] + a[2][2]) / 3.0;
        let p2 = (a[0][0] - q).powi(2) + (a[1][1] - q).powi(2) + (a[2][2] - q).powi(2) + 2.0 * p1;
        let p = (p2 / 6.0).sqrt();
        let b = |r: usize, c: usize| (a[r][c] - if r == c { q } else { 0.0 }) / p;
        let det = b(0, 0) * (b(1, 1) * b(2, 2) - b(1, 2) * b(2, 1)) - b(0, 1) * (b(1, 0) * b(2, 2) - b(1, 2) * b(2, 0))
            + b(0, 2) * (b(1, 0) * b(2, 1) - b(1, 1) * b(2, 0));
        let phi = (det / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
        let e1 = q + 2.0 * p * phi.cos();
        let e3 = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
        [e1, 3.0 * q - e1 - e3, e3]
    };
    e.sort_by(|x, y| y.total_cmp(x));
    e
}

/// The shape of every occupied cell of `cells` (over `points`, the coordinates it indexes).
pub(super) fn cell_shapes(points: &[[f64; 3]], cells: &Cells) -> CellMap<LocalShape> {
    let side = cells.side;
    let mut moments: CellMap<Moments> = CellMap::default();
    for (key, idx) in &cells.members {
        let corner = [key[0] as f64 * side, key[1] as f64 * side, key[2] as f64 * side];
        let m = moments.entry(*key).or_default();
        for &i in idx {
            let p = points[i as usize];
            m.add([p[0] - corner[0], p[1] - corner[1], p[2] - corner[2]]);
        }
    }
    let mut shapes: CellMap<LocalShape> = CellMap::default();
    shapes.reserve(moments.len());
    for key in moments.keys() {
        let mut block = Moments::default();
        for dx in -1..=1i64 {
            for dy in -1..=1i64 {
                for dz in -1..=1i64 {
                    if let Some(m) = moments.get(&[key[0] + dx, key[1] + dy, key[2] + dz]) {
                        block.add_shifted(m, [dx as f64 * side, dy as f64 * side, dz as f64 * side]);
                    }
                }
            }
        }
        let [l1, l2, l3] = symmetric_eigenvalues(&block.covariance()).map(|l| l.max(0.0));
        let linearity = if l1 > 0.0 { (l1 - l2) / l1 } else { 0.0 };
        shapes.insert(*key, LocalShape { count: block.n as usize, linearity, spread: (0.5 * (l2 + l3)).sqrt() });
    }
    shapes
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, SymmetricEigen};

    #[test]
    fn closed_form_eigenvalues_match_nalgebra() {
        let cases = [
            [[2.0, 0.3, -0.1], [0.3, 1.0, 0.2], [-0.1, 0.2, 0.5]],
            [[1.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 2.0]],
            [[1e-4, 1e-6, 0.0], [1e-6, 1e-4, 0.0], [0.0, 0.0, 0.09]],
            [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0]],
        ];
        for a in cases {
            let m = Matrix3::from_fn(|r, c| a[r][c]);
            let mut want: Vec<f64> = SymmetricEigen::new(m).eigenvalues.iter().copied().collect();
            want.sort_by(|x, y| y.total_cmp(x));
            let got = symmetric_eigenvalues(&a);
            for k in 0..3 {
                assert!((got[k] - want[k]).abs() < 1e-9 * (1.0 + want[0].abs()), "{a:?}: {got:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn a_thick_line_is_linear_and_its_spread_is_its_radius_over_root_two() {
        // A tube of radius 0.1 m along x, far from the origin (precision of the shifted moments).
        let mut pts = Vec::new();
        for i in 0..400 {
            let t = f64::from(i) * 0.005;
            let a = f64::from(i) * 2.399;
            pts.push([1e5 + t, 0.1 * a.cos(), 0.1 * a.sin()]);
        }
        let cells = Cells::new(&pts, 0.2);
        let shapes = cell_shapes(&pts, &cells);
        let mid = shapes[&super::super::cells::cell_of(&pts[200], 0.2)];
        assert!(mid.linearity > 0.8, "{mid:?}");
        assert!((mid.spread - 0.1 / 2f64.sqrt()).abs() < 0.01, "{mid:?}");
    }
}
