//! Ready-made configurations.

use std::net::IpAddr;
use std::path::PathBuf;
use std::time::Duration;

use handeye_hal::ur_dh::UrModel;
use handeye_hal::{CaptureSettings, MotionLimits, UrPose};

use crate::calib::Mount;

use super::defaults;
use super::types::*;

/// A ready-made configuration for the simulated rig (`handeye sim rig`, the demo): a UR5e at
/// `host`/`ports` and the simulated GigE Vision camera at `camera_address`, mounted on the
/// flange where the simulated camera's default mount puts it (`[0, -0.08, 0.04, -0.26, 0, 0]`),
/// three automatically planned views (fitted together), TCP and register (double 24..29, int 24) write-back, results
/// in `storage_dir`. `config/sim-rig.example.toml` is the same as a file.
pub fn sim_rig(
    host: IpAddr,
    ports: RobotPorts,
    camera_address: String,
    storage_dir: PathBuf,
) -> Config {
    Config {
        origin: "<sim rig>".to_string(),
        robot: RobotConfig {
            model: UrModel::Ur5e,
            urdf: None,
            host,
            ports,
            limits: MotionLimits {
                max_joint_speed_rad_s: 1.0,
                max_joint_accel_rad_s2: 2.0,
                ..defaults::motion_limits()
            },
            allow_power_on: defaults::ALLOW_POWER_ON,
            kinematics: defaults::KINEMATICS,
            calibration: None,
        },
        camera: CameraConfig {
            backend: CameraBackend::Gige {
                address: camera_address,
            },
            capture: CaptureSettings {
                frames: 1,
                ..defaults::capture()
            },
            settle: Duration::from_millis(200),
            sensor: defaults::SENSOR,
            trigger: defaults::TRIGGER,
            settings: handeye_hal::CameraSettings::default(),
        },
        mount: MountConfig {
            mount: Mount::EyeInHand,
            prior: Some(UrPose([0.0, -0.08, 0.04, -0.26, 0.0, 0.0]).into()),
            max_camera_flange_distance_m: Some(defaults::MAX_CAMERA_FLANGE_DISTANCE_M),
        },
        views: ViewsConfig {
            targets: ViewTargets::Auto {
                count: defaults::VIEW_COUNT,
                min_distance_m: defaults::MIN_DISTANCE_M,
                max_distance_m: defaults::MAX_DISTANCE_M,
                seed: defaults::SEED,
            },
            obstacles: Vec::new(),
            floor_clearance_m: defaults::FLOOR_CLEARANCE_M,
            return_to_start: defaults::RETURN_TO_START,
        },
        gate: defaults::gate(),
        check: CheckConfig {
            max_drift_translation_mm: defaults::MAX_DRIFT_TRANSLATION_MM,
            max_drift_rotation_deg: defaults::MAX_DRIFT_ROTATION_DEG,
        },
        write_back: WriteBackConfig {
            tcp: true,
            registers: Some(RegisterMap {
                double_start: 24,
                sequence_int: 24,
            }),
            files: defaults::WRITE_BACK_FILES,
        },
        storage: StorageConfig {
            dir: storage_dir,
            keep_captures: defaults::KEEP_CAPTURES,
        },
        daemon: defaults::daemon(),
    }
}
