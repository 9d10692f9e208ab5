//! Read-only access to (N, 3) point clouds in any float layout.
//!
//! The [`PointCloud`] trait lets every kernel take a Rust slice or a strided
//! view of a numpy array (float32 or float64, contiguous or not) without a copy.

use std::ops::Range;

use crate::error::{invalid, Result};

/// A cloud of 3-D points, read one point at a time as f64 metres.
pub trait PointCloud {
    /// Number of points (rows).
    fn len(&self) -> usize;
    /// The `i`-th point. Out-of-range indices return `[NaN; 3]` instead of panicking.
    fn point(&self, i: usize) -> [f64; 3];
    /// True when the cloud holds no points.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Calls `f(i, point(i))` for every `i` in `range` (clamped to the cloud), in index
    /// order. Layouts that allow it override this with a straight slice walk (no
    /// per-point index arithmetic or bounds checks): the form hot loops should use.
    #[inline]
    fn for_each_point_in<F: FnMut(usize, [f64; 3])>(&self, range: Range<usize>, mut f: F) {
        for i in range.start..range.end.min(self.len()) {
            f(i, self.point(i));
        }
    }
    /// Calls `f(i, point(i))` for every point, in index order.
    #[inline]
    fn for_each_point<F: FnMut(usize, [f64; 3])>(&self, f: F) {
        self.for_each_point_in(0..self.len(), f);
    }
}

/// `range` clamped to `0..len` (empty when it starts past the end).
#[inline]
fn clamp(range: Range<usize>, len: usize) -> Range<usize> {
    let end = range.end.min(len);
    range.start.min(end)..end
}

const NAN3: [f64; 3] = [f64::NAN; 3];

impl PointCloud for [[f64; 3]] {
    #[inline]
    fn len(&self) -> usize {
        <[[f64; 3]]>::len(self)
    }
    #[inline]
    fn point(&self, i: usize) -> [f64; 3] {
        self.get(i).copied().unwrap_or(NAN3)
    }
    #[inline]
    fn for_each_point_in<F: FnMut(usize, [f64; 3])>(&self, range: Range<usize>, mut f: F) {
        let r = clamp(range, self.len());
        for (k, p) in self[r.clone()].iter().enumerate() {
            f(r.start + k, *p);
        }
    }
}

impl PointCloud for [[f32; 3]] {
    #[inline]
    fn len(&self) -> usize {
        <[[f32; 3]]>::len(self)
    }
    #[inline]
    fn point(&self, i: usize) -> [f64; 3] {
        self.get(i).map_or(NAN3, |p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])])
    }
    #[inline]
    fn for_each_point_in<F: FnMut(usize, [f64; 3])>(&self, range: Range<usize>, mut f: F) {
        let r = clamp(range, self.len());
        for (k, p) in self[r.clone()].iter().enumerate() {
            f(r.start + k, [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])]);
        }
    }
}

impl PointCloud for Vec<[f64; 3]> {
    #[inline]
    fn len(&self) -> usize {
        self.as_slice().len()
    }
    #[inline]
    fn point(&self, i: usize) -> [f64; 3] {
        self.as_slice().point(i)
    }
    #[inline]
    fn for_each_point_in<F: FnMut(usize, [f64; 3])>(&self, range: Range<usize>, f: F) {
        self.as_slice().for_each_point_in(range, f)
    }
}

impl<P: PointCloud + ?Sized> PointCloud for &P {
    #[inline]
    fn len(&self) -> usize {
        (**self).len()
    }
    #[inline]
    fn point(&self, i: usize) -> [f64; 3] {
        (**self).point(i)
    }
    #[inline]
    fn for_each_point_in<F: FnMut(usize, [f64; 3])>(&self, range: Range<usize>, f: F) {
        (**self).for_each_point_in(range, f)
    }
}

/// A strided (rows, 3) view into a flat slice of `f32` or `f64`.
///
/// Element (i, j) lives at `offset + i * row_stride + j * col_stride` (strides in
/// elements, may be negative, as numpy allows). The constructor proves every
/// element index of every row lies inside `data`, so [`PointCloud::point`] never panics.
#[derive(Debug, Clone, Copy)]
pub struct StridedPoints<'a, T> {
    data: &'a [T],
    rows: usize,
    row_stride: isize,
    col_stride: isize,
    offset: usize,
}

