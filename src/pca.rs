//! `pca`: principal axes of a point set.

use fusion_core::Pca;
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::prelude::*;

use crate::errors::detach;
use crate::pyutils::{extract_cloud, frozen_array, vec3_text, with_cloud};

/// Principal component analysis of a point set: ``mean`` (3,) m,
/// ``eigenvalues`` (3,) descending (m², covariance with N-1 as ``np.cov``),
/// ``eigenvectors`` (3,3) whose column k is the unit eigenvector of
/// ``eigenvalues[k]`` (as ``numpy.linalg.eigh`` returns them), ``n_points`` the
/// finite points used. Arrays are read-only.
#[pyclass(frozen, module = "insulator_rs._core", name = "Pca")]
pub struct PyPca {
    mean: Py<PyArray1<f64>>,
    eigenvalues: Py<PyArray1<f64>>,
    eigenvectors: Py<PyArray2<f64>>,
    n_points: usize,
}

#[pymethods]
impl PyPca {
    /// Mean of the finite points, (3,) float64, m.
    #[getter]
    fn mean<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.mean.bind(py).clone()
    }
    /// Covariance eigenvalues in descending order, (3,) float64, m².
    #[getter]
    fn eigenvalues<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.eigenvalues.bind(py).clone()
    }
    /// Unit eigenvectors as columns, (3,3) float64; column k pairs with eigenvalues[k].
    #[getter]
    fn eigenvectors<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        self.eigenvectors.bind(py).clone()
    }
    /// Number of finite points used.
    #[getter]
    fn n_points(&self) -> usize {
        self.n_points
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!(
            "Pca(mean={}, eigenvalues={}, n_points={})",
            vec3_text(self.mean.bind(py))?,
            vec3_text(self.eigenvalues.bind(py))?,
            self.n_points
        ))
    }
}

/// PCA of ``points`` (N,3 float32/float64, m); NaN/Inf points are skipped.
///
/// ``ValueError`` when fewer than two finite points remain (an empty cloud included).
#[pyfunction]
#[pyo3(signature = (points,))]
fn pca(py: Python<'_>, points: &Bound<'_, PyAny>) -> PyResult<PyPca> {
    let cloud = extract_cloud(points, "points")?;
    let view = cloud.view()?;
    let Pca {
        mean,
        eigenvalues,
        eigenvectors,
        n_points,
    } = detach(py, move || with_cloud!(view, p => fusion_core::pca(&p)))?;
    // The core stores eigenvector k as row k; Python gets it as column k.
    let columns = Array2::from_shape_fn((3, 3), |(i, k)| eigenvectors[k][i]);
    Ok(PyPca {
        mean: frozen_array(mean.to_vec().into_pyarray(py))?,
        eigenvalues: frozen_array(eigenvalues.to_vec().into_pyarray(py))?,
        eigenvectors: frozen_array(columns.into_pyarray(py))?,
        n_points,
    })
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyPca>()?;
    m.add_function(wrap_pyfunction!(pca, m)?)
}
