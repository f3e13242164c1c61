//! What the controller sends, checked before anything reads it: every RTDE field a move,
//! a pose or a register comes from, the kinematics info of the primary interface, and the
//! state a move runs in ([`MoveWatch`]). A value no controller can send is an error naming
//! the field, its value and what to check.

use handeye_hal::ur_limits::{self, within_pose_bound};
use handeye_hal::{HalError, RobotStatus, SafetyMode};

use super::rtde_client::Sample;
use crate::dashboard::safety_mode_from_code;
use crate::primary::{KinematicsInfo, CALIBRATION_LINEARISED};
use crate::rtde::Value;
use crate::UrPose;

/// Farthest a pose the controller reports may lie from `base`, m (the hal's bound).
pub(super) const MAX_POSE_DISTANCE_M: f64 = ur_limits::MAX_POSE_DISTANCE_M;
/// Farthest a TCP offset (`flange_from_tcp`) may lie from the flange, m (the hal's bound, the
/// same for a TCP read and one set).
pub(super) const MAX_TCP_OFFSET_M: f64 = ur_limits::MAX_TCP_OFFSET_M;
/// Largest joint angle a controller can report, rad: UR joints turn ±360°; a little slack for
/// rounding.
const MAX_REPORTED_JOINT_RAD: f64 = ur_limits::JOINT_POSITION_LIMIT_RAD + 1e-3;
/// Largest joint speed a controller can report, rad/s: no UR joint turns faster than 2π rad/s
/// (the small arms' wrists); a measured speed overshoots its target a little, so half as much
/// again. Beyond it the value is corrupt, not a speed.
const MAX_REPORTED_JOINT_SPEED_RAD_S: f64 = 1.5 * std::f64::consts::TAU;

/// What the controller sent that cannot be a real value: an error naming the field, its
/// values and what to check (nothing that reads it moves the arm or writes anything).
fn corrupt(name: &str, values: &[f64], why: &str) -> HalError {
    HalError::Protocol {
        peer: "RTDE".into(),
        detail: format!(
            "the controller reported {name} = {values:?}, {why}; the controller or something \
             between it and this PC sends corrupt data: check the controller's log and the \
             network before calibrating"
        ),
    }
}

/// A field the controller must send is not in its data.
fn missing(name: &str) -> HalError {
    HalError::Protocol {
        peer: "RTDE".into(),
        detail: format!("no {name} in the controller's data"),
    }
}

/// Six numbers the controller must send as `name`: present, finite (else "which are not
/// finite `what`"), each within ±`max` (else `beyond()`, made only then: the move loop reads
/// every sample).
fn bounded_vec6(
    s: &Sample,
    name: &str,
    what: &str,
    max: f64,
    beyond: impl FnOnce() -> String,
) -> Result<[f64; 6], HalError> {
    let v = s.vec6(name).ok_or_else(|| missing(name))?;
    if v.iter().any(|x| !x.is_finite()) {
        return Err(corrupt(name, &v, &format!("which are not finite {what}")));
    }
    if v.iter().any(|x| x.abs() > max) {
        return Err(corrupt(name, &v, &beyond()));
    }
    Ok(v)
}

/// A pose field (`x, y, z` m, rotation vector rad) the controller must send: present,
/// finite, within `max_m` of its frame's origin.
pub(super) fn pose_field(s: &Sample, name: &str, max_m: f64) -> Result<UrPose, HalError> {
    let p = s.vec6(name).ok_or_else(|| missing(name))?;
    within_pose_bound(&p, max_m).map_err(|why| corrupt(name, &p, &why))?;
    Ok(UrPose(p))
}

/// The joint angles the controller must send (`actual_q`): present, finite, within a UR
/// joint's ±360°.
pub(super) fn joints_field(s: &Sample) -> Result<[f64; 6], HalError> {
    bounded_vec6(s, "actual_q", "angles", MAX_REPORTED_JOINT_RAD, || {
        "beyond the ±360° (±6.283 rad) a UR joint turns".into()
    })
}

/// The joint speeds the controller must send (`actual_qd`): present, finite, within
/// [`MAX_REPORTED_JOINT_SPEED_RAD_S`].
pub(super) fn speeds_field(s: &Sample) -> Result<[f64; 6], HalError> {
    bounded_vec6(
        s,
        "actual_qd",
        "joint speeds",
        MAX_REPORTED_JOINT_SPEED_RAD_S,
        || {
            format!(
                "faster than the {MAX_REPORTED_JOINT_SPEED_RAD_S:.2} rad/s a UR joint can turn \
                 (2π rad/s and half as much again)"
            )
        },
    )
}

/// The speed slider the controller must send (`target_speed_fraction`): present, within
/// [0, 1].
pub(super) fn speed_fraction_field(s: &Sample) -> Result<f64, HalError> {
    let f = s
        .f64("target_speed_fraction")
        .ok_or_else(|| missing("target_speed_fraction"))?;
    if !(0.0..=1.0).contains(&f) {
        return Err(corrupt(
            "target_speed_fraction",
            &[f],
            "outside the speed slider's 0..1",
        ));
    }
    Ok(f)
}

pub(super) fn int_field(s: &Sample, name: &str) -> Result<i32, HalError> {
    match s.get(name) {
        Some(Value::Int32(v)) => Ok(v),
        Some(other) => Err(HalError::Protocol {
            peer: "RTDE".into(),
            detail: format!("{name} is {other:?}, expected INT32"),
        }),
        None => Err(HalError::InvalidArgument(format!(
            "{name} not in the recipe"
        ))),
    }
}

