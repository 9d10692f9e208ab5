//! `deskew` and `deskew_points_in_boxes`: motion compensation of a scan with per-point times.

use fusion_core::PoseStream;
use nalgebra::{Isometry3, Matrix4};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use crate::camera::PyCameraModel;
use crate::culling::extract_boxes;
use crate::errors::{detach, to_pyerr};
use crate::pyutils::{extract_cloud, extract_f64_array, extract_rigid, format_shape, with_cloud};

/// The pose stream from ``pose_times`` (K,) and ``poses`` (K, 4, 4) T_w_b.
fn extract_stream(py: Python<'_>, pose_times: &Bound<'_, PyAny>, poses: &Bound<'_, PyAny>) -> PyResult<PoseStream> {
    let (times, tshape) = extract_f64_array(pose_times, "pose_times")?;
    if tshape.len() != 1 {
        return Err(PyValueError::new_err(format!("pose_times: expected shape (K,), got {}", format_shape(&tshape))));
    }
    let (values, shape) = extract_f64_array(poses, "poses")?;
    if shape.len() != 3 || shape[1] != 4 || shape[2] != 4 {
        return Err(PyValueError::new_err(format!("poses: expected shape (K, 4, 4), got {}", format_shape(&shape))));
    }
    let poses = values
        .chunks_exact(16)
        .enumerate()
        .map(|(k, m)| {
            fusion_core::rigid_from_matrix(&Matrix4::from_row_slice(m), "poses").map_err(|e| {
                PyValueError::new_err(format!("poses[{k}]: {}", e.to_string().trim_start_matches("poses: ")))
            })
        })
        .collect::<PyResult<Vec<Isometry3<f64>>>>()?;
    PoseStream::new(times, poses).map_err(|e| to_pyerr(py, e))
}

fn extract_times(obj: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    let (times, shape) = extract_f64_array(obj, "times")?;
    if shape.len() != 1 {
        return Err(PyValueError::new_err(format!("times: expected shape (N,), got {}", format_shape(&shape))));
    }
    Ok(times)
}

fn to_array<'py>(py: Python<'py>, cloud: Vec<[f64; 3]>) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let n = cloud.len();
    Ok(Array2::from_shape_vec((n, 3), cloud.into_flattened())
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?
        .into_pyarray(py))
}

/// Re-expresses every point of ``points_l`` (N,3 float32/float64, L frame, m), measured at
/// ``times`` (N,) s, in L at ``t_ref``: ``T_w_b(t)`` is interpolated from the pose stream
/// ``pose_times`` (K,) strictly increasing, ``poses`` (K,4,4) T_w_b, by slerp (rotation) and
/// lerp (translation); ``T_b_l`` is the LiDAR extrinsics. Returns (N,3) float64; a point
/// with a NaN coordinate stays NaN. A time (or ``t_ref``) outside the pose stream is a
/// ``ValueError`` naming ``times`` (``t_ref``): no extrapolation.
#[pyfunction]
#[pyo3(signature = (points_l, times, pose_times, poses, t_ref, T_b_l))]
#[allow(non_snake_case)]
fn deskew<'py>(
    py: Python<'py>,
    points_l: &Bound<'py, PyAny>,
    times: &Bound<'py, PyAny>,
    pose_times: &Bound<'py, PyAny>,
    poses: &Bound<'py, PyAny>,
    t_ref: f64,
    T_b_l: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let cloud = extract_cloud(points_l, "points_l")?;
    let times = extract_times(times)?;
    let stream = extract_stream(py, pose_times, poses)?;
    let t_b_l = extract_rigid(T_b_l, "T_b_l")?;
    let view = cloud.view()?;
    let out = detach(py, move || with_cloud!(view, p => fusion_core::deskew(&p, &times, &stream, t_ref, &t_b_l)))?;
    to_array(py, out)
}

/// `(deskewed (N,3) float64, per-box int64 index arrays)`.
type Deskewed<'py> = (Bound<'py, PyArray2<f64>>, Vec<Bound<'py, PyArray1<i64>>>);

/// :func:`deskew` fused with :func:`points_in_boxes` on the deskewed cloud, in one pass:
/// returns ``(deskewed, indices)`` where ``indices[k]`` are the ascending indices of the
/// points projecting inside box k through ``T_c_l`` and ``cam`` (same rules as
/// ``points_in_boxes``).
#[pyfunction]
#[pyo3(signature = (points_l, times, pose_times, poses, t_ref, T_b_l, T_c_l, cam, boxes))]
#[allow(non_snake_case, clippy::too_many_arguments)]
fn deskew_points_in_boxes<'py>(
    py: Python<'py>,
    points_l: &Bound<'py, PyAny>,
    times: &Bound<'py, PyAny>,
    pose_times: &Bound<'py, PyAny>,
    poses: &Bound<'py, PyAny>,
    t_ref: f64,
    T_b_l: &Bound<'py, PyAny>,
    T_c_l: &Bound<'py, PyAny>,
    cam: PyRef<'py, PyCameraModel>,
    boxes: &Bound<'py, PyAny>,
) -> PyResult<Deskewed<'py>> {
    let cloud = extract_cloud(points_l, "points_l")?;
    let times = extract_times(times)?;
    let stream = extract_stream(py, pose_times, poses)?;
    let t_b_l = extract_rigid(T_b_l, "T_b_l")?;
    let t_c_l = extract_rigid(T_c_l, "T_c_l")?;
    let boxes = extract_boxes(boxes)?;
    let camera = cam.inner;
    let view = cloud.view()?;
    let (out, lists) = detach(py, move || {
        with_cloud!(view, p => fusion_core::deskew_points_in_boxes(&p, &times, &stream, t_ref, &t_b_l, &t_c_l, &camera, &boxes))
    })?;
    let lists = lists
        .into_iter()
        .map(|l| l.into_iter().map(|i| i as i64).collect::<Vec<i64>>().into_pyarray(py))
        .collect();
    Ok((to_array(py, out)?, lists))
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(deskew, m)?)?;
    m.add_function(wrap_pyfunction!(deskew_points_in_boxes, m)?)
}
