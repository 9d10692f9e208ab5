//! Bindings of `scene_raycast`: `RaycastScene` (build, `cast`, `render`) and
//! its `RaycastHits` result. Arrays are extracted and validated here, the
//! kernels run with the GIL released through `errors::detach`, which maps every
//! `RaycastError` (an argument error) to a `ValueError` starting with the argument's name.

use nalgebra::{Matrix3, Point3, Vector3};
use numpy::ndarray::{Array2, Array3};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use scene_raycast::{render, Lighting, Scene};

use crate::errors::detach;
use crate::pyutils::{extract_cloud, extract_rigid, frozen_array, Cloud, Count};

/// The rows of a (N, 3) array: borrowed in place when it is C-contiguous float64
/// (a 12 MP camera's ray table is 288 MB), else copied.
enum Rows<'py> {
    Borrowed(PyReadonlyArray2<'py, f64>),
    Copied(Vec<[f64; 3]>),
}

impl Rows<'_> {
    fn as_rows(&self) -> &[[f64; 3]] {
        match self {
            // `rows3` borrows only arrays that `borrowed_rows` reads.
            Rows::Borrowed(arr) => borrowed_rows(arr).unwrap_or(&[]),
            Rows::Copied(rows) => rows,
        }
    }
}

/// The rows of a C-contiguous (N, 3) float64 array, without a copy.
fn borrowed_rows<'a>(arr: &'a PyReadonlyArray2<'_, f64>) -> Option<&'a [[f64; 3]]> {
    let flat = arr.as_slice().ok()?;
    if arr.shape()[1] != 3 || flat.len() % 3 != 0 {
        return None;
    }
    // SAFETY: `[f64; 3]` has the size of three f64 and the alignment of one, so the
    // 3N contiguous f64 of a C-contiguous (N, 3) array are N rows; the read-only
    // borrow `arr` keeps the buffer alive and unchanged while the slice lives.
    Some(unsafe { std::slice::from_raw_parts(flat.as_ptr().cast::<[f64; 3]>(), flat.len() / 3) })
}

/// A (N, 3) float64 or float32 array (validated by `pyutils::extract_cloud`) as rows.
fn rows3<'py>(name: &'static str, obj: &Bound<'py, PyAny>) -> PyResult<Rows<'py>> {
    fn collect<T: Copy + Into<f64> + numpy::Element>(
        arr: &PyReadonlyArray2<'_, T>,
    ) -> Vec<[f64; 3]> {
        let view = arr.as_array();
        view.rows()
            .into_iter()
            .map(|r| [r[0].into(), r[1].into(), r[2].into()])
            .collect()
    }
    Ok(match extract_cloud(obj, name)? {
        Cloud::F64(arr) if borrowed_rows(&arr).is_some() => Rows::Borrowed(arr),
        Cloud::F64(arr) => Rows::Copied(collect(&arr)),
        Cloud::F32(arr) => Rows::Copied(collect(&arr)),
    })
}

fn not_an_array(name: &str, obj: &Bound<'_, PyAny>, want: &str) -> PyErr {
    let got = match (obj.getattr("dtype"), obj.getattr("shape")) {
        (Ok(dtype), Ok(shape)) => format!("an array of dtype {dtype} and shape {shape}"),
        _ => obj
            .get_type()
            .name()
            .map_or_else(|_| "an unknown object".to_owned(), |n| n.to_string()),
    };
    PyTypeError::new_err(format!("{name}: expected {want}, got {got}"))
}

/// (T, 3) vertex indices of any integer dtype, checked for sign and width.
fn triangle_rows(obj: &Bound<'_, PyAny>) -> PyResult<Vec<[u32; 3]>> {
    let wide: Vec<[i64; 3]> = if let Ok(arr) = obj.extract::<PyReadonlyArray2<'_, u32>>() {
        index_rows(&arr)?
    } else if let Ok(arr) = obj.extract::<PyReadonlyArray2<'_, i64>>() {
        index_rows(&arr)?
    } else if let Ok(arr) = obj.extract::<PyReadonlyArray2<'_, i32>>() {
        index_rows(&arr)?
    } else {
        return Err(not_an_array(
            "triangles",
            obj,
            "a (T, 3) uint32, int32 or int64 array",
        ));
    };
    wide.iter()
        .enumerate()
        .map(|(t, row)| {
            let mut out = [0u32; 3];
            for (o, &v) in out.iter_mut().zip(row) {
                *o = u32::try_from(v).map_err(|_| {
                    PyValueError::new_err(format!(
                        "triangles: triangle {t} has index {v}, outside [0, 2^32)"
                    ))
                })?;
            }
            Ok(out)
        })
        .collect()
}

