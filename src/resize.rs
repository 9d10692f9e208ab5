//! `resize_linear`: the letterbox's bilinear resize, the same bytes on x86-64 and aarch64.

use numpy::ndarray::{ArrayD, IxDyn};
use numpy::{Element, IntoPyArray, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;

use fusion_core::resize::MAX_SIDE;

use crate::errors::detach;
use crate::pyutils::{format_shape, Count};

/// Resizes an (H, W) or (H, W, C) uint8 image (C in 1..4, any strides) to ``width`` x
/// ``height`` with bilinear interpolation: the bytes of OpenCV's 8-bit
/// ``cv2.resize(image, (width, height), interpolation=cv2.INTER_LINEAR)`` on x86-64
/// (its generic fixed-point path), computed in integers, so identical on every CPU.
/// Returns a new C-contiguous uint8 array of shape (height, width[, C]).
///
/// ``TypeError`` for a non-array or a dtype other than uint8; ``ValueError`` for any
/// other shape, an empty image, or a side outside 1..=2**20.
#[pyfunction]
#[pyo3(signature = (image, width, height))]
fn resize_linear<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    width: Count,
    height: Count,
) -> PyResult<Bound<'py, PyArrayDyn<u8>>> {
    let new_w: usize = width.get("width", 1)?;
    let new_h: usize = height.get("height", 1)?;
    for (name, side) in [("width", new_w), ("height", new_h)] {
        if side > MAX_SIDE {
            return Err(PyValueError::new_err(format!("{name}: must be in 1..={MAX_SIDE}, got {side}")));
        }
    }
    let array = image.cast::<PyUntypedArray>().map_err(|_| {
        PyTypeError::new_err("image: expected a numpy.ndarray of dtype uint8 and shape (H, W) or (H, W, C)")
    })?;
    let dtype = array.dtype();
    if !dtype.is_equiv_to(&u8::get_dtype(py)) {
        return Err(PyTypeError::new_err(format!("image: expected dtype uint8, got {dtype}")));
    }
    let shape = array.shape().to_vec();
    let (h, w, c) = match shape.as_slice() {
        [h, w] => (*h, *w, 1),
        [h, w, c @ 1..=4] => (*h, *w, *c),
        _ => {
            return Err(PyValueError::new_err(format!(
                "image: expected shape (H, W) or (H, W, C) with C in 1..4, got {}",
                format_shape(&shape)
            )))
        }
    };
    if h == 0 || w == 0 {
        return Err(PyValueError::new_err(format!("image: empty image of shape {}", format_shape(&shape))));
    }
    if h > MAX_SIDE || w > MAX_SIDE {
        return Err(PyValueError::new_err(format!(
            "image: sides must be <= {MAX_SIDE}, got shape {}",
            format_shape(&shape)
        )));
    }
    let typed = image.cast::<PyArrayDyn<u8>>()?;
    let readonly = typed
        .try_readonly()
        .map_err(|e| PyValueError::new_err(format!("image: the array cannot be borrowed for reading ({e})")))?;
    let view = readonly.as_array();
    let contiguous = view.as_standard_layout();
    let src = contiguous
        .as_slice()
        .ok_or_else(|| PyRuntimeError::new_err("image: no contiguous copy could be made"))?;
    let out = detach(py, move || fusion_core::resize_linear(src, h, w, c, new_h, new_w))?;
    let out_shape: Vec<usize> = if shape.len() == 2 { vec![new_h, new_w] } else { vec![new_h, new_w, c] };
    let out = ArrayD::from_shape_vec(IxDyn(&out_shape), out).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok(out.into_pyarray(py))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(resize_linear, m)?)
}
