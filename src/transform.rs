//! `chain_transforms`: T_c_l = T_c_b @ T_b_l (the paper's eq. 1), validated.

use numpy::ndarray::Array2;
use numpy::{PyArray2, ToPyArray};
use pyo3::prelude::*;

use crate::pyutils::extract_rigid;

/// Composes two rigid 4x4 transforms: returns ``T_c_l = T_c_b @ T_b_l`` (float64).
///
/// Both inputs must be proper rigid transforms (finite, last row 0 0 0 1,
/// orthonormal rotation with det +1 within 1e-6); a ``ValueError`` names the
/// offending argument otherwise.
#[pyfunction]
#[pyo3(name = "chain_transforms", signature = (T_c_b, T_b_l))]
#[allow(non_snake_case)]
fn chain_transforms<'py>(
    py: Python<'py>,
    T_c_b: &Bound<'py, PyAny>,
    T_b_l: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let t_c_b = extract_rigid(T_c_b, "T_c_b")?;
    let t_b_l = extract_rigid(T_b_l, "T_b_l")?;
    let m = fusion_core::chain(&t_c_b, &t_b_l).to_homogeneous();
    let rows = Array2::from_shape_fn((4, 4), |(i, j)| m[(i, j)]);
    Ok(rows.to_pyarray(py))
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(chain_transforms, m)?)
}
