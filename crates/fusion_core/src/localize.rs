//! The paper's four insulator localization methods on a box-culled, accumulated cloud.
//!
//! Input points are in the body frame B with the UAV at the origin, so "the nearest
//! cluster" is the cluster whose centroid is nearest the origin. Each method returns the
//! insulator centre and its unit axis.
//!
//! "median(projection(S, line))" (Algorithms 1 and 2) is implemented as the point on the
//! line at the median of the scalar projections `t_k = d . (p_k - a)` of the points of S
//! (numpy's median: mean of the two middle values for an even count). Taking the median
//! along the axis makes the centre robust to tower members and conductor stubs at one end.

use std::str::FromStr;

// The fifth method is a child of this module: it reads the shared line fit and parameters, and
// the one entry point below dispatches to it.
pub mod bounded;

use bounded::BoxEvidence;
use crate::dbscan::{dbscan_finite, NOISE};
use crate::error::{check_positive, invalid, FusionError, Result};
use crate::pca::{canonical_sign, pca_of};
use crate::points::{collect_finite, PointCloud};
use crate::ransac::{line_distance, ransac_line_finite, RansacParams};

// Defaults for a Livox Mid-360 at 8-10 m from the insulator, 3 accumulated detection frames.
// The Mid-360 gives ~200k points/s over 360 x 59 deg, i.e. roughly 1 point/deg^2 per 0.1 s
// frame; at 9 m one degree spans ~0.16 m, so a 2 m x 0.25 m insulator (~12.7 x 1.6 deg) holds
// ~20 points a frame and ~60 after 3 frames, spaced ~0.1 m with non-repetitive gaps of up to
// ~0.2 m. Range noise is ~2 cm (1 sigma).

/// DBSCAN radius (m). In the simulated study (`insulator-rs eval localization`,
/// docs/results/localization/README.md) neighbouring Mid-360 returns on an insulator at
/// 9-10 m are 0.16-0.21 m apart over 3 frames, and the strip is only ~1-2 returns wide, so
/// a core point's 4 nearest neighbours lie up to ~2 spacings (0.32-0.42 m) along the axis:
/// eps 0.3 split the insulator there and the nearest piece pulled the centre along the axis
/// (DBSCAN+RANSAC 0.60 m at 10 m). 0.5 m (~2.5 spacings) keeps it whole (0.32 m); 0.6-0.7 m
/// gains DBSCAN+RANSAC a few cm at 10 m but merges steel or conductor into the nearest
/// cluster at 8 m (DBSCAN axis error 1.5 -> 6.5 -> 10 deg), and 0.5 m stays within the
/// usual >= 0.5 m clearance between an insulator and the lattice members behind it.
pub const DEFAULT_EPS: f64 = 0.5;
/// DBSCAN core size (points, itself included): an insulator gives ~60 points, isolated
/// returns from rain, birds or edge effects rarely gather 5 within eps. The study's
/// failures at this value are clouds of 4-21 points that hold almost no target returns
/// (the insulator was hidden), where refusing is the right answer.
pub const DEFAULT_MIN_POINTS: usize = 5;
/// Line distance tau (m) for "points that belong to the insulator": the shed radius is
/// 0.10-0.15 m and the fitted line runs through the visible half of the surface, so
/// surface returns lie within ~1.3 r (<= 0.19 m incl. 2 cm noise) of it; 0.2 m keeps them
/// and drops most of a lattice member that crosses the insulator's end at an angle.
pub const DEFAULT_TAU: f64 = 0.2;
/// RANSAC inlier distance (m) inside localization: about one shed radius, so a hypothesis
/// along the insulator collects its visible surface strip (radius + 2 sigma noise ~ 0.14 m
/// from the axis seen edge-on) while a crossing member or conductor only contributes where
/// it touches the line.
pub const DEFAULT_RANSAC_THRESHOLD: f64 = 0.1;
/// RANSAC cap (hypotheses): with >= 30 % inliers the adaptive bound stops near 50 draws.
pub const DEFAULT_MAX_ITERATIONS: usize = 1000;
/// RANSAC confidence of having drawn one all-inlier pair.
pub const DEFAULT_CONFIDENCE: f64 = 0.99;

