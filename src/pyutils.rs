//! Argument extraction shared by every binding: point clouds, 4x4 poses, small
//! float matrices and integer knobs, each failing with a `TypeError` or
//! `ValueError` that names the argument and says what was expected and what
//! came in.

use fusion_core::StridedPoints;
use nalgebra::{Isometry3, Matrix4};
use numpy::{
    AllowTypeChange, Element, PyArray1, PyArray2, PyArrayDescrMethods, PyArrayDyn, PyArrayLikeDyn, PyArrayMethods,
    PyReadonlyArray2, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

use crate::errors::to_pyerr;

/// A borrowed (N, 3) float32 or float64 numpy array.
pub enum Cloud<'py> {
    F32(PyReadonlyArray2<'py, f32>),
    F64(PyReadonlyArray2<'py, f64>),
}

/// A no-copy view of a [`Cloud`] that fusion_core kernels read through
/// `PointCloud`; `Send`, so it can cross into `py.detach`.
#[derive(Clone, Copy)]
pub enum CloudView<'a> {
    F32(StridedPoints<'a, f32>),
    F64(StridedPoints<'a, f64>),
}

/// Runs `$body` with `$p` bound to the concrete `StridedPoints` of a
/// [`CloudView`], so each kernel is monomorphised for f32 and f64 input.
macro_rules! with_cloud {
    ($view:expr, $p:ident => $body:expr) => {
        match $view {
            $crate::pyutils::CloudView::F32($p) => $body,
            $crate::pyutils::CloudView::F64($p) => $body,
        }
    };
}
pub(crate) use with_cloud;

fn python_type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type().name().map_or_else(|_| "?".to_owned(), |n| n.to_string())
}

fn shape_text(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape.iter().map(usize::to_string).collect::<Vec<_>>().join(", ")
        ),
    }
}

/// Takes a float32/float64 numpy array of shape (N, 3), any strides, without copying.
///
/// A view whose strides are not whole elements or whose data is misaligned (rare:
/// raw buffers, packed records) is copied once so the kernel can read it safely.
pub fn extract_cloud<'py>(obj: &Bound<'py, PyAny>, name: &'static str) -> PyResult<Cloud<'py>> {
    let array = obj.cast::<PyUntypedArray>().map_err(|_| {
        PyTypeError::new_err(format!(
            "{name}: expected a numpy.ndarray of shape (N, 3) and dtype float32 or float64, got {}",
            python_type_name(obj)
        ))
    })?;
    let dtype = array.dtype();
    let is_f64 = dtype.is_equiv_to(&f64::get_dtype(obj.py()));
    let is_f32 = dtype.is_equiv_to(&f32::get_dtype(obj.py()));
    if !is_f64 && !is_f32 {
        return Err(PyTypeError::new_err(format!(
            "{name}: expected dtype float32 or float64, got {dtype}"
        )));
    }
    let shape = array.shape();
    if shape.len() != 2 || shape[1] != 3 {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape (N, 3), got {}",
            shape_text(shape)
        )));
    }
    if is_f64 {
        Ok(Cloud::F64(borrow_readable::<f64>(obj, name)?))
    } else {
        Ok(Cloud::F32(borrow_readable::<f32>(obj, name)?))
    }
}

/// Borrows a 2-D array of `T` read-only, copying it first if its layout cannot be
/// read as whole, aligned elements.
fn borrow_readable<'py, T: Element>(obj: &Bound<'py, PyAny>, name: &'static str) -> PyResult<PyReadonlyArray2<'py, T>> {
    let array = obj.cast::<PyArray2<T>>()?;
    let array = if element_layout::<T>(array).is_some() {
        array.clone()
    } else {
        // ndarray.copy() returns a fresh C-contiguous, aligned array.
        array.call_method0("copy")?.cast_into::<PyArray2<T>>()?
    };
    array
        .try_readonly()
        .map_err(|e| PyValueError::new_err(format!("{name}: the array cannot be borrowed for reading ({e})")))
}

/// True when `data` is aligned for `T` and every byte stride is a whole number of elements,
/// i.e. the array can be read through `&[T]`.
#[allow(clippy::manual_is_multiple_of)] // `is_multiple_of` is newer than the MSRV (1.80)
fn whole_aligned_elements<T>(data: *const T, strides: &[isize]) -> bool {
    let item = std::mem::size_of::<T>() as isize;
    (data as usize) % std::mem::align_of::<T>() == 0 && strides.iter().all(|s| s % item == 0)
}

/// (row stride, column stride) in elements, if the array can be read through `&[T]`.
fn element_layout<T>(array: &Bound<'_, PyArray2<T>>) -> Option<(isize, isize)> {
    let item = std::mem::size_of::<T>() as isize;
    let strides = array.strides();
    whole_aligned_elements(array.data().cast_const(), strides).then(|| (strides[0] / item, strides[1] / item))
}

