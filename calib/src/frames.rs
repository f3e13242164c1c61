//! Frame names and the fixed transforms between them.
//!
//! - `base_link`: URDF/ROS root of a UR arm (REP-103; origin at the centre of the mounting face,
//!   z up). The robot model ([`crate::model`]) works in its URDF root link, called `model`.
//! - `base`: what the UR controller reports poses in (`actual_TCP_pose`, `get_actual_tcp_pose()`),
//!   which is `base_link` turned by π about z.
//! - `flange`/`tool0`: the tool flange (UR `tool0` = controller TCP with zero offset).
//! - `camera`: the 3D camera's optical frame (OpenCV: x right, y down, z forward), metres.

use std::f64::consts::PI;

use nalgebra::{Isometry3, Matrix3, Matrix6, Vector3};

/// `base_from_base_link` for UR arms: rotation by π about z, no translation.
///
/// The UR controller's `base` and URDF `base_link` share their origin; x and y are negated.
pub fn ur_base_from_base_link() -> Isometry3<f64> {
    Isometry3::rotation(Vector3::z() * PI)
}

/// A transform as a 4×4 homogeneous matrix, row-major (metres), as reports and JSON carry it.
pub fn to_row_major(t: &Isometry3<f64>) -> [[f64; 4]; 4] {
    let m = t.to_homogeneous();
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

/// A transform from a row-major 4×4 matrix; `None` unless the rotation part is orthonormal
/// (within 1e-6) with determinant +1 and the last row is `0 0 0 1`.
pub fn from_row_major(m: &[[f64; 4]; 4]) -> Option<Isometry3<f64>> {
    let r = nalgebra::Matrix3::from_fn(|i, j| m[i][j]);
    let ok_rotation =
        (r.transpose() * r - nalgebra::Matrix3::identity()).norm() < 1e-6 && r.determinant() > 0.0;
    let ok_last = m[3] == [0.0, 0.0, 0.0, 1.0];
    if !(ok_rotation && ok_last && m.iter().flatten().all(|v| v.is_finite())) {
        return None;
    }
    let rot = nalgebra::UnitQuaternion::from_matrix(&r);
    Some(Isometry3::from_parts(
        nalgebra::Translation3::new(m[0][3], m[1][3], m[2][3]),
        rot,
    ))
}

/// How a left perturbation `(α, β)` in the frame of `model_from_frame` moves things in the
/// model frame: `ρ = R α + p × R β`, `φ = R β`.
pub fn adjoint(model_from_frame: &Isometry3<f64>) -> Matrix6<f64> {
    let r: Matrix3<f64> = model_from_frame.rotation.to_rotation_matrix().into_inner();
    let p = model_from_frame.translation.vector;
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(p.cross_matrix() * r));
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn row_major_round_trip() {
        let t = Isometry3::new(Vector3::new(0.1, -0.2, 0.3), Vector3::new(0.4, 0.5, -0.6));
        let m = to_row_major(&t);
        assert_eq!(m[0][3], 0.1);
        assert_eq!(m[3], [0.0, 0.0, 0.0, 1.0]);
        let back = from_row_major(&m).expect("valid");
        assert!((back.to_homogeneous() - t.to_homogeneous()).norm() < 1e-12);
        let mut bad = m;
        bad[0][0] = 2.0;
        assert!(from_row_major(&bad).is_none());
    }

    #[test]
    fn base_negates_x_and_y_of_base_link() {
        let p = ur_base_from_base_link() * Point3::new(1.0, 2.0, 3.0);
        assert!((p - Point3::new(-1.0, -2.0, 3.0)).norm() < 1e-12);
    }
}
