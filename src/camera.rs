//! `CameraModel`: pinhole intrinsics plus OpenCV (k1, k2, p1, p2, k3) distortion.

use numpy::PyArray2;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use crate::errors::to_pyerr;
use crate::pyutils::Count;

/// A pinhole camera with OpenCV's radial-tangential distortion.
///
/// ``fx``, ``fy``, ``cx``, ``cy`` in pixels; ``width``, ``height`` the image
/// size in pixels; ``dist`` = (k1, k2, p1, p2, k3) exactly as OpenCV orders
/// them. Projection matches ``cv2.projectPoints`` with the same K and dist.
#[pyclass(frozen, eq, module = "insulator_rs._core", name = "CameraModel")]
#[derive(Clone, PartialEq)]
pub struct PyCameraModel {
    pub inner: fusion_core::CameraModel,
}

#[pymethods]
impl PyCameraModel {
    #[new]
    #[pyo3(signature = (fx, fy, cx, cy, width, height, dist = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        width: Count,
        height: Count,
        dist: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let width: u32 = width.get("width", 1)?;
        let height: u32 = height.get("height", 1)?;
        let dist = match dist {
            None => [0.0; 5],
            Some(d) => extract_dist(d)?,
        };
        fusion_core::CameraModel::new(fx, fy, cx, cy, width, height, dist)
            .map(|inner| Self { inner })
            .map_err(|e| to_pyerr(py, e))
    }

    /// Focal length along x, pixels.
    #[getter]
    fn fx(&self) -> f64 {
        self.inner.fx
    }
    /// Focal length along y, pixels.
    #[getter]
    fn fy(&self) -> f64 {
        self.inner.fy
    }
    /// Principal point x, pixels.
    #[getter]
    fn cx(&self) -> f64 {
        self.inner.cx
    }
    /// Principal point y, pixels.
    #[getter]
    fn cy(&self) -> f64 {
        self.inner.cy
    }
    /// Image width, pixels.
    #[getter]
    fn width(&self) -> u32 {
        self.inner.width
    }
    /// Image height, pixels.
    #[getter]
    fn height(&self) -> u32 {
        self.inner.height
    }
    /// Distortion (k1, k2, p1, p2, k3).
    #[getter]
    fn dist(&self) -> (f64, f64, f64, f64, f64) {
        let [k1, k2, p1, p2, k3] = self.inner.dist;
        (k1, k2, p1, p2, k3)
    }

    /// The 3x3 intrinsic matrix K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (float64).
    fn camera_matrix<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let c = &self.inner;
        let k = vec![vec![c.fx, 0.0, c.cx], vec![0.0, c.fy, c.cy], vec![0.0, 0.0, 1.0]];
        PyArray2::from_vec2(py, &k).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    fn __repr__(&self) -> String {
        let c = &self.inner;
        let [k1, k2, p1, p2, k3] = c.dist;
        format!(
            "CameraModel(fx={:?}, fy={:?}, cx={:?}, cy={:?}, width={}, height={}, dist=({k1:?}, {k2:?}, {p1:?}, {p2:?}, {k3:?}))",
            c.fx, c.fy, c.cx, c.cy, c.width, c.height
        )
    }

    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyTuple>)> {
        let c = slf.get().inner;
        let args = (c.fx, c.fy, c.cx, c.cy, c.width, c.height, slf.get().dist()).into_pyobject(slf.py())?;
        Ok((slf.get_type().into_any(), args))
    }
}

/// Five finite-or-not floats from any sequence; the core checks finiteness.
fn extract_dist(obj: &Bound<'_, PyAny>) -> PyResult<[f64; 5]> {
    let values: Vec<f64> = obj.extract().map_err(|_| {
        PyTypeError::new_err(format!(
            "dist: expected a sequence of 5 floats (k1, k2, p1, p2, k3), got {}",
            obj.get_type().name().map_or_else(|_| "?".to_owned(), |n| n.to_string())
        ))
    })?;
    <[f64; 5]>::try_from(values.as_slice()).map_err(|_| {
        PyValueError::new_err(format!(
            "dist: expected 5 coefficients (k1, k2, p1, p2, k3), got {}",
            values.len()
        ))
    })
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyCameraModel>()?;
    m.add("NEAR_LIMIT", fusion_core::NEAR_LIMIT)?;
    Ok(())
}
