//! The limits of Universal Robots arms, in one table: what each model's joints can do (the
//! datasheets' joint speeds, UR's joint acceleration and position limits) and the caps handeye
//! puts on top of them. Everything that bounds a UR motion reads it:
//!
//! - the configuration's ranges for `robot.max_joint_speed_rad_s` / `max_joint_accel_rad_s2`
//!   and `handeye robot move`'s `--speed`, `--accel` and `--joints` checks;
//! - the motion guard (`handeye::guard`), which caps every move at the configured caps and at
//!   the arm model's own limits ([`UrLimits::cap`]);
//! - the UR driver, which enforces its own caps ([`DRIVER_SPEED_CAP_RAD_S`],
//!   [`DRIVER_ACCEL_CAP_RAD_S2`] unless configured) and the model's limits again, as a second
//!   layer under the guard;
//! - the UR controller simulator, whose arm moves no faster than its model's joints.

use std::f64::consts::{PI, TAU};

use crate::ur_dh::UrModel;
use crate::MotionLimits;

/// Every UR joint turns at most ±2π rad from zero (the controller's default joint limits).
pub const JOINT_POSITION_LIMIT_RAD: f64 = TAU;

/// UR's joint acceleration limit, rad/s² (every model, every joint).
pub const MAX_JOINT_ACCEL_RAD_S2: f64 = 40.0;

/// Highest joint speed cap a configuration or command may ask for, rad/s: π (the base,
/// shoulder and elbow of the fastest models; the wrists of the small ones turn at 2π), rounded
/// up to 3.15 so that `π` written as 3.1416 is accepted. The model's own limits cap it further.
pub const MAX_JOINT_SPEED_CAP_RAD_S: f64 = 3.15;

/// The UR driver's own speed cap when none is configured, rad/s: a second layer under the
/// configured caps the guard applies.
pub const DRIVER_SPEED_CAP_RAD_S: f64 = 1.0;

/// The UR driver's own acceleration cap when none is configured, rad/s².
pub const DRIVER_ACCEL_CAP_RAD_S2: f64 = 2.0;

/// Farthest a TCP (`flange_from_tcp`, UR `tcp_offset`) may lie from the flange, m: the
/// controller's own installation limit for a TCP is well inside it; beyond it the value is
/// corrupt, not a tool. The UR driver refuses a TCP beyond it when it reads one and before it
/// sets one, and the write-back journal's TCPs are held to it ([`within_pose_bound`]).
pub const MAX_TCP_OFFSET_M: f64 = 2.0;

/// Farthest any other pose a UR controller reports or holds may lie from its frame's origin,
/// m (`actual_TCP_pose` from `base`; a result pose in the result registers): a UR30 reaches
/// 1.3 m, a camera fixed in a cell a few metres more; beyond it the value is corrupt, not a
/// pose.
pub const MAX_POSE_DISTANCE_M: f64 = 10.0;

/// Whether `p` (UR `x, y, z` m, rotation vector rad) can be a pose within `max_m` of its
/// frame's origin: `Err` says why not, in words the callers put after the value ("which is
/// not a finite pose", "5.000 m from its frame's origin (at most 2 m is a real pose)"). The
/// one check of the UR driver's reads ([`MAX_TCP_OFFSET_M`], [`MAX_POSE_DISTANCE_M`]), its
/// `set_tcp`, and the write-back journal's values.
pub fn within_pose_bound(p: &[f64; 6], max_m: f64) -> Result<(), String> {
    if p.iter().any(|v| !v.is_finite()) {
        return Err("which is not a finite pose".into());
    }
    let distance = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    if distance > max_m {
        return Err(format!(
            "{distance:.3} m from its frame's origin (at most {max_m} m is a real pose)"
        ));
    }
    Ok(())
}

// The driver's own caps lie within what any configuration may ask for (checked when built).
const _: () = assert!(DRIVER_ACCEL_CAP_RAD_S2 < MAX_JOINT_ACCEL_RAD_S2);
const _: () = assert!(DRIVER_SPEED_CAP_RAD_S < MAX_JOINT_SPEED_CAP_RAD_S);

/// The limits of one UR model's joints.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UrLimits {
    /// Highest speed of each joint (base, shoulder, elbow, wrist 1, 2, 3), rad/s.
    pub joint_speed_rad_s: [f64; 6],
    /// Highest acceleration of every joint, rad/s².
    pub joint_accel_rad_s2: f64,
    /// Each joint stays within ± this, rad.
    pub joint_position_rad: f64,
}