/// A localization method: the paper's four, on the cloud alone, and the bounded fifth, whose
/// line is the LiDAR's and whose ends are the camera's (it needs the detection boxes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Method {
    /// Nearest DBSCAN cluster: centroid and PCA axis.
    Dbscan,
    /// RANSAC line on the whole cloud; centre = median projection of points within tau.
    Ransac,
    /// Paper Algorithm 1.
    DbscanRansac,
    /// Paper Algorithm 2.
    DbscanPca,
    /// Algorithm 1's line, its ends from the detection boxes ([`bounded`]).
    Bounded,
}

/// Parameters of the line fit, by their Python keyword names.
const DBSCAN_PARAMETERS: [&str; 2] = ["eps", "min_points"];
const RANSAC_PARAMETERS: [&str; 4] = ["ransac_threshold", "max_iterations", "confidence", "seed"];

impl Method {
    /// All methods: the paper's four in its order, then the bounded one.
    pub const ALL: [Method; 5] = [Method::Dbscan, Method::Ransac, Method::DbscanRansac, Method::DbscanPca, Method::Bounded];
    /// The paper's four: the methods that read the cloud alone (no detection boxes).
    pub const PAPER: [Method; 4] = [Method::Dbscan, Method::Ransac, Method::DbscanRansac, Method::DbscanPca];

    /// The method's name as Python passes it.
    pub fn as_str(&self) -> &'static str {
        match self {
            Method::Dbscan => "dbscan",
            Method::Ransac => "ransac",
            Method::DbscanRansac => "dbscan+ransac",
            Method::DbscanPca => "dbscan+pca",
            Method::Bounded => "bounded",
        }
    }

    /// Whether the method reads detection boxes ([`BoxEvidence`]).
    pub fn needs_boxes(&self) -> bool {
        matches!(self, Method::Bounded)
    }

    /// The tuning parameters the method reads, by their Python keyword names (the fields of
    /// [`LocalizeParams`] and, for the bounded method, of [`BoxEvidence`]). A parameter not
    /// listed has no effect on the method's result; every listed one can change it (tested).
    pub fn parameters(&self) -> Vec<&'static str> {
        let mut names: Vec<&'static str> = Vec::new();
        match self {
            Method::Dbscan => names.extend(DBSCAN_PARAMETERS),
            Method::Ransac => {
                names.push("tau");
                names.extend(RANSAC_PARAMETERS);
            }
            Method::DbscanRansac | Method::Bounded => {
                names.extend(DBSCAN_PARAMETERS);
                names.push("tau");
                names.extend(RANSAC_PARAMETERS);
            }
            Method::DbscanPca => {
                names.extend(DBSCAN_PARAMETERS);
                names.push("tau");
            }
        }
        if self.needs_boxes() {
            names.extend(bounded::BOX_PARAMETERS);
        }
        names
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Method {
    type Err = FusionError;
    fn from_str(s: &str) -> Result<Self> {
        Method::ALL.into_iter().find(|m| m.as_str() == s).ok_or_else(|| {
            let names: Vec<String> = Method::ALL.iter().map(|m| format!("{:?}", m.as_str())).collect();
            invalid("method", format!("unknown method {s:?}; expected one of {}", names.join(", ")))
        })
    }
}

/// Tuning of the localization methods (see the `DEFAULT_*` constants for the reasoning).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalizeParams {
    /// DBSCAN radius (m).
    pub eps: f64,
    /// DBSCAN core size (points, itself included).
    pub min_points: usize,
    /// Distance to the line (m) within which points count as the insulator.
    pub tau: f64,
    /// RANSAC settings (threshold in m).
    pub ransac: RansacParams,
}

impl Default for LocalizeParams {
    fn default() -> Self {
        Self {
            eps: DEFAULT_EPS,
            min_points: DEFAULT_MIN_POINTS,
            tau: DEFAULT_TAU,
            ransac: RansacParams {
                threshold: DEFAULT_RANSAC_THRESHOLD,
                max_iterations: DEFAULT_MAX_ITERATIONS,
                confidence: DEFAULT_CONFIDENCE,
                seed: 0,
            },
        }
    }
}