/// What is wrong with the kinematics info a controller published, if anything: DH values
/// that are not finite, a `calibration_status` that is none of the three a controller has.
pub(super) fn check_kinematics(k: &KinematicsInfo) -> Result<(), String> {
    let dh = &k.dh;
    for (name, values) in [
        ("theta", &dh.theta),
        ("a", &dh.a),
        ("d", &dh.d),
        ("alpha", &dh.alpha),
    ] {
        if values.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "the controller published DH {name} = {values:?} (primary interface, kinematics \
                 info), which are not finite"
            ));
        }
    }
    if k.calibration_status > CALIBRATION_LINEARISED {
        return Err(format!(
            "the controller published calibration_status = {} (primary interface, kinematics \
             info), none of the 0, 1, 2 a controller has",
            k.calibration_status
        ));
    }
    Ok(())
}

pub(super) fn check_can_move(st: &RobotStatus, during: &str) -> Result<(), HalError> {
    match st.safety_mode {
        SafetyMode::ProtectiveStop => {
            return Err(HalError::ProtectiveStop {
                during: format!("{during} (before start)"),
            })
        }
        SafetyMode::RobotEmergencyStop | SafetyMode::SystemEmergencyStop => {
            return Err(HalError::EmergencyStop {
                during: format!("{during} (before start)"),
            })
        }
        _ => {}
    }
    if !st.remote_control {
        return Err(HalError::NotInRemoteControl);
    }
    if !st.can_move() {
        return Err(HalError::NotReady {
            state: format!("{:?}, {:?}", st.robot_mode, st.safety_mode),
        });
    }
    Ok(())
}

/// `runtime_state` while a program plays.
pub(super) const RUNTIME_PLAYING: f64 = 2.0;
/// The runtime states a controller has: 0 stopping, 1 stopped, 2 playing, 3 pausing, 4 paused,
/// 5 resuming.
const RUNTIME_STATES: std::ops::RangeInclusive<f64> = 0.0..=5.0;

/// The controller state a move started in, held on every RTDE sample of the move
/// ([`MoveWatch::check`]): a change fails the move, and the move loop stops the arm, so a
/// run ends before anything is written.
#[derive(Debug, Clone, Copy)]
pub(super) struct MoveWatch {
    /// The safety mode at the start (one a move may start in: normal or reduced).
    safety: SafetyMode,
    /// What moves, for the errors.
    during: &'static str,
}

impl MoveWatch {
    /// Watches a move that starts in `start` (checked with [`check_can_move`]).
    pub(super) fn new(start: &RobotStatus, during: &'static str) -> Self {
        Self {
            safety: start.safety_mode,
            during,
        }
    }

    /// Checks one sample of the move: the safety mode as at the start (a protective or an
    /// emergency stop is its own error; a code no controller has is corrupt data), the runtime
    /// state one a controller has, the speed slider within 0..1. Returns whether a program
    /// plays.
    pub(super) fn check(&self, s: &Sample) -> Result<bool, HalError> {
        let during = self.during;
        let code = s.f64("safety_mode").ok_or_else(|| missing("safety_mode"))?;
        match safety_mode_from_code(code as i32) {
            now if now == self.safety => {}
            SafetyMode::ProtectiveStop => {
                return Err(HalError::ProtectiveStop {
                    during: during.into(),
                })
            }
            SafetyMode::RobotEmergencyStop | SafetyMode::SystemEmergencyStop => {
                return Err(HalError::EmergencyStop {
                    during: during.into(),
                })
            }
            SafetyMode::Undefined => {
                return Err(corrupt(
                    "safety_mode",
                    &[code],
                    "none of the safety modes a controller has (1 normal … 13), during the \
                     move, so the arm was stopped",
                ))
            }
            now => {
                return Err(HalError::Refused {
                    device: "UR controller".into(),
                    request: during.into(),
                    reason: format!(
                        "its safety mode changed from {:?} to {now:?} during the move, so the \
                         arm was stopped; clear the cause on the pendant (the safety log says \
                         which), then retry",
                        self.safety
                    ),
                })
            }
        }
        let state = s
            .f64("runtime_state")
            .ok_or_else(|| missing("runtime_state"))?;
        if !RUNTIME_STATES.contains(&state) || state.fract() != 0.0 {
            return Err(corrupt(
                "runtime_state",
                &[state],
                "none of the runtime states a controller has (0 stopping … 5 resuming), \
                 during the move, so the arm was stopped",
            ));
        }
        speed_fraction_field(s)?;
        Ok(state == RUNTIME_PLAYING)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use handeye_hal::ur_dh::UrModel;

    #[test]
    fn kinematics_no_arm_has_are_refused_naming_the_value() {
        let good = KinematicsInfo::for_arm(UrModel::Ur5e.dh(), CALIBRATION_LINEARISED);
        assert_eq!(check_kinematics(&good), Ok(()));
        // A real UR10's huge compensating d values are finite: taken (the model check judges).
        let mut huge = good;
        huge.dh.d[1] = 439.0;
        assert_eq!(check_kinematics(&huge), Ok(()));
        for status in 0..=CALIBRATION_LINEARISED {
            assert_eq!(
                check_kinematics(&KinematicsInfo::for_arm(UrModel::Ur5e.dh(), status)),
                Ok(())
            );
        }
        let mut nan = good;
        nan.dh.alpha[4] = f64::NAN;
        let why = check_kinematics(&nan).expect_err("NaN");
        assert!(why.contains("DH alpha = [") && why.contains("NaN"), "{why}");
        let mut inf = good;
        inf.dh.theta[0] = f64::NEG_INFINITY;
        assert!(check_kinematics(&inf)
            .expect_err("inf")
            .contains("DH theta = [-inf"));
        let status = KinematicsInfo::for_arm(UrModel::Ur5e.dh(), 7);
        assert!(check_kinematics(&status)
            .expect_err("status")
            .contains("calibration_status = 7"));
    }
}
