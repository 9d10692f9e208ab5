//! Test scenes shared by the bounded method's and the ambiguity rule's unit tests: a
//! pinhole camera looking along B's x axis, straight "strings" of LiDAR points, their boxes.

use nalgebra::{Isometry3, Matrix4, Point3};

use crate::camera::CameraModel;
use crate::culling::PixelBox;
use crate::transform::rigid_from_matrix;

/// The camera looking along B's x axis, level (C's z = B's x, C's x = -B's y, C's y = -B's z).
pub(crate) fn forward_camera() -> Isometry3<f64> {
    let m = Matrix4::new(0.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    rigid_from_matrix(&m, "T_b_c").unwrap()
}

pub(crate) fn pinhole() -> CameraModel {
    CameraModel::new(700.0, 700.0, 639.5, 479.5, 1280, 960, [0.0; 5]).unwrap()
}

/// Pixel of a B-frame point through the camera at `t_b_c`.
pub(crate) fn project(cam: &CameraModel, t_b_c: &Isometry3<f64>, p: [f64; 3]) -> [f64; 2] {
    let c = t_b_c.inverse() * Point3::from(p);
    cam.project_camera_point(&c.coords).unwrap()
}

/// Box of a segment's projection, from a dense sampling (exact for a pinhole at the ends).
pub(crate) fn segment_box(cam: &CameraModel, t_b_c: &Isometry3<f64>, a: [f64; 3], b: [f64; 3]) -> PixelBox {
    let mut bx = PixelBox { x1: f64::INFINITY, y1: f64::INFINITY, x2: f64::NEG_INFINITY, y2: f64::NEG_INFINITY };
    for k in 0..=4000 {
        let s = f64::from(k) / 4000.0;
        let p = [a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2])];
        let uv = project(cam, t_b_c, p);
        bx.x1 = bx.x1.min(uv[0]);
        bx.y1 = bx.y1.min(uv[1]);
        bx.x2 = bx.x2.max(uv[0]);
        bx.y2 = bx.y2.max(uv[1]);
    }
    // The half-open box must contain the ends: widen by a hair past the last sample.
    PixelBox { x1: bx.x1 - 1e-9, y1: bx.y1 - 1e-9, x2: bx.x2 + 1e-9, y2: bx.y2 + 1e-9 }
}

/// A "string" from `c - L/2 u` to `c + L/2 u`, of which the LiDAR saw the part between
/// fractions `f0` and `f1` of its length (points every 2 cm, two rows 3 cm apart so
/// RANSAC's inliers and the line are well defined).
pub(crate) fn seen_part(c: [f64; 3], u: [f64; 3], len: f64, f0: f64, f1: f64) -> Vec<[f64; 3]> {
    let n = ((f1 - f0) * len / 0.02).ceil() as usize + 1;
    let mut pts = Vec::new();
    for k in 0..n {
        let s = (f0 + (f1 - f0) * k as f64 / (n - 1) as f64 - 0.5) * len;
        pts.push([c[0] + s * u[0], c[1] + s * u[1], c[2] + s * u[2]]);
    }
    pts
}

pub(crate) fn ends(c: [f64; 3], u: [f64; 3], len: f64) -> ([f64; 3], [f64; 3]) {
    let h = 0.5 * len;
    ([c[0] - h * u[0], c[1] - h * u[1], c[2] - h * u[2]], [c[0] + h * u[0], c[1] + h * u[1], c[2] + h * u[2]])
}

pub(crate) fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

