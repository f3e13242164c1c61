//! How a real arm differs from its nominal model: drawn by the scan simulator, propagated into
//! the registration's covariance.

use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, Unit, UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::{Distribution, Normal};

use handeye_hal::ur_dh::JointErrorSizes;

use super::RobotModel;

/// How the real arm differs from its nominal model. The controller knows these deltas from its
/// factory calibration and reports true flange poses; the CAD model we register against is
/// nominal. Per chain joint, a small rigid error of its origin: a zero offset (rotation about
/// the joint axis), a displacement along each of three axes, and a misalignment (rotation
/// about the two axes perpendicular to the joint axis). The first joint's axis is the frame a
/// controller reports in (standard DH's base frame is joint 1's axis), so its error is only a
/// zero offset and a displacement along its axis. For UR arms these are the sizes of
/// [`PhysicalArm`](handeye_hal::ur_dh::PhysicalArm)'s joint errors.
///
/// Beyond the joints, each link's housing (what a camera sees: castings, covers) sits off the
/// link's kinematic frame by a small rigid error, the base's off joint 1's axis included; no
/// controller knows it, so it is carried by both paths (kinematics known or not).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KinematicError {
    /// Standard deviation of each joint's zero offset, radians.
    pub joint_offset_sigma_rad: f64,
    /// Standard deviation of each joint origin's displacement along each axis, metres (the
    /// name is older than the model: a link-length error is one of the three).
    pub link_length_sigma_m: f64,
    /// Standard deviation of each joint axis' misalignment about each perpendicular, radians.
    pub axis_misalignment_sigma_rad: f64,
    /// Standard deviation of each link housing's displacement from the link's frame along each
    /// axis, metres (the base's from joint 1's axis included).
    pub housing_translation_sigma_m: f64,
    /// Standard deviation of each link housing's rotation about each axis through the link
    /// frame's origin, radians.
    pub housing_rotation_sigma_rad: f64,
    /// Standard deviation of each joint reading's error, radians: the encoder's own error, a
    /// periodic function of the joint's angle ([`super::reading::EncoderErrors`]), so every
    /// pose of the arm reports its flange off by its own amount.
    pub joint_reading_sigma_rad: f64,
    /// The sag under gravity no controller's DH models, radians: how far the shoulder turns
    /// down with the arm stretched horizontally; every joint turns in proportion to its moment
    /// arm ([`super::reading::gravity_sag`]).
    pub deflection_rad: f64,
}

/// Encoder error of a UR joint reading, 1σ: 0.005° (87 µrad). A joint 0.85 m from the flange
/// moves it by 0.07 mm; the six together put the flange of a UR5e about 0.06 mm and 0.008° off
/// (the size of UR's published pose repeatability class, ±0.03 mm e-Series to ±0.1 mm CB3;
/// an error that repeats at the same angle does not show in repeatability, so the accuracy
/// class is the bound, not the repeatability figure).
pub const UR_JOINT_READING_SIGMA_RAD: f64 = 0.005 * std::f64::consts::PI / 180.0;

/// Sag of a UR arm stretched horizontally that its controller's DH does not model: 0.1 mrad
/// (0.085 mm at the flange of a UR5e). What a factory calibration absorbs (the mean of the
/// gravity deflection over its poses) is not counted.
pub const UR_DEFLECTION_RAD: f64 = 1e-4;

