use std::future::Future;
use std::time::Duration;

use nalgebra::Isometry3;

use crate::{ControllerKinematics, HalError};

/// Joint angles in radians, URDF chain order (for UR: base, shoulder, elbow, wrist 1, 2, 3).
pub type JointPositions = Vec<f64>;

/// Speed and acceleration caps for a joint move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionLimits {
    /// Maximum joint speed, rad/s (the configured safety cap).
    pub max_joint_speed_rad_s: f64,
    /// Maximum joint acceleration, rad/s².
    pub max_joint_accel_rad_s2: f64,
    /// Give up (and stop the arm) if the move has not arrived within this time.
    pub timeout: Duration,
}

impl Default for MotionLimits {
    fn default() -> Self {
        Self {
            max_joint_speed_rad_s: 0.5,
            max_joint_accel_rad_s2: 1.0,
            timeout: Duration::from_secs(60),
        }
    }
}

/// Robot mode as UR reports it (RTDE `robot_mode`, dashboard `robotmode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
#[allow(missing_docs)]
pub enum RobotMode {
    NoController,
    Disconnected,
    ConfirmSafety,
    Booting,
    PowerOff,
    PowerOn,
    Idle,
    Backdrive,
    Running,
    UpdatingFirmware,
}

/// Safety mode as UR reports it (RTDE `safety_mode`, dashboard `safetymode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
#[allow(missing_docs)]
pub enum SafetyMode {
    Normal,
    Reduced,
    ProtectiveStop,
    Recovery,
    SafeguardStop,
    SystemEmergencyStop,
    RobotEmergencyStop,
    Violation,
    Fault,
    ValidateJointId,
    Undefined,
    AutomaticModeSafeguardStop,
    SystemThreePositionEnablingStop,
}

/// What preflight needs to know before anything moves.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RobotStatus {
    /// Power/brake state.
    pub robot_mode: RobotMode,
    /// Safety state; anything but `Normal`/`Reduced` forbids motion.
    pub safety_mode: SafetyMode,
    /// Whether the controller accepts remote commands (e-Series remote control; always true on CB3).
    pub remote_control: bool,
    /// Whether a program is running on the controller.
    pub program_running: bool,
    /// The speed slider (UR RTDE `target_speed_fraction`), 0–1: the controller scales every
    /// commanded speed by it, so moves take longer than planned below 1. Preflight records it.
    /// Records written before this field existed read as 1.
    #[serde(default = "full_speed")]
    pub speed_fraction: f64,
}

fn full_speed() -> f64 {
    1.0
}

impl RobotStatus {
    /// Whether the arm can be commanded to move right now.
    pub fn can_move(&self) -> bool {
        self.robot_mode == RobotMode::Running
            && matches!(self.safety_mode, SafetyMode::Normal | SafetyMode::Reduced)
            && self.remote_control
    }
}

/// Who a controller says it is, asked at every preflight: recorded with the run, kept with the
/// calibration it produced, and compared with the next run's (a calibration belongs to one
/// arm). Each field is `None` when the controller does not tell (old firmware).
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ControllerIdentity {
    /// The arm's serial number (UR: dashboard `get serial number`, e.g. `20205500001`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial: Option<String>,
    /// The model as the controller names it (UR: dashboard `get robot model`, e.g. `UR5`; some
    /// versions name the family only, so a UR5e may answer `UR5`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    /// The controller's software version (UR: dashboard `PolyScope version`, e.g.
    /// `5.11.1.108318`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub software_version: Option<String>,
    /// The controller's per-joint checksums of its kinematics calibration (UR: primary
    /// KinematicsInfo): they change when the arm is recalibrated or a joint replaced.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kinematics_checksum: Option<[u32; 6]>,
}

impl ControllerIdentity {
    /// The kinematics checksums as one short text (`8 hex digits` per joint, `-`-separated).
    pub fn checksum_text(&self) -> Option<String> {
        self.kinematics_checksum.map(|c| {
            c.iter()
                .map(|v| format!("{v:08x}"))
                .collect::<Vec<_>>()
                .join("-")
        })
    }

