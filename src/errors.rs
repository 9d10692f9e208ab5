//! The one place where the core crates' errors become Python exceptions, and the
//! helper that runs a kernel with the GIL released.
//!
//! * `FusionError::InvalidArgument` -> `ValueError("<argument>: <reason>")`.
//! * `FusionError::NoInsulator` -> `insulator_rs.exceptions.LocalizationError`.
//! * `FusionError::Ambiguous` -> `insulator_rs.exceptions.AmbiguousLocalizationError` (a
//!   `LocalizationError`: the bounded method refused a box it cannot tell apart).
//! * every `RaycastError` (scene_raycast) is an argument error naming the
//!   argument -> `ValueError`.
//! * livox_mid360's `PacketError` (a malformed datagram) and `ControlError` (a bad
//!   command frame) -> `insulator_rs.exceptions.PacketError`, with the crate's message
//!   (it starts with the packet or frame field at fault: `packet.crc32: ...`,
//!   `command.sof: ...`).
//!
//! Every exception class is declared in Python (`insulator_rs/exceptions.py`); the
//! bindings look the classes up there at module init ([`register`]) and keep them,
//! so `insulator_rs.LocalizationError is insulator_rs.exceptions.LocalizationError`.
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
static AMBIGUOUS_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static PACKET_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// `insulator_rs.exceptions.<name>`, looked up once and kept in `cell`.
fn lookup<'py>(py: Python<'py>, cell: &'static PyOnceLock<Py<PyType>>, name: &str) -> PyResult<&'py Py<PyType>> {
    cell.get_or_try_init(py, || {
        let class = py.import("insulator_rs.exceptions")?.getattr(name)?;
        Ok(class.cast_into::<PyType>()?.unbind())
    })
}

/// Looks up the exception classes declared in `exceptions.py`; re-exports
/// `LocalizationError` and `AmbiguousLocalizationError` from the module (the same class
/// objects).
pub fn register(py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    lookup(py, &PACKET_ERROR, "PacketError")?;
    let class = lookup(py, &LOCALIZATION_ERROR, "LocalizationError")?;
    m.add("LocalizationError", class.clone_ref(py))?;
    let class = lookup(py, &AMBIGUOUS_ERROR, "AmbiguousLocalizationError")?;
    m.add("AmbiguousLocalizationError", class.clone_ref(py))
}

/// An exception of a class looked up by [`register`] (a `RuntimeError` if the module
/// was never initialised, which cannot happen once it is imported: never a panic).
fn raise(py: Python<'_>, cell: &'static PyOnceLock<Py<PyType>>, message: String) -> PyErr {
    match cell.get(py) {
        Some(class) => PyErr::from_type(class.bind(py).clone(), message),
        None => PyRuntimeError::new_err(message),
    }
}

/// An error of a core crate, with the Python exception it becomes.
pub trait CoreError: std::fmt::Display {
    fn into_pyerr(self, py: Python<'_>) -> PyErr;
}

impl CoreError for FusionError {
    fn into_pyerr(self, py: Python<'_>) -> PyErr {
        match self {
            FusionError::InvalidArgument { .. } => PyValueError::new_err(self.to_string()),
            FusionError::NoInsulator(_) => raise(py, &LOCALIZATION_ERROR, self.to_string()),
            FusionError::Ambiguous(_) => raise(py, &AMBIGUOUS_ERROR, self.to_string()),
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
    fn into_pyerr(self, py: Python<'_>) -> PyErr {
        raise(py, &PACKET_ERROR, self.to_string())
    }
}

impl CoreError for ControlError {
    fn into_pyerr(self, py: Python<'_>) -> PyErr {
        raise(py, &PACKET_ERROR, self.to_string())
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