impl<'a, T: Copy + Into<f64>> StridedPoints<'a, T> {
    /// Wraps `data` as a (rows, 3) array; errors (naming `points`) if any element would fall
    /// outside `data`.
    pub fn new(data: &'a [T], rows: usize, row_stride: isize, col_stride: isize, offset: usize) -> Result<Self> {
        if rows > 0 {
            // Extreme element indices over i in {0, rows-1}, j in {0, 2}; i128 cannot overflow here.
            let base = offset as i128;
            let last_row = (rows as i128 - 1) * row_stride as i128;
            let last_col = 2 * col_stride as i128;
            let corners = [base, base + last_row, base + last_col, base + last_row + last_col];
            let lo = corners.iter().copied().min().unwrap_or(base);
            let hi = corners.iter().copied().max().unwrap_or(base);
            if lo < 0 || hi >= data.len() as i128 {
                return Err(invalid(
                    "points",
                    format!(
                        "strided view out of bounds: rows={rows}, row_stride={row_stride}, col_stride={col_stride}, \
                         offset={offset} needs element indices {lo}..={hi} but the buffer holds {} elements",
                        data.len()
                    ),
                ));
            }
        }
        Ok(Self { data, rows, row_stride, col_stride, offset })
    }

    #[inline]
    fn element(&self, i: usize, j: isize) -> f64 {
        // In range by construction for i < rows; `get` keeps it panic-free regardless.
        let idx = self.offset as isize + i as isize * self.row_stride + j * self.col_stride;
        usize::try_from(idx).ok().and_then(|k| self.data.get(k)).map_or(f64::NAN, |&v| v.into())
    }
}

impl<T: Copy + Into<f64>> PointCloud for StridedPoints<'_, T> {
    #[inline]
    fn len(&self) -> usize {
        self.rows
    }
    #[inline]
    fn point(&self, i: usize) -> [f64; 3] {
        if i >= self.rows {
            return NAN3;
        }
        [self.element(i, 0), self.element(i, 1), self.element(i, 2)]
    }
    #[inline]
    fn for_each_point_in<F: FnMut(usize, [f64; 3])>(&self, range: Range<usize>, mut f: F) {
        let r = clamp(range, self.rows);
        // C-contiguous (N, 3), the usual numpy layout: walk the rows as a plain slice.
        if self.row_stride == 3 && self.col_stride == 1 {
            let start = self.offset.saturating_add(r.start.saturating_mul(3));
            if let Some(rows) = self.data.get(start..start.saturating_add(r.len().saturating_mul(3))) {
                for (k, p) in rows.chunks_exact(3).enumerate() {
                    f(r.start + k, [p[0].into(), p[1].into(), p[2].into()]);
                }
                return;
            }
        }
        for i in r {
            f(i, [self.element(i, 0), self.element(i, 1), self.element(i, 2)]);
        }
    }
}

/// True when all three coordinates are finite.
#[inline]
pub fn is_finite_point(p: &[f64; 3]) -> bool {
    p[0].is_finite() && p[1].is_finite() && p[2].is_finite()
}

/// The finite points of a cloud, copied out, with their original indices.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FinitePoints {
    /// Finite points in input order.
    pub coords: Vec<[f64; 3]>,
    /// `indices[k]` is the input index of `coords[k]`.
    pub indices: Vec<usize>,
    /// Number of points skipped because a coordinate was NaN or infinite.
    pub n_nonfinite: usize,
}