impl LocalizeParams {
    /// Validates every field, naming it as the Python keyword argument.
    pub fn validate(&self) -> Result<()> {
        check_positive("eps", self.eps)?;
        if self.min_points < 1 {
            return Err(invalid("min_points", "must be >= 1"));
        }
        check_positive("tau", self.tau)?;
        self.ransac.validate_as("ransac_threshold", "max_iterations")
    }
}

/// A localized insulator, whichever method found it.
#[derive(Debug, Clone, PartialEq)]
pub struct Localization {
    /// The method that found it.
    pub method: Method,
    /// Insulator centre (m, frame B).
    pub center: [f64; 3],
    /// Unit axis, sign canonical (largest-|component| positive).
    pub direction: [f64; 3],
    /// Points that determined the centre.
    pub n_points: usize,
    /// Clusters found by the first DBSCAN (1 for `Ransac`: its inlier set).
    pub n_clusters: usize,
    /// Input points skipped because a coordinate was NaN or infinite.
    pub n_nonfinite: usize,
    /// The bounded method: how many ends of the insulator the boxes bounded, 2 (centre from
    /// the image), 1 (one end plus half the known length; without a length, Algorithm 1's
    /// centre) or 0. Always 0 for the paper's four.
    pub ends_from_image: usize,
    /// The bounded method: extent (m) between the two image bounds when both ends were bounded.
    pub length: Option<f64>,
    /// The bounded method: views whose box the line passed through (0 for the paper's four).
    pub views_used: usize,
}

impl Localization {
    /// A result of the cloud alone (the image fields empty; `method` and `n_nonfinite` are
    /// filled in by [`localize`]).
    pub(crate) fn from_cloud(center: [f64; 3], direction: [f64; 3], n_points: usize, n_clusters: usize) -> Self {
        Self {
            method: Method::DbscanRansac,
            center,
            direction,
            n_points,
            n_clusters,
            n_nonfinite: 0,
            ends_from_image: 0,
            length: None,
            views_used: 0,
        }
    }
}

/// Localizes the insulator in a B-frame cloud with the given method; `boxes` are the
/// detection boxes the bounded method reads (and only it: the paper's four refuse them, so a
/// caller never believes they were used).
///
/// Errors: `InvalidArgument` for bad parameters, for boxes missing (bounded) or given
/// (the paper's four); `NoInsulator` when nothing usable remains (no cluster, fewer than 2
/// points, RANSAC finds no line); `Ambiguous` when the bounded method, given the
/// insulator's length, finds another line in the box that it cannot tell from the one fitted
/// ([`bounded::ambiguity`]).
pub fn localize<P: PointCloud + ?Sized>(
    points: &P,
    method: Method,
    params: &LocalizeParams,
    boxes: Option<&BoxEvidence<'_>>,
) -> Result<Localization> {
    params.validate()?;
    let boxes = match (method.needs_boxes(), boxes) {
        (true, None) => return Err(invalid("boxes", format!("the {method} method needs the detection boxes"))),
        (false, Some(_)) => {
            return Err(invalid("boxes", format!("the {method} method reads the cloud alone, not detection boxes")))
        }
        (_, b) => b,
    };
    if let Some(b) = boxes {
        b.validate()?;
    }
    let finite = collect_finite(points);
    let coords = &finite.coords;
    if coords.len() < 2 {
        return Err(FusionError::NoInsulator(format!("{} finite points, need at least 2", coords.len())));
    }
    let mut loc = match (method, boxes) {
        (Method::Dbscan, _) => by_dbscan(coords, params),
        (Method::Ransac, _) => by_ransac(coords, params),
        (Method::DbscanRansac, _) => by_dbscan_ransac(coords, params),
        (Method::DbscanPca, _) => by_dbscan_pca(coords, params),
        (Method::Bounded, Some(b)) => bounded::by_bounded(coords, params, b),
        (Method::Bounded, None) => Err(invalid("boxes", "the bounded method needs the detection boxes")),
    }?;
    loc.method = method;
    loc.n_nonfinite = finite.n_nonfinite;
    loc.direction = canonical_sign(loc.direction);
    Ok(loc)
}