fn index_rows<T: Copy + Into<i64> + numpy::Element>(
    arr: &PyReadonlyArray2<'_, T>,
) -> PyResult<Vec<[i64; 3]>> {
    let view = arr.as_array();
    if view.ncols() != 3 {
        return Err(PyValueError::new_err(format!(
            "triangles: expected shape (T, 3), got {:?}",
            arr.shape()
        )));
    }
    Ok(view
        .rows()
        .into_iter()
        .map(|r| [r[0].into(), r[1].into(), r[2].into()])
        .collect())
}

fn instance_rows(obj: &Bound<'_, PyAny>) -> PyResult<Vec<i32>> {
    if let Ok(arr) = obj.extract::<PyReadonlyArray1<'_, i32>>() {
        return Ok(arr.as_array().to_vec());
    }
    if let Ok(arr) = obj.extract::<PyReadonlyArray1<'_, i64>>() {
        return arr
            .as_array()
            .iter()
            .map(|&v| {
                i32::try_from(v).map_err(|_| {
                    PyValueError::new_err(format!("instance_ids: id {v} does not fit in int32"))
                })
            })
            .collect();
    }
    Err(not_an_array(
        "instance_ids",
        obj,
        "a (T,) int32 or int64 array",
    ))
}

fn vec3(name: &str, v: [f64; 3]) -> PyResult<Vector3<f64>> {
    if v.iter().all(|c| c.is_finite()) {
        Ok(Vector3::from(v))
    } else {
        Err(PyValueError::new_err(format!(
            "{name}: expected 3 finite numbers, got {v:?}"
        )))
    }
}

/// The rotation and position of a 4x4 rigid pose (checked by `pyutils::extract_rigid`).
fn pose(name: &'static str, obj: &Bound<'_, PyAny>) -> PyResult<(Matrix3<f64>, Point3<f64>)> {
    let iso = extract_rigid(obj, name)?;
    Ok((
        iso.rotation.to_rotation_matrix().into_inner(),
        Point3::from(iso.translation.vector),
    ))
}

/// Hits of a batch of rays: one entry per ray, as numpy arrays.
#[pyclass(frozen, module = "insulator_rs._core")]
pub struct RaycastHits {
    distance: Py<PyArray1<f64>>,
    instance_id: Py<PyArray1<i32>>,
    triangle: Py<PyArray1<i64>>,
    normal: Py<PyArray2<f64>>,
}

#[pymethods]
impl RaycastHits {
    /// (N,) float64, metres along the unit ray; inf on a miss.
    #[getter]
    fn distance(&self, py: Python<'_>) -> Py<PyArray1<f64>> {
        self.distance.clone_ref(py)
    }
    /// (N,) int32, the instance hit; -1 on a miss.
    #[getter]
    fn instance_id(&self, py: Python<'_>) -> Py<PyArray1<i32>> {
        self.instance_id.clone_ref(py)
    }
    /// (N,) int64, the triangle hit; -1 on a miss.
    #[getter]
    fn triangle(&self, py: Python<'_>) -> Py<PyArray1<i64>> {
        self.triangle.clone_ref(py)
    }
    /// (N, 3) float64, unit winding normal of the triangle hit in W; zeros on a miss.
    #[getter]
    fn normal(&self, py: Python<'_>) -> Py<PyArray2<f64>> {
        self.normal.clone_ref(py)
    }
    fn __len__(&self, py: Python<'_>) -> usize {
        self.distance.bind(py).len()
    }
    fn __repr__(&self, py: Python<'_>) -> String {
        let ids = self.instance_id.bind(py).readonly();
        let hits = ids.as_array().iter().filter(|&&i| i >= 0).count();
        format!("RaycastHits(n_rays={}, n_hits={hits})", ids.len())
    }
}

/// A static triangle scene in the world frame W for ray casting.
#[pyclass(frozen, module = "insulator_rs._core")]
pub struct RaycastScene {
    scene: Scene,
}

#[pymethods]
impl RaycastScene {
    /// Builds the BVH. `vertices` (V, 3) float64 in W (m), `triangles` (T, 3)
    /// vertex indices, `instance_ids` (T,) non-negative ints.
    #[new]
    fn new(
        py: Python<'_>,
        vertices: &Bound<'_, PyAny>,
        triangles: &Bound<'_, PyAny>,
        instance_ids: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let vertices = rows3("vertices", vertices)?;
        let triangles = triangle_rows(triangles)?;
        let ids = instance_rows(instance_ids)?;
        let vertices = vertices.as_rows();
        let scene = detach(py, || Scene::new(vertices, &triangles, &ids))?;
        Ok(Self { scene })
    }

    /// Number of triangles.
    #[getter]
    fn n_triangles(&self) -> usize {
        self.scene.n_triangles()
    }

