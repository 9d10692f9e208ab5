//! The one place where the core crates' errors become Python exceptions, and the
//! helper that runs a kernel with the GIL released.
//!
//! * `FusionError::InvalidArgument` -> `ValueError("<argument>: <reason>")`.
//! * `FusionError::NoInsulator` -> `insulator_rs.LocalizationError`, a class
//!   created here at import time as a subclass of
//!   `insulator_rs.exceptions.InsulatorError` (the package's base class).
//! * every `RaycastError` (scene_raycast) is an argument error naming the
//!   argument -> `ValueError`.
//! * livox_mid360's `PacketError` (a malformed datagram) and `ControlError` (a bad
//!   command frame) -> `ValueError` with the crate's message.
//!
//! A binding never maps a core error itself: it runs the kernel through
//! [`detach`], which works for any error type implementing [`CoreError`].

use fusion_core::FusionError;
use livox_mid360::{ControlError, PacketError};
use scene_raycast::RaycastError;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::marker::Ungil;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyType;

static LOCALIZATION_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

const LOCALIZATION_ERROR_DOC: &std::ffi::CStr = c"The cloud holds no usable insulator.

Raised by ``localize`` when no cluster is found, fewer than two usable points
remain, or the line fit fails. The message says which.";

/// Creates `LocalizationError` (once) and adds it to the module.
pub fn register(py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    let class = LOCALIZATION_ERROR.get_or_try_init(py, || {
        let base = py.import("insulator_rs.exceptions")?.getattr("InsulatorError")?;
        let base = base.cast_into::<PyType>()?;
        PyErr::new_type(
            py,
            c"insulator_rs.LocalizationError",
            Some(LOCALIZATION_ERROR_DOC),
            Some(&base),
            None,
        )
    })?;
    m.add("LocalizationError", class.clone_ref(py))
}

/// An error of a core crate, with the Python exception it becomes.
pub trait CoreError: std::fmt::Display {
    fn into_pyerr(self, py: Python<'_>) -> PyErr;
}

impl CoreError for FusionError {
    fn into_pyerr(self, py: Python<'_>) -> PyErr {
        match self {
            FusionError::InvalidArgument { .. } => PyValueError::new_err(self.to_string()),
            FusionError::NoInsulator(_) => match LOCALIZATION_ERROR.get(py) {
                Some(class) => PyErr::from_type(class.bind(py).clone(), self.to_string()),
                // Unreachable after module init; still an exception, never a panic.
                None => PyRuntimeError::new_err(self.to_string()),
            },
        }
    }
}

impl CoreError for RaycastError {
    /// Every variant names the argument at fault (the message starts with it).
    fn into_pyerr(self, _py: Python<'_>) -> PyErr {
        PyValueError::new_err(self.to_string())
    }
}

impl CoreError for PacketError {
    fn into_pyerr(self, _py: Python<'_>) -> PyErr {
        PyValueError::new_err(self.to_string())
    }
}

impl CoreError for ControlError {
    fn into_pyerr(self, _py: Python<'_>) -> PyErr {
        PyValueError::new_err(self.to_string())
    }
}

/// Converts a core error into its Python exception (where a kernel runs with the GIL held).
pub fn to_pyerr<E: CoreError>(py: Python<'_>, err: E) -> PyErr {
    err.into_pyerr(py)
}

/// Runs `kernel` with the GIL released and maps its error to a Python exception.
///
/// Everything the kernel reads must already have been extracted from Python.
pub fn detach<T, E, F>(py: Python<'_>, kernel: F) -> PyResult<T>
where
    F: Ungil + FnOnce() -> Result<T, E>,
    E: CoreError + Send,
    T: Send,
{
    py.detach(kernel).map_err(|err| err.into_pyerr(py))
}
