//! `localize_bounded`: the fifth localization method (LiDAR line, camera-bounded ends).

use fusion_core::{BoundedLocalization, BoundedParams, BoxView, LocalizeParams, RansacParams};
use numpy::{IntoPyArray, PyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::camera::PyCameraModel;
use crate::culling::extract_boxes;
use crate::errors::detach;
use crate::pyutils::{extract_cloud, extract_f64_array, format_shape, frozen_array, vec3_text, with_cloud, Count};

/// A bounded localization in the body frame B: ``center`` (3,) m, ``direction`` (3,)
/// unit axis (largest-|component| positive), ``n_points`` the points on the line,
/// ``n_clusters``, ``n_nonfinite``, ``ends_from_image`` (how many of the insulator's
/// ends the boxes bounded: 2, 1 or 0), ``length`` (m between the two image bounds, or
/// None), ``views_used`` (boxes the line passed through), ``method`` ("bounded").
#[pyclass(frozen, module = "insulator_rs._core", name = "BoundedLocalization")]
pub struct PyBoundedLocalization {
    center: Py<PyArray1<f64>>,
    direction: Py<PyArray1<f64>>,
    n_points: usize,
    n_clusters: usize,
    n_nonfinite: usize,
    ends_from_image: usize,
    length: Option<f64>,
    views_used: usize,
}

#[pymethods]
impl PyBoundedLocalization {
    /// Insulator centre, (3,) float64, m, body frame B.
    #[getter]
    fn center<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.center.bind(py).clone()
    }
    /// Unit axis direction, (3,) float64, largest-|component| positive.
    #[getter]
    fn direction<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.direction.bind(py).clone()
    }
    /// Points on the fitted line (RANSAC inliers within tau).
    #[getter]
    fn n_points(&self) -> usize {
        self.n_points
    }
    /// Clusters the DBSCAN found.
    #[getter]
    fn n_clusters(&self) -> usize {
        self.n_clusters
    }
    /// Input points skipped for a NaN/Inf coordinate.
    #[getter]
    fn n_nonfinite(&self) -> usize {
        self.n_nonfinite
    }
    /// Ends of the insulator bounded by the boxes (2, 1 or 0).
    #[getter]
    fn ends_from_image(&self) -> usize {
        self.ends_from_image
    }
    /// Distance (m) between the two image bounds along the line, or None.
    #[getter]
    fn length(&self) -> Option<f64> {
        self.length
    }
    /// Boxes the fitted line passed through.
    #[getter]
    fn views_used(&self) -> usize {
        self.views_used
    }
    /// Always "bounded".
    #[getter]
    fn method(&self) -> &'static str {
        "bounded"
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!(
            "BoundedLocalization(center={}, direction={}, n_points={}, ends_from_image={}, length={}, views_used={})",
            vec3_text(self.center.bind(py))?,
            vec3_text(self.direction.bind(py))?,
            self.n_points,
            self.ends_from_image,
            self.length.map_or_else(|| "None".to_owned(), |l| format!("{l:.4}")),
            self.views_used
        ))
    }
}

/// The camera poses: a (4, 4) for a single box or a (K, 4, 4) stack, one per box.
fn extract_poses(obj: &Bound<'_, PyAny>, n_boxes: usize) -> PyResult<Vec<nalgebra::Isometry3<f64>>> {
    let (values, shape) = extract_f64_array(obj, "T_b_c")?;
    let k = match shape.as_slice() {
        [4, 4] => 1,
        [k, 4, 4] => *k,
        _ => {
            return Err(PyValueError::new_err(format!(
                "T_b_c: expected shape (4, 4) or (K, 4, 4), got {}",
                format_shape(&shape)
            )))
        }
    };
    if k != n_boxes {
        return Err(PyValueError::new_err(format!("T_b_c: {k} poses for {n_boxes} boxes (one pose per box)")));
    }
    values
        .chunks_exact(16)
        .map(|m| {
            fusion_core::rigid_from_matrix(&nalgebra::Matrix4::from_row_slice(m), "T_b_c")
                .map_err(|e| PyValueError::new_err(e.to_string()))
        })
        .collect()
}

