//! Frame names and the fixed transforms between them.
//!
//! - `base_link`: URDF/ROS root of a UR arm (REP-103; origin at the centre of the mounting face,
//!   z up). The robot model ([`crate::model`]) works in its URDF root link, called `model`.
//! - `base`: what the UR controller reports poses in (`actual_TCP_pose`, `get_actual_tcp_pose()`),
//!   which is `base_link` turned by π about z.
//! - `flange`/`tool0`: the tool flange (UR `tool0` = controller TCP with zero offset).
//! - `camera`: the 3D camera's optical frame (OpenCV: x right, y down, z forward), metres.

use std::f64::consts::PI;

use nalgebra::{Isometry3, Vector3};

/// `base_from_base_link` for UR arms: rotation by π about z, no translation.
///
/// The UR controller's `base` and URDF `base_link` share their origin; x and y are negated.
pub fn ur_base_from_base_link() -> Isometry3<f64> {
    Isometry3::rotation(Vector3::z() * PI)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn base_negates_x_and_y_of_base_link() {
        let p = ur_base_from_base_link() * Point3::new(1.0, 2.0, 3.0);
        assert!((p - Point3::new(-1.0, -2.0, 3.0)).norm() < 1e-12);
    }
}