/// Member indices of each cluster, indexed by label.
fn cluster_members(labels: &[i32]) -> Vec<Vec<usize>> {
    let mut members: Vec<Vec<usize>> = Vec::new();
    for (i, &l) in labels.iter().enumerate() {
        if let Ok(l) = usize::try_from(l) {
            if members.len() <= l {
                members.resize_with(l + 1, Vec::new);
            }
            members[l].push(i);
        }
    }
    members
}

fn centroid(coords: &[[f64; 3]], idx: &[usize]) -> [f64; 3] {
    let m = idx.len().max(1) as f64;
    let mut c = [0.0; 3];
    for &k in idx {
        for j in 0..3 {
            c[j] += coords[k][j] / m;
        }
    }
    c
}

fn norm(p: &[f64; 3]) -> f64 {
    (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
}

/// DBSCAN, then the cluster whose centroid is nearest the origin (lowest label on ties).
fn nearest_cluster(coords: &[[f64; 3]], params: &LocalizeParams) -> Result<(Vec<usize>, usize)> {
    let labels = dbscan_finite(coords, params.eps, params.min_points);
    let clusters = cluster_members(&labels);
    let n_clusters = clusters.len();
    let nearest = clusters
        .into_iter()
        .map(|m| (norm(&centroid(coords, &m)), m))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, m)| m)
        .ok_or_else(|| FusionError::NoInsulator(format!("DBSCAN found no cluster among {} points", coords.len())))?;
    if nearest.len() < 2 {
        return Err(FusionError::NoInsulator("nearest cluster has fewer than 2 points".into()));
    }
    Ok((nearest, n_clusters))
}

/// Indices (from `candidates`) of the points within `tau` of the line (a, d).
pub(crate) fn within_tau(coords: &[[f64; 3]], candidates: &[usize], a: &[f64; 3], d: &[f64; 3], tau: f64) -> Vec<usize> {
    candidates.iter().copied().filter(|&k| line_distance(&coords[k], a, d) <= tau).collect()
}

/// Point on the line (a, d) at the median scalar projection of the given points.
fn median_projection(coords: &[[f64; 3]], idx: &[usize], a: &[f64; 3], d: &[f64; 3]) -> Result<[f64; 3]> {
    let mut t: Vec<f64> = idx
        .iter()
        .map(|&k| {
            let p = coords[k];
            (p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1] + (p[2] - a[2]) * d[2]
        })
        .collect();
    if t.is_empty() {
        return Err(FusionError::NoInsulator("no points within tau of the line".into()));
    }
    t.sort_by(f64::total_cmp);
    let h = t.len() / 2;
    let median = if t.len() % 2 == 1 { t[h] } else { 0.5 * (t[h - 1] + t[h]) };
    Ok([a[0] + median * d[0], a[1] + median * d[1], a[2] + median * d[2]])
}

fn no_line(e: FusionError) -> FusionError {
    match e {
        FusionError::InvalidArgument { reason, .. } => FusionError::NoInsulator(format!("RANSAC failed: {reason}")),
        other => other,
    }
}

/// Method 1: nearest cluster's centroid and principal axis.
fn by_dbscan(coords: &[[f64; 3]], params: &LocalizeParams) -> Result<Localization> {
    let (nearest, n_clusters) = nearest_cluster(coords, params)?;
    let pca = pca_of(nearest.iter().map(|&k| coords[k])).map_err(no_line)?;
    Ok(Localization::from_cloud(pca.mean, pca.axis(), nearest.len(), n_clusters))
}

/// Method 2: RANSAC line on the whole cloud, median projection of points within tau.
fn by_ransac(coords: &[[f64; 3]], params: &LocalizeParams) -> Result<Localization> {
    let fit = ransac_line_finite(coords, &params.ransac).map_err(no_line)?;
    let all: Vec<usize> = (0..coords.len()).collect();
    let s = within_tau(coords, &all, &fit.point, &fit.direction, params.tau);
    let center = median_projection(coords, &s, &fit.point, &fit.direction)?;
    Ok(Localization::from_cloud(center, fit.direction, s.len(), 1))
}

/// The line of Algorithm 1 (nearest cluster -> RANSAC line) and the points S that belong
/// to the insulator (the RANSAC inliers within tau of it).
#[derive(Debug)]
pub(crate) struct InsulatorLine {
    /// A point of the line (the inliers' centroid) and its unit direction.
    pub point: [f64; 3],
    pub direction: [f64; 3],
    /// The points of S.
    pub members: Vec<[f64; 3]>,
    /// Clusters found by DBSCAN.
    pub n_clusters: usize,
}