impl UrModel {
    /// This model's joint limits: the datasheets' joint speeds (the base and shoulder of the
    /// large arms are slower, the wrists of the small ones faster), UR's acceleration and
    /// position limits.
    pub fn limits(self) -> UrLimits {
        let (slow_base, fast_wrists) = match self {
            UrModel::Ur3 | UrModel::Ur3e => (false, true),
            UrModel::Ur10
            | UrModel::Ur10e
            | UrModel::Ur12e
            | UrModel::Ur16e
            | UrModel::Ur20
            | UrModel::Ur30 => (true, false),
            UrModel::Ur5 | UrModel::Ur5e | UrModel::Ur7e | UrModel::Ur15 => (false, false),
        };
        let joint_speed_rad_s = std::array::from_fn(|i| match i {
            0 | 1 if slow_base => 2.0 * PI / 3.0,
            3..=5 if fast_wrists => 2.0 * PI,
            _ => PI,
        });
        UrLimits {
            joint_speed_rad_s,
            joint_accel_rad_s2: MAX_JOINT_ACCEL_RAD_S2,
            joint_position_rad: JOINT_POSITION_LIMIT_RAD,
        }
    }
}

impl UrLimits {
    /// The highest speed one `movej` speed may be for this arm, rad/s: its slowest joint's
    /// (a joint move's speed applies to whichever joint leads).
    pub fn move_speed_rad_s(&self) -> f64 {
        self.joint_speed_rad_s
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
    }

    /// `limits` within what this arm can do: speed at most [`Self::move_speed_rad_s`],
    /// acceleration at most [`Self::joint_accel_rad_s2`]; the timeout unchanged.
    pub fn cap(&self, limits: MotionLimits) -> MotionLimits {
        MotionLimits {
            max_joint_speed_rad_s: limits.max_joint_speed_rad_s.min(self.move_speed_rad_s()),
            max_joint_accel_rad_s2: limits.max_joint_accel_rad_s2.min(self.joint_accel_rad_s2),
            timeout: limits.timeout,
        }
    }

    /// Whether every joint of `q` is finite and within the position limit.
    pub fn within_reach(&self, q: &[f64]) -> bool {
        q.iter()
            .all(|v| v.is_finite() && v.abs() <= self.joint_position_rad)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn the_table_holds_the_datasheets_speeds() {
        let ur5e = UrModel::Ur5e.limits();
        assert_eq!(ur5e.joint_speed_rad_s, [PI; 6]);
        assert_eq!(ur5e.move_speed_rad_s(), PI);
        let ur3e = UrModel::Ur3e.limits();
        assert_eq!(ur3e.joint_speed_rad_s, [PI, PI, PI, TAU, TAU, TAU]);
        let ur10e = UrModel::Ur10e.limits();
        assert_eq!(ur10e.joint_speed_rad_s[..2], [TAU / 3.0; 2]);
        assert_eq!(ur10e.joint_speed_rad_s[2..], [PI; 4]);
        assert_eq!(ur10e.move_speed_rad_s(), TAU / 3.0);
        for m in UrModel::ALL {
            let l = m.limits();
            assert_eq!(l.joint_accel_rad_s2, MAX_JOINT_ACCEL_RAD_S2, "{m}");
            // No model is faster than the highest cap a configuration may ask for, in its
            // slowest joint.
            assert!(l.move_speed_rad_s() <= MAX_JOINT_SPEED_CAP_RAD_S, "{m}");
            assert!(DRIVER_SPEED_CAP_RAD_S < l.move_speed_rad_s(), "{m}");
        }
    }

    #[test]
    fn a_pose_is_finite_and_within_its_bound() {
        let tool = [0.0, 0.0, 0.15, 0.0, 0.0, 0.1];
        assert_eq!(within_pose_bound(&tool, MAX_TCP_OFFSET_M), Ok(()));
        let far = [5.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let why = within_pose_bound(&far, MAX_TCP_OFFSET_M).expect_err("5 m");
        assert!(
            why.contains("5.000 m") && why.contains("at most 2 m"),
            "{why}"
        );
        assert_eq!(within_pose_bound(&far, MAX_POSE_DISTANCE_M), Ok(()));
        let huge = [1e300, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert!(within_pose_bound(&huge, MAX_POSE_DISTANCE_M).is_err());
        let nan = [0.0, 0.0, 0.0, f64::NAN, 0.0, 0.0];
        assert_eq!(
            within_pose_bound(&nan, MAX_POSE_DISTANCE_M),
            Err("which is not a finite pose".into())
        );
    }

    #[test]
    fn caps_clamp_to_the_arm_and_keep_the_timeout() {
        let asked = MotionLimits {
            max_joint_speed_rad_s: 3.0,
            max_joint_accel_rad_s2: 100.0,
            timeout: Duration::from_secs(7),
        };
        let capped = UrModel::Ur20.limits().cap(asked);
        assert_eq!(capped.max_joint_speed_rad_s, TAU / 3.0);
        assert_eq!(capped.max_joint_accel_rad_s2, 40.0);
        assert_eq!(capped.timeout, Duration::from_secs(7));
        let slow = MotionLimits {
            max_joint_speed_rad_s: 0.25,
            max_joint_accel_rad_s2: 0.5,
            timeout: Duration::from_secs(7),
        };
        assert_eq!(UrModel::Ur20.limits().cap(slow), slow);
        let l = UrModel::Ur5e.limits();
        assert!(l.within_reach(&[TAU, -TAU, 0.0]));
        assert!(!l.within_reach(&[TAU + 1e-6]));
        assert!(!l.within_reach(&[f64::NAN]));
    }
}
