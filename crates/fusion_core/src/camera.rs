//! Pinhole camera with OpenCV's radial-tangential (k1, k2, p1, p2, k3) distortion.
//!
//! Frame C is the camera optical frame (x right, y down, z forward), as in OpenCV.

use nalgebra::Vector3;

use crate::error::{check_positive, invalid, Result};

/// Points with camera-frame depth z at or below this (metres) are not projected.
pub const NEAR_LIMIT: f64 = 1e-3;

/// Intrinsics in pixels and OpenCV distortion coefficients `[k1, k2, p1, p2, k3]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraModel {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
    pub dist: [f64; 5],
}

impl CameraModel {
    /// Validated constructor: every value finite, fx, fy > 0, width, height >= 1.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64, width: u32, height: u32, dist: [f64; 5]) -> Result<Self> {
        let cam = Self { fx, fy, cx, cy, width, height, dist };
        cam.validate()?;
        Ok(cam)
    }

    /// Re-checks the constructor's invariants (the fields are public, so kernels re-validate).
    pub fn validate(&self) -> Result<()> {
        check_positive("fx", self.fx)?;
        check_positive("fy", self.fy)?;
        if !self.cx.is_finite() {
            return Err(invalid("cx", format!("must be finite, got {}", self.cx)));
        }
        if !self.cy.is_finite() {
            return Err(invalid("cy", format!("must be finite, got {}", self.cy)));
        }
        if self.width == 0 {
            return Err(invalid("width", "must be >= 1"));
        }
        if self.height == 0 {
            return Err(invalid("height", "must be >= 1"));
        }
        if let Some(k) = self.dist.iter().find(|d| !d.is_finite()) {
            return Err(invalid("dist", format!("coefficients must be finite, got {k}")));
        }
        Ok(())
    }

    /// True when all distortion coefficients are zero (pure pinhole).
    #[inline]
    pub fn is_pinhole(&self) -> bool {
        self.dist.iter().all(|&d| d == 0.0)
    }

    /// Pixel (u, v) of a camera-frame point, or `None` when it is not in front of the
    /// camera (z <= [`NEAR_LIMIT`]) or not finite. Distortion is OpenCV's, term for term.
    #[inline]
    pub fn project_camera_point(&self, p_c: &Vector3<f64>) -> Option<[f64; 2]> {
        self.project_xyz(p_c.x, p_c.y, p_c.z)
    }

    /// Same as [`Self::project_camera_point`] on raw coordinates (hot-loop form).
    #[inline(always)]
    pub(crate) fn project_xyz(&self, x: f64, y: f64, z: f64) -> Option<[f64; 2]> {
        // Finite checks first, so a NaN depth never reaches the comparison.
        if !x.is_finite() || !y.is_finite() || !z.is_finite() || z <= NEAR_LIMIT {
            return None;
        }
        let inv_z = 1.0 / z;
        let xp = x * inv_z;
        let yp = y * inv_z;
        let [k1, k2, p1, p2, k3] = self.dist;
        let r2 = xp * xp + yp * yp;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let xy2 = 2.0 * xp * yp;
        let xpp = xp * radial + p1 * xy2 + p2 * (r2 + 2.0 * xp * xp);
        let ypp = yp * radial + p1 * (r2 + 2.0 * yp * yp) + p2 * xy2;
        let u = self.fx * xpp + self.cx;
        let v = self.fy * ypp + self.cy;
        (u.is_finite() && v.is_finite()).then_some([u, v])
    }

    /// True when the pixel lies inside the image: 0 <= u < width and 0 <= v < height.
    #[inline]
    pub fn contains(&self, uv: [f64; 2]) -> bool {
        uv[0] >= 0.0 && uv[0] < f64::from(self.width) && uv[1] >= 0.0 && uv[1] < f64::from(self.height)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(dist: [f64; 5]) -> CameraModel {
        CameraModel::new(800.0, 820.0, 320.0, 240.0, 640, 480, dist).unwrap()
    }

    #[test]
    fn pinhole_by_hand() {
        let c = cam([0.0; 5]);
        // x' = 0.5/2 = 0.25, y' = -0.25/2 = -0.125 -> u = 800*0.25+320, v = 820*(-0.125)+240.
        let uv = c.project_camera_point(&Vector3::new(0.5, -0.25, 2.0)).unwrap();
        assert!((uv[0] - 520.0).abs() < 1e-12 && (uv[1] - 137.5).abs() < 1e-12);
        assert!(c.is_pinhole());
    }

    #[test]
    fn distortion_by_hand() {
        let (k1, k2, p1, p2, k3) = (-0.3, 0.1, 0.001, -0.002, 0.05);
        let c = cam([k1, k2, p1, p2, k3]);
        // Point (1, 2, 4): x' = 0.25, y' = 0.5, r2 = 0.3125.
        let (xp, yp, r2): (f64, f64, f64) = (0.25, 0.5, 0.3125);
        let radial = 1.0 + k1 * r2 + k2 * r2.powi(2) + k3 * r2.powi(3);
        // radial = 1 - 0.09375 + 0.009765625 + 0.00152587890625 = 0.91754150390625
        assert!((radial - 0.917_541_503_906_25).abs() < 1e-15);
        let xpp = xp * radial + 2.0 * p1 * xp * yp + p2 * (r2 + 2.0 * xp * xp);
        let ypp = yp * radial + p1 * (r2 + 2.0 * yp * yp) + 2.0 * p2 * xp * yp;
        let uv = c.project_camera_point(&Vector3::new(1.0, 2.0, 4.0)).unwrap();
        assert!((uv[0] - (800.0 * xpp + 320.0)).abs() < 1e-9);
        assert!((uv[1] - (820.0 * ypp + 240.0)).abs() < 1e-9);
        // Numerically: x'' = 0.2293853759765625 + 0.00025 - 0.000875 = 0.2287603759765625
        assert!((uv[0] - (800.0 * 0.228_760_375_976_562_5 + 320.0)).abs() < 1e-9);
    }

    #[test]
    fn near_and_non_finite_are_none() {
        let c = cam([0.0; 5]);
        assert!(c.project_camera_point(&Vector3::new(0.0, 0.0, NEAR_LIMIT)).is_none());
        assert!(c.project_camera_point(&Vector3::new(0.0, 0.0, -1.0)).is_none());
        assert!(c.project_camera_point(&Vector3::new(f64::NAN, 0.0, 1.0)).is_none());
        assert!(c.project_camera_point(&Vector3::new(0.0, 0.0, f64::INFINITY)).is_none());
        assert!(c.project_camera_point(&Vector3::new(0.0, 0.0, 2.0 * NEAR_LIMIT)).is_some());
    }

    #[test]
    fn contains_is_half_open() {
        let c = cam([0.0; 5]);
        assert!(c.contains([0.0, 0.0]));
        assert!(c.contains([639.999, 479.999]));
        assert!(!c.contains([640.0, 10.0]));
        assert!(!c.contains([10.0, 480.0]));
        assert!(!c.contains([-0.001, 10.0]));
        assert!(!c.contains([f64::NAN, 10.0]));
    }

    #[test]
    fn constructor_names_bad_argument() {
        let name = |r: Result<CameraModel>| match r {
            Err(crate::FusionError::InvalidArgument { name, .. }) => name,
            _ => "ok",
        };
        assert_eq!(name(CameraModel::new(0.0, 1.0, 0.0, 0.0, 1, 1, [0.0; 5])), "fx");
        assert_eq!(name(CameraModel::new(1.0, -1.0, 0.0, 0.0, 1, 1, [0.0; 5])), "fy");
        assert_eq!(name(CameraModel::new(1.0, 1.0, f64::NAN, 0.0, 1, 1, [0.0; 5])), "cx");
        assert_eq!(name(CameraModel::new(1.0, 1.0, 0.0, f64::INFINITY, 1, 1, [0.0; 5])), "cy");
        assert_eq!(name(CameraModel::new(1.0, 1.0, 0.0, 0.0, 0, 1, [0.0; 5])), "width");
        assert_eq!(name(CameraModel::new(1.0, 1.0, 0.0, 0.0, 1, 0, [0.0; 5])), "height");
        assert_eq!(name(CameraModel::new(1.0, 1.0, 0.0, 0.0, 1, 1, [0.0, f64::NAN, 0.0, 0.0, 0.0])), "dist");
        assert_eq!(name(CameraModel::new(1.0, 1.0, 0.0, 0.0, 1, 1, [0.0; 5])), "ok");
    }
}
