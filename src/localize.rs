//! `localize`: the five insulator localization methods (the paper's four and the bounded
//! fifth) through fusion_core's one entry point, and their one result class.

use std::str::FromStr;

use fusion_core::localize::bounded::{DEFAULT_BORDER_MARGIN, DEFAULT_MAX_EXTENT};
use fusion_core::{BoxEvidence, BoxView, Localization, LocalizeParams, Method, RansacParams};
use numpy::{IntoPyArray, PyArray1};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::camera::PyCameraModel;
use crate::culling::extract_boxes;
use crate::errors::{detach, to_pyerr};
use crate::pyutils::{extract_cloud, extract_f64_array, format_shape, frozen_array, vec3_text, with_cloud, Count};

/// An insulator estimate in the body frame B: ``method``, ``center`` (3,) m, ``direction``
/// (3,) unit axis with its largest-|component| positive, ``n_points`` the points that
/// determined the centre, ``n_clusters`` clusters the first DBSCAN found (1 for
/// ``"ransac"``: its inlier set), ``n_nonfinite`` input points skipped for NaN/Inf; the
/// bounded method's ``ends_from_image`` (how many of the insulator's ends the boxes bounded:
/// 2, 1 or 0), ``length`` (m between the two image bounds, or None) and ``views_used``
/// (boxes the line passed through), which are 0, None and 0 for the paper's four.
#[pyclass(frozen, module = "insulator_rs._core", name = "Localization")]
pub struct PyLocalization {
    center: Py<PyArray1<f64>>,
    direction: Py<PyArray1<f64>>,
    n_points: usize,
    n_clusters: usize,
    n_nonfinite: usize,
    method: Method,
    ends_from_image: usize,
    length: Option<f64>,
    views_used: usize,
}

