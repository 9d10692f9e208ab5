//! `points_in_boxes`: per detection box, the indices of the points projecting inside it.

use fusion_core::{FusionError, PixelBox};
use numpy::{IntoPyArray, PyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::camera::PyCameraModel;
use crate::errors::detach;
use crate::pyutils::{extract_cloud, extract_f64_array, extract_rigid, format_shape, with_cloud};

/// Boxes from an (M,4) ``x1, y1, x2, y2`` or (M,5) array (the 5th column, a
/// detector score, is ignored); an empty array or list means no boxes.
pub(crate) fn extract_boxes(obj: &Bound<'_, PyAny>) -> PyResult<Vec<PixelBox>> {
    let (values, shape) = extract_f64_array(obj, "boxes")?;
    if values.is_empty() && (shape.len() == 1 || (shape.len() == 2 && matches!(shape[1], 0 | 4 | 5))) {
        return Ok(Vec::new());
    }
    let cols = match shape.as_slice() {
        [_, c @ (4 | 5)] => *c,
        _ => {
            return Err(PyValueError::new_err(format!(
                "boxes: expected shape (M, 4) or (M, 5) (x1, y1, x2, y2[, score]), got {}",
                format_shape(&shape)
            )))
        }
    };
    values
        .chunks_exact(cols)
        .enumerate()
        .map(|(row, b)| {
            PixelBox::new(b[0], b[1], b[2], b[3]).map_err(|e| {
                let reason = match e {
                    FusionError::InvalidArgument { reason, .. } => reason,
                    other => other.to_string(),
                };
                PyValueError::new_err(format!("boxes: row {row}: {reason}"))
            })
        })
        .collect()
}

/// For each box, the ascending indices (int64) of the points of ``points_l`` that
/// are in front of the camera, inside the image, and project inside the box
/// (half-open: x1 <= u < x2, y1 <= v < y2).
///
/// ``points_l`` (N,3) float32/float64 in L (m); ``T_c_l`` 4x4 rigid L -> camera;
/// ``boxes`` (M,4) or (M,5) pixels. One pass over the cloud for all boxes. A box
/// partly outside the image is used as is; a box wholly outside gives an empty
/// array; an inverted, zero-area or NaN box is a ``ValueError`` naming its row.
/// Points with a NaN/Inf coordinate are never returned.
#[pyfunction]
#[pyo3(signature = (points_l, T_c_l, cam, boxes))]
#[allow(non_snake_case)]
fn points_in_boxes<'py>(
    py: Python<'py>,
    points_l: &Bound<'py, PyAny>,
    T_c_l: &Bound<'py, PyAny>,
    cam: PyRef<'py, PyCameraModel>,
    boxes: &Bound<'py, PyAny>,
) -> PyResult<Vec<Bound<'py, PyArray1<i64>>>> {
    let cloud = extract_cloud(points_l, "points_l")?;
    let t_c_l = extract_rigid(T_c_l, "T_c_l")?;
    let boxes = extract_boxes(boxes)?;
    let camera = cam.inner;
    let view = cloud.view()?;
    let lists = detach(
        py,
        move || with_cloud!(view, p => fusion_core::points_in_boxes(&p, &t_c_l, &camera, &boxes)),
    )?;
    Ok(lists
        .into_iter()
        .map(|list| {
            list.into_iter()
                .map(|i| i as i64)
                .collect::<Vec<i64>>()
                .into_pyarray(py)
        })
        .collect())
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(points_in_boxes, m)?)
}
