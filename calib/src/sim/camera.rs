//! Where the simulated camera looks from. Its pinhole model is [`crate::geometry::Intrinsics`]
//! (re-exported as [`crate::sim::Intrinsics`]).

use nalgebra::{Point3, Vector3};

/// `world_from_camera` for a camera at `eye` looking at `target` (OpenCV axes: z along the view
/// direction, y as close to `down` as the view direction allows).
pub fn look_at(
    eye: &Point3<f64>,
    target: &Point3<f64>,
    down: &Vector3<f64>,
) -> nalgebra::Isometry3<f64> {
    let z = (target - eye).normalize();
    let x = down.cross(&z);
    let x = if x.norm() < 1e-9 {
        z.cross(&Vector3::x()).normalize()
    } else {
        x.normalize()
    };
    let y = z.cross(&x);
    let r = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, z]));
    nalgebra::Isometry3::from_parts(nalgebra::Translation3::from(eye.coords), r.into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_puts_the_target_on_the_optical_axis_with_y_down() {
        let t = look_at(
            &Point3::new(0.6, 0.2, 0.5),
            &Point3::new(0.0, 0.0, 0.1),
            &-Vector3::z(),
        );
        let p = t.inverse() * Point3::new(0.0, 0.0, 0.1);
        assert!(p.x.abs() < 1e-12 && p.y.abs() < 1e-12 && p.z > 0.0);
        // a point above the target appears above the image centre (negative y)
        assert!((t.inverse() * Point3::new(0.0, 0.0, 0.3)).y < 0.0);
    }
}
