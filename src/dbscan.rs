//! `dbscan`: density clustering of a 3-D cloud (scikit-learn semantics, kd-tree).

use numpy::{IntoPyArray, PyArray1};
use pyo3::prelude::*;

use crate::errors::detach;
use crate::pyutils::{extract_cloud, with_cloud, Count};

/// Labels each point of ``points`` (N,3 float32/float64, m) with its cluster.
///
/// scikit-learn's DBSCAN semantics: a point is core when at least
/// ``min_points`` points (itself included) lie within ``eps`` metres
/// (inclusive). Returns (N,) int32: clusters numbered 0, 1, ... in the order
/// of their first core point, -1 for noise and for points with a NaN/Inf
/// coordinate. ``eps`` must be finite and > 0, ``min_points`` >= 1. An empty
/// cloud gives an empty array.
#[pyfunction]
#[pyo3(signature = (points, eps, min_points))]
fn dbscan<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    eps: f64,
    min_points: Count,
) -> PyResult<Bound<'py, PyArray1<i32>>> {
    let cloud = extract_cloud(points, "points")?;
    let min_points: usize = min_points.get("min_points", 1)?;
    let view = cloud.view()?;
    let labels = detach(
        py,
        move || with_cloud!(view, p => fusion_core::dbscan(&p, eps, min_points)),
    )?;
    Ok(labels.into_pyarray(py))
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(dbscan, m)?)?;
    m.add("NOISE", fusion_core::NOISE)?;
    Ok(())
}
