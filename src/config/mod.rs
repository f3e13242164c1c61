//! The configuration a cell integrator writes: one TOML file describing the robot, the camera,
//! how the camera is mounted, where to look from, the pass/fail gate, what to write back and
//! where to keep results.
//!
//! TOML → private `Raw*` structs (serde, unknown keys refused) → validated [`Config`]. Every
//! number is checked (finite, within a sane range, units in the key names); every error names
//! the file, the dotted key and its line, and says what is allowed:
//!
//! ```text
//! cell.toml:7: robot.max_joint_speed_rad_s = 5: expected 0 < value <= 3.15 rad/s
//! ```
//!
//! Relative paths (`robot.urdf`, `camera.files`, `storage.dir`, `{config_dir}` in
//! `camera.command`) are resolved against the directory of the configuration file. Defaults
//! live in [`defaults`] and nowhere else; the files `config/*.example.toml` document every key
//! and are loaded by a test so they never rot.

mod locate;
#[cfg(test)]
mod tests;

use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::time::Duration;

use handeye_hal::ur_dh::UrModel;
use handeye_hal::{CaptureSettings, MotionLimits, UrPose};
use nalgebra::Isometry3;
use serde::Deserialize;

use crate::calib::{GateThresholds, Mount};
use locate::KeyIndex;

/// A validated configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Where it came from (file path or e.g. `"<sim rig>"`), for messages and the run record.
    pub origin: String,
    /// The arm and its controller.
    pub robot: RobotConfig,
    /// The 3D camera.
    pub camera: CameraConfig,
    /// How the camera is mounted, and a guess of where.
    pub mount: MountConfig,
    /// Where to look at the base from, and what not to hit on the way.
    pub views: ViewsConfig,
    /// Pass/fail thresholds of a calibration (`[gate]` keys override fields of
    /// [`GateThresholds::default`], same names).
    pub gate: GateThresholds,
    /// Drift check against the current calibration.
    pub check: CheckConfig,
    /// What a passing calibration is written to.
    pub write_back: WriteBackConfig,
    /// Where results and captures are kept.
    pub storage: StorageConfig,
    /// The daemon: startup run, HTTP API, schedule, capture retention (`[daemon]`).
    pub daemon: DaemonConfig,
}

/// What the daemon does on its own (`[daemon]`).
#[derive(Debug, Clone, PartialEq)]
pub struct DaemonConfig {
    /// Run at startup, once the robot and camera are connected (`startup = "none" |
    /// "calibrate" | "check"`).
    pub startup: Option<crate::record::RunMode>,
    /// Address of the HTTP API and web page (`listen`, `IP:PORT`); localhost by default.
    pub listen: std::net::SocketAddr,
    /// File holding the bearer token that requests which move the arm must carry
    /// (`token_file`); `None`: such requests are refused.
    pub token_file: Option<PathBuf>,
    /// Scheduled drift checks every this long (`check_interval_s`); `None`: no schedule.
    pub check_interval: Option<Duration>,
    /// Scheduled drift checks at these local times (`check_at = ["Mon-Fri 06:00"]`), besides
    /// or instead of the interval.
    pub check_at: Vec<crate::calendar::CalendarTime>,
    /// What a trigger gets while a run is going (`when_busy`).
    pub when_busy: WhenBusy,
    /// After a scheduled check finds drift, calibrate and write back (`recalibrate_on_drift`);
    /// off by default.
    pub recalibrate_on_drift: bool,
    /// Keep the raw captures of this many newest runs (`keep_captures_runs`) …
    pub keep_captures_runs: usize,
    /// … and of every run younger than this many days (`keep_captures_days`).
    pub keep_captures_days: f64,
    /// The pendant button (`[daemon.pendant]`); `None`: not used.
    pub pendant: Option<PendantConfig>,
}

/// What a trigger gets while a run is going (`daemon.when_busy`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum WhenBusy {
    /// Refused with who is busy since when (`"refuse"`, the default).
    #[default]
    Refuse,
    /// Queued behind it, up to [`QUEUE_LIMIT`] runs (`"queue"`).
    Queue,
}

/// The most runs `daemon.when_busy = "queue"` keeps waiting behind the running one.
pub const QUEUE_LIMIT: usize = 4;

/// The register handshake with a pendant program (`[daemon.pendant]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PendantConfig {
    /// `output_int_register_<request>`: the program writes 1 to ask for a calibration, 2 for a
    /// check, 0 when it has read the answer (`request_register`).
    pub request_register: u32,
    /// `input_int_register_<status>`: the daemon answers 1 busy, 2 done (accepted), 3 failed
    /// (rejected, aborted or error), 4 refused (busy with another run) (`status_register`).
    pub status_register: u32,
}

/// The arm and its controller (`[robot]`).
#[derive(Debug, Clone, PartialEq)]
pub struct RobotConfig {
    /// Arm model (`model = "ur5e"`); selects the URDF and the nominal DH table.
    pub model: UrModel,
    /// Robot description (`urdf`, resolved against the config file's directory); `None`: find
    /// `<model>.urdf` under the robots directory at run time.
    pub urdf: Option<PathBuf>,
    /// Controller address (`host`): the IP set on the pendant (Settings → System → Network).
    pub host: IpAddr,
    /// Controller TCP ports (`[robot.ports]`), UR's standard ones by default.
    pub ports: RobotPorts,
    /// Speed and acceleration caps and the move timeout (`max_joint_speed_rad_s`,
    /// `max_joint_accel_rad_s2`, `move_timeout_s`).
    pub limits: MotionLimits,
    /// Whether we may power the arm on and release its brakes ourselves (`allow_power_on`);
    /// never by default.
    pub allow_power_on: bool,
    /// Where forward kinematics comes from (`kinematics`).
    pub kinematics: KinematicsSource,
    /// The arm's calibration as `ur_calibration` writes it (`calibration`, a YAML file): a run
    /// the controller tells no kinematics (or with `kinematics = "nominal"`) poses the model's
    /// six joints by it; the controller's kinematics take precedence.
    pub calibration: Option<PathBuf>,
}

/// TCP ports of a UR controller. Simulators on non-standard ports need them; real controllers
/// always use the standard ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct RobotPorts {
    /// Dashboard server (power, brakes, programs, safety popups).
    pub dashboard: u16,
    /// Primary interface (URScript, 10 Hz state).
    pub primary: u16,
    /// Secondary interface (URScript, 10 Hz state).
    pub secondary: u16,
    /// Real-time interface (URScript, 125/500 Hz state).
    pub realtime: u16,
    /// RTDE (state and registers).
    pub rtde: u16,
}

impl RobotPorts {
    /// The ports every UR controller listens on: 29999, 30001, 30002, 30003, 30004.
    pub const UR_STANDARD: RobotPorts = RobotPorts {
        dashboard: 29999,
        primary: 30001,
        secondary: 30002,
        realtime: 30003,
        rtde: 30004,
    };
}