#[pymethods]
impl PyLocalization {
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
    /// Number of points that determined the centre.
    #[getter]
    fn n_points(&self) -> usize {
        self.n_points
    }
    /// Number of clusters the first DBSCAN found (1 for ``"ransac"``).
    #[getter]
    fn n_clusters(&self) -> usize {
        self.n_clusters
    }
    /// Number of input points skipped for a NaN/Inf coordinate.
    #[getter]
    fn n_nonfinite(&self) -> usize {
        self.n_nonfinite
    }
    /// The method that produced the estimate.
    #[getter]
    fn method(&self) -> &'static str {
        self.method.as_str()
    }
    /// Ends of the insulator bounded by the boxes (2, 1 or 0; 0 for the paper's four).
    #[getter]
    fn ends_from_image(&self) -> usize {
        self.ends_from_image
    }
    /// Distance (m) between the two image bounds along the line, or None.
    #[getter]
    fn length(&self) -> Option<f64> {
        self.length
    }
    /// Boxes the fitted line passed through (0 for the paper's four).
    #[getter]
    fn views_used(&self) -> usize {
        self.views_used
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        let image = if self.method.needs_boxes() {
            format!(
                ", ends_from_image={}, length={}, views_used={}",
                self.ends_from_image,
                self.length.map_or_else(|| "None".to_owned(), |l| format!("{l:.4}")),
                self.views_used
            )
        } else {
            String::new()
        };
        Ok(format!(
            "Localization(method={:?}, center={}, direction={}, n_points={}, n_clusters={}, n_nonfinite={}{image})",
            self.method.as_str(),
            vec3_text(self.center.bind(py))?,
            vec3_text(self.direction.bind(py))?,
            self.n_points,
            self.n_clusters,
            self.n_nonfinite
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

/// The detection events of the bounded method: boxes, one camera pose per box, the camera.
struct Views {
    views: Vec<BoxView>,
    camera: fusion_core::CameraModel,
}

/// The bounded method's inputs, or none for the paper's four (which refuse them: an input a
/// method does not read is an error, never silently dropped).
fn extract_views(
    method: Method,
    boxes: Option<&Bound<'_, PyAny>>,
    t_b_c: Option<&Bound<'_, PyAny>>,
    cam: Option<PyRef<'_, PyCameraModel>>,
    insulator_length: Option<f64>,
) -> PyResult<Option<Views>> {
    if !method.needs_boxes() {
        let given = [
            ("boxes", boxes.is_some()),
            ("T_b_c", t_b_c.is_some()),
            ("cam", cam.is_some()),
            ("insulator_length", insulator_length.is_some()),
        ];
        return match given.iter().find(|(_, g)| *g) {
            Some((name, _)) => Err(PyValueError::new_err(format!(
                "{name}: the {method} method reads the cloud alone; only \"bounded\" reads {name}"
            ))),
            None => Ok(None),
        };
    }
    let missing = |name: &str| PyValueError::new_err(format!("{name}: the {method} method needs it"));
    let pixel_boxes = extract_boxes(boxes.ok_or_else(|| missing("boxes"))?)?;
    let poses = extract_poses(t_b_c.ok_or_else(|| missing("T_b_c"))?, pixel_boxes.len())?;
    let camera = cam.ok_or_else(|| missing("cam"))?.inner;
    let views = pixel_boxes.into_iter().zip(poses).map(|(pixel_box, t_b_c)| BoxView { pixel_box, t_b_c }).collect();
    Ok(Some(Views { views, camera }))
}

/// Localizes the insulator in a culled, accumulated cloud ``points_b``
/// (N,3 float32/float64, body frame B, m; the UAV at the origin).
///
/// ``method``: ``"dbscan"`` (nearest cluster: centroid and PCA axis),
/// ``"ransac"`` (RANSAC line through the whole cloud; centre = point on the line
/// at the median projection of the points within ``tau``), ``"dbscan+ransac"``
/// (the paper's Algorithm 1), ``"dbscan+pca"`` (Algorithm 2) or ``"bounded"``
/// (Algorithm 1's line, its ends from the camera: each detection box ``boxes`` (K,4 or
/// K,5 px, ``x1, y1, x2, y2``) of the camera ``cam`` at pose ``T_b_c`` ((4,4) for one box
/// or (K,4,4), camera -> B of the cloud) bounds the insulator where the line's projection
/// leaves it; the centre is the middle of the median bounds). Only ``"bounded"`` reads
/// ``boxes``, ``T_b_c``, ``cam``, ``insulator_length`` (m), ``border_margin`` (px: a box
/// edge this close to the image border bounds nothing) and ``max_extent`` (m: caps the walk
/// along the line); the others refuse the first four. With one end bounded the centre is
/// that end plus half ``insulator_length`` (if given). ``eps`` (m) and ``min_points`` drive
/// DBSCAN, ``tau`` (m) is the distance to the line that counts a point as insulator,
/// ``ransac_threshold`` (m), ``max_iterations``, ``confidence`` and ``seed`` drive RANSAC.
/// ``localize_defaults(method)`` lists the parameters each method reads, with their
/// defaults (for a Livox Mid-360 at 8-10 m, 3 accumulated frames). NaN/Inf points are
/// skipped and counted.
///
/// Raises ``LocalizationError`` when the cloud holds no usable insulator (an empty cloud
/// included); ``AmbiguousLocalizationError`` (a ``LocalizationError``) when the bounded
/// method, given ``insulator_length``, finds another, larger line in the box that fits the
/// length better than the one fitted (a conductor in front of the string); ``ValueError`` on
/// a bad parameter.
#[pyfunction]
#[pyo3(signature = (
    points_b,
    method = "dbscan+ransac",
    *,
    boxes = None,
    T_b_c = None,
    cam = None,
    insulator_length = None,
    border_margin = DEFAULT_BORDER_MARGIN,
    max_extent = DEFAULT_MAX_EXTENT,
    eps = LocalizeParams::default().eps,
    min_points = Count(LocalizeParams::default().min_points as i128),
    tau = LocalizeParams::default().tau,
    ransac_threshold = LocalizeParams::default().ransac.threshold,
    max_iterations = Count(LocalizeParams::default().ransac.max_iterations as i128),
    confidence = LocalizeParams::default().ransac.confidence,
    seed = Count(i128::from(LocalizeParams::default().ransac.seed)),
),
// The defaults spelled out for help(); tests/test_core_localize.py checks them against
// localize_defaults() (the fusion_core constants), so they cannot drift.
text_signature = "(points_b, method='dbscan+ransac', *, boxes=None, T_b_c=None, cam=None, \
insulator_length=None, border_margin=2.0, max_extent=6.0, eps=0.5, min_points=5, tau=0.2, \
ransac_threshold=0.1, max_iterations=1000, confidence=0.99, seed=0)")]
#[allow(clippy::too_many_arguments, non_snake_case)]
fn localize(
    py: Python<'_>,
    points_b: &Bound<'_, PyAny>,
    method: &str,
    boxes: Option<&Bound<'_, PyAny>>,
    T_b_c: Option<&Bound<'_, PyAny>>,
    cam: Option<PyRef<'_, PyCameraModel>>,
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
) -> PyResult<PyLocalization> {
    let method = Method::from_str(method).map_err(|e| to_pyerr(py, e))?;
    let params = LocalizeParams {
        eps,
        min_points: min_points.get("min_points", 1)?,
        tau,
        ransac: RansacParams {
            threshold: ransac_threshold,
            max_iterations: max_iterations.get("max_iterations", 1)?,
            confidence,
            seed: seed.get("seed", 0)?,
        },
    };
    let views = extract_views(method, boxes, T_b_c, cam, insulator_length)?;
    let cloud = extract_cloud(points_b, "points_b")?;
    let view = cloud.view()?;
    let loc: Localization = detach(py, move || {
        let evidence = views.as_ref().map(|v| BoxEvidence {
            insulator_length,
            border_margin,
            max_extent,
            ..BoxEvidence::new(&v.views, &v.camera)
        });
        with_cloud!(view, p => fusion_core::localize(&p, method, &params, evidence.as_ref()))
    })?;
    Ok(PyLocalization {
        center: frozen_array(loc.center.to_vec().into_pyarray(py))?,
        direction: frozen_array(loc.direction.to_vec().into_pyarray(py))?,
        n_points: loc.n_points,
        n_clusters: loc.n_clusters,
        n_nonfinite: loc.n_nonfinite,
        method: loc.method,
        ends_from_image: loc.ends_from_image,
        length: loc.length,
        views_used: loc.views_used,
    })
}

