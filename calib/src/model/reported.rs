//! Whether a flange pose a controller (or a capture file) reports belongs to the joint angles
//! reported with it: the forward kinematics of those joints, by the controller's own DH when
//! it is known (exact, so a tight tolerance) or by the model's nominal URDF (a real arm's
//! factory calibration moves its flange by millimetres, so a loose one).
//!
//! A flange pose that fails this is corrupt, another robot's, the TCP's instead of the
//! flange's, or in another frame: a hand-eye result computed from it is wrong by as much, so
//! nothing may be computed, moved or written from it.

use handeye_hal::ur_dh::DhParams;
use nalgebra::Isometry3;

use super::RobotModel;

/// How far a reported flange pose may be from the forward kinematics of its joints.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlangeTolerance {
    /// Largest distance between the two flange origins, m.
    pub translation_m: f64,
    /// Largest angle between the two flange orientations, rad.
    pub rotation_rad: f64,
}

/// By the controller's own DH: the controller computes its flange pose from its joints with
/// exactly these parameters, so the two agree to rounding (a capture keeps micrometres and
/// microradians), and to the joints' motion between two samples of an arm standing still
/// (micro-radians). 0.05 mm / 0.05 mrad leaves room for both and refuses any real error: a
/// joint off by 0.003°, a flange pose of other joints, or poses in another frame than the
/// controller's `base` (a ROS `world`, a URDF root: joint 1's axis 0.3 mm / 0.3 mrad off it
/// moves the flange by more), which would put the mount off by as much while its σ could
/// not say so.
pub const EXACT_DH: FlangeTolerance = FlangeTolerance {
    translation_m: 0.000_05,
    rotation_rad: 0.000_05,
};

/// By the nominal URDF: a real arm's factory calibration moves its flange by millimetres and
/// hundredths of a degree, so more than this is a pose of other joints, of the TCP instead of
/// the flange, in another frame, or of another robot model.
pub const NOMINAL: FlangeTolerance = FlangeTolerance {
    translation_m: 0.03,
    rotation_rad: 0.05,
};

/// The forward kinematics a reported flange pose is compared with, and how closely.
#[derive(Debug, Clone, Copy)]
pub enum FlangeReference<'a> {
    /// The controller's DH set ([`EXACT_DH`]); `model_from_base` places the controller's
    /// `base` frame (in which DH poses are) in the model.
    ControllerDh {
        /// The controller's published standard DH.
        dh: &'a DhParams,
        /// `model_from_base`: the controller's `base` frame in the model root.
        model_from_base: &'a Isometry3<f64>,
    },
    /// The model's nominal URDF ([`NOMINAL`]).
    Nominal,
}

/// A reported flange pose that does not belong to its joints (or is not a pose at all).
#[derive(Debug, Clone, PartialEq)]
pub struct FlangeMismatch {
    /// Distance between the reported and the computed flange, m (NaN when not finite).
    pub translation_m: f64,
    /// Angle between them, rad (NaN when not finite).
    pub rotation_rad: f64,
    /// The tolerance it broke.
    pub tolerance: FlangeTolerance,
    /// `model_from_flange` by the forward kinematics.
    pub computed: Isometry3<f64>,
    /// Which kinematics computed it (`"the controller's DH"`, `"the nominal URDF"`).
    pub by: &'static str,
}

impl std::fmt::Display for FlangeMismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if !(self.translation_m.is_finite() && self.rotation_rad.is_finite()) {
            return write!(f, "is not a finite pose");
        }
        write!(
            f,
            "is {:.4} m / {:.3}° from the flange pose {} gives for its joints (at most {} m / \
             {:.3}°)",
            self.translation_m,
            self.rotation_rad.to_degrees(),
            self.by,
            self.tolerance.translation_m,
            self.tolerance.rotation_rad.to_degrees()
        )
    }
}

impl std::error::Error for FlangeMismatch {}