impl InsulatorLine {
    /// The point of the line at parameter `t` (`a + t d`).
    pub(crate) fn at(&self, t: f64) -> [f64; 3] {
        let (a, d) = (&self.point, &self.direction);
        [a[0] + t * d[0], a[1] + t * d[1], a[2] + t * d[2]]
    }

    /// Scalar projections `t = d . (p - a)` of the points of S, ascending.
    pub(crate) fn sorted_projections(&self) -> Vec<f64> {
        let (a, d) = (&self.point, &self.direction);
        let mut t: Vec<f64> =
            self.members.iter().map(|p| (p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1] + (p[2] - a[2]) * d[2]).collect();
        t.sort_by(f64::total_cmp);
        t
    }
}

/// Nearest DBSCAN cluster, its RANSAC line and the inliers within tau (Algorithm 1, lines 1-3).
pub(crate) fn dbscan_ransac_line(coords: &[[f64; 3]], params: &LocalizeParams) -> Result<InsulatorLine> {
    let (nearest, n_clusters) = nearest_cluster(coords, params)?;
    let sub: Vec<[f64; 3]> = nearest.iter().map(|&k| coords[k]).collect();
    let fit = ransac_line_finite(&sub, &params.ransac).map_err(no_line)?;
    let s = within_tau(&sub, &fit.inliers, &fit.point, &fit.direction, params.tau);
    if s.is_empty() {
        return Err(FusionError::NoInsulator("no points within tau of the line".into()));
    }
    let members = s.iter().map(|&k| sub[k]).collect();
    Ok(InsulatorLine { point: fit.point, direction: fit.direction, members, n_clusters })
}

/// Method 3 (Algorithm 1): nearest cluster -> RANSAC line -> median projection of the
/// RANSAC inliers within tau of the line.
fn by_dbscan_ransac(coords: &[[f64; 3]], params: &LocalizeParams) -> Result<Localization> {
    let line = dbscan_ransac_line(coords, params)?;
    let all: Vec<usize> = (0..line.members.len()).collect();
    let center = median_projection(&line.members, &all, &line.point, &line.direction)?;
    Ok(Localization::from_cloud(center, line.direction, line.members.len(), line.n_clusters))
}