fn strided_view<'a, T: Element + Copy + Into<f64>>(
    array: &'a PyReadonlyArray2<'_, T>,
) -> PyResult<StridedPoints<'a, T>> {
    let rows = array.shape()[0];
    if rows == 0 {
        return StridedPoints::new(&[], 0, 3, 1, 0).map_err(|e| PyValueError::new_err(e.to_string()));
    }
    let (row_stride, col_stride) = element_layout::<T>(array)
        .ok_or_else(|| PyValueError::new_err("points: unexpected unaligned array after copy"))?;
    // Element offsets (from the data pointer) of the corners of the (rows, 3) block.
    // They fit in isize: numpy already addresses them in bytes.
    let row_span = (rows as isize - 1) * row_stride;
    let col_span = 2 * col_stride;
    let lo = row_span.min(0) + col_span.min(0);
    let hi = row_span.max(0) + col_span.max(0);
    let len = (hi - lo + 1) as usize;
    // SAFETY: numpy places every element (i, j) of the array at
    // data + i*strides[0] + j*strides[1], inside the one buffer the array views;
    // `lo` and `hi` are the lowest and highest of those element offsets, so the
    // `len` elements from data + lo all lie in that allocation. The pointer and
    // strides are aligned for T (checked by `element_layout`). The read-only
    // borrow (`PyReadonlyArray2`, lifetime 'a) keeps Rust writers out while the
    // slice lives; Python code writing into the same array from another thread
    // during the call would race, as with any numpy C extension that releases the GIL.
    let data = unsafe { std::slice::from_raw_parts(array.data().offset(lo).cast_const(), len) };
    StridedPoints::new(data, rows, row_stride, col_stride, (-lo) as usize)
        .map_err(|e| PyValueError::new_err(e.to_string()))
}

impl Cloud<'_> {
    /// The no-copy view the kernels read.
    pub fn view(&self) -> PyResult<CloudView<'_>> {
        Ok(match self {
            Cloud::F32(a) => CloudView::F32(strided_view(a)?),
            Cloud::F64(a) => CloudView::F64(strided_view(a)?),
        })
    }
}

/// A small float64 array of any shape, converted from any array-like (lists,
/// integer or float32 arrays), as (row-major values, shape).
pub fn extract_f64_array(obj: &Bound<'_, PyAny>, name: &'static str) -> PyResult<(Vec<f64>, Vec<usize>)> {
    let array = obj.extract::<PyArrayLikeDyn<'_, f64, AllowTypeChange>>().map_err(|e| {
        PyTypeError::new_err(format!(
            "{name}: expected a float array, got {} ({})",
            python_type_name(obj),
            e.value(obj.py())
        ))
    })?;
    let shape = array.shape().to_vec();
    let bound: &Bound<'_, PyArrayDyn<f64>> = &array;
    let aligned = whole_aligned_elements(bound.data().cast_const(), bound.strides());
    // The arrays here are tiny (poses, boxes): one copy into a Vec is free.
    let values = if aligned {
        array.as_array().iter().copied().collect()
    } else {
        let copy = bound.call_method0("copy")?.cast_into::<PyArrayDyn<f64>>()?;
        copy.readonly().as_array().iter().copied().collect()
    };
    Ok((values, shape))
}

/// A 4x4 homogeneous rigid transform (float64 array-like), checked by fusion_core
/// (finite, last row 0 0 0 1, orthonormal rotation with det +1); errors name `name`.
pub fn extract_rigid(obj: &Bound<'_, PyAny>, name: &'static str) -> PyResult<Isometry3<f64>> {
    let (values, shape) = extract_f64_array(obj, name)?;
    if shape != [4, 4] {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape (4, 4), got {}",
            shape_text(&shape)
        )));
    }
    let matrix = Matrix4::from_row_slice(&values);
    fusion_core::rigid_from_matrix(&matrix, name).map_err(|e| to_pyerr(obj.py(), e))
}

/// An integer argument taken from any Python int (or `__index__` object) without
/// `OverflowError`: values beyond i128 saturate. Range checks happen in
/// [`Count::get`], which names the argument in its `ValueError`.
#[derive(Clone, Copy, Debug)]
pub struct Count(pub i128);

impl<'py> FromPyObject<'py> for Count {
    fn extract_bound(obj: &Bound<'py, PyAny>) -> PyResult<Self> {
        let index = obj
            .call_method0("__index__")
            .map_err(|_| PyTypeError::new_err(format!("expected an integer, got {}", python_type_name(obj))))?;
        match index.extract::<i128>() {
            Ok(v) => Ok(Count(v)),
            Err(_) => Ok(Count(if index.lt(0)? { i128::MIN } else { i128::MAX })),
        }
    }
}

impl Count {
    /// The value as `T`, checked to be >= `min` and to fit `T`; else a `ValueError` naming `name`.
    pub fn get<T: TryFrom<i128>>(self, name: &'static str, min: i128) -> PyResult<T> {
        let Count(value) = self;
        if value == i128::MIN || value == i128::MAX {
            return Err(PyValueError::new_err(format!("{name}: integer out of range")));
        }
        if value < min {
            return Err(PyValueError::new_err(format!("{name}: must be >= {min}, got {value}")));
        }
        T::try_from(value).map_err(|_| PyValueError::new_err(format!("{name}: value too large, got {value}")))
    }
}

/// Formats the shape of an array for messages: `(3,)`, `(5, 2)`.
pub fn format_shape(shape: &[usize]) -> String {
    shape_text(shape)
}

/// Marks a freshly made result array read-only (results are frozen) and keeps it.
pub fn frozen_array<T>(array: Bound<'_, T>) -> PyResult<Py<T>> {
    array.as_any().getattr("flags")?.setattr("writeable", false)?;
    Ok(array.unbind())
}

/// `[x, y, z]` with 4 decimals, for reprs.
pub fn vec3_text(array: &Bound<'_, PyArray1<f64>>) -> PyResult<String> {
    let values = array.readonly();
    let parts: Vec<String> = values.as_array().iter().map(|x| format!("{x:.4}")).collect();
    Ok(format!("[{}]", parts.join(", ")))
}
