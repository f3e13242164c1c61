//! How a real arm differs from its nominal model: drawn by the scan simulator, propagated into
//! the registration's covariance.

use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, Unit, UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::{Distribution, Normal};

use super::RobotModel;

/// How the real arm differs from its nominal model. The controller knows these deltas from its
/// factory calibration and reports true flange poses; the CAD model we register against is
/// nominal. Per chain joint: a zero offset (rotation about the joint axis), a link-length error
/// (along the link vector leading to the joint), and a small axis misalignment (rotation about
/// an axis perpendicular to the joint axis).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KinematicError {
    /// Standard deviation of each joint's zero offset, radians.
    pub joint_offset_sigma_rad: f64,
    /// Standard deviation of each link's length error, metres.
    pub link_length_sigma_m: f64,
    /// Standard deviation of each joint axis' misalignment, radians.
    pub axis_misalignment_sigma_rad: f64,
}

impl Default for KinematicError {
    /// Typical of UR factory-calibration deltas: 0.3 mrad zero offsets, 0.3 mm link lengths,
    /// 0.3 mrad axis misalignment (for UR arms: DH θ, d and a, α; the sizes of
    /// `DhParams::factory_calibration_delta`).
    fn default() -> Self {
        Self {
            joint_offset_sigma_rad: 0.0003,
            link_length_sigma_m: 0.0003,
            axis_misalignment_sigma_rad: 0.0003,
        }
    }
}

/// The link vector leading to a joint, as a unit vector in the joint frame (where the error is
/// inserted); zero for a joint at its parent's origin.
fn link_direction(parent_from_joint: &Isometry3<f64>) -> Vector3<f64> {
    let link = parent_from_joint.rotation.inverse() * parent_from_joint.translation.vector;
    link.try_normalize(1e-9).unwrap_or_else(Vector3::zeros)
}

/// A unit vector perpendicular to `axis`: the direction about which [`KinematicError::sample`]
/// draws a joint's misalignment (registration takes it and `axis × it` as the two).
pub(crate) fn perpendicular(axis: &Vector3<f64>) -> Vector3<f64> {
    axis.cross(&if axis.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    })
    .normalize()
}

/// Largest 1σ of any kinematic error: 50 mrad (~3°) of joint offset or misalignment, 50 mm of
/// link length. A robot that far from its model is not calibrated by registering its CAD.
pub const MAX_KINEMATIC_SIGMA: f64 = 0.05;

impl KinematicError {
    /// Whether the standard deviations are plausible (finite, 0 ≤ σ ≤
    /// [`MAX_KINEMATIC_SIGMA`] in radians and metres); the message names the key (as in a
    /// `[kinematic_error]` table).
    pub fn validate(&self) -> Result<(), String> {
        for (key, v, unit) in [
            (
                "kinematic_error.joint_offset_sigma_rad",
                self.joint_offset_sigma_rad,
                "rad",
            ),
            (
                "kinematic_error.link_length_sigma_m",
                self.link_length_sigma_m,
                "m",
            ),
            (
                "kinematic_error.axis_misalignment_sigma_rad",
                self.axis_misalignment_sigma_rad,
                "rad",
            ),
        ] {
            handeye_hal::limits::check_range(
                key,
                v,
                0.0,
                MAX_KINEMATIC_SIGMA,
                unit,
                "a real arm is within a few tenths of a millimetre and milliradian of its model",
            )?;
        }
        Ok(())
    }

    /// The arm is exactly its nominal model.
    pub fn none() -> Self {
        Self {
            joint_offset_sigma_rad: 0.0,
            link_length_sigma_m: 0.0,
            axis_misalignment_sigma_rad: 0.0,
        }
    }

    /// One random draw of per-joint origin errors (one isometry per chain joint, for
    /// [`RobotModel::link_poses_with_errors`]).
    pub fn sample(&self, model: &RobotModel, rng: &mut impl Rng) -> Vec<Isometry3<f64>> {
        let mut gauss = |s: f64| {
            if s > 0.0 {
                Normal::new(0.0, s).map_or(0.0, |d| d.sample(rng))
            } else {
                0.0
            }
        };
        model
            .joint_axes()
            .iter()
            .zip(model.joint_origins())
            .map(|(axis, origin)| {
                let t = link_direction(&origin) * gauss(self.link_length_sigma_m);
                let twist = UnitQuaternion::from_scaled_axis(
                    perpendicular(axis) * gauss(self.axis_misalignment_sigma_rad),
                );
                let zero =
                    UnitQuaternion::from_axis_angle(axis, gauss(self.joint_offset_sigma_rad));
                Isometry3::from_parts(Translation3::from(t), twist * zero)
            })
            .collect()
    }

    /// Covariance of one joint's origin error as a small (translation, rotation vector) in
    /// the joint frame, m² / rad², for a joint turning about `axis` at `parent_from_joint`.
    /// The misalignment is taken about every direction perpendicular to the axis (a real arm's
    /// is not known to be about one), so this errs on the large side of [`Self::sample`].
    pub fn joint_covariance(
        &self,
        axis: &Unit<Vector3<f64>>,
        parent_from_joint: &Isometry3<f64>,
    ) -> Matrix6<f64> {
        let along = link_direction(parent_from_joint);
        let a = axis.into_inner();
        let about_axis = a * a.transpose();
        let mut c = Matrix6::zeros();
        c.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(along * along.transpose() * self.link_length_sigma_m.powi(2)));
        c.fixed_view_mut::<3, 3>(3, 3).copy_from(
            &(about_axis * self.joint_offset_sigma_rad.powi(2)
                + (Matrix3::identity() - about_axis) * self.axis_misalignment_sigma_rad.powi(2)),
        );
        c
    }
}