/// Checks `model_from_flange` (a reported flange pose, in the model root) against the forward
/// kinematics of `joints` by `reference`. Errors when the model cannot pose `joints` (their
/// count) with the model's message.
pub fn check_reported_flange(
    model: &RobotModel,
    joints: &[f64],
    model_from_flange: &Isometry3<f64>,
    reference: FlangeReference<'_>,
) -> Result<Result<(), FlangeMismatch>, super::ModelError> {
    // Also checks the joints' count and that they are finite.
    let nominal = model.frame_pose(model.flange_link(), joints)?;
    let (computed, tolerance, by) = match reference {
        FlangeReference::ControllerDh {
            dh,
            model_from_base,
        } => {
            let q: [f64; 6] = joints
                .try_into()
                .map_err(|_| super::ModelError::JointCount {
                    robot: model.name().to_string(),
                    expected: 6,
                    got: joints.len(),
                    joints: model.joint_names().join(", "),
                })?;
            (
                model_from_base * dh.forward(&q),
                EXACT_DH,
                "the controller's DH",
            )
        }
        FlangeReference::Nominal => (nominal, NOMINAL, "the nominal URDF"),
    };
    let d = computed.inverse() * model_from_flange;
    let (dt, dr) = (d.translation.vector.norm(), d.rotation.angle());
    // NaN compares false: written so that a NaN pose fails.
    let within = dt <= tolerance.translation_m && dr <= tolerance.rotation_rad;
    Ok(if within {
        Ok(())
    } else {
        Err(FlangeMismatch {
            translation_m: if dt.is_finite() { dt } else { f64::NAN },
            rotation_rad: if dr.is_finite() { dr } else { f64::NAN },
            tolerance,
            computed,
            by,
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use handeye_hal::ur_dh::UrModel;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn ur5e() -> Option<std::sync::Arc<RobotModel>> {
        crate::testutil::shared_robot("ur/ur5e/ur5e.urdf")
    }

    const Q: [f64; 6] = [0.3, -1.2, 1.1, -1.4, -1.5, 0.2];

    #[test]
    fn a_flange_by_the_controllers_dh_passes_and_one_a_centimetre_or_two_degrees_off_fails() {
        let Some(model) = ur5e() else { return };
        let dh = UrModel::Ur5e.dh();
        let model_from_base = crate::frames::ur_base_from_base_link().inverse();
        let reference = FlangeReference::ControllerDh {
            dh: &dh,
            model_from_base: &model_from_base,
        };
        let exact = model_from_base * dh.forward(&Q);
        assert_eq!(
            check_reported_flange(&model, &Q, &exact, reference)
                .expect("the model poses the joints"),
            Ok(())
        );
        // Twenty micrometres and microradians of sampling and rounding: still the same flange.
        let near = exact
            * Translation3::new(0.000_02, 0.0, 0.0)
            * UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.000_02, 0.0));
        assert_eq!(
            check_reported_flange(&model, &Q, &near, reference)
                .expect("the model poses the joints"),
            Ok(())
        );
        for off in [
            Isometry3::translation(0.01, 0.0, 0.0),
            Isometry3::rotation(Vector3::new(2f64.to_radians(), 0.0, 0.0)),
        ] {
            let e = check_reported_flange(&model, &Q, &(exact * off), reference)
                .expect("the model poses the joints")
                .expect_err("refused");
            assert!(e.to_string().contains("the controller's DH"), "{e}");
            // The nominal URDF's tolerance would have taken it: the exact DH is what refuses.
            assert_eq!(
                check_reported_flange(&model, &Q, &(exact * off), FlangeReference::Nominal)
                    .expect("the model poses the joints"),
                Ok(())
            );
        }
    }

    /// Issue 43: flange poses in a frame whose z is not joint 1's axis (0.3 mm / 0.3 mrad
    /// off, a ROS `world` or a URDF root) are refused when the controller's DH is known.
    #[test]
    fn issue_43_poses_in_a_frame_off_joint_1_s_axis_are_refused() {
        let Some(model) = ur5e() else { return };
        let dh = UrModel::Ur5e.dh();
        let model_from_base = crate::frames::ur_base_from_base_link().inverse();
        let reference = FlangeReference::ControllerDh {
            dh: &dh,
            model_from_base: &model_from_base,
        };
        let frame_off = Isometry3::new(Vector3::new(3e-4, 0.0, 0.0), Vector3::new(0.0, 3e-4, 0.0));
        for q in [
            Q,
            [1.2, -0.8, 0.6, -1.9, -1.5, 2.0],
            [-0.4, -1.6, 1.9, -0.3, 1.4, -1.0],
        ] {
            let in_other_frame = model_from_base * frame_off * dh.forward(&q);
            let e = check_reported_flange(&model, &q, &in_other_frame, reference)
                .expect("the model poses the joints")
                .expect_err("refused");
            assert!(e.translation_m > 1e-4 || e.rotation_rad > 1e-4, "{e}");
        }
    }

    #[test]
    fn a_nan_flange_fails_both_ways() {
        let Some(model) = ur5e() else { return };
        let mut nan = model
            .frame_pose(model.flange_link(), &Q)
            .expect("the model poses the joints");
        nan.translation.vector.x = f64::NAN;
        let e = check_reported_flange(&model, &Q, &nan, FlangeReference::Nominal)
            .expect("the model poses the joints")
            .expect_err("refused");
        assert_eq!(e.to_string(), "is not a finite pose");
        let dh = UrModel::Ur5e.dh();
        let m = crate::frames::ur_base_from_base_link().inverse();
        let e = check_reported_flange(
            &model,
            &Q,
            &nan,
            FlangeReference::ControllerDh {
                dh: &dh,
                model_from_base: &m,
            },
        )
        .expect("the model poses the joints");
        assert!(e.is_err());
    }
}
