//! `localize`: the paper's four insulator localization methods.

use std::str::FromStr;

use fusion_core::{Localization, LocalizeParams, Method, RansacParams};
use numpy::{IntoPyArray, PyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::{detach, to_pyerr};
use crate::pyutils::{extract_cloud, frozen_array, vec3_text, with_cloud, Count};

/// An insulator estimate in the body frame B: ``center`` (3,) m, ``direction``
/// (3,) unit axis with its largest-|component| positive, ``n_points`` the points
/// that determined the centre, ``n_clusters`` clusters the first DBSCAN found (1
/// for ``"ransac"``: its inlier set), ``n_nonfinite`` input points skipped for NaN/Inf, ``method``.
#[pyclass(frozen, module = "insulator_rs._core", name = "Localization")]
pub struct PyLocalization {
    center: Py<PyArray1<f64>>,
    direction: Py<PyArray1<f64>>,
    n_points: usize,
    n_clusters: usize,
    n_nonfinite: usize,
    method: &'static str,
}

#[pymethods]
impl PyLocalization {
    /// Insulator centre, (3,) float64, m, body frame B.
    #[getter]
    fn center<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.center.bind(py).clone()
    }
    /// Unit axis direction, (3,) float64, largest-|component| positive.
    #[getter]
    fn direction<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.direction.bind(py).clone()
    }
    /// Number of points that determined the centre.
    #[getter]
    fn n_points(&self) -> usize {
        self.n_points
    }
    /// Number of clusters the first DBSCAN found (1 for ``"ransac"``).
    #[getter]
    fn n_clusters(&self) -> usize {
        self.n_clusters
    }
    /// Number of input points skipped for a NaN/Inf coordinate.
    #[getter]
    fn n_nonfinite(&self) -> usize {
        self.n_nonfinite
    }
    /// The method that produced the estimate.
    #[getter]
    fn method(&self) -> &'static str {
        self.method
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!(
            "Localization(method={:?}, center={}, direction={}, n_points={}, n_clusters={}, n_nonfinite={})",
            self.method,
            vec3_text(self.center.bind(py))?,
            vec3_text(self.direction.bind(py))?,
            self.n_points,
            self.n_clusters,
            self.n_nonfinite
        ))
    }
}

/// Localizes the insulator in a culled, accumulated cloud ``points_b``
/// (N,3 float32/float64, body frame B, m; the UAV at the origin).
///
/// ``method``: ``"dbscan"`` (nearest cluster: centroid and PCA axis),
/// ``"ransac"`` (RANSAC line through the whole cloud; centre = point on the line
/// at the median projection of the points within ``tau``), ``"dbscan+ransac"``
/// (the paper's Algorithm 1) or ``"dbscan+pca"`` (Algorithm 2). ``eps`` (m) and
/// ``min_points`` drive DBSCAN, ``tau`` (m) is the distance to the line that
/// counts a point as insulator, ``ransac_threshold`` (m), ``max_iterations``,
/// ``confidence`` and ``seed`` drive RANSAC. Defaults (for a Livox Mid-360 at
/// 8-10 m, 3 accumulated frames): ``localize_defaults()``. NaN/Inf points are
/// skipped and counted. Raises ``LocalizationError`` when the cloud holds no
/// usable insulator (an empty cloud included), ``ValueError`` on a bad parameter.
#[pyfunction]
#[pyo3(signature = (
    points_b,
    method = "dbscan+ransac",
    *,
    eps = LocalizeParams::default().eps,
    min_points = Count(LocalizeParams::default().min_points as i128),
    tau = LocalizeParams::default().tau,
    ransac_threshold = LocalizeParams::default().ransac.threshold,
    max_iterations = Count(LocalizeParams::default().ransac.max_iterations as i128),
    confidence = LocalizeParams::default().ransac.confidence,
    seed = Count(i128::from(LocalizeParams::default().ransac.seed)),
),
// The defaults spelled out for help(); tests/test_core_localize.py checks them against
// localize_defaults() (the fusion_core constants), so they cannot drift.
text_signature = "(points_b, method='dbscan+ransac', *, eps=0.5, min_points=5, tau=0.2, \
ransac_threshold=0.1, max_iterations=1000, confidence=0.99, seed=0)")]
#[allow(clippy::too_many_arguments)]
fn localize(
    py: Python<'_>,
    points_b: &Bound<'_, PyAny>,
    method: &str,
    eps: f64,
    min_points: Count,
    tau: f64,
    ransac_threshold: f64,
    max_iterations: Count,
    confidence: f64,
    seed: Count,
) -> PyResult<PyLocalization> {
    let method = Method::from_str(method).map_err(|e| to_pyerr(py, e))?;
    let params = LocalizeParams {
        eps,
        min_points: min_points.get("min_points", 1)?,
        tau,
        ransac: RansacParams {
            threshold: ransac_threshold,
            max_iterations: max_iterations.get("max_iterations", 1)?,
            confidence,
            seed: seed.get("seed", 0)?,
        },
    };
    let cloud = extract_cloud(points_b, "points_b")?;
    let view = cloud.view()?;
    let Localization {
        center,
        direction,
        n_points,
        n_clusters,
        n_nonfinite,
    } = detach(
        py,
        move || with_cloud!(view, p => fusion_core::localize(&p, method, &params)),
    )?;
    Ok(PyLocalization {
        center: frozen_array(center.to_vec().into_pyarray(py))?,
        direction: frozen_array(direction.to_vec().into_pyarray(py))?,
        n_points,
        n_clusters,
        n_nonfinite,
        method: method.as_str(),
    })
}

/// The default ``localize`` / ``ransac_line`` parameters (Livox Mid-360 at 8-10 m,
/// 3 accumulated frames), as a fresh dict: eps, min_points, tau,
/// ransac_threshold, max_iterations, confidence, seed.
#[pyfunction]
fn localize_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = LocalizeParams::default();
    let out = PyDict::new(py);
    out.set_item("eps", d.eps)?;
    out.set_item("min_points", d.min_points)?;
    out.set_item("tau", d.tau)?;
    out.set_item("ransac_threshold", d.ransac.threshold)?;
    out.set_item("max_iterations", d.ransac.max_iterations)?;
    out.set_item("confidence", d.ransac.confidence)?;
    out.set_item("seed", d.ransac.seed)?;
    Ok(out)
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyLocalization>()?;
    m.add_function(wrap_pyfunction!(localize, m)?)?;
    m.add_function(wrap_pyfunction!(localize_defaults, m)?)
}
