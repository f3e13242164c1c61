//! Every default of the configuration, in one place (the example files quote the same values).

use super::{KinematicsSource, RobotPorts};
use crate::calib::{GateThresholds, Mount};
use handeye_hal::{CaptureSettings, MotionLimits};

/// `[robot.ports]`: UR's standard ports.
pub const ROBOT_PORTS: RobotPorts = RobotPorts::UR_STANDARD;
/// `robot.max_joint_speed_rad_s`, `max_joint_accel_rad_s2`, `move_timeout_s`: the hal's
/// conservative caps (0.5 rad/s, 1 rad/s², 60 s).
pub fn motion_limits() -> MotionLimits {
    MotionLimits::default()
}
/// `daemon.listen`: the API on localhost only.
pub const DAEMON_LISTEN: &str = "127.0.0.1:8650";
/// `daemon.keep_captures_runs`.
pub const KEEP_CAPTURES_RUNS: usize = 50;
/// `daemon.keep_captures_days`.
pub const KEEP_CAPTURES_DAYS: f64 = 30.0;
/// `[daemon]` with every key at its default: no startup run, API on localhost, no
/// token (nothing that moves the arm is accepted), no schedule.
pub fn daemon() -> super::DaemonConfig {
    super::DaemonConfig {
        startup: None,
        listen: DAEMON_LISTEN
            .parse()
            .unwrap_or_else(|_| std::net::SocketAddr::from(([127, 0, 0, 1], 8650))),
        token_file: None,
        check_interval: None,
        check_at: Vec::new(),
        when_busy: super::WhenBusy::Refuse,
        recalibrate_on_drift: false,
        keep_captures_runs: KEEP_CAPTURES_RUNS,
        keep_captures_days: KEEP_CAPTURES_DAYS,
        pendant: None,
    }
}
/// `robot.allow_power_on`: never power on or release brakes by ourselves.
pub const ALLOW_POWER_ON: bool = false;
/// `robot.kinematics`.
pub const KINEMATICS: KinematicsSource = KinematicsSource::Controller;
/// `camera.frames`, `frame_timeout_s`, `exposure_us`: 1 frame, 10 s, camera's own exposure.
pub fn capture() -> CaptureSettings {
    CaptureSettings::default()
}
/// `camera.settle_s`.
pub const SETTLE_S: f64 = 0.5;
/// `camera.sensor`: the industrial structured-light cameras the registration was built on.
pub const SENSOR: crate::geometry::SensorClass = crate::geometry::SensorClass::StructuredLight;
/// `camera.trigger`: free running (a camera left in trigger mode is switched out of it).
pub const TRIGGER: handeye_hal::Trigger = handeye_hal::Trigger::Free;
/// `camera.call_timeout_s` (gentl backend): a producer call that has not returned by then is
/// abandoned (its host process killed).
pub const CALL_TIMEOUT_S: f64 = 10.0;
/// `camera.timeout_s` (exec backend): vendor SDKs take seconds to connect.
pub const EXEC_TIMEOUT_S: f64 = 30.0;
/// `mount.type`.
pub const MOUNT: Mount = Mount::EyeInHand;
/// `mount.max_camera_flange_distance_m` (eye-in-hand).
pub const MAX_CAMERA_FLANGE_DISTANCE_M: f64 = 0.3;
/// `views.count` (auto): three views fitted together (one leaves the housings and the mount
/// apart by the housings' tolerance: ~0.4 mm instead of ~0.1 mm, docs/src/benchmarks.md).
pub const VIEW_COUNT: usize = 3;
/// `views.min_distance_m` (auto).
pub const MIN_DISTANCE_M: f64 = 0.4;
/// `views.max_distance_m` (auto).
pub const MAX_DISTANCE_M: f64 = 0.8;
/// `views.seed` (auto).
pub const SEED: u64 = 1;
/// `views.floor_clearance_m`.
pub const FLOOR_CLEARANCE_M: f64 = 0.03;
/// `views.return_to_start`.
pub const RETURN_TO_START: bool = true;
/// `[gate]` (a structured-light camera's; [`gate_for`] another class's).
pub fn gate() -> GateThresholds {
    gate_for(SENSOR)
}
/// `[gate]` for a camera of `sensor`'s class.
pub fn gate_for(sensor: crate::geometry::SensorClass) -> GateThresholds {
    GateThresholds::for_sensor(sensor)
}
/// `check.max_drift_translation_mm` for a structured-light camera: about three times the 95th
/// percentile of the difference between a check and its calibration of an unmoved camera at
/// the calibration's views (0.148 mm over 540 simulated checks), above the largest of them
/// (0.38 mm), a margin for what the simulator leaves out (the arm's random repeatability,
/// warm-up); a shift of 0.58 mm is caught in 95 % of checks (docs/src/benchmarks.md, "Drift
/// checks"). Another class's: [`drift_for`].
pub const MAX_DRIFT_TRANSLATION_MM: f64 = 0.5;
/// `check.max_drift_rotation_deg` for a structured-light camera: about three times the 95th
/// percentile of the same checks (0.013°), above their largest (0.033°); a turn of 0.058° is
/// caught in 95 % of checks.
pub const MAX_DRIFT_ROTATION_DEG: f64 = 0.05;
/// `[check]` limits (mm, degrees) of a time-of-flight camera, sized as structured light's:
/// about three times the larger 95th percentile of two benches' simulated checks of an unmoved
/// camera (0.472 mm / 0.051°; `handeye bench --camera helios2 --views-per-run 3 --kinematics
/// known|unknown`, 1 076 checks), above their largest (1.20 mm / 0.10°). At structured light's
/// 0.5 mm / 0.05° 34 of 536 of those checks raised a false alarm.
pub const TOF_MAX_DRIFT: (f64, f64) = (1.5, 0.15);
/// `check.max_drift_translation_mm` / `max_drift_rotation_deg` for a camera of `sensor`'s
/// class. Active stereo's are the split halves' limits of its gate
/// ([`GateThresholds::for_sensor`]): a check is a second fit from other frames, and two fits of
/// such a camera may disagree by that much with neither wrong.
pub fn drift_for(sensor: crate::geometry::SensorClass) -> (f64, f64) {
    use crate::geometry::SensorClass;
    match sensor {
        SensorClass::StructuredLight => (MAX_DRIFT_TRANSLATION_MM, MAX_DRIFT_ROTATION_DEG),
        SensorClass::TimeOfFlight => TOF_MAX_DRIFT,
        SensorClass::ActiveStereo => GateThresholds::for_sensor(sensor)
            .max_split_half
            .unwrap_or((MAX_DRIFT_TRANSLATION_MM, MAX_DRIFT_ROTATION_DEG)),
    }
}
/// `write_back.tcp` for eye-in-hand (eye-to-hand: always false).
pub const WRITE_BACK_TCP_EYE_IN_HAND: bool = true;
/// `write_back.files`.
pub const WRITE_BACK_FILES: bool = true;
/// `storage.dir`, relative to the config file's directory.
pub const STORAGE_DIR: &str = "handeye-data";
/// `storage.keep_captures`.
pub const KEEP_CAPTURES: bool = true;
