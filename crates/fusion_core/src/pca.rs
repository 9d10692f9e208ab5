//! Principal component analysis of a 3-D point set (mean, covariance eigen-decomposition).

use nalgebra::{Matrix3, SymmetricEigen};

use crate::error::{invalid, Result};
use crate::points::{collect_finite, PointCloud};

/// Convergence limit for the symmetric eigen-solver (a 3x3 converges in a handful).
const EIGEN_MAX_ITERATIONS: usize = 1000;

/// Mean and principal axes of a point set.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pca {
    /// Centroid (metres, frame of the input).
    pub mean: [f64; 3],
    /// Covariance eigenvalues (m^2, divisor N-1 like `np.cov`), descending.
    pub eigenvalues: [f64; 3],
    /// `eigenvectors[k]` is the unit eigenvector of `eigenvalues[k]`, sign canonical
    /// (largest-|component| positive, see [`canonical_sign`]).
    pub eigenvectors: [[f64; 3]; 3],
    /// Number of finite points used.
    pub n_points: usize,
}

impl Pca {
    /// The principal (largest-variance) axis.
    pub fn axis(&self) -> [f64; 3] {
        self.eigenvectors[0]
    }
}

/// Flips `v` so that its largest-magnitude component is positive (first one on ties).
pub fn canonical_sign(v: [f64; 3]) -> [f64; 3] {
    let mut k = 0;
    for j in 1..3 {
        if v[j].abs() > v[k].abs() {
            k = j;
        }
    }
    if v[k] < 0.0 {
        [-v[0], -v[1], -v[2]]
    } else {
        v
    }
}

/// PCA of the finite points of `points` (non-finite ones skipped). Needs >= 2 finite points.
pub fn pca<P: PointCloud + ?Sized>(points: &P) -> Result<Pca> {
    let finite = collect_finite(points);
    pca_of(finite.coords.iter().copied())
}

