//! `insulator_rs._core`: thin pyo3 bindings over fusion_core.
//!
//! One file per core module, each with `register(py, m)`; argument extraction in
//! `pyutils`, error mapping and GIL release in `errors`. No algorithm lives here.

use pyo3::prelude::*;

mod camera;
mod culling;
mod dbscan;
mod deskew;
mod errors;
mod livox;
mod localize;
mod pca;
mod projection;
mod pyutils;
mod raycast;
mod ransac;
mod resize;
mod strings;
mod transform;

#[pymodule]
fn _core(py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    errors::register(py, m)?;
    camera::register(py, m)?;
    transform::register(py, m)?;
    projection::register(py, m)?;
    culling::register(py, m)?;
    deskew::register(py, m)?;
    dbscan::register(py, m)?;
    ransac::register(py, m)?;
    pca::register(py, m)?;
    localize::register(py, m)?;
    raycast::register(m)?;
    livox::register(m)?;
    resize::register(m)?;
    strings::register(py, m)?;
    Ok(())
}
