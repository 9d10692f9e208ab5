//! `find_insulator_strings`: insulator strings in a tower-scale cloud by geometry alone, and
//! its result class.

use fusion_core::{InsulatorString, StringParams};
use numpy::{IntoPyArray, PyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::errors::detach;
use crate::pyutils::{extract_cloud, extract_f64_array, format_shape, frozen_array, vec3_text, with_cloud};

/// One insulator string found in a cloud: ``center`` (3,) m and ``axis`` (3,) unit (largest
/// |component| positive) in the cloud's frame, ``length`` m of the shed stack, ``radius`` m of
/// its sheds, ``n_points`` thinned points (one per voxel) in it, ``score`` its shed contrast
/// (dimensionless, higher is surer), ``elevation`` rad of the axis above the horizontal (pi/2:
/// a suspension string; near 0: a tension string).
#[pyclass(frozen, module = "insulator_rs._core", name = "InsulatorString")]
pub struct PyInsulatorString {
    center: Py<PyArray1<f64>>,
    axis: Py<PyArray1<f64>>,
    length: f64,
    radius: f64,
    n_points: usize,
    score: f64,
    elevation: f64,
}

#[pymethods]
impl PyInsulatorString {
    /// Centre of the shed stack, (3,) float64, m.
    #[getter]
    fn center<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.center.bind(py).clone()
    }
    /// Unit axis, (3,) float64, largest-|component| positive.
    #[getter]
    fn axis<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.axis.bind(py).clone()
    }
    /// Length of the shed stack, m.
    #[getter]
    fn length(&self) -> f64 {
        self.length
    }
    /// Radius of the sheds, m.
    #[getter]
    fn radius(&self) -> f64 {
        self.radius
    }
    /// Thinned points (one per voxel) in the string.
    #[getter]
    fn n_points(&self) -> usize {
        self.n_points
    }
    /// Shed contrast (dimensionless; at least the call's ``min_score``).
    #[getter]
    fn score(&self) -> f64 {
        self.score
    }
    /// Angle of the axis above the horizontal, rad.
    #[getter]
    fn elevation(&self) -> f64 {
        self.elevation
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!(
            "InsulatorString(center={}, axis={}, length={:.3}, radius={:.3}, n_points={}, score={:.1}, elevation={:.3})",
            vec3_text(self.center.bind(py))?,
            vec3_text(self.axis.bind(py))?,
            self.length,
            self.radius,
            self.n_points,
            self.score,
            self.elevation
        ))
    }
}

impl PyInsulatorString {
    fn new(py: Python<'_>, s: InsulatorString) -> PyResult<Self> {
        Ok(PyInsulatorString {
            center: frozen_array(s.center.to_vec().into_pyarray(py))?,
            axis: frozen_array(s.axis.to_vec().into_pyarray(py))?,
            length: s.length,
            radius: s.radius,
            n_points: s.n_points,
            score: s.score,
            elevation: s.elevation,
        })
    }
}

/// The vertical: three numbers (a tuple, a list, an array), refused by name otherwise.
#[derive(Clone, Copy)]
struct Up([f64; 3]);

impl<'py> FromPyObject<'py> for Up {
    fn extract_bound(obj: &Bound<'py, PyAny>) -> PyResult<Self> {
        let (values, shape) = extract_f64_array(obj, "up")?;
        match values.as_slice() {
            [x, y, z] if shape.len() == 1 => Ok(Up([*x, *y, *z])),
            _ => Err(PyValueError::new_err(format!("up: expected 3 numbers, got shape {}", format_shape(&shape)))),
        }
    }
}

/// The insulator strings in ``points`` ((N,3) float32/float64, m, any horizontal frame),
/// strongest first; ``up`` is the vertical (3 numbers). An empty or flat cloud gives ``[]``.
///
/// ``ValueError`` (naming the argument) on a NaN/Inf coordinate, more than 5e7 points, a zero
/// ``up`` or a bad tuning value.
#[pyfunction]
#[pyo3(signature = (
    points,
    *,
    up = Up([0.0, 0.0, 1.0]),
    voxel_size = StringParams::default().voxel_size,
    min_length = StringParams::default().min_length,
    max_length = StringParams::default().max_length,
    min_score = StringParams::default().min_score,
),
text_signature = "(points, *, up=(0.0, 0.0, 1.0), voxel_size=0.04, min_length=0.8, max_length=5.0, min_score=10.0)")]
fn find_insulator_strings(
    py: Python<'_>,
    points: &Bound<'_, PyAny>,
    up: Up,
    voxel_size: f64,
    min_length: f64,
    max_length: f64,
    min_score: f64,
) -> PyResult<Vec<PyInsulatorString>> {
    let Up(up) = up;
    let params = StringParams { voxel_size, min_length, max_length, min_score };
    let cloud = extract_cloud(points, "points")?;
    let view = cloud.view()?;
    let found = detach(py, move || with_cloud!(view, p => fusion_core::find_insulator_strings(&p, up, &params)))?;
    found.into_iter().map(|s| PyInsulatorString::new(py, s)).collect()
}

/// `find_insulator_strings`' defaults, by keyword (the fusion_core constants).
#[pyfunction]
fn find_insulator_strings_defaults() -> Vec<(&'static str, f64)> {
    let d = StringParams::default();
    vec![("voxel_size", d.voxel_size), ("min_length", d.min_length), ("max_length", d.max_length), ("min_score", d.min_score)]
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyInsulatorString>()?;
    m.add("MAX_STRING_POINTS", fusion_core::strings::MAX_POINTS)?;
    m.add_function(wrap_pyfunction!(find_insulator_strings, m)?)?;
    m.add_function(wrap_pyfunction!(find_insulator_strings_defaults, m)?)
}
