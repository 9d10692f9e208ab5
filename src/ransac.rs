//! `ransac_line`: seeded RANSAC 3-D line fit with a least-squares refit.

use fusion_core::{LineFit, RansacParams};
use numpy::{IntoPyArray, PyArray1};
use pyo3::prelude::*;

use crate::errors::detach;
use crate::pyutils::{extract_cloud, frozen_array, vec3_text, with_cloud, Count};

/// A fitted 3-D line: ``point`` (3,) the centroid of the inliers (m),
/// ``direction`` (3,) unit, ``inliers`` (K,) int64 ascending indices of the
/// points within the threshold of the line, ``iterations`` the RANSAC
/// iterations run. Arrays are read-only.
#[pyclass(frozen, module = "insulator_rs._core", name = "LineFit")]
pub struct PyLineFit {
    point: Py<PyArray1<f64>>,
    direction: Py<PyArray1<f64>>,
    inliers: Py<PyArray1<i64>>,
    iterations: usize,
    n_inliers: usize,
}

impl PyLineFit {
    fn new(py: Python<'_>, fit: LineFit) -> PyResult<Self> {
        let n_inliers = fit.inliers.len();
        let inliers: Vec<i64> = fit.inliers.into_iter().map(|i| i as i64).collect();
        Ok(Self {
            point: frozen_array(fit.point.to_vec().into_pyarray(py))?,
            direction: frozen_array(fit.direction.to_vec().into_pyarray(py))?,
            inliers: frozen_array(inliers.into_pyarray(py))?,
            iterations: fit.iterations,
            n_inliers,
        })
    }
}

#[pymethods]
impl PyLineFit {
    /// Centroid of the inliers, (3,) float64, m.
    #[getter]
    fn point<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.point.bind(py).clone()
    }
    /// Unit direction, (3,) float64.
    #[getter]
    fn direction<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.direction.bind(py).clone()
    }
    /// Ascending indices of the inliers, (K,) int64.
    #[getter]
    fn inliers<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        self.inliers.bind(py).clone()
    }
    /// RANSAC iterations run before the adaptive stop or the cap.
    #[getter]
    fn iterations(&self) -> usize {
        self.iterations
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!(
            "LineFit(point={}, direction={}, n_inliers={}, iterations={})",
            vec3_text(self.point.bind(py))?,
            vec3_text(self.direction.bind(py))?,
            self.n_inliers,
            self.iterations
        ))
    }
}

/// Fits a 3-D line to ``points`` (N,3 float32/float64, m) with RANSAC.
///
/// Two-point hypotheses drawn from a PCG generator seeded with ``seed``
/// (deterministic); stops when the probability of having missed a better
/// model drops below ``1 - confidence`` or after ``max_iterations``; the best
/// model is refit by least squares (PCA) on its inliers, and the inliers
/// (distance <= ``threshold`` m) recomputed against the refit line. Defaults of
/// the knobs: ``localize_defaults()``. Points with
/// NaN/Inf are skipped. ``ValueError`` when fewer than two distinct finite
/// points exist or a parameter is out of range.
#[pyfunction]
#[pyo3(signature = (
    points,
    threshold,
    *,
    max_iterations = Count(RansacParams::default().max_iterations as i128),
    confidence = RansacParams::default().confidence,
    seed = Count(i128::from(RansacParams::default().seed)),
),
// The defaults spelled out for help(); tests/test_core_pca_ransac.py checks them against
// localize_defaults() (the fusion_core constants), so they cannot drift.
text_signature = "(points, threshold, *, max_iterations=1000, confidence=0.99, seed=0)")]
fn ransac_line<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    threshold: f64,
    max_iterations: Count,
    confidence: f64,
    seed: Count,
) -> PyResult<PyLineFit> {
    let cloud = extract_cloud(points, "points")?;
    let params = RansacParams {
        threshold,
        max_iterations: max_iterations.get("max_iterations", 1)?,
        confidence,
        seed: seed.get("seed", 0)?,
    };
    let view = cloud.view()?;
    let fit = detach(
        py,
        move || with_cloud!(view, p => fusion_core::ransac_line(&p, &params)),
    )?;
    PyLineFit::new(py, fit)
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyLineFit>()?;
    m.add_function(wrap_pyfunction!(ransac_line, m)?)
}