/// Localizes the insulator in ``points_b`` (N,3 float32/float64, body frame B, m) with
/// its line from the LiDAR and its ends from the camera: the line is Algorithm 1's
/// (nearest DBSCAN cluster, RANSAC line, inliers within ``tau``); each detection box
/// ``boxes`` (K,4 or K,5 px, ``x1, y1, x2, y2``) of the camera ``cam`` at pose ``T_b_c``
/// ((4,4) for one box or (K,4,4), camera -> B of the cloud) bounds the insulator where
/// the line's projection leaves it. The centre is the middle of the median bounds.
///
/// A box edge within ``border_margin`` px of the image border bounds nothing; with one
/// end bounded the centre is that end plus half ``insulator_length`` (m, if given), with
/// none Algorithm 1's centre (``ends_from_image`` says which). ``max_extent`` (m) caps the
/// walk along the line. The other keywords are ``localize``'s. Raises
/// ``LocalizationError`` when no line is found, ``ValueError`` on a bad argument.
#[pyfunction]
#[pyo3(signature = (
    points_b,
    boxes,
    T_b_c,
    cam,
    *,
    insulator_length = None,
    border_margin = BoundedParams::default().border_margin,
    max_extent = BoundedParams::default().max_extent,
    eps = LocalizeParams::default().eps,
    min_points = Count(LocalizeParams::default().min_points as i128),
    tau = LocalizeParams::default().tau,
    ransac_threshold = LocalizeParams::default().ransac.threshold,
    max_iterations = Count(LocalizeParams::default().ransac.max_iterations as i128),
    confidence = LocalizeParams::default().ransac.confidence,
    seed = Count(i128::from(LocalizeParams::default().ransac.seed)),
),
text_signature = "(points_b, boxes, T_b_c, cam, *, insulator_length=None, border_margin=2.0, \
max_extent=6.0, eps=0.5, min_points=5, tau=0.2, ransac_threshold=0.1, max_iterations=1000, \
confidence=0.99, seed=0)")]
#[allow(clippy::too_many_arguments, non_snake_case)]
fn localize_bounded(
    py: Python<'_>,
    points_b: &Bound<'_, PyAny>,
    boxes: &Bound<'_, PyAny>,
    T_b_c: &Bound<'_, PyAny>,
    cam: PyRef<'_, PyCameraModel>,
    insulator_length: Option<f64>,
    border_margin: f64,
    max_extent: f64,
    eps: f64,
    min_points: Count,
    tau: f64,
    ransac_threshold: f64,
    max_iterations: Count,
    confidence: f64,
    seed: Count,
) -> PyResult<PyBoundedLocalization> {
    let params = BoundedParams {
        localize: LocalizeParams {
            eps,
            min_points: min_points.get("min_points", 1)?,
            tau,
            ransac: RansacParams {
                threshold: ransac_threshold,
                max_iterations: max_iterations.get("max_iterations", 1)?,
                confidence,
                seed: seed.get("seed", 0)?,
            },
        },
        insulator_length,
        border_margin,
        max_extent,
    };
    let pixel_boxes = extract_boxes(boxes)?;
    let poses = extract_poses(T_b_c, pixel_boxes.len())?;
    let views: Vec<BoxView> =
        pixel_boxes.into_iter().zip(poses).map(|(pixel_box, t_b_c)| BoxView { pixel_box, t_b_c }).collect();
    let camera = cam.inner;
    let cloud = extract_cloud(points_b, "points_b")?;
    let view = cloud.view()?;
    let BoundedLocalization { localization, ends_from_image, length, views_used } = detach(
        py,
        move || with_cloud!(view, p => fusion_core::localize_bounded(&p, &views, &camera, &params)),
    )?;
    Ok(PyBoundedLocalization {
        center: frozen_array(localization.center.to_vec().into_pyarray(py))?,
        direction: frozen_array(localization.direction.to_vec().into_pyarray(py))?,
        n_points: localization.n_points,
        n_clusters: localization.n_clusters,
        n_nonfinite: localization.n_nonfinite,
        ends_from_image,
        length,
        views_used,
    })
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyBoundedLocalization>()?;
    m.add_function(wrap_pyfunction!(localize_bounded, m)?)
}