    /// Casts rays from `origins` along `directions` (both (N, 3) in W; the
    /// directions need not be unit) up to `max_range` metres (> 0, inf allowed).
    fn cast(
        &self,
        py: Python<'_>,
        origins: &Bound<'_, PyAny>,
        directions: &Bound<'_, PyAny>,
        max_range: f64,
    ) -> PyResult<RaycastHits> {
        let origins = rows3("origins", origins)?;
        let directions = rows3("directions", directions)?;
        let (origins, directions) = (origins.as_rows(), directions.as_rows());
        let hits = detach(py, || self.scene.cast(origins, directions, max_range))?;
        let n = hits.len();
        let normal = Array2::from_shape_vec((n, 3), hits.normal.into_flattened())
            .map_err(|e| PyValueError::new_err(format!("normal: {e}")))?;
        Ok(RaycastHits {
            distance: frozen_array(hits.distance.into_pyarray(py))?,
            instance_id: frozen_array(hits.instance_id.into_pyarray(py))?,
            triangle: frozen_array(hits.triangle.into_pyarray(py))?,
            normal: frozen_array(normal.into_pyarray(py))?,
        })
    }

    /// Renders a camera image.
    ///
    /// `T_w_c` (4x4) is the camera pose in W (optical frame C: z forward, x
    /// right, y down); `rays_c` (height*width, 3) is the ray of every pixel in C,
    /// row-major (any lens model); `albedo` (K, 3) the linear RGB colour of
    /// instance ids 0..K. Colours are linear RGB >= 0; `sun_direction` points
    /// from the scene to the sun in W; `haze_density` in 1/m; `noise_sigma` in
    /// 8-bit counts. Returns `(rgb (H, W, 3) uint8, instance_id (H, W) int32
    /// (-1 for sky/far ground), depth (H, W) float32 (m, inf where no geometry))`.
    #[pyo3(signature = (
        T_w_c, rays_c, width, height, albedo, *,
        sun_direction = [0.5, 0.3, 0.81], sun_color = [1.0, 0.97, 0.9],
        ambient = [0.35, 0.38, 0.45], sky_zenith = [0.25, 0.45, 0.85],
        sky_horizon = [0.75, 0.82, 0.92], ground_color = [0.3, 0.35, 0.22],
        ground_height = 0.0, haze_density = 0.0, noise_sigma = 0.0, seed = Count(0),
        shadows = true, max_range = 1000.0
    ))]
    #[allow(non_snake_case, clippy::too_many_arguments)]
    fn render<'py>(
        &self,
        py: Python<'py>,
        T_w_c: &Bound<'py, PyAny>,
        rays_c: &Bound<'py, PyAny>,
        width: Count,
        height: Count,
        albedo: &Bound<'py, PyAny>,
        sun_direction: [f64; 3],
        sun_color: [f64; 3],
        ambient: [f64; 3],
        sky_zenith: [f64; 3],
        sky_horizon: [f64; 3],
        ground_color: [f64; 3],
        ground_height: f64,
        haze_density: f64,
        noise_sigma: f64,
        seed: Count,
        shadows: bool,
        max_range: f64,
    ) -> PyResult<(
        Bound<'py, PyArray3<u8>>,
        Bound<'py, PyArray2<i32>>,
        Bound<'py, PyArray2<f32>>,
    )> {
        let width: usize = width.get("width", 1)?;
        let height: usize = height.get("height", 1)?;
        let seed: u64 = seed.get("seed", 0)?;
        let (rotation, position) = pose("T_w_c", T_w_c)?;
        let rays = rows3("rays_c", rays_c)?;
        let albedo = rows3("albedo", albedo)?;
        let lighting = Lighting {
            sun_direction: vec3("sun_direction", sun_direction)?,
            sun_color,
            ambient,
            sky_zenith,
            sky_horizon,
            ground_color,
            ground_height,
            haze_density,
            noise_sigma,
            seed,
            shadows,
            max_range,
        };
        let (rays, albedo) = (rays.as_rows(), albedo.as_rows());
        let image = detach(py, || {
            render(
                &self.scene,
                &rotation,
                &position,
                rays,
                width,
                height,
                albedo,
                &lighting,
            )
        })?;
        let shape_error =
            |e: numpy::ndarray::ShapeError| PyValueError::new_err(format!("image: {e}"));
        let rgb = Array3::from_shape_vec((height, width, 3), image.rgb).map_err(shape_error)?;
        let ids =
            Array2::from_shape_vec((height, width), image.instance_id).map_err(shape_error)?;
        let depth = Array2::from_shape_vec((height, width), image.depth).map_err(shape_error)?;
        Ok((
            rgb.into_pyarray(py),
            ids.into_pyarray(py),
            depth.into_pyarray(py),
        ))
    }

    fn __repr__(&self) -> String {
        format!("RaycastScene(n_triangles={})", self.scene.n_triangles())
    }
}

/// Adds the ray-casting classes to the extension module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<RaycastScene>()?;
    m.add_class::<RaycastHits>()?;
    Ok(())
}
