//! Rigid transforms between frames, as the paper chains them (eq. 1).
//!
//! `T_a_b` maps coordinates in frame b to frame a: `p_a = T_a_b * p_b`.

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};

use crate::error::{invalid, Result};

/// Tolerance on `R^T R = I` (max abs element) and on `det(R) = 1`.
pub const RIGID_TOLERANCE: f64 = 1e-6;
/// Tolerance on the homogeneous last row `[0, 0, 0, 1]`.
pub const LAST_ROW_TOLERANCE: f64 = 1e-9;

/// Validates a 4x4 homogeneous matrix as a proper rigid transform and converts it.
///
/// Requires finite entries, last row `0 0 0 1`, `R^T R = I` and `det(R) = +1`
/// within [`RIGID_TOLERANCE`]; otherwise `InvalidArgument` naming `name`.
pub fn rigid_from_matrix(m: &Matrix4<f64>, name: &'static str) -> Result<Isometry3<f64>> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err(invalid(name, "matrix has a non-finite entry"));
    }
    let last = [m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)]];
    let expected = [0.0, 0.0, 0.0, 1.0];
    if last.iter().zip(expected).any(|(a, b)| (a - b).abs() > LAST_ROW_TOLERANCE) {
        return Err(invalid(name, format!("last row must be [0, 0, 0, 1], got {last:?}")));
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let ortho_err = (r.transpose() * r - Matrix3::identity()).amax();
    if ortho_err > RIGID_TOLERANCE {
        return Err(invalid(name, format!("rotation block is not orthonormal (max |R^T R - I| = {ortho_err:.3e})")));
    }
    let det = r.determinant();
    if (det - 1.0).abs() > RIGID_TOLERANCE {
        return Err(invalid(name, format!("rotation block must have det +1 (got {det:.6}; a reflection?)")));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let translation = Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Ok(Isometry3::from_parts(translation, rotation))
}

/// `T_c_l = T_c_b * T_b_l`: LiDAR frame to camera frame through the body frame (paper eq. 1).
pub fn chain(t_c_b: &Isometry3<f64>, t_b_l: &Isometry3<f64>) -> Isometry3<f64> {
    t_c_b * t_b_l
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Vector3};
    use proptest::prelude::*;

    fn rot_z(a: f64) -> Matrix4<f64> {
        let (s, c) = a.sin_cos();
        Matrix4::new(c, -s, 0.0, 1.0, s, c, 0.0, 2.0, 0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, 1.0)
    }

    #[test]
    fn accepts_rigid_and_maps_points() {
        let m = rot_z(std::f64::consts::FRAC_PI_2);
        let t = rigid_from_matrix(&m, "T_c_l").unwrap();
        // (1, 0, 0) rotated 90 deg about z -> (0, 1, 0), plus (1, 2, 3).
        let p = t * Point3::new(1.0, 0.0, 0.0);
        assert!((p - Point3::new(1.0, 3.0, 3.0)).norm() < 1e-12);
        let back = t.to_homogeneous();
        assert!((back - m).amax() < 1e-12);
    }

    #[test]
    fn rejects_non_rigid_naming_argument() {
        let check = |m: Matrix4<f64>| match rigid_from_matrix(&m, "T_b_l") {
            Err(crate::FusionError::InvalidArgument { name, .. }) => name == "T_b_l",
            _ => false,
        };
        let mut scaled = rot_z(0.3);
        scaled[(0, 0)] *= 1.01;
        assert!(check(scaled));
        let mut reflect = Matrix4::identity();
        reflect[(2, 2)] = -1.0;
        assert!(check(reflect));
        let mut last = Matrix4::identity();
        last[(3, 0)] = 0.1;
        assert!(check(last));
        let mut nan = Matrix4::identity();
        nan[(0, 3)] = f64::NAN;
        assert!(check(nan));
        let mut shear = Matrix4::identity();
        shear[(0, 1)] = 1e-3;
        assert!(check(shear));
        // Within tolerance is accepted.
        let mut tiny = Matrix4::identity();
        tiny[(0, 1)] = 1e-8;
        assert!(rigid_from_matrix(&tiny, "T").is_ok());
    }

    #[test]
    fn chain_is_composition() {
        let a = rigid_from_matrix(&rot_z(0.4), "a").unwrap();
        let b = rigid_from_matrix(&rot_z(-1.1), "b").unwrap();
        let c = chain(&a, &b);
        let p = Point3::new(0.3, -2.0, 5.0);
        assert!((c * p - a * (b * p)).norm() < 1e-12);
        let hm = a.to_homogeneous() * b.to_homogeneous();
        assert!((c.to_homogeneous() - hm).amax() < 1e-12);
    }

    proptest! {
        #[test]
        fn random_rotations_round_trip(ax in -1.0f64..1.0, ay in -1.0f64..1.0, az in -1.0f64..1.0,
                                       angle in -3.1f64..3.1, tx in -10.0f64..10.0) {
            let axis = Vector3::new(ax, ay, az);
            prop_assume!(axis.norm() > 1e-3);
            let iso = Isometry3::new(Vector3::new(tx, -tx, 0.5), axis.normalize() * angle);
            let m = iso.to_homogeneous();
            let t = rigid_from_matrix(&m, "T").unwrap();
            prop_assert!((t.to_homogeneous() - m).amax() < 1e-12);
        }
    }
}
