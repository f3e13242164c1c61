//! UR's pose convention `p[x, y, z, rx, ry, rz]` (metres, rotation vector in radians).
//! This is the only place in the project that converts it.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// A UR pose `p[x, y, z, rx, ry, rz]`: position in metres and a rotation vector (axis × angle,
/// radians, angle in [0, π]). Which frames it relates depends on where it came from (RTDE
/// `actual_TCP_pose` is `base_from_tcp`; `tcp_offset` is `flange_from_tcp`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UrPose(pub [f64; 6]);

impl UrPose {
    /// Format as URScript `p[...]` with full precision.
    pub fn to_script(&self) -> String {
        let v: Vec<String> = self.0.iter().map(|x| format!("{x:.9}")).collect();
        format!("p[{}]", v.join(","))
    }

    /// Whether two poses describe the same transform within `tol_m` metres and `tol_rad`
    /// radians (compares rotations, not vectors: near π both `r` and its mirror are valid).
    pub fn approx_eq(&self, other: &UrPose, tol_m: f64, tol_rad: f64) -> bool {
        let a = Isometry3::from(*self);
        let b = Isometry3::from(*other);
        (a.translation.vector - b.translation.vector).norm() <= tol_m
            && a.rotation.angle_to(&b.rotation) <= tol_rad
    }
}

impl From<UrPose> for Isometry3<f64> {
    fn from(p: UrPose) -> Self {
        let [x, y, z, rx, ry, rz] = p.0;
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_scaled_axis(Vector3::new(rx, ry, rz)),
        )
    }
}

impl From<Isometry3<f64>> for UrPose {
    fn from(t: Isometry3<f64>) -> Self {
        let r = t.rotation.scaled_axis();
        let p = t.translation.vector;
        UrPose([p.x, p.y, p.z, r.x, r.y, r.z])
    }
}

impl From<&Isometry3<f64>> for UrPose {
    fn from(t: &Isometry3<f64>) -> Self {
        UrPose::from(*t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn round_trip(r: Vector3<f64>) {
        let p = UrPose([0.1, -0.2, 0.3, r.x, r.y, r.z]);
        let iso = Isometry3::from(p);
        let back = UrPose::from(iso);
        assert!(p.approx_eq(&back, 1e-12, 1e-9), "{p:?} vs {back:?}");
        let angle = Vector3::new(back.0[3], back.0[4], back.0[5]).norm();
        assert!(angle <= PI + 1e-9, "angle {angle} > π");
        let iso2 = Isometry3::from(back);
        assert!((iso.to_homogeneous() - iso2.to_homogeneous()).abs().max() < 1e-9);
    }

    #[test]
    fn round_trip_near_zero() {
        for r in [
            Vector3::zeros(),
            Vector3::new(1e-12, 0.0, 0.0),
            Vector3::new(1e-7, -2e-7, 3e-8),
            Vector3::new(0.0, 0.0, 1e-4),
        ] {
            round_trip(r);
        }
    }

    #[test]
    fn round_trip_near_pi() {
        let axes = [
            Vector3::x(),
            Vector3::y(),
            Vector3::z(),
            Vector3::new(1.0, 1.0, 1.0).normalize(),
            Vector3::new(-0.3, 0.9, 0.1).normalize(),
        ];
        for k in axes {
            for a in [PI, PI - 1e-9, PI - 1e-6, PI - 1e-3] {
                round_trip(k * a);
            }
        }
        // The mirrored vector (1 − 2π/|r|)·r is the same rotation.
        let r = Vector3::new(0.0, 0.0, PI - 1e-4);
        let m = r * (1.0 - 2.0 * PI / r.norm());
        let a = UrPose([0.0, 0.0, 0.0, r.x, r.y, r.z]);
        let b = UrPose([0.0, 0.0, 0.0, m.x, m.y, m.z]);
        assert!(a.approx_eq(&b, 1e-12, 1e-9));
    }

    #[test]
    fn documented_flange_pose_of_ur5e_at_zero() {
        let t = handeye_hal::ur_dh::UrModel::Ur5e.dh().forward(&[0.0; 6]);
        let p = UrPose::from(t);
        let expect = UrPose([
            -0.8172,
            -0.2329,
            0.0628,
            std::f64::consts::FRAC_PI_2,
            0.0,
            0.0,
        ]);
        assert!(p.approx_eq(&expect, 1e-9, 1e-9), "{p:?}");
        assert!(p.to_script().starts_with("p[-0.817200000,"));
    }
}
