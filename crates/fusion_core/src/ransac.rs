//! Seeded RANSAC fit of a 3-D line with an adaptive iteration count and a least-squares refit.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::error::{check_positive, invalid, Result};
use crate::pca::pca_of;
use crate::points::{collect_finite, PointCloud};

/// Most least-squares refits of the winning hypothesis (each: PCA on inliers, recompute inliers).
const REFIT_ROUNDS: usize = 5;

/// Two samples closer than this (metres) do not define a line; the draw is skipped.
const MIN_SAMPLE_SEPARATION: f64 = 1e-9;

/// RANSAC settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RansacParams {
    /// Inlier distance to the line (metres, inclusive).
    pub threshold: f64,
    /// Hard cap on hypotheses drawn.
    pub max_iterations: usize,
    /// Stop once P(an all-inlier sample was drawn) = 1 - (1 - w^2)^k reaches this.
    pub confidence: f64,
    /// Seed of the Pcg64 generator: the same seed and input give the same fit.
    pub seed: u64,
}

impl Default for RansacParams {
    fn default() -> Self {
        Self { threshold: 0.05, max_iterations: 1000, confidence: 0.99, seed: 0 }
    }
}

impl RansacParams {
    /// Checks threshold > 0, max_iterations >= 1, 0 < confidence < 1, reporting the given names.
    pub(crate) fn validate_as(&self, threshold_name: &'static str, iterations_name: &'static str) -> Result<()> {
        check_positive(threshold_name, self.threshold)?;
        if self.max_iterations < 1 {
            return Err(invalid(iterations_name, "must be >= 1"));
        }
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return Err(invalid("confidence", format!("must be in (0, 1), got {}", self.confidence)));
        }
        Ok(())
    }
}

/// A fitted line.
#[derive(Debug, Clone, PartialEq)]
pub struct LineFit {
    /// Centroid of the inliers (on the line up to the inlier spread).
    pub point: [f64; 3],
    /// Unit direction, sign canonical (largest-|component| positive).
    pub direction: [f64; 3],
    /// Ascending input indices of the points within `threshold` of the refit line.
    pub inliers: Vec<usize>,
    /// Hypotheses drawn.
    pub iterations: usize,
}