/// ``localize(points_b, "bounded", boxes=boxes, T_b_c=T_b_c, cam=cam, **tuning)``: the bounded
/// method in its positional form (``tuning``: ``insulator_length``, ``border_margin``,
/// ``max_extent`` and the line fit's keywords, as ``localize`` takes them).
#[pyfunction]
#[pyo3(signature = (points_b, boxes, T_b_c, cam, **tuning))]
#[allow(non_snake_case)]
fn localize_bounded<'py>(
    py: Python<'py>,
    points_b: &Bound<'py, PyAny>,
    boxes: &Bound<'py, PyAny>,
    T_b_c: &Bound<'py, PyAny>,
    cam: &Bound<'py, PyAny>,
    tuning: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let kwargs = match tuning {
        Some(t) => t.copy()?,
        None => PyDict::new(py),
    };
    for (name, value) in [("boxes", boxes), ("T_b_c", T_b_c), ("cam", cam)] {
        if kwargs.contains(name)? {
            return Err(PyTypeError::new_err(format!("{name}: given both by position and by keyword")));
        }
        kwargs.set_item(name, value)?;
    }
    wrap_pyfunction!(localize, py)?.call((points_b, Method::Bounded.as_str()), Some(&kwargs))
}

/// The default ``localize`` parameters (Livox Mid-360 at 8-10 m, 3 accumulated frames), as
/// a fresh dict. Without ``method``: the line fit's (eps, min_points, tau,
/// ransac_threshold, max_iterations, confidence, seed, also ``ransac_line``'s). With a
/// ``method``: exactly the parameters that method reads (``"bounded"`` adds
/// insulator_length, border_margin and max_extent); any other has no effect on it.
#[pyfunction]
#[pyo3(signature = (method = None))]
fn localize_defaults<'py>(py: Python<'py>, method: Option<&str>) -> PyResult<Bound<'py, PyDict>> {
    let d = LocalizeParams::default();
    let all = PyDict::new(py);
    all.set_item("eps", d.eps)?;
    all.set_item("min_points", d.min_points)?;
    all.set_item("tau", d.tau)?;
    all.set_item("ransac_threshold", d.ransac.threshold)?;
    all.set_item("max_iterations", d.ransac.max_iterations)?;
    all.set_item("confidence", d.ransac.confidence)?;
    all.set_item("seed", d.ransac.seed)?;
    let Some(method) = method else {
        return Ok(all);
    };
    let method = Method::from_str(method).map_err(|e| to_pyerr(py, e))?;
    all.set_item("insulator_length", py.None())?;
    all.set_item("border_margin", DEFAULT_BORDER_MARGIN)?;
    all.set_item("max_extent", DEFAULT_MAX_EXTENT)?;
    let out = PyDict::new(py);
    for name in method.parameters() {
        out.set_item(name, all.get_item(name)?)?;
    }
    Ok(out)
}

/// The names of the localization methods, in fusion_core's order (the paper's four, then
/// ``"bounded"``): what ``insulator_rs.LocalizationMethod`` must list.
#[pyfunction]
fn localize_methods() -> Vec<&'static str> {
    Method::ALL.iter().map(Method::as_str).collect()
}

pub fn register(_py: Python<'_>, m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyLocalization>()?;
    m.add("SCALE_TOLERANCE", fusion_core::SCALE_TOLERANCE)?;
    m.add_function(wrap_pyfunction!(localize, m)?)?;
    m.add_function(wrap_pyfunction!(localize_bounded, m)?)?;
    m.add_function(wrap_pyfunction!(localize_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(localize_methods, m)?)
}