/// Copies the finite points of `points` (one pass), counting the skipped ones.
pub fn collect_finite<P: PointCloud + ?Sized>(points: &P) -> FinitePoints {
    let n = points.len();
    let mut out = FinitePoints { coords: Vec::with_capacity(n), indices: Vec::with_capacity(n), n_nonfinite: 0 };
    // The layout's own walk (no per-point index arithmetic or bounds checks on strided views).
    points.for_each_point(|i, p| {
        if is_finite_point(&p) {
            out.coords.push(p);
            out.indices.push(i);
        } else {
            out.n_nonfinite += 1;
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn slices_and_vecs_read_back() {
        let v: Vec<[f64; 3]> = vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]];
        assert_eq!(PointCloud::len(&v), 2);
        assert_eq!(v.point(1), [4.0, 5.0, 6.0]);
        assert!(v.point(2)[0].is_nan());
        let f: [[f32; 3]; 1] = [[0.5, 1.5, -2.0]];
        assert_eq!(f[..].point(0), [0.5, 1.5, -2.0]);
        let empty: &[[f64; 3]] = &[];
        assert!(PointCloud::is_empty(empty));
    }

    #[test]
    fn strided_contiguous_transposed_and_negative() {
        let data: Vec<f64> = (0..12).map(f64::from).collect();
        // C-contiguous (4, 3).
        let c = StridedPoints::new(&data, 4, 3, 1, 0).unwrap();
        assert_eq!(c.point(2), [6.0, 7.0, 8.0]);
        // Fortran order (4, 3): element (i, j) at i + 4 j.
        let f = StridedPoints::new(&data, 4, 1, 4, 0).unwrap();
        assert_eq!(f.point(1), [1.0, 5.0, 9.0]);
        // Reversed rows (numpy a[::-1]): offset at the last row, negative row stride.
        let r = StridedPoints::new(&data, 4, -3, 1, 9).unwrap();
        assert_eq!(r.point(0), [9.0, 10.0, 11.0]);
        assert_eq!(r.point(3), [0.0, 1.0, 2.0]);
        // Every other row.
        let s = StridedPoints::new(&data, 2, 6, 1, 0).unwrap();
        assert_eq!(s.point(1), [6.0, 7.0, 8.0]);
        assert!(s.point(2)[0].is_nan());
        let data32: Vec<f32> = vec![1.0, 2.0, 3.0];
        assert_eq!(StridedPoints::new(&data32, 1, 3, 1, 0).unwrap().point(0), [1.0, 2.0, 3.0]);
        // The bulk walk (contiguous fast path and strided fallback) visits the same points.
        let c_off = StridedPoints::new(&data, 3, 3, 1, 3).unwrap();
        for view in [c, f, r, s, c_off] {
            assert_eq!(walk(&view), (0..view.len()).map(|i| (i, view.point(i))).collect::<Vec<_>>());
            check_ranges(&view);
        }
        let v: Vec<[f64; 3]> = vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]];
        assert_eq!(walk(&v), vec![(0, v[0]), (1, v[1])]);
        let v32: [[f32; 3]; 2] = [[0.5, 1.5, -2.0], [f32::MAX, 0.0, 1.0]];
        assert_eq!(walk(&v32[..]), vec![(0, v32[..].point(0)), (1, v32[..].point(1))]);
        check_ranges(&v);
        check_ranges(&v32[..]);
    }

    /// Sub-range walks (the parallel chunks' form) visit `range` clamped to the cloud, never
    /// panicking.
    fn check_ranges<P: PointCloud + ?Sized>(p: &P) {
        for (lo, hi) in [(1, 3), (0, 0), (2, 100), (7, 9), (3, 1)] {
            let mut got = Vec::new();
            p.for_each_point_in(lo..hi, |i, q| got.push((i, q)));
            let want: Vec<_> = (lo..hi.min(p.len())).map(|i| (i, p.point(i))).collect();
            assert_eq!(got, want, "range {lo}..{hi}");
        }
    }

    fn walk<P: PointCloud + ?Sized>(p: &P) -> Vec<(usize, [f64; 3])> {
        let mut out = Vec::new();
        p.for_each_point(|i, q| out.push((i, q)));
        out
    }

    #[test]
    fn strided_rejects_out_of_bounds() {
        let data = [0.0f64; 9];
        assert!(StridedPoints::new(&data, 4, 3, 1, 0).is_err());
        assert!(StridedPoints::new(&data, 3, 3, 1, 1).is_err());
        assert!(StridedPoints::new(&data, 3, -3, 1, 0).is_err());
        assert!(StridedPoints::new(&data, 1, 3, 5, 0).is_err());
        assert!(StridedPoints::new(&data, 1, 3, 4, 0).is_ok());
        assert!(StridedPoints::new(&data, 2, isize::MAX, 1, 0).is_err());
        assert!(StridedPoints::new(&data, usize::MAX, 3, 1, 0).is_err());
        let err = StridedPoints::new(&data, 4, 3, 1, 0).unwrap_err();
        assert!(err.to_string().starts_with("points:"));
        // Zero rows is a valid empty view whatever the strides.
        assert_eq!(StridedPoints::new(&data[..0], 0, 3, 1, 0).unwrap().len(), 0);
    }

    #[test]
    fn collect_finite_skips_and_counts() {
        let v = vec![[0.0, 0.0, 0.0], [f64::NAN, 0.0, 0.0], [1.0, f64::INFINITY, 0.0], [2.0, 2.0, 2.0]];
        let f = collect_finite(&v);
        assert_eq!(f.coords, vec![[0.0, 0.0, 0.0], [2.0, 2.0, 2.0]]);
        assert_eq!(f.indices, vec![0, 3]);
        assert_eq!(f.n_nonfinite, 2);
    }

    proptest! {
        /// Any (len, rows, strides, offset): the constructor either accepts and then every
        /// element read matches a checked reference, or rejects; it never panics.
        #[test]
        fn strided_never_panics(len in 0usize..64, rows in 0usize..40, rs in -20isize..20,
                                cs in -20isize..20, offset in 0usize..70) {
            let data: Vec<f32> = (0..len).map(|k| k as f32).collect();
            match StridedPoints::new(&data, rows, rs, cs, offset) {
                Ok(view) => {
                    for i in 0..rows {
                        let p = view.point(i);
                        for (j, &value) in p.iter().enumerate() {
                            let idx = offset as isize + i as isize * rs + j as isize * cs;
                            prop_assert!(idx >= 0 && (idx as usize) < len);
                            prop_assert_eq!(value, idx as f64);
                        }
                    }
                    prop_assert!(view.point(rows).iter().all(|x| x.is_nan()));
                }
                Err(_) => {
                    // Rejected: some element of some row really is out of bounds.
                    let oob = (0..rows).any(|i| (0..3).any(|j| {
                        let idx = offset as isize + i as isize * rs + j as isize * cs;
                        idx < 0 || idx as usize >= len
                    }));
                    prop_assert!(oob);
                }
            }
        }
    }
}