/// PCA of finite points given by a re-iterable iterator (two passes: mean, then covariance).
pub(crate) fn pca_of<I>(points: I) -> Result<Pca>
where
    I: Iterator<Item = [f64; 3]> + Clone,
{
    let mut n = 0usize;
    let mut sum = [0.0f64; 3];
    for p in points.clone() {
        n += 1;
        for k in 0..3 {
            sum[k] += p[k];
        }
    }
    if n < 2 {
        return Err(invalid("points", format!("PCA needs at least 2 finite points, got {n}")));
    }
    let nf = n as f64;
    let mean = [sum[0] / nf, sum[1] / nf, sum[2] / nf];
    let mut cov = Matrix3::<f64>::zeros();
    for p in points {
        let d = [p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]];
        for r in 0..3 {
            for c in r..3 {
                cov[(r, c)] += d[r] * d[c];
            }
        }
    }
    for r in 0..3 {
        for c in r..3 {
            cov[(r, c)] /= nf - 1.0;
            cov[(c, r)] = cov[(r, c)];
        }
    }
    if cov.iter().any(|v| !v.is_finite()) {
        return Err(invalid("points", "coordinates too large: covariance overflows"));
    }
    let eig = SymmetricEigen::try_new(cov, f64::EPSILON, EIGEN_MAX_ITERATIONS)
        .ok_or_else(|| invalid("points", "eigen-decomposition did not converge"))?;
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let mut eigenvalues = [0.0; 3];
    let mut eigenvectors = [[0.0; 3]; 3];
    for (slot, &k) in order.iter().enumerate() {
        eigenvalues[slot] = eig.eigenvalues[k];
        let col = eig.eigenvectors.column(k);
        let norm = col.norm();
        eigenvectors[slot] = canonical_sign([col[0] / norm, col[1] / norm, col[2] / norm]);
    }
    Ok(Pca { mean, eigenvalues, eigenvectors, n_points: n })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn line_along_known_axis() {
        // Points t * (1, 2, 2)/3 for t = -2..2 plus a tiny perpendicular wobble.
        let d = [1.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0];
        let pts: Vec<[f64; 3]> = (-20..=20)
            .map(|k| {
                let t = f64::from(k) * 0.1;
                let w = if k % 2 == 0 { 1e-3 } else { -1e-3 };
                [1.0 + t * d[0] + w, -1.0 + t * d[1], 3.0 + t * d[2]]
            })
            .collect();
        let p = pca(&pts).unwrap();
        let a = p.axis();
        let dot = a[0] * d[0] + a[1] * d[1] + a[2] * d[2];
        assert!(dot > 1.0 - 1e-6, "axis {a:?}");
        assert!(p.eigenvalues[0] > p.eigenvalues[1] && p.eigenvalues[1] >= p.eigenvalues[2]);
        // The +-1e-3 wobble has 21 "+" and 20 "-" terms: mean x = 1 + 1e-3 / 41.
        assert!((p.mean[0] - (1.0 + 1e-3 / 41.0)).abs() < 1e-12 && (p.mean[1] + 1.0).abs() < 1e-12);
        // Variance of t = -2..2 step 0.1 (41 values, N-1): sum t^2 / 40 = 2 * 0.01 * 2870 / 40 = 1.435.
        assert!((p.eigenvalues[0] - 1.435).abs() < 1e-5);
        assert_eq!(p.n_points, 41);
    }

    #[test]
    fn hand_computed_covariance() {
        // x in {0, 2}, y = z = 0: var_x (N-1) = 2; other eigenvalues 0.
        let p = pca(&vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [f64::NAN, 1.0, 1.0]]).unwrap();
        assert!((p.eigenvalues[0] - 2.0).abs() < 1e-12);
        assert_eq!(p.eigenvectors[0], [1.0, 0.0, 0.0]);
        assert_eq!(p.mean, [1.0, 0.0, 0.0]);
        assert_eq!(p.n_points, 2);
    }

    #[test]
    fn too_few_points() {
        assert!(pca(&vec![[0.0; 3]]).is_err());
        assert!(pca(&vec![[0.0; 3], [f64::NAN; 3]]).is_err());
        assert!(pca(&vec![[1e300, 0.0, 0.0], [-1e300, 0.0, 0.0]]).is_err());
        // Identical points: zero variance, still a valid orthonormal basis.
        let p = pca(&vec![[1.0; 3]; 3]).unwrap();
        assert_eq!(p.eigenvalues, [0.0; 3]);
    }

    #[test]
    fn canonical_sign_flips() {
        assert_eq!(canonical_sign([0.1, -0.9, 0.2]), [-0.1, 0.9, -0.2]);
        assert_eq!(canonical_sign([0.1, 0.9, 0.2]), [0.1, 0.9, 0.2]);
    }

    proptest! {
        /// Eigenpairs satisfy C v = lambda v, are orthonormal and sorted descending.
        #[test]
        fn eigen_pairs_are_consistent(pts in prop::collection::vec(prop::array::uniform3(-10.0f64..10.0), 2..80)) {
            let p = pca(&pts).unwrap();
            let n = pts.len() as f64;
            let mut c = Matrix3::<f64>::zeros();
            for q in &pts {
                let d = nalgebra::Vector3::new(q[0] - p.mean[0], q[1] - p.mean[1], q[2] - p.mean[2]);
                c += d * d.transpose() / (n - 1.0);
            }
            for k in 0..3 {
                let v = nalgebra::Vector3::from(p.eigenvectors[k]);
                prop_assert!((c * v - v * p.eigenvalues[k]).norm() < 1e-8 * (1.0 + c.norm()));
                prop_assert!((v.norm() - 1.0).abs() < 1e-12);
                for j in 0..k {
                    prop_assert!(v.dot(&nalgebra::Vector3::from(p.eigenvectors[j])).abs() < 1e-8);
                }
            }
            prop_assert!(p.eigenvalues[0] >= p.eigenvalues[1] && p.eigenvalues[1] >= p.eigenvalues[2]);
        }
    }
}