/// Distance from `p` to the line through `a` with unit direction `d`.
#[inline]
pub(crate) fn line_distance(p: &[f64; 3], a: &[f64; 3], d: &[f64; 3]) -> f64 {
    let v = [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
    let c = [v[1] * d[2] - v[2] * d[1], v[2] * d[0] - v[0] * d[2], v[0] * d[1] - v[1] * d[0]];
    (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
}

/// Hypotheses needed so that 1 - (1 - w^2)^k >= confidence, for inlier ratio `w`.
fn required_iterations(w: f64, confidence: f64) -> f64 {
    let good = w * w;
    if good >= 1.0 {
        return 1.0;
    }
    if good <= 0.0 {
        return f64::INFINITY;
    }
    ((1.0 - confidence).ln() / (1.0 - good).ln()).ceil()
}

/// Fits a line to the finite points of `points` (non-finite ones skipped).
///
/// Draws pairs of distinct points with a seeded Pcg64, keeps the hypothesis with the most
/// inliers (distance <= threshold), stops once the adaptive bound or `max_iterations` is
/// reached, refits by PCA on the best inliers and recomputes the inliers against the refit
/// line (refit repeated until the inlier set is stable, at most 5 times). Needs >= 2
/// distinct finite points (else `InvalidArgument` naming `points`).
pub fn ransac_line<P: PointCloud + ?Sized>(points: &P, params: &RansacParams) -> Result<LineFit> {
    params.validate_as("threshold", "max_iterations")?;
    let finite = collect_finite(points);
    let mut fit = ransac_line_finite(&finite.coords, params)?;
    for i in &mut fit.inliers {
        *i = finite.indices[*i];
    }
    Ok(fit)
}

/// RANSAC on points known finite, params already validated; inliers index `coords`.
pub(crate) fn ransac_line_finite(coords: &[[f64; 3]], params: &RansacParams) -> Result<LineFit> {
    let n = coords.len();
    if n < 2 {
        return Err(invalid("points", format!("a line needs at least 2 finite points, got {n}")));
    }
    let first = coords[0];
    if coords.iter().all(|p| *p == first) {
        return Err(invalid("points", "a line needs at least 2 distinct points; all points coincide"));
    }
    let mut rng = Pcg64::seed_from_u64(params.seed);
    let mut best: Option<([f64; 3], [f64; 3], usize)> = None;
    let mut needed = f64::INFINITY;
    let mut iterations = 0usize;
    while iterations < params.max_iterations && (iterations as f64) < needed {
        iterations += 1;
        let i = rng.random_range(0..n);
        let mut j = rng.random_range(0..n - 1);
        if j >= i {
            j += 1;
        }
        let (a, b) = (coords[i], coords[j]);
        let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if len < MIN_SAMPLE_SEPARATION {
            continue;
        }
        let d = [d[0] / len, d[1] / len, d[2] / len];
        let count = coords.iter().filter(|p| line_distance(p, &a, &d) <= params.threshold).count();
        let better = match best {
            Some((_, _, c)) => count > c,
            None => true,
        };
        if better {
            best = Some((a, d, count));
            needed = required_iterations(count as f64 / n as f64, params.confidence);
        }
    }
    let Some((a, d, _)) = best else {
        // Only reachable when every draw hit coincident points (heavy duplication, tiny cap).
        return Err(invalid("points", format!("no two distinct points drawn in {iterations} iterations")));
    };
    let inliers_of = |a: &[f64; 3], d: &[f64; 3]| -> Vec<usize> {
        (0..n).filter(|&k| line_distance(&coords[k], a, d) <= params.threshold).collect()
    };
    // Least-squares refit: the principal axis through the centroid of the inliers, repeated
    // while the inlier set changes (at most REFIT_ROUNDS times) so the final line is the
    // least-squares line of (nearly) its own inliers rather than of a 2-point hypothesis.
    let mut inliers = inliers_of(&a, &d);
    let mut direction = d;
    for _ in 0..REFIT_ROUNDS {
        let refit = pca_of(inliers.iter().map(|&k| coords[k]))?;
        direction = refit.axis();
        let next = inliers_of(&refit.mean, &direction);
        if next.is_empty() || next == inliers {
            // An empty set cannot happen with a sane threshold; keep the previous one if it does.
            if !next.is_empty() {
                inliers = next;
            }
            break;
        }
        inliers = next;
    }
    let m = inliers.len() as f64;
    let mut point = [0.0; 3];
    for &k in &inliers {
        for c in 0..3 {
            point[c] += coords[k][c] / m;
        }
    }
    Ok(LineFit { point, direction, inliers, iterations })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use rand::Rng;

    fn noisy_line(n: usize, outliers: usize, seed: u64) -> Vec<[f64; 3]> {
        let mut rng = Pcg64::seed_from_u64(seed);
        let d = [0.6, 0.0, 0.8];
        let mut pts: Vec<[f64; 3]> = (0..n)
            .map(|_| {
                let t: f64 = rng.random_range(-1.0..1.0);
                let e = [rng.random_range(-0.01..0.01), rng.random_range(-0.01..0.01), rng.random_range(-0.01..0.01)];
                [5.0 + t * d[0] + e[0], 1.0 + t * d[1] + e[1], 2.0 + t * d[2] + e[2]]
            })
            .collect();
        for _ in 0..outliers {
            pts.push([rng.random_range(3.0..7.0), rng.random_range(-1.0..3.0), rng.random_range(0.0..4.0)]);
        }
        pts
    }

    #[test]
    fn recovers_line_with_outliers() {
        let pts = noisy_line(200, 100, 7);
        let fit = ransac_line(&pts, &RansacParams::default()).unwrap();
        let d = fit.direction;
        assert!((d[0] * 0.6 + d[2] * 0.8).abs() > 0.999, "direction {d:?}");
        assert!(line_distance(&fit.point, &[5.0, 1.0, 2.0], &[0.6, 0.0, 0.8]) < 0.01);
        assert!(fit.inliers.len() >= 200 && fit.inliers.len() < 215);
        assert!((0..200).all(|k| fit.inliers.binary_search(&k).is_ok()));
        // Adaptive: w ~ 2/3 needs ~8 draws at 0.99, far below the cap.
        assert!(fit.iterations < 60, "iterations {}", fit.iterations);
        // Inliers are exactly the points within threshold of the reported line.
        let want: Vec<usize> = (0..pts.len()).filter(|&k| line_distance(&pts[k], &fit.point, &d) <= 0.05).collect();
        let sym_diff = want.iter().filter(|k| fit.inliers.binary_search(k).is_err()).count();
        assert!(sym_diff <= 1, "inliers must be measured against the refit line");
    }

    #[test]
    fn deterministic_for_a_seed() {
        let pts = noisy_line(100, 150, 3);
        let p = RansacParams { seed: 42, ..RansacParams::default() };
        assert_eq!(ransac_line(&pts, &p).unwrap(), ransac_line(&pts, &p).unwrap());
    }

    #[test]
    fn iteration_cap_and_bound() {
        assert_eq!(required_iterations(1.0, 0.99), 1.0);
        // w = 0.5: ln(0.01)/ln(0.75) = 16.008 -> 17.
        assert_eq!(required_iterations(0.5, 0.99), 17.0);
        let pts = noisy_line(10, 300, 1);
        let fit = ransac_line(&pts, &RansacParams { max_iterations: 5, ..RansacParams::default() }).unwrap();
        assert_eq!(fit.iterations, 5);
    }

    #[test]
    fn bad_input() {
        let p = RansacParams::default();
        assert!(ransac_line(&vec![[0.0; 3]], &p).is_err());
        assert!(ransac_line(&vec![[1.0; 3]; 10], &p).is_err());
        assert!(ransac_line(&vec![[0.0; 3], [f64::NAN; 3]], &p).is_err());
        let two = vec![[0.0; 3], [1.0, 0.0, 0.0], [f64::NAN, 0.0, 0.0]];
        let fit = ransac_line(&two, &p).unwrap();
        assert_eq!(fit.inliers, vec![0, 1]);
        assert_eq!(fit.direction, [1.0, 0.0, 0.0]);
        let name = |q: RansacParams| match ransac_line(&two, &q) {
            Err(crate::FusionError::InvalidArgument { name, .. }) => name,
            _ => "ok",
        };
        assert_eq!(name(RansacParams { threshold: 0.0, ..p }), "threshold");
        assert_eq!(name(RansacParams { max_iterations: 0, ..p }), "max_iterations");
        assert_eq!(name(RansacParams { confidence: 1.0, ..p }), "confidence");
        assert_eq!(name(RansacParams { confidence: f64::NAN, ..p }), "confidence");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any cloud: either a clean error or a unit direction with consistent inliers.
        #[test]
        fn never_panics_and_is_consistent(pts in prop::collection::vec(prop::array::uniform3(-5.0f64..5.0), 0..60),
                                          seed in 0u64..1000, threshold in 0.001f64..2.0) {
            let p = RansacParams { threshold, seed, ..RansacParams::default() };
            if let Ok(fit) = ransac_line(&pts, &p) {
                let d = fit.direction;
                prop_assert!(((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 1.0).abs() < 1e-9);
                prop_assert!(!fit.inliers.is_empty());
                prop_assert!(fit.inliers.windows(2).all(|w| w[0] < w[1]));
                prop_assert!(fit.iterations >= 1 && fit.iterations <= p.max_iterations);
            } else {
                prop_assert!(pts.len() < 2 || pts.iter().all(|q| *q == pts[0]));
            }
        }
    }
}
