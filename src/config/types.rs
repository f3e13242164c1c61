//! The validated configuration's types: what the rest of the program reads.

use std::net::IpAddr;
use std::path::PathBuf;
use std::time::Duration;

use handeye_hal::ur_dh::UrModel;
use handeye_hal::{CaptureSettings, MotionLimits};
use nalgebra::Isometry3;
use serde::Deserialize;

use super::defaults;
use crate::calib::{GateThresholds, Mount};

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
    /// How the camera measures depth (`sensor`: `"structured-light"`, the default,
    /// `"active-stereo"` for a RealSense D4xx class, `"time-of-flight"`): the registration is
    /// tuned for its errors ([`crate::calib::RegisterOptions::for_sensor`]) and the `[gate]`
    /// keys not given default to its class's ([`crate::calib::GateThresholds::for_sensor`]).
    pub sensor: crate::geometry::SensorClass,
    /// How frames are started (`trigger`: `"free"`, the default, clears a camera's
    /// `TriggerMode`; `"software"` fires `TriggerSoftware` per frame); gige and gentl only.
    pub trigger: handeye_hal::Trigger,
    /// The camera's user set to load and the features to write before every capture
    /// (`user_set`, `[camera.features]` in the order written); gige and gentl only.
    pub settings: handeye_hal::CameraSettings,
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
    /// A camera through its vendor's GenTL producer (`backend = "gentl"`, `producer` = the
    /// `.cti`, `device` = serial, model, id or index).
    Gentl {
        /// The producer; `None`: the first `*.cti` on `GENICAM_GENTL64_PATH`, as the GenTL
        /// standard searches (resolved when connecting).
        producer: Option<PathBuf>,
        /// Which of the producer's devices (serial number, model, producer id or index); the
        /// first one when `None`.
        device: Option<String>,
        /// Deadline of each producer call (`call_timeout_s`): past it the producer's host
        /// process is killed and replaced, and the request fails naming the call.
        call_timeout: Duration,
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