impl Default for RobotPorts {
    fn default() -> Self {
        defaults::ROBOT_PORTS
    }
}

/// Where the arm's forward kinematics comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum KinematicsSource {
    /// The controller's own (factory-calibrated) kinematics: its reported flange pose.
    Controller,
    /// The nominal model (URDF / nominal DH) at the reported joint angles.
    Nominal,
}

/// The 3D camera (`[camera]`).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraConfig {
    /// How the camera is reached.
    pub backend: CameraBackend,
    /// Frames per capture, per-frame timeout, exposure (`frames`, `frame_timeout_s`,
    /// `exposure_us`).
    pub capture: CaptureSettings,
    /// Wait after the arm stops before capturing (`settle_s`): lets the arm and mount stop
    /// vibrating.
    pub settle: Duration,
}

/// How the camera is reached (`backend`).
#[derive(Debug, Clone, PartialEq)]
pub enum CameraBackend {
    /// A GigE Vision 3D camera (`backend = "gige"`, `address = "IP"` or `"IP:PORT"`; GVCP's
    /// port 3956 when none is given).
    Gige {
        /// `IP` or `IP:PORT`, as written (checked to parse).
        address: String,
    },
    /// An external command that captures one frame to a file (`backend = "exec"`,
    /// `command = [...]`, `timeout_s`); see [`crate::camera::ExecCamera`]. `{config_dir}`
    /// in an argument is replaced by the config file's directory when loading.
    Exec {
        /// Program and arguments (no shell), `{out}` and `{frame}` left for the camera.
        command: Vec<String>,
        /// Per-frame timeout of the command.
        timeout: Duration,
    },
    /// Replay of point-cloud files (`backend = "file"`, `files = [...]`), for dry runs and CI.
    File {
        /// PLY/PCD files, resolved against the config file's directory; at least one.
        paths: Vec<PathBuf>,
    },
}

/// How the camera is mounted (`[mount]`).
#[derive(Debug, Clone, PartialEq)]
pub struct MountConfig {
    /// Eye-in-hand (camera on the flange) or eye-to-hand (fixed in the cell) (`type`).
    pub mount: Mount,
    /// A guess of the result (`prior = [x, y, z, rx, ry, rz]`, m and rotation vector rad):
    /// eye-in-hand `flange_from_camera` (flange = `tool0`), eye-to-hand `base_from_camera` in
    /// the controller's `base` frame. Needed to plan views automatically for eye-in-hand.
    pub prior: Option<Isometry3<f64>>,
    /// Eye-in-hand: registration looks for the camera within this distance of the flange
    /// (`max_camera_flange_distance_m`); `None` for eye-to-hand.
    pub max_camera_flange_distance_m: Option<f64>,
}

/// Where to look from (`[views]`).
#[derive(Debug, Clone, PartialEq)]
pub struct ViewsConfig {
    /// Configured joint targets or automatically generated views (`mode`).
    pub targets: ViewTargets,
    /// Boxes the arm must not enter (`[[views.obstacles]]`).
    pub obstacles: Vec<Obstacle>,
    /// Minimum height of every link above the mounting plane (`floor_clearance_m`).
    pub floor_clearance_m: f64,
    /// Move back to the starting joints after capturing (`return_to_start`).
    pub return_to_start: bool,
}

/// The views of a calibration.
#[derive(Debug, Clone, PartialEq)]
pub enum ViewTargets {
    /// `mode = "joints"`: `joints = [[q1, .., q6], ...]`, rad, URDF order, each |q| <= 2π.
    Joints(Vec<[f64; 6]>),
    /// `mode = "auto"`: views generated to look at the base from `min_distance_m` to
    /// `max_distance_m`.
    Auto {
        /// Number of views (`count`).
        count: usize,
        /// Closest camera–base distance, m (`min_distance_m`).
        min_distance_m: f64,
        /// Farthest camera–base distance, m (`max_distance_m`).
        max_distance_m: f64,
        /// Seed of the view generator (`seed`): the same seed plans the same views.
        seed: u64,
    },
}

/// An axis-aligned box in the controller's `base` frame that the arm must not enter.
#[derive(Debug, Clone, PartialEq)]
pub struct Obstacle {
    /// Name for messages (`name`).
    pub name: String,
    /// Centre, m (`centre_m`).
    pub centre_m: [f64; 3],
    /// Full edge lengths, m, all > 0 (`size_m`).
    pub size_m: [f64; 3],
}

/// Drift check thresholds (`[check]`): a check run alarms when the fresh result is farther than
/// this from the current calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckConfig {
    /// Translation, mm (`max_drift_translation_mm`).
    pub max_drift_translation_mm: f64,
    /// Rotation, degrees (`max_drift_rotation_deg`).
    pub max_drift_rotation_deg: f64,
}

/// What a passing calibration is written to (`[write_back]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WriteBackConfig {
    /// Set the controller's TCP to the camera (`tcp`); eye-in-hand only.
    pub tcp: bool,
    /// RTDE input registers for a pendant program (`[write_back.registers]`).
    pub registers: Option<RegisterMap>,
    /// Result files in `storage.dir` (`files`).
    pub files: bool,
}

/// RTDE input registers the result is written to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct RegisterMap {
    /// `input_double_register_<double_start>..+5` get x, y, z (m), rx, ry, rz (rad).
    pub double_start: u32,
    /// `input_int_register_<sequence_int>` is incremented after each write.
    pub sequence_int: u32,
}

/// Where results and captures are kept (`[storage]`).
#[derive(Debug, Clone, PartialEq)]
pub struct StorageConfig {
    /// Result directory (`dir`, resolved against the config file's directory).
    pub dir: PathBuf,
    /// Keep the captured clouds of each run (`keep_captures`).
    pub keep_captures: bool,
}

/// Every default of the configuration, in one place (the example files quote the same values).
pub mod defaults {
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
    /// `camera.timeout_s` (exec backend): vendor SDKs take seconds to connect.
    pub const EXEC_TIMEOUT_S: f64 = 30.0;
    /// `mount.type`.
    pub const MOUNT: Mount = Mount::EyeInHand;
    /// `mount.max_camera_flange_distance_m` (eye-in-hand).
    pub const MAX_CAMERA_FLANGE_DISTANCE_M: f64 = 0.3;
    /// `views.count` (auto).
    pub const VIEW_COUNT: usize = 1;
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
    /// `[gate]`.
    pub fn gate() -> GateThresholds {
        GateThresholds::default()
    }
    /// `check.max_drift_translation_mm`.
    pub const MAX_DRIFT_TRANSLATION_MM: f64 = 1.0;
    /// `check.max_drift_rotation_deg`.
    pub const MAX_DRIFT_ROTATION_DEG: f64 = 0.2;
    /// `write_back.tcp` for eye-in-hand (eye-to-hand: always false).
    pub const WRITE_BACK_TCP_EYE_IN_HAND: bool = true;
    /// `write_back.files`.
    pub const WRITE_BACK_FILES: bool = true;
    /// `storage.dir`, relative to the config file's directory.
    pub const STORAGE_DIR: &str = "handeye-data";
    /// `storage.keep_captures`.
    pub const KEEP_CAPTURES: bool = true;
}