    /// Why a calibration made on the controller `then` may not hold on this one: another arm
    /// (the serials differ) or the same arm with other kinematics (the checksums differ), as
    /// a sentence that says to recalibrate; `None` when both match or either side does not
    /// tell.
    pub fn calibration_mismatch(&self, then: &ControllerIdentity) -> Option<String> {
        if let (Some(a), Some(b)) = (&then.serial, &self.serial) {
            if a != b {
                return Some(format!(
                    "the current calibration was made on arm {a}; this controller is {b}: \
                     recalibrate"
                ));
            }
        }
        if let (Some(a), Some(b)) = (then.checksum_text(), self.checksum_text()) {
            if a != b {
                let arm = self
                    .serial
                    .as_deref()
                    .map_or_else(String::new, |s| format!(" {s}"));
                return Some(format!(
                    "the arm{arm}'s kinematics changed since the current calibration \
                     (kinematics checksum {a} then, {b} now: recalibrated or a joint \
                     replaced): recalibrate"
                ));
            }
        }
        None
    }
}

/// `UR5 serial 20205500001, software 5.11.1.108318, kinematics checksum 1a2b…`; what the
/// controller did not tell is `?`.
impl std::fmt::Display for ControllerIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let or_unknown = |v: Option<&str>| v.unwrap_or("?").to_string();
        write!(
            f,
            "{} serial {}, software {}, kinematics checksum {}",
            or_unknown(self.model.as_deref()),
            or_unknown(self.serial.as_deref()),
            or_unknown(self.software_version.as_deref()),
            self.checksum_text().unwrap_or_else(|| "?".into())
        )
    }
}

