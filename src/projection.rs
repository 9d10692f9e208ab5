//! `project_points`: an L-frame cloud straight into pixels through T_c_l and the camera.

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::prelude::*;

use crate::camera::PyCameraModel;
use crate::errors::detach;
use crate::pyutils::{extract_cloud, extract_rigid, with_cloud};

/// `(uv (N,2) float64, valid (N,) bool)`.
type UvValid<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<bool>>);

/// Projects every point of ``points_l`` (N,3, float32/float64, L frame, m) into pixels.
///
/// Returns ``(uv, valid)``: ``uv`` (N,2) float64 pixel coordinates, NaN for
/// points behind or within ``NEAR_LIMIT`` of the camera or with a NaN/Inf
/// coordinate; ``valid`` (N,) bool, true where the point is in front of the
/// camera and lands inside the image (0 <= u < width, 0 <= v < height).
/// ``T_c_l`` is the 4x4 rigid transform from L to the camera optical frame.
/// An empty cloud gives empty arrays.
#[pyfunction]
#[pyo3(signature = (points_l, T_c_l, cam))]
#[allow(non_snake_case)]
fn project_points<'py>(
    py: Python<'py>,
    points_l: &Bound<'py, PyAny>,
    T_c_l: &Bound<'py, PyAny>,
    cam: PyRef<'py, PyCameraModel>,
) -> PyResult<UvValid<'py>> {
    let cloud = extract_cloud(points_l, "points_l")?;
    let t_c_l = extract_rigid(T_c_l, "T_c_l")?;
    let camera = cam.inner;
    let view = cloud.view()?;
    let projection = detach(py, move || {
        Ok::<_, fusion_core::FusionError>(with_cloud!(view, p => fusion_core::project_points(&p, &t_c_l, &camera)))
    })?;
    let n = projection.valid.len();
    let uv = Array2::from_shape_vec((n, 2), projection.uv.into_flattened())
        .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
    Ok((uv.into_pyarray(py), projection.valid.into_pyarray(py)))
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(project_points, m)?)
}