/// Method 4 (Algorithm 2): PCA line of the nearest cluster; S = its points within tau;
/// SC = DBSCAN(S); if SC holds more than one cluster, re-estimate from the largest one T
/// (centroid, PCA) and take the median projection of the nearest cluster's points within
/// tau of that line; otherwise keep the initial centroid and axis.
fn by_dbscan_pca(coords: &[[f64; 3]], params: &LocalizeParams) -> Result<Localization> {
    let (nearest, n_clusters) = nearest_cluster(coords, params)?;
    let first = pca_of(nearest.iter().map(|&k| coords[k])).map_err(no_line)?;
    let (c, v) = (first.mean, first.axis());
    let s = within_tau(coords, &nearest, &c, &v, params.tau);
    let s_coords: Vec<[f64; 3]> = s.iter().map(|&k| coords[k]).collect();
    let sc_labels = dbscan_finite(&s_coords, params.eps, params.min_points);
    let sc = cluster_members(&sc_labels);
    if sc.len() > 1 {
        // Largest cluster of S; the lowest label wins a tie.
        let mut largest = &sc[0];
        for cl in &sc[1..] {
            if cl.len() > largest.len() {
                largest = cl;
            }
        }
        let t_pca = pca_of(largest.iter().map(|&k| s_coords[k])).map_err(no_line)?;
        let (c2, v2) = (t_pca.mean, t_pca.axis());
        let s2 = within_tau(coords, &nearest, &c2, &v2, params.tau);
        let center = median_projection(coords, &s2, &c2, &v2)?;
        return Ok(Localization::from_cloud(center, v2, s2.len(), n_clusters));
    }
    debug_assert!(sc_labels.iter().all(|&l| l == NOISE || l == 0));
    Ok(Localization::from_cloud(c, v, nearest.len(), n_clusters))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn method_names_round_trip() {
        for m in Method::ALL {
            assert_eq!(m.as_str().parse::<Method>().unwrap(), m);
            assert_eq!(m.to_string(), m.as_str());
        }
        match "pca".parse::<Method>() {
            Err(FusionError::InvalidArgument { name, .. }) => assert_eq!(name, "method"),
            other => panic!("unexpected {other:?}"),
        }
    }

    #[test]
    fn median_projection_odd_and_even() {
        let coords = vec![[0.0, 0.0, 0.0], [1.0, 5.0, 0.0], [2.0, 0.0, 0.0], [10.0, 0.0, 0.0]];
        let a = [0.0, 0.0, 0.0];
        let d = [1.0, 0.0, 0.0];
        // t = 0, 1, 2 -> median 1 -> (1, 0, 0): the point on the line, not the point itself.
        assert_eq!(median_projection(&coords, &[0, 1, 2], &a, &d).unwrap(), [1.0, 0.0, 0.0]);
        // t = 0, 1, 2, 10 -> median 1.5.
        assert_eq!(median_projection(&coords, &[0, 1, 2, 3], &a, &d).unwrap(), [1.5, 0.0, 0.0]);
        assert!(median_projection(&coords, &[], &a, &d).is_err());
    }

    #[test]
    fn params_are_validated_by_name() {
        let pts = vec![[1.0, 0.0, 0.0], [1.1, 0.0, 0.0]];
        let base = LocalizeParams::default();
        let name = |p: LocalizeParams| match localize(&pts, Method::Dbscan, &p, None) {
            Err(FusionError::InvalidArgument { name, .. }) => name,
            _ => "ok",
        };
        assert_eq!(name(LocalizeParams { eps: 0.0, ..base }), "eps");
        assert_eq!(name(LocalizeParams { min_points: 0, ..base }), "min_points");
        assert_eq!(name(LocalizeParams { tau: f64::NAN, ..base }), "tau");
        let r = |threshold, max_iterations| RansacParams { threshold, max_iterations, ..base.ransac };
        assert_eq!(name(LocalizeParams { ransac: r(-1.0, 10), ..base }), "ransac_threshold");
        assert_eq!(name(LocalizeParams { ransac: r(0.1, 0), ..base }), "max_iterations");
    }

    #[test]
    fn nearest_cluster_is_chosen_by_centroid_distance() {
        // Two straight "insulators": one at 5 m (index-later), one at 9 m (index-first).
        let mut pts: Vec<[f64; 3]> = (0..40).map(|k| [9.0, 0.0, f64::from(k) * 0.05]).collect();
        pts.extend((0..40).map(|k| [5.0, 0.0, f64::from(k) * 0.05]));
        for m in Method::PAPER {
            if m == Method::Ransac {
                continue; // RANSAC alone has no notion of nearest
            }
            let loc = localize(&pts, m, &LocalizeParams::default(), None).unwrap();
            assert!((loc.center[0] - 5.0).abs() < 1e-9, "{m}: {:?}", loc.center);
            assert!((loc.center[2] - 0.975).abs() < 1e-9, "{m}: {:?}", loc.center);
            assert_eq!(loc.direction, [0.0, 0.0, 1.0]);
            assert_eq!(loc.n_clusters, 2);
        }
    }

    #[test]
    fn pca_branch_reclusters_when_s_splits() {
        // Nearest cluster: a dense line along z (x = 5) joined at its top by a diagonal member
        // that drags the initial PCA axis off; S splits into pieces and the largest is the line.
        let mut pts: Vec<[f64; 3]> = (0..60).map(|k| [5.0, 0.0, f64::from(k) * 0.03]).collect();
        pts.extend((1..40).map(|k| [5.0, f64::from(k) * 0.05, 1.77 + f64::from(k) * 0.05]));
        let p = LocalizeParams::default();
        let loc = localize(&pts, Method::DbscanPca, &p, None).unwrap();
        assert!(loc.direction[2] > 0.99, "axis {:?}", loc.direction);
        assert!((loc.center[0] - 5.0).abs() < 0.05 && loc.center[1].abs() < 0.1, "{:?}", loc.center);
    }
}