/// A configuration that could not be used. Every variant but [`ConfigError::Read`] names the
/// origin, the 1-based line and, where there is one, the dotted key (`robot.ports.rtde`,
/// `views.obstacles[0].size_m`: arrays count from 0).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// Not valid TOML.
    #[error("{origin}:{line}:{column}: invalid TOML: {message}")]
    Syntax {
        /// File or other origin.
        origin: String,
        /// 1-based line.
        line: usize,
        /// 1-based column (bytes).
        column: usize,
        /// What the parser expected.
        message: String,
    },
    /// A key this program does not know (often a typo or a missing unit suffix).
    #[error("{origin}:{line}: unknown key `{key}`; allowed here: {allowed}")]
    UnknownKey {
        /// File or other origin.
        origin: String,
        /// 1-based line.
        line: usize,
        /// Dotted key.
        key: String,
        /// The keys allowed in that table.
        allowed: String,
    },
    /// A required key is absent.
    #[error("{origin}:{line}: `{key}` is required")]
    MissingKey {
        /// File or other origin.
        origin: String,
        /// 1-based line (of the table that lacks it).
        line: usize,
        /// Dotted key.
        key: String,
    },
    /// A value of the wrong type or shape.
    #[error("{origin}:{line}: {key}: {message}")]
    WrongType {
        /// File or other origin.
        origin: String,
        /// 1-based line.
        line: usize,
        /// Dotted key.
        key: String,
        /// What was found and what is expected.
        message: String,
    },
    /// A value out of range, or keys that contradict each other.
    #[error("{}: {}", at(origin, *line), keyed(key, message))]
    Invalid {
        /// File or other origin.
        origin: String,
        /// 1-based line of the key (or of the closest key or table that is in the file);
        /// `None` when nothing relevant is written in the file at all.
        line: Option<usize>,
        /// Dotted key.
        key: String,
        /// The value and what is allowed.
        message: String,
    },
}

/// `message`, prefixed with `key` unless it already starts with it.
fn keyed(key: &str, message: &str) -> String {
    if message.starts_with(key) {
        message.to_string()
    } else {
        format!("{key}: {message}")
    }
}

fn at(origin: &str, line: Option<usize>) -> String {
    match line {
        Some(l) => format!("{origin}:{l}"),
        None => origin.to_string(),
    }
}

impl ConfigError {
    /// The 1-based line the error is about, when known.
    pub fn line(&self) -> Option<usize> {
        match self {
            ConfigError::Read { .. } => None,
            ConfigError::Syntax { line, .. }
            | ConfigError::UnknownKey { line, .. }
            | ConfigError::MissingKey { line, .. }
            | ConfigError::WrongType { line, .. } => Some(*line),
            ConfigError::Invalid { line, .. } => *line,
        }
    }

    /// The dotted key the error is about, when known.
    pub fn key(&self) -> Option<&str> {
        match self {
            ConfigError::Read { .. } | ConfigError::Syntax { .. } => None,
            ConfigError::UnknownKey { key, .. }
            | ConfigError::MissingKey { key, .. }
            | ConfigError::WrongType { key, .. }
            | ConfigError::Invalid { key, .. } => Some(key),
        }
    }
}

impl Config {
    /// Parses and validates TOML `text`; `origin` names it in messages (a path, `"<stdin>"`),
    /// `base_dir` is what relative paths are resolved against.
    pub fn from_toml(text: &str, origin: &str, base_dir: &Path) -> Result<Config, ConfigError> {
        let index = KeyIndex::new(text);
        if let Err(e) = text.parse::<toml::Table>() {
            let offset = e.span().map_or(0, |s| s.start);
            return Err(ConfigError::Syntax {
                origin: origin.to_string(),
                line: index.line_at(offset),
                column: index.column_at(offset),
                message: e.message().trim().replace('\n', "; "),
            });
        }
        let raw: RawConfig = toml::from_str(text).map_err(|e| schema_error(&e, origin, &index))?;
        let ctx = Ctx {
            origin,
            index,
            base_dir,
        };
        ctx.config(raw)
    }

    /// Reads and validates a configuration file; relative paths in it are resolved against
    /// its directory (made absolute). Blocking I/O.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        let base_dir = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        // Absolute, so the paths stay right if the process changes directory later.
        let base_dir = std::path::absolute(base_dir).unwrap_or_else(|_| base_dir.to_path_buf());
        Config::from_toml(&text, &path.display().to_string(), &base_dir)
    }
}