/// A UR-class arm. All lengths m, angles rad; joint order = URDF order.
///
/// Implementations are cheap handles onto one connection; every method may be called from any
/// task. A method that moves the arm stops it before returning an error.
pub trait Robot: Send + Sync + 'static {
    /// Mode, safety mode, remote-control flag, program-running flag.
    fn status(&self) -> impl Future<Output = Result<RobotStatus, HalError>> + Send;

    /// The measured joint angles at the latest controller sample.
    fn joint_positions(&self) -> impl Future<Output = Result<JointPositions, HalError>> + Send;

    /// `base_from_flange` as the controller computes it (its own calibrated kinematics), in the
    /// controller's `base` frame, with the TCP offset removed.
    fn flange_pose(&self) -> impl Future<Output = Result<Isometry3<f64>, HalError>> + Send;

    /// Joint move that returns only when the arm has arrived; fails with `ProtectiveStop`,
    /// `EmergencyStop`, `NotInRemoteControl`, `Timeout` (arm stopped first).
    ///
    /// Cancelling: dropping the returned future before it completes (e.g. losing a
    /// `tokio::select!` against a shutdown signal, or `tokio::time::timeout`) cancels the move
    /// and stops the arm; implementations must guarantee this (the stop is issued from a drop
    /// guard on the current tokio runtime, so it may land a few milliseconds after the drop).
    fn move_joints(
        &self,
        q: &[f64],
        limits: MotionLimits,
    ) -> impl Future<Output = Result<(), HalError>> + Send;

    /// Stop any motion now (decelerating within the controller's limits).
    fn stop(&self) -> impl Future<Output = Result<(), HalError>> + Send;

    /// Powers the arm on and releases its brakes (UR: dashboard `power on`, then
    /// `brake release`), returning once the controller reports [`RobotMode::Running`]; fails
    /// with `Timeout` when it does not get there, `Refused` when the controller will not (an
    /// emergency stop). Releasing the brakes may move the arm a little. Callers do this only
    /// when the configuration says so explicitly (`robot.allow_power_on`).
    fn power_on(&self) -> impl Future<Output = Result<(), HalError>> + Send;

    /// Set the runtime TCP (`flange_from_tcp`; volatile on UR) and confirm by read-back.
    fn set_tcp(
        &self,
        flange_from_tcp: &Isometry3<f64>,
    ) -> impl Future<Output = Result<(), HalError>> + Send;

    /// Write a double input register (e.g. RTDE `input_double_register_N`) for a pendant program.
    fn write_double_register(
        &self,
        index: u32,
        value: f64,
    ) -> impl Future<Output = Result<(), HalError>> + Send;

    /// Read a double register back as the controller reflects it.
    fn read_double_register(
        &self,
        index: u32,
    ) -> impl Future<Output = Result<f64, HalError>> + Send;

    /// Write an integer input register (e.g. RTDE `input_int_register_N`) for a pendant program
    /// (a "result ready" flag, a run counter) and confirm by read-back.
    fn write_int_register(
        &self,
        index: u32,
        value: i32,
    ) -> impl Future<Output = Result<(), HalError>> + Send;

    /// Read an integer input register (`input_int_register_N`) as the controller reflects it.
    fn read_int_register(&self, index: u32) -> impl Future<Output = Result<i32, HalError>> + Send;

    /// Read an integer output register (`output_int_register_N`): what a program on the
    /// controller wrote (`write_output_integer_register`), e.g. a pendant program's request.
    fn read_output_int_register(
        &self,
        index: u32,
    ) -> impl Future<Output = Result<i32, HalError>> + Send;

    /// The active TCP offset `flange_from_tcp` (metres, radians; `flange` = UR `tool0`) as the
    /// controller reports it, i.e. what `set_tcp` or the pendant installation left active.
    fn tcp_offset(&self) -> impl Future<Output = Result<Isometry3<f64>, HalError>> + Send;

    /// The controller's own (factory-calibrated) kinematics, the ones its reported poses
    /// ([`Robot::flange_pose`]) are computed with; `None` when the controller does not publish
    /// them (old firmware, a controller that sent none within the connect timeout).
    /// Cheap: implementations cache them (the UR driver reads them once when it connects).
    fn kinematics(
        &self,
    ) -> impl Future<Output = Result<Option<ControllerKinematics>, HalError>> + Send;

    /// Who the controller says it is: serial, model, software version, kinematics checksum
    /// (what it does not tell stays `None`). Asked anew each call (a few dashboard requests on
    /// UR).
    fn identity(&self) -> impl Future<Output = Result<ControllerIdentity, HalError>> + Send;

    /// How many times the connection had to be re-established since this handle was made.
    /// A calibration run compares it between its steps: joints, poses and captures taken on
    /// either side of a reconnection (a restarted controller, a new RTDE session) are not
    /// trusted together. Implementations that never reconnect keep the default 0.
    fn link_generation(&self) -> u64 {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arm(serial: &str, checksum: u32) -> ControllerIdentity {
        ControllerIdentity {
            serial: Some(serial.into()),
            model: Some("UR5".into()),
            software_version: Some("5.11.1.108318".into()),
            kinematics_checksum: Some([checksum; 6]),
        }
    }

    #[test]
    fn another_arm_or_other_kinematics_say_recalibrate() {
        let then = arm("20205500001", 7);
        assert_eq!(arm("20205500001", 7).calibration_mismatch(&then), None);
        let other = arm("20205500002", 7)
            .calibration_mismatch(&then)
            .expect("another arm");
        assert_eq!(
            other,
            "the current calibration was made on arm 20205500001; this controller is \
             20205500002: recalibrate"
        );
        let changed = arm("20205500001", 8)
            .calibration_mismatch(&then)
            .expect("other kinematics");
        assert!(
            changed.contains("00000007-") && changed.contains("00000008-"),
            "{changed}"
        );
        assert!(changed.ends_with("recalibrate"), "{changed}");
        assert_eq!(
            then.to_string(),
            "UR5 serial 20205500001, software 5.11.1.108318, kinematics checksum \
             00000007-00000007-00000007-00000007-00000007-00000007"
        );
        assert_eq!(
            ControllerIdentity::default().to_string(),
            "? serial ?, software ?, kinematics checksum ?"
        );
        // What either side does not tell is not compared.
        let unknown = ControllerIdentity::default();
        assert_eq!(unknown.calibration_mismatch(&then), None);
        assert_eq!(then.calibration_mismatch(&unknown), None);
    }

    #[test]
    fn identity_round_trips_and_old_records_read() {
        let id = arm("20205500001", 7);
        let text = serde_json::to_string(&id).expect("json");
        assert_eq!(
            serde_json::from_str::<ControllerIdentity>(&text).ok(),
            Some(id)
        );
        let empty: ControllerIdentity = serde_json::from_str("{}").expect("empty");
        assert_eq!(empty, ControllerIdentity::default());
    }
}