impl Default for KinematicError {
    /// A manufactured UR arm ([`JointErrorSizes::FACTORY`]): what a factory calibration finds
    /// (0.3 mrad zero offsets, 0.3 mm joint displacements, 0.3 mrad axis misalignments) and
    /// housings 0.3 mm / 0.3 mrad per axis off their links' frames.
    fn default() -> Self {
        let f = JointErrorSizes::FACTORY;
        Self {
            joint_offset_sigma_rad: f.zero_offset_rad,
            link_length_sigma_m: f.translation_m,
            axis_misalignment_sigma_rad: f.misalignment_rad,
            housing_translation_sigma_m: f.housing_translation_m,
            housing_rotation_sigma_rad: f.housing_rotation_rad,
            joint_reading_sigma_rad: UR_JOINT_READING_SIGMA_RAD,
            deflection_rad: UR_DEFLECTION_RAD,
        }
    }
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

/// One draw of a zero-mean normal of standard deviation `sigma` (0 for σ ≤ 0).
fn normal(rng: &mut impl Rng, sigma: f64) -> f64 {
    if sigma > 0.0 {
        Normal::new(0.0, sigma).map_or(0.0, |d| d.sample(rng))
    } else {
        0.0
    }
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
            (
                "kinematic_error.housing_translation_sigma_m",
                self.housing_translation_sigma_m,
                "m",
            ),
            (
                "kinematic_error.housing_rotation_sigma_rad",
                self.housing_rotation_sigma_rad,
                "rad",
            ),
            (
                "kinematic_error.joint_reading_sigma_rad",
                self.joint_reading_sigma_rad,
                "rad",
            ),
            ("kinematic_error.deflection_rad", self.deflection_rad, "rad"),
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

    /// The arm is exactly its nominal model, housings and all.
    pub fn none() -> Self {
        Self {
            joint_offset_sigma_rad: 0.0,
            link_length_sigma_m: 0.0,
            axis_misalignment_sigma_rad: 0.0,
            housing_translation_sigma_m: 0.0,
            housing_rotation_sigma_rad: 0.0,
            joint_reading_sigma_rad: 0.0,
            deflection_rad: 0.0,
        }
    }

    /// These sizes with joint readings that are exact (no encoder error, no sag): what every
    /// simulator handed the solver before readings were modelled.
    pub fn with_exact_readings(self) -> Self {
        Self {
            joint_reading_sigma_rad: 0.0,
            deflection_rad: 0.0,
            ..self
        }
    }

    /// Only the readings' errors of these sizes: an arm whose kinematics and housings are
    /// exactly what the solver is told (a simulated controller's own calibration).
    pub fn readings_only(self) -> Self {
        Self {
            joint_reading_sigma_rad: self.joint_reading_sigma_rad,
            deflection_rad: self.deflection_rad,
            ..Self::none()
        }
    }

    /// These sizes with the housings on their links' frames (the arm as the simulators built
    /// it before housings were modelled).
    pub fn without_housings(self) -> Self {
        Self {
            housing_translation_sigma_m: 0.0,
            housing_rotation_sigma_rad: 0.0,
            ..self
        }
    }

    /// These sizes as a physical UR arm's joint errors.
    pub fn joint_sizes(&self) -> JointErrorSizes {
        JointErrorSizes {
            zero_offset_rad: self.joint_offset_sigma_rad,
            translation_m: self.link_length_sigma_m,
            misalignment_rad: self.axis_misalignment_sigma_rad,
            housing_translation_m: self.housing_translation_sigma_m,
            housing_rotation_rad: self.housing_rotation_sigma_rad,
        }
    }

    /// One random draw of each link housing's offset from its link's frame (one isometry per
    /// chain depth 0..=dof, in that link's frame, for [`RobotModel::with_housings`]).
    pub fn sample_housings(&self, model: &RobotModel, rng: &mut impl Rng) -> Vec<Isometry3<f64>> {
        let mut gauss = |s: f64| normal(rng, s);
        (0..=model.dof())
            .map(|_| {
                let t = Vector3::from_fn(|_, _| gauss(self.housing_translation_sigma_m));
                let r = Vector3::from_fn(|_, _| gauss(self.housing_rotation_sigma_rad));
                Isometry3::new(t, r)
            })
            .collect()
    }

    /// One random draw of per-joint origin errors (one isometry per chain joint, in the joint
    /// frame, for [`RobotModel::link_poses_with_errors`]).
    pub fn sample(&self, model: &RobotModel, rng: &mut impl Rng) -> Vec<Isometry3<f64>> {
        let mut gauss = |s: f64| normal(rng, s);
        model
            .joint_axes()
            .iter()
            .enumerate()
            .map(|(k, axis)| {
                let a = axis.into_inner();
                let u1 = perpendicular(&a);
                let u2 = a.cross(&u1);
                let zero = a * gauss(self.joint_offset_sigma_rad);
                if k == 0 {
                    let t = a * gauss(self.link_length_sigma_m);
                    return Isometry3::from_parts(
                        Translation3::from(t),
                        UnitQuaternion::from_scaled_axis(zero),
                    );
                }
                let tilt = u1 * gauss(self.axis_misalignment_sigma_rad)
                    + u2 * gauss(self.axis_misalignment_sigma_rad);
                let t = Vector3::from_fn(|_, _| gauss(self.link_length_sigma_m));
                Isometry3::from_parts(
                    Translation3::from(t),
                    UnitQuaternion::from_scaled_axis(tilt + zero),
                )
            })
            .collect()
    }

    /// Covariance of one joint's origin error as a small (translation, rotation vector) in
    /// the joint frame, m² / rad², for a joint turning about `axis`, as [`Self::sample`] draws
    /// it (`first`: the chain's first joint, whose error is only about and along its axis).
    pub fn joint_covariance(&self, axis: &Unit<Vector3<f64>>, first: bool) -> Matrix6<f64> {
        let a = axis.into_inner();
        let about_axis = a * a.transpose();
        let (translation, misalignment) = if first {
            (
                about_axis * self.link_length_sigma_m.powi(2),
                Matrix3::zeros(),
            )
        } else {
            (
                Matrix3::identity() * self.link_length_sigma_m.powi(2),
                (Matrix3::identity() - about_axis) * self.axis_misalignment_sigma_rad.powi(2),
            )
        };
        let mut c = Matrix6::zeros();
        c.fixed_view_mut::<3, 3>(0, 0).copy_from(&translation);
        c.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(about_axis * self.joint_offset_sigma_rad.powi(2) + misalignment));
        c
    }
}