/// A ready-made configuration for the simulated rig (`handeye sim rig`, the demo): a UR5e at
/// `host`/`ports` and the simulated GigE Vision camera at `camera_address`, mounted on the
/// flange where the simulated camera's default mount puts it (`[0, -0.08, 0.04, -0.26, 0, 0]`),
/// one automatically planned view, TCP and register (double 24..29, int 24) write-back, results
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
        },
        mount: MountConfig {
            mount: Mount::EyeInHand,
            prior: Some(UrPose([0.0, -0.08, 0.04, -0.26, 0.0, 0.0]).into()),
            max_camera_flange_distance_m: Some(defaults::MAX_CAMERA_FLANGE_DISTANCE_M),
        },
        views: ViewsConfig {
            targets: ViewTargets::Auto {
                count: 1,
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

// ---------------------------------------------------------------------------------------------
// Raw TOML shape. Optional keys are `Option`s: defaults are applied in validation, from
// `defaults`, never here. Integers are read as i64 and range-checked with the same messages as
// floats.

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    robot: RawRobot,
    camera: RawCamera,
    #[serde(default)]
    mount: RawMount,
    #[serde(default)]
    views: RawViews,
    #[serde(default)]
    gate: RawGate,
    #[serde(default)]
    check: RawCheck,
    #[serde(default)]
    write_back: RawWriteBack,
    #[serde(default)]
    storage: RawStorage,
    #[serde(default)]
    daemon: RawDaemon,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDaemon {
    startup: Option<String>,
    listen: Option<String>,
    token_file: Option<String>,
    check_interval_s: Option<f64>,
    check_at: Option<Vec<String>>,
    when_busy: Option<String>,
    recalibrate_on_drift: Option<bool>,
    keep_captures_runs: Option<i64>,
    keep_captures_days: Option<f64>,
    pendant: Option<RawPendant>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPendant {
    request_register: i64,
    status_register: i64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRobot {
    model: String,
    urdf: Option<String>,
    host: String,
    #[serde(default)]
    ports: RawPorts,
    max_joint_speed_rad_s: Option<f64>,
    max_joint_accel_rad_s2: Option<f64>,
    move_timeout_s: Option<f64>,
    allow_power_on: Option<bool>,
    kinematics: Option<KinematicsSource>,
    calibration: Option<String>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPorts {
    dashboard: Option<i64>,
    primary: Option<i64>,
    secondary: Option<i64>,
    realtime: Option<i64>,
    rtde: Option<i64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
enum RawBackend {
    Gige,
    Exec,
    File,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    backend: RawBackend,
    address: Option<String>,
    command: Option<Vec<String>>,
    timeout_s: Option<f64>,
    files: Option<Vec<String>>,
    frames: Option<i64>,
    frame_timeout_s: Option<f64>,
    exposure_us: Option<f64>,
    settle_s: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
enum RawMountType {
    #[serde(rename = "eye-in-hand")]
    EyeInHand,
    #[serde(rename = "eye-to-hand")]
    EyeToHand,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMount {
    #[serde(rename = "type")]
    kind: Option<RawMountType>,
    prior: Option<[f64; 6]>,
    max_camera_flange_distance_m: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
enum RawMode {
    Joints,
    Auto,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawViews {
    mode: Option<RawMode>,
    joints: Option<Vec<[f64; 6]>>,
    count: Option<i64>,
    min_distance_m: Option<f64>,
    max_distance_m: Option<f64>,
    seed: Option<i64>,
    #[serde(default)]
    obstacles: Vec<RawObstacle>,
    floor_clearance_m: Option<f64>,
    return_to_start: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawObstacle {
    name: String,
    centre_m: [f64; 3],
    size_m: [f64; 3],
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGate {
    min_coverage: Option<f64>,
    min_link_support: Option<f64>,
    max_free_space_violations: Option<f64>,
    max_rmse_mm: Option<f64>,
    min_inlier_fraction: Option<f64>,
    max_uncertainty_translation_mm: Option<f64>,
    max_uncertainty_rotation_deg: Option<f64>,
    max_residual_translation_mm: Option<f64>,
    max_residual_rotation_deg: Option<f64>,
    max_dropped_fraction: Option<f64>,
    max_ambiguity: Option<f64>,
    max_depth_scale_error: Option<f64>,
    max_change_translation_mm: Option<f64>,
    max_change_rotation_deg: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCheck {
    max_drift_translation_mm: Option<f64>,
    max_drift_rotation_deg: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawWriteBack {
    tcp: Option<bool>,
    registers: Option<RawRegisters>,
    files: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRegisters {
    double_start: i64,
    sequence_int: i64,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStorage {
    dir: Option<String>,
    keep_captures: Option<bool>,
}

// ---------------------------------------------------------------------------------------------
// Ranges: every number's allowed interval, with its unit, stated once.

#[derive(Debug, Clone, Copy)]
struct Range {
    lo: f64,
    lo_inclusive: bool,
    hi: f64,
    hi_inclusive: bool,
    unit: &'static str,
}

/// `lo < value <= hi`.
const fn above(lo: f64, hi: f64, unit: &'static str) -> Range {
    Range {
        lo,
        lo_inclusive: false,
        hi,
        hi_inclusive: true,
        unit,
    }
}

/// `lo <= value <= hi`.
const fn within(lo: f64, hi: f64, unit: &'static str) -> Range {
    Range {
        lo,
        lo_inclusive: true,
        hi,
        hi_inclusive: true,
        unit,
    }
}

impl Range {
    fn contains(&self, v: f64) -> bool {
        v.is_finite()
            && (if self.lo_inclusive {
                v >= self.lo
            } else {
                v > self.lo
            })
            && (if self.hi_inclusive {
                v <= self.hi
            } else {
                v < self.hi
            })
    }

    fn describe(&self) -> String {
        let lo = if self.lo_inclusive { "<=" } else { "<" };
        let hi = if self.hi_inclusive { "<=" } else { "<" };
        let unit = if self.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", self.unit)
        };
        format!("{} {lo} value {hi} {}{unit}", self.lo, self.hi)
    }
}

mod ranges {
    use super::{above, within, Range};
    use std::f64::consts::PI;

    pub(super) const PORT: Range = within(1.0, 65535.0, "");
    pub(super) const JOINT_SPEED: Range = above(0.0, 3.15, "rad/s");
    pub(super) const JOINT_ACCEL: Range = above(0.0, 40.0, "rad/s²");
    pub(super) const MOVE_TIMEOUT: Range = above(0.0, 3600.0, "s");
    pub(super) const FRAMES: Range = within(1.0, 100.0, "");
    pub(super) const FRAME_TIMEOUT: Range = above(0.0, 600.0, "s");
    pub(super) const EXPOSURE: Range = above(0.0, 10_000_000.0, "µs");
    pub(super) const SETTLE: Range = within(0.0, 60.0, "s");
    pub(super) const EXEC_TIMEOUT: Range = above(0.0, 3600.0, "s");
    pub(super) const PRIOR_TRANSLATION: Range = within(-5.0, 5.0, "m");
    pub(super) const PRIOR_ROTATION: Range = within(-2.0 * PI, 2.0 * PI, "rad");
    pub(super) const CAMERA_FLANGE_DISTANCE: Range = above(0.0, 2.0, "m");
    pub(super) const JOINT: Range = within(-2.0 * PI, 2.0 * PI, "rad (±2π)");
    pub(super) const VIEW_COUNT: Range = within(1.0, 10.0, "");
    pub(super) const VIEW_DISTANCE: Range = above(0.1, 3.0, "m");
    pub(super) const SEED: Range = within(0.0, 9.007_199_254_740_992e15, "");
    pub(super) const OBSTACLE_CENTRE: Range = within(-10.0, 10.0, "m");
    pub(super) const OBSTACLE_SIZE: Range = above(0.0, 20.0, "m");
    pub(super) const CHECK_INTERVAL: Range = within(1.0, 31_536_000.0, "s");
    pub(super) const KEEP_RUNS: Range = within(0.0, 1_000_000.0, "");
    pub(super) const KEEP_DAYS: Range = within(0.0, 36_500.0, "days");
    pub(super) const FLOOR_CLEARANCE: Range = within(0.0, 0.5, "m");
    pub(super) const FRACTION: Range = within(0.0, 1.0, "");
    pub(super) const GATE_MM: Range = above(0.0, 1000.0, "mm");
    pub(super) const GATE_DEG: Range = above(0.0, 180.0, "°");
    pub(super) const DEPTH_SCALE_ERROR: Range = within(0.0, 0.5, "");
    pub(super) const DRIFT_MM: Range = above(0.0, 1000.0, "mm");
    pub(super) const DRIFT_DEG: Range = above(0.0, 180.0, "°");
    pub(super) const REGISTER: Range = within(0.0, 47.0, "");
}

// ---------------------------------------------------------------------------------------------
// Errors from serde/toml, mapped to keys and lines.

fn schema_error(e: &toml::de::Error, origin: &str, index: &KeyIndex) -> ConfigError {
    let span = e.span().unwrap_or(0..0);
    let line = index.line_at(span.start);
    let message = e.message().trim().replace('\n', "; ");
    let origin = origin.to_string();
    if let Some(rest) = message.strip_prefix("missing field `") {
        let field = rest.split('`').next().unwrap_or_default();
        let key = match index.table_starting_at(span.start) {
            Some(table) if span.end > span.start => format!("{table}.{field}"),
            _ => field.to_string(),
        };
        return ConfigError::MissingKey { origin, line, key };
    }
    let key = index.path_at(span.start).unwrap_or("?").to_string();
    if message.starts_with("unknown field `") {
        let allowed = message
            .split_once(", expected ")
            .map(|(_, a)| a.trim_start_matches("one of ").replace('`', ""))
            .unwrap_or_else(|| "nothing".to_string());
        return ConfigError::UnknownKey {
            origin,
            line,
            key,
            allowed,
        };
    }
    let message = message
        .replace("expected f64", "expected a number")
        .replace("expected i64", "expected an integer")
        .replace("expected a boolean", "expected true or false");
    ConfigError::WrongType {
        origin,
        line,
        key,
        message,
    }
}

// ---------------------------------------------------------------------------------------------
// Validation.

struct Ctx<'a> {
    origin: &'a str,
    index: KeyIndex,
    base_dir: &'a Path,
}

impl Ctx<'_> {
    /// An error about `key`, located at the first of `key` and `near` that is in the file.
    fn invalid_near(&self, key: &str, near: &[&str], message: impl Into<String>) -> ConfigError {
        let line = std::iter::once(key)
            .chain(near.iter().copied())
            .find_map(|k| self.index.line_of(k));
        ConfigError::Invalid {
            origin: self.origin.to_string(),
            line,
            key: key.to_string(),
            message: message.into(),
        }
    }

    /// An error about `key`, located at it or its enclosing tables.
    fn invalid(&self, key: &str, message: impl Into<String>) -> ConfigError {
        let parents: Vec<&str> = key
            .char_indices()
            .filter(|&(_, c)| c == '.' || c == '[')
            .map(|(i, _)| &key[..i])
            .rev()
            .collect();
        self.invalid_near(key, &parents, message)
    }

    fn check(&self, key: &str, v: f64, range: Range) -> Result<f64, ConfigError> {
        if range.contains(v) {
            return Ok(v);
        }
        let finite = if v.is_finite() {
            ""
        } else {
            "a finite number, "
        };
        Err(self.invalid(
            key,
            format!("{key} = {v}: expected {finite}{}", range.describe()),
        ))
    }

    fn num(&self, key: &str, v: Option<f64>, default: f64, r: Range) -> Result<f64, ConfigError> {
        v.map_or(Ok(default), |v| self.check(key, v, r))
    }

    fn int(&self, key: &str, v: i64, r: Range) -> Result<i64, ConfigError> {
        // Integers in the ranges used here are exact in f64.
        if r.contains(v as f64) {
            Ok(v)
        } else {
            Err(self.invalid(key, format!("{key} = {v}: expected {}", r.describe())))
        }
    }

    fn seconds(
        &self,
        key: &str,
        v: Option<f64>,
        default: Duration,
        r: Range,
    ) -> Result<Duration, ConfigError> {
        v.map_or(Ok(default), |v| {
            self.check(key, v, r).map(Duration::from_secs_f64)
        })
    }

    /// A relative path is taken relative to the config file's directory.
    fn path(&self, key: &str, p: &str) -> Result<PathBuf, ConfigError> {
        if p.trim().is_empty() {
            return Err(self.invalid(key, format!("{key} is empty: expected a file path")));
        }
        Ok(self.base_dir.join(p))
    }

    /// Refuses a key that means nothing in the chosen variant.
    fn unused<T>(&self, key: &str, v: &Option<T>, why: &str) -> Result<(), ConfigError> {
        match v {
            Some(_) => Err(self.invalid(key, format!("{key} is not used {why}; remove it"))),
            None => Ok(()),
        }
    }

    fn config(&self, raw: RawConfig) -> Result<Config, ConfigError> {
        let robot = self.robot(raw.robot)?;
        let camera = self.camera(raw.camera)?;
        let mount = self.mount(raw.mount)?;
        let views = self.views(raw.views, &mount)?;
        let gate = self.gate(raw.gate)?;
        let check = CheckConfig {
            max_drift_translation_mm: self.num(
                "check.max_drift_translation_mm",
                raw.check.max_drift_translation_mm,
                defaults::MAX_DRIFT_TRANSLATION_MM,
                ranges::DRIFT_MM,
            )?,
            max_drift_rotation_deg: self.num(
                "check.max_drift_rotation_deg",
                raw.check.max_drift_rotation_deg,
                defaults::MAX_DRIFT_ROTATION_DEG,
                ranges::DRIFT_DEG,
            )?,
        };
        let write_back = self.write_back(raw.write_back, mount.mount)?;
        let storage = StorageConfig {
            dir: match &raw.storage.dir {
                Some(d) => self.path("storage.dir", d)?,
                None => self.base_dir.join(defaults::STORAGE_DIR),
            },
            keep_captures: raw.storage.keep_captures.unwrap_or(defaults::KEEP_CAPTURES),
        };
        let daemon = self.daemon(raw.daemon)?;
        if let (Some(p), Some(r)) = (daemon.pendant, write_back.registers) {
            if p.status_register == r.sequence_int {
                return Err(self.invalid(
                    "daemon.pendant.status_register",
                    format!(
                        "daemon.pendant.status_register = {} is write_back.registers.sequence_int too; give the answer its own input_int register",
                        p.status_register
                    ),
                ));
            }
        }
        Ok(Config {
            origin: self.origin.to_string(),
            robot,
            camera,
            mount,
            views,
            gate,
            check,
            write_back,
            storage,
            daemon,
        })
    }

    fn daemon(&self, d: RawDaemon) -> Result<DaemonConfig, ConfigError> {
        let base = defaults::daemon();
        let startup = match d.startup.as_deref().map(str::trim) {
            None | Some("none") => None,
            Some(name) => match crate::record::RunMode::parse(name) {
                Some(mode) => Some(mode),
                None => {
                    return Err(self.invalid(
                        "daemon.startup",
                        format!(
                            "daemon.startup = \"{name}\": expected \"none\", \"calibrate\" or \"check\""
                        ),
                    ))
                }
            },
        };
        let listen = match &d.listen {
            None => base.listen,
            Some(l) => l.trim().parse().map_err(|_| {
                self.invalid(
                    "daemon.listen",
                    format!("daemon.listen = \"{l}\": expected IP:PORT, e.g. \"127.0.0.1:8650\" (localhost only) or \"0.0.0.0:8650\""),
                )
            })?,
        };
        let token_file = d
            .token_file
            .as_deref()
            .map(|p| self.path("daemon.token_file", p))
            .transpose()?;
        let check_interval = d
            .check_interval_s
            .map(|v| {
                self.check("daemon.check_interval_s", v, ranges::CHECK_INTERVAL)
                    .map(Duration::from_secs_f64)
            })
            .transpose()?;
        let mut check_at = Vec::new();
        for (i, t) in d.check_at.iter().flatten().enumerate() {
            let key = format!("daemon.check_at[{i}]");
            check_at.push(
                t.parse::<crate::calendar::CalendarTime>()
                    .map_err(|e| self.invalid(&key, format!("{key}: {e}")))?,
            );
        }
        let when_busy = match d.when_busy.as_deref().map(str::trim) {
            None | Some("refuse") => WhenBusy::Refuse,
            Some("queue") => WhenBusy::Queue,
            Some(other) => {
                let shown: String = other.chars().take(40).collect();
                return Err(self.invalid(
                    "daemon.when_busy",
                    format!("daemon.when_busy = {shown:?}: expected \"refuse\" (answer busy) or \"queue\" (run it after the current one)"),
                ));
            }
        };
        let keep_captures_runs = match d.keep_captures_runs {
            Some(v) => self.int("daemon.keep_captures_runs", v, ranges::KEEP_RUNS)? as usize,
            None => base.keep_captures_runs,
        };
        let pendant = match d.pendant {
            None => None,
            Some(p) => {
                let request = self.int(
                    "daemon.pendant.request_register",
                    p.request_register,
                    ranges::REGISTER,
                )? as u32;
                let status = self.int(
                    "daemon.pendant.status_register",
                    p.status_register,
                    ranges::REGISTER,
                )? as u32;
                Some(PendantConfig {
                    request_register: request,
                    status_register: status,
                })
            }
        };
        Ok(DaemonConfig {
            pendant,
            startup,
            listen,
            token_file,
            check_interval,
            check_at,
            when_busy,
            recalibrate_on_drift: d.recalibrate_on_drift.unwrap_or(base.recalibrate_on_drift),
            keep_captures_runs,
            keep_captures_days: self.num(
                "daemon.keep_captures_days",
                d.keep_captures_days,
                base.keep_captures_days,
                ranges::KEEP_DAYS,
            )?,
        })
    }

    fn robot(&self, r: RawRobot) -> Result<RobotConfig, ConfigError> {
        let model = r
            .model
            .parse::<UrModel>()
            .map_err(|e| self.invalid("robot.model", e.to_string()))?;
        let host = r.host.trim().parse::<IpAddr>().map_err(|_| {
            self.invalid(
                "robot.host",
                format!(
                    "robot.host = {:?}: expected the controller's IPv4 or IPv6 address, e.g. \"192.168.56.101\" (host names are not resolved; the pendant shows the IP under Settings → System → Network)",
                    r.host
                ),
            )
        })?;
        let port = |name: &str, v: Option<i64>, default: u16| -> Result<u16, ConfigError> {
            match v {
                None => Ok(default),
                Some(v) => {
                    let key = format!("robot.ports.{name}");
                    // PORT's range fits in u16.
                    self.int(&key, v, ranges::PORT).map(|v| v as u16)
                }
            }
        };
        let std = defaults::ROBOT_PORTS;
        let ports = RobotPorts {
            dashboard: port("dashboard", r.ports.dashboard, std.dashboard)?,
            primary: port("primary", r.ports.primary, std.primary)?,
            secondary: port("secondary", r.ports.secondary, std.secondary)?,
            realtime: port("realtime", r.ports.realtime, std.realtime)?,
            rtde: port("rtde", r.ports.rtde, std.rtde)?,
        };
        let dl = defaults::motion_limits();
        let limits = MotionLimits {
            max_joint_speed_rad_s: self.num(
                "robot.max_joint_speed_rad_s",
                r.max_joint_speed_rad_s,
                dl.max_joint_speed_rad_s,
                ranges::JOINT_SPEED,
            )?,
            max_joint_accel_rad_s2: self.num(
                "robot.max_joint_accel_rad_s2",
                r.max_joint_accel_rad_s2,
                dl.max_joint_accel_rad_s2,
                ranges::JOINT_ACCEL,
            )?,
            timeout: self.seconds(
                "robot.move_timeout_s",
                r.move_timeout_s,
                dl.timeout,
                ranges::MOVE_TIMEOUT,
            )?,
        };
        Ok(RobotConfig {
            model,
            urdf: r
                .urdf
                .as_deref()
                .map(|p| self.path("robot.urdf", p))
                .transpose()?,
            host,
            ports,
            limits,
            allow_power_on: r.allow_power_on.unwrap_or(defaults::ALLOW_POWER_ON),
            kinematics: r.kinematics.unwrap_or(defaults::KINEMATICS),
            calibration: r
                .calibration
                .as_deref()
                .map(|p| self.path("robot.calibration", p))
                .transpose()?,
        })
    }

    fn camera(&self, c: RawCamera) -> Result<CameraConfig, ConfigError> {
        let backend = match c.backend {
            RawBackend::Gige => {
                let why = "with backend = \"gige\"";
                self.unused("camera.command", &c.command, why)?;
                self.unused("camera.timeout_s", &c.timeout_s, why)?;
                self.unused("camera.files", &c.files, why)?;
                let Some(address) = c.address else {
                    return Err(self.invalid_near(
                        "camera.address",
                        &["camera.backend", "camera"],
                        "backend = \"gige\" needs `address = \"IP\"` or \"IP:PORT\" (the camera's IP, from the vendor's tool or `arv-tool-0.8`)",
                    ));
                };
                let a = address.trim();
                if a.parse::<IpAddr>().is_err() && a.parse::<SocketAddr>().is_err() {
                    return Err(self.invalid(
                        "camera.address",
                        format!("camera.address = {address:?}: expected \"IP\" or \"IP:PORT\", e.g. \"192.168.1.50\" (GVCP port 3956 by default)"),
                    ));
                }
                CameraBackend::Gige {
                    address: a.to_string(),
                }
            }
            RawBackend::Exec => {
                let why = "with backend = \"exec\"";
                self.unused("camera.address", &c.address, why)?;
                self.unused("camera.files", &c.files, why)?;
                let command = c.command.unwrap_or_default();
                if command.first().is_none_or(|p| p.trim().is_empty()) {
                    return Err(self.invalid_near(
                        "camera.command",
                        &["camera.backend", "camera"],
                        "backend = \"exec\" needs `command = [\"program\", \"arg\", ...]` with a non-empty program; `{out}` in an argument is the file to write",
                    ));
                }
                let dir = self.base_dir.display().to_string();
                CameraBackend::Exec {
                    command: command
                        .iter()
                        .map(|a| a.replace("{config_dir}", &dir))
                        .collect(),
                    timeout: self.seconds(
                        "camera.timeout_s",
                        c.timeout_s,
                        Duration::from_secs_f64(defaults::EXEC_TIMEOUT_S),
                        ranges::EXEC_TIMEOUT,
                    )?,
                }
            }
            RawBackend::File => {
                let why = "with backend = \"file\"";
                self.unused("camera.address", &c.address, why)?;
                self.unused("camera.command", &c.command, why)?;
                self.unused("camera.timeout_s", &c.timeout_s, why)?;
                let files = c.files.unwrap_or_default();
                if files.is_empty() {
                    return Err(self.invalid_near(
                        "camera.files",
                        &["camera.backend", "camera"],
                        "backend = \"file\" needs at least one file: `files = [\"scan.ply\"]`",
                    ));
                }
                CameraBackend::File {
                    paths: files
                        .iter()
                        .enumerate()
                        .map(|(i, f)| self.path(&format!("camera.files[{i}]"), f))
                        .collect::<Result<_, _>>()?,
                }
            }
        };
        let dc = defaults::capture();
        let frames = match c.frames {
            // FRAMES fits in u32.
            Some(n) => self.int("camera.frames", n, ranges::FRAMES)? as u32,
            None => dc.frames,
        };
        let capture = CaptureSettings {
            frames,
            frame_timeout: self.seconds(
                "camera.frame_timeout_s",
                c.frame_timeout_s,
                dc.frame_timeout,
                ranges::FRAME_TIMEOUT,
            )?,
            exposure: match c.exposure_us {
                Some(us) => {
                    let us = self.check("camera.exposure_us", us, ranges::EXPOSURE)?;
                    Some(Duration::from_nanos((us * 1e3).round() as u64))
                }
                None => dc.exposure,
            },
        };
        Ok(CameraConfig {
            backend,
            capture,
            settle: self.seconds(
                "camera.settle_s",
                c.settle_s,
                Duration::from_secs_f64(defaults::SETTLE_S),
                ranges::SETTLE,
            )?,
        })
    }

    fn mount(&self, m: RawMount) -> Result<MountConfig, ConfigError> {
        let mount = match m.kind {
            None => defaults::MOUNT,
            Some(RawMountType::EyeInHand) => Mount::EyeInHand,
            Some(RawMountType::EyeToHand) => Mount::EyeToHand,
        };
        let max_camera_flange_distance_m = match mount {
            Mount::EyeInHand => Some(self.num(
                "mount.max_camera_flange_distance_m",
                m.max_camera_flange_distance_m,
                defaults::MAX_CAMERA_FLANGE_DISTANCE_M,
                ranges::CAMERA_FLANGE_DISTANCE,
            )?),
            Mount::EyeToHand => {
                self.unused(
                    "mount.max_camera_flange_distance_m",
                    &m.max_camera_flange_distance_m,
                    "with type = \"eye-to-hand\" (the camera is not on the flange)",
                )?;
                None
            }
        };
        let prior = match m.prior {
            None => None,
            Some(v) => {
                for (i, x) in v.iter().enumerate() {
                    let r = if i < 3 {
                        ranges::PRIOR_TRANSLATION
                    } else {
                        ranges::PRIOR_ROTATION
                    };
                    self.check(&format!("mount.prior[{i}]"), *x, r)?;
                }
                let p = Isometry3::from(UrPose::from(v));
                if let Some(max) = max_camera_flange_distance_m {
                    let d = p.translation.vector.norm();
                    if d > max {
                        return Err(self.invalid(
                            "mount.prior",
                            format!("mount.prior puts the camera {d:.3} m from the flange, farther than mount.max_camera_flange_distance_m = {max} m; fix the prior (x, y, z in metres, in the flange frame) or raise the limit"),
                        ));
                    }
                }
                Some(p)
            }
        };
        Ok(MountConfig {
            mount,
            prior,
            max_camera_flange_distance_m,
        })
    }

    fn views(&self, v: RawViews, mount: &MountConfig) -> Result<ViewsConfig, ConfigError> {
        let targets = match v.mode.unwrap_or(RawMode::Auto) {
            RawMode::Joints => {
                let why = "with mode = \"joints\"";
                self.unused("views.count", &v.count, why)?;
                self.unused("views.min_distance_m", &v.min_distance_m, why)?;
                self.unused("views.max_distance_m", &v.max_distance_m, why)?;
                self.unused("views.seed", &v.seed, why)?;
                let joints = v.joints.unwrap_or_default();
                if joints.is_empty() {
                    return Err(self.invalid_near(
                        "views.joints",
                        &["views.mode", "views"],
                        "mode = \"joints\" needs at least one target: `joints = [[q1, q2, q3, q4, q5, q6]]` in rad, URDF order (base, shoulder, elbow, wrist 1, 2, 3)",
                    ));
                }
                for (i, q) in joints.iter().enumerate() {
                    for (j, x) in q.iter().enumerate() {
                        self.check(&format!("views.joints[{i}][{j}]"), *x, ranges::JOINT)?;
                    }
                }
                ViewTargets::Joints(joints)
            }
            RawMode::Auto => {
                self.unused(
                    "views.joints",
                    &v.joints,
                    "with mode = \"auto\" (the default); set mode = \"joints\" to use them",
                )?;
                if mount.mount == Mount::EyeInHand && mount.prior.is_none() {
                    return Err(self.invalid_near(
                        "mount.prior",
                        &["views.mode", "mount", "views"],
                        "automatic views of an eye-in-hand camera need a guess of where it sits: give mount.prior = [x, y, z, rx, ry, rz] (flange_from_camera, m and rad, to a few cm and ~10°), or give joint targets ([views] mode = \"joints\", joints = [[...]])",
                    ));
                }
                let count = match v.count {
                    // VIEW_COUNT fits in usize.
                    Some(n) => self.int("views.count", n, ranges::VIEW_COUNT)? as usize,
                    None => defaults::VIEW_COUNT,
                };
                let min_distance_m = self.num(
                    "views.min_distance_m",
                    v.min_distance_m,
                    defaults::MIN_DISTANCE_M,
                    ranges::VIEW_DISTANCE,
                )?;
                let max_distance_m = self.num(
                    "views.max_distance_m",
                    v.max_distance_m,
                    defaults::MAX_DISTANCE_M,
                    ranges::VIEW_DISTANCE,
                )?;
                if min_distance_m >= max_distance_m {
                    return Err(self.invalid_near(
                        "views.min_distance_m",
                        &["views.max_distance_m", "views"],
                        format!("views.min_distance_m = {min_distance_m} must be less than views.max_distance_m = {max_distance_m}"),
                    ));
                }
                let seed = match v.seed {
                    // SEED is non-negative.
                    Some(s) => self.int("views.seed", s, ranges::SEED)? as u64,
                    None => defaults::SEED,
                };
                ViewTargets::Auto {
                    count,
                    min_distance_m,
                    max_distance_m,
                    seed,
                }
            }
        };
        let mut obstacles = Vec::with_capacity(v.obstacles.len());
        for (i, o) in v.obstacles.into_iter().enumerate() {
            let key = format!("views.obstacles[{i}]");
            if o.name.trim().is_empty() {
                return Err(self.invalid(
                    &format!("{key}.name"),
                    "an obstacle needs a non-empty name (it appears in messages)",
                ));
            }
            for (j, x) in o.centre_m.iter().enumerate() {
                self.check(&format!("{key}.centre_m[{j}]"), *x, ranges::OBSTACLE_CENTRE)?;
            }
            for (j, x) in o.size_m.iter().enumerate() {
                self.check(&format!("{key}.size_m[{j}]"), *x, ranges::OBSTACLE_SIZE)?;
            }
            obstacles.push(Obstacle {
                name: o.name,
                centre_m: o.centre_m,
                size_m: o.size_m,
            });
        }
        Ok(ViewsConfig {
            targets,
            obstacles,
            floor_clearance_m: self.num(
                "views.floor_clearance_m",
                v.floor_clearance_m,
                defaults::FLOOR_CLEARANCE_M,
                ranges::FLOOR_CLEARANCE,
            )?,
            return_to_start: v.return_to_start.unwrap_or(defaults::RETURN_TO_START),
        })
    }

    fn gate(&self, g: RawGate) -> Result<GateThresholds, ConfigError> {
        // Destructured without `..`: a new threshold fails to compile here until it has a key.
        let GateThresholds {
            min_coverage,
            min_link_support,
            max_free_space_violations,
            max_rmse_mm,
            min_inlier_fraction,
            max_uncertainty_translation_mm,
            max_uncertainty_rotation_deg,
            max_residual_translation_mm,
            max_residual_rotation_deg,
            max_dropped_fraction,
            max_ambiguity,
            max_depth_scale_error,
            max_change_translation_mm,
            max_change_rotation_deg,
        } = defaults::gate();
        use ranges::{DEPTH_SCALE_ERROR, FRACTION, GATE_DEG, GATE_MM};
        Ok(GateThresholds {
            min_coverage: self.num("gate.min_coverage", g.min_coverage, min_coverage, FRACTION)?,
            min_link_support: self.num(
                "gate.min_link_support",
                g.min_link_support,
                min_link_support,
                FRACTION,
            )?,
            max_free_space_violations: self.num(
                "gate.max_free_space_violations",
                g.max_free_space_violations,
                max_free_space_violations,
                FRACTION,
            )?,
            max_rmse_mm: self.num("gate.max_rmse_mm", g.max_rmse_mm, max_rmse_mm, GATE_MM)?,
            min_inlier_fraction: self.num(
                "gate.min_inlier_fraction",
                g.min_inlier_fraction,
                min_inlier_fraction,
                FRACTION,
            )?,
            max_uncertainty_translation_mm: self.num(
                "gate.max_uncertainty_translation_mm",
                g.max_uncertainty_translation_mm,
                max_uncertainty_translation_mm,
                GATE_MM,
            )?,
            max_uncertainty_rotation_deg: self.num(
                "gate.max_uncertainty_rotation_deg",
                g.max_uncertainty_rotation_deg,
                max_uncertainty_rotation_deg,
                GATE_DEG,
            )?,
            max_residual_translation_mm: self.num(
                "gate.max_residual_translation_mm",
                g.max_residual_translation_mm,
                max_residual_translation_mm,
                GATE_MM,
            )?,
            max_residual_rotation_deg: self.num(
                "gate.max_residual_rotation_deg",
                g.max_residual_rotation_deg,
                max_residual_rotation_deg,
                GATE_DEG,
            )?,
            max_dropped_fraction: self.num(
                "gate.max_dropped_fraction",
                g.max_dropped_fraction,
                max_dropped_fraction,
                FRACTION,
            )?,
            max_ambiguity: self.num(
                "gate.max_ambiguity",
                g.max_ambiguity,
                max_ambiguity,
                FRACTION,
            )?,
            max_depth_scale_error: self.num(
                "gate.max_depth_scale_error",
                g.max_depth_scale_error,
                max_depth_scale_error,
                DEPTH_SCALE_ERROR,
            )?,
            max_change_translation_mm: self.num(
                "gate.max_change_translation_mm",
                g.max_change_translation_mm,
                max_change_translation_mm,
                GATE_MM,
            )?,
            max_change_rotation_deg: self.num(
                "gate.max_change_rotation_deg",
                g.max_change_rotation_deg,
                max_change_rotation_deg,
                GATE_DEG,
            )?,
        })
    }

    fn write_back(&self, w: RawWriteBack, mount: Mount) -> Result<WriteBackConfig, ConfigError> {
        let tcp = match (mount, w.tcp) {
            (Mount::EyeToHand, Some(true)) => {
                return Err(self.invalid(
                    "write_back.tcp",
                    "write_back.tcp = true with mount type = \"eye-to-hand\": a fixed camera is not a TCP; set tcp = false (use registers or files)",
                ))
            }
            (Mount::EyeToHand, _) => false,
            (Mount::EyeInHand, t) => t.unwrap_or(defaults::WRITE_BACK_TCP_EYE_IN_HAND),
        };
        let registers = match w.registers {
            None => None,
            Some(r) => {
                let double_start = self.int(
                    "write_back.registers.double_start",
                    r.double_start,
                    ranges::REGISTER,
                )?;
                if double_start + 5 > 47 {
                    return Err(self.invalid(
                        "write_back.registers.double_start",
                        format!("write_back.registers.double_start = {double_start}: the six doubles {double_start}..{} must fit in input_double_register_0..47; expected 0 <= value <= 42", double_start + 5),
                    ));
                }
                let sequence_int = self.int(
                    "write_back.registers.sequence_int",
                    r.sequence_int,
                    ranges::REGISTER,
                )?;
                // Both are within 0..=47.
                Some(RegisterMap {
                    double_start: double_start as u32,
                    sequence_int: sequence_int as u32,
                })
            }
        };
        Ok(WriteBackConfig {
            tcp,
            registers,
            files: w.files.unwrap_or(defaults::WRITE_BACK_FILES),
        })
    }
}
