//! The record of one run: everything that happened, what was measured and what was written,
//! with every stage's timing. The run returns it whatever the outcome; the recorder keeps it
//! (`runs/<id>/record.json` and the history), `calibrate`/`check --json` print it, `handeye
//! history` and the web page read it back. Poses are 4×4 row-major arrays in metres; mm and
//! degrees only where the field name says so.
//!
//! The data floor of the service: the record's types and the words every layer above uses
//! for them (a run's mode, who asked for it, how it ended, what a check's drift means).

use handeye_hal::ur_dh::DhParams;
use handeye_hal::{CameraInfo, ControllerIdentity, RobotStatus};
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

pub use crate::calib::Outcome;
use crate::calib::{CalibrationReport, Mount, Uncertainty};
use crate::plan::PathCheck;

/// What a run was asked to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RunMode {
    /// Measure and, when the gate passes, write the result back.
    Calibrate,
    /// Measure the same way, never write back; compare with the current calibration.
    Check,
}

impl RunMode {
    /// Lower-case name as in JSON, the history and the configuration (`daemon.startup`).
    pub fn name(self) -> &'static str {
        match self {
            RunMode::Calibrate => "calibrate",
            RunMode::Check => "check",
        }
    }

    /// The mode of a name ([`Self::name`]).
    pub fn parse(name: &str) -> Option<RunMode> {
        [RunMode::Calibrate, RunMode::Check]
            .into_iter()
            .find(|m| m.name() == name)
    }
}

impl std::fmt::Display for RunMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.name())
    }
}

/// Who asked for a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Trigger {
    /// The daemon's start (`daemon.startup`).
    Startup,
    /// The drift-check schedule (`daemon.check_interval_s`, `daemon.check_at`).
    Schedule,
    /// A scheduled check found drift and `daemon.recalibrate_on_drift` is on.
    Drift,
    /// The HTTP API (or the web page).
    Api,
    /// The pendant program, through registers.
    Pendant,
    /// A command: `handeye calibrate` or `handeye check`.
    Cli,
}

impl Trigger {
    /// Every trigger.
    pub const ALL: [Trigger; 6] = [
        Trigger::Startup,
        Trigger::Schedule,
        Trigger::Drift,
        Trigger::Api,
        Trigger::Pendant,
        Trigger::Cli,
    ];

    /// Lower-case name as stored in the history.
    pub fn name(self) -> &'static str {
        match self {
            Trigger::Startup => "startup",
            Trigger::Schedule => "schedule",
            Trigger::Drift => "drift",
            Trigger::Api => "api",
            Trigger::Pendant => "pendant",
            Trigger::Cli => "cli",
        }
    }

    /// The trigger of a stored name ([`Self::name`]).
    pub fn parse(name: &str) -> Option<Trigger> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }
}

impl std::fmt::Display for Trigger {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.name())
    }
}

/// The stages of a run, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Robot and camera state checked; nothing moves before it passes.
    Preflight,
    /// Views chosen, targets and paths checked for limits and collisions.
    Plan,
    /// Joint move to a view.
    Move,
    /// Waiting for the arm to settle.
    Settle,
    /// Joints, flange pose and frames recorded.
    Capture,
    /// Scans registered against the posed model.
    Register,
    /// Chain closed, views fused, gate applied.
    Solve,
    /// Result written to the controller and files.
    WriteBack,
    /// Joint move back to where the arm started.
    Return,
}

impl Stage {
    /// Every stage, in order.
    pub const ALL: [Stage; 9] = [
        Stage::Preflight,
        Stage::Plan,
        Stage::Move,
        Stage::Settle,
        Stage::Capture,
        Stage::Register,
        Stage::Solve,
        Stage::WriteBack,
        Stage::Return,
    ];

    /// The stage of a name ([`Self::name`]).
    pub fn parse(name: &str) -> Option<Stage> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }

    /// Lower-case name as in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Preflight => "preflight",
            Stage::Plan => "plan",
            Stage::Move => "move",
            Stage::Settle => "settle",
            Stage::Capture => "capture",
            Stage::Register => "register",
            Stage::Solve => "solve",
            Stage::WriteBack => "write_back",
            Stage::Return => "return",
        }
    }
}

/// Wall-clock time per stage, summed over views, milliseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct RunTimings {
    /// Preflight.
    pub preflight: f64,
    /// Planning and path checks.
    pub plan: f64,
    /// Moves to the views (arm motion).
    pub moves: f64,
    /// Settling before capture.
    pub settle: f64,
    /// Recording joints/pose and capturing frames (camera exposure and transfer).
    pub capture: f64,
    /// Registration of every frame.
    pub register: f64,
    /// Solve, fusion and gate.
    pub solve: f64,
    /// Write-back and read-back.
    pub write_back: f64,
    /// The move back to the start.
    pub return_move: f64,
    /// The whole run.
    pub total: f64,
}

impl RunTimings {
    /// Adds `ms` to `stage`'s time.
    pub fn add(&mut self, stage: Stage, ms: f64) {
        let field = match stage {
            Stage::Preflight => &mut self.preflight,
            Stage::Plan => &mut self.plan,
            Stage::Move => &mut self.moves,
            Stage::Settle => &mut self.settle,
            Stage::Capture => &mut self.capture,
            Stage::Register => &mut self.register,
            Stage::Solve => &mut self.solve,
            Stage::WriteBack => &mut self.write_back,
            Stage::Return => &mut self.return_move,
        };
        *field += ms;
    }

    /// Every stage's time with its JSON name, in run order (without the total).
    pub fn stages(&self) -> [(&'static str, f64); 9] {
        [
            ("preflight", self.preflight),
            ("plan", self.plan),
            ("moves", self.moves),
            ("settle", self.settle),
            ("capture", self.capture),
            ("register", self.register),
            ("solve", self.solve),
            ("write_back", self.write_back),
            ("return_move", self.return_move),
        ]
    }

    /// Everything except arm motion, settling and the camera's own capture time: what the
    /// run itself costs.
    pub fn overhead(&self) -> f64 {
        self.total - self.moves - self.settle - self.capture - self.return_move
    }
}

/// Where the kinematics that posed the model came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KinematicsOrigin {
    /// The controller's calibrated DH.
    Controller,
    /// The calibration file `robot.calibration`.
    File,
    /// The URDF's nominal joints.
    Nominal,
}

impl KinematicsOrigin {
    /// Lower-case name as in JSON.
    pub fn name(self) -> &'static str {
        match self {
            KinematicsOrigin::Controller => "controller",
            KinematicsOrigin::File => "file",
            KinematicsOrigin::Nominal => "nominal",
        }
    }
}

impl std::fmt::Display for KinematicsOrigin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.name())
    }
}

/// Which kinematics posed the model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KinematicsUsed {
    /// `controller` (the controller's calibrated DH), `file` (`robot.calibration`) or `nominal`
    /// (the URDF).
    pub source: KinematicsOrigin,
    /// Why the controller's were not used when the configuration asked for them, and which
    /// file posed the model.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// The DH parameters that posed the model: the controller's, or the file's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dh: Option<DhParams>,
}

/// What preflight found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PreflightRecord {
    /// Robot state.
    pub status: RobotStatus,
    /// The camera's identity.
    pub camera: CameraInfo,
    /// Joint angles before anything moved, rad.
    pub start_joints: Vec<f64>,
    /// The TCP active on the controller before the run (`flange_from_tcp`).
    pub tcp_offset: [[f64; 4]; 4],
    /// Kinematics the model is posed with.
    pub kinematics: KinematicsUsed,
    /// Whether handeye powered the arm on and released its brakes (`robot.allow_power_on`).
    #[serde(default)]
    pub powered_on: bool,
    /// Who the controller says it is (serial, model, software version, kinematics
    /// checksum); `None` when it could not be asked (the warnings say why) and in records
    /// written before it was asked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub controller: Option<ControllerIdentity>,
}

/// One view of the plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlannedView {
    /// Joint target, rad, URDF order.
    pub joints: Vec<f64>,
    /// Camera-to-base distance the planner expects, m (eye-in-hand with a prior).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distance_to_base_m: Option<f64>,
    /// How the path from the previous position was checked.
    pub path: PathCheck,
    /// Why the camera at the mount prior would not see the base from here (eye-in-hand with a
    /// prior; a taught view the planner would not have chosen), `None` when it would.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_seeing_base: Option<String>,
}

/// What a dry run expects of the run it planned: the σ of the views simulated at the mount
/// prior, and the run's time at the configured speeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Forecast {
    /// The result's 1σ, mm, from scans simulated at the planned views (the camera at the mount
    /// prior, a manufactured arm, the structured-light camera preset); `None` when they could
    /// not be registered.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uncertainty_translation_mm: Option<f64>,
    /// The same, degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uncertainty_rotation_deg: Option<f64>,
    /// Why there is no σ.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uncertainty_note: Option<String>,
    /// The moves out, between the views and back at the configured speed and acceleration
    /// caps, s.
    pub moves_s: f64,
    /// The whole run: the moves, settling, capture and registration at about 0.9 s a frame
    /// and 1 s for the rest (the simulated rig's order, a 1280×960 structured-light scan), s.
    pub run_s: f64,
}

/// One captured frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    /// Where the raw scan was kept (PLY), when kept.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub path: Option<String>,
    /// Grid size.
    pub width: u32,
    /// Grid size.
    pub height: u32,
    /// Valid (finite) points.
    pub valid_points: usize,
}

/// What was recorded at one view.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CaptureRecord {
    /// View index.
    pub view: usize,
    /// Measured joints before the frames, rad.
    pub joints: Vec<f64>,
    /// `base_from_flange` the controller reported at that instant (its `base` frame).
    pub base_from_flange: [[f64; 4]; 4],
    /// Unix time of the joint/pose sample, s.
    pub unix_time_s: f64,
    /// Largest joint change between before and after the frames, rad (the arm must not move
    /// while the camera exposes).
    pub joint_change_during_capture_rad: f64,
    /// The frames.
    pub frames: Vec<FrameRecord>,
}

/// The measured result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResultRecord {
    /// Eye-in-hand or eye-to-hand.
    pub mount: Mount,
    /// Eye-in-hand: the camera on the flange (`flange_from_camera`), 4×4, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flange_from_camera: Option<[[f64; 4]; 4]>,
    /// The camera in the controller's `base` frame (eye-in-hand: at the first view), 4×4, m.
    pub base_from_camera: [[f64; 4]; 4],
    /// The unknown as UR `x,y,z,rx,ry,rz` (m, rotation vector rad): `flange_from_camera` or
    /// `base_from_camera`.
    pub ur_pose: [f64; 6],
    /// Reported 1-σ uncertainty.
    pub uncertainty: Uncertainty,
    /// The calibration report (per frame quality, residuals, timings).
    pub report: CalibrationReport,
}

impl ResultRecord {
    /// The unknown the run solved for ([`Mount::unknown_name`]), 4×4, m.
    pub fn unknown(&self) -> &[[f64; 4]; 4] {
        match (self.mount, &self.flange_from_camera) {
            (Mount::EyeInHand, Some(t)) => t,
            _ => &self.base_from_camera,
        }
    }

    /// The unknown the run solved for ([`Mount::unknown_name`]).
    pub fn estimate(&self) -> Option<Isometry3<f64>> {
        crate::frames::from_row_major(self.unknown())
    }
}

/// A check's comparison with the current calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriftRecord {
    /// Where the current calibration came from.
    pub reference: String,
    /// The current calibration, 4×4, m.
    pub reference_pose: [[f64; 4]; 4],
    /// Camera position change, mm.
    pub translation_mm: f64,
    /// Camera rotation change, degrees.
    pub rotation_deg: f64,
    /// Threshold, mm.
    pub max_translation_mm: f64,
    /// Threshold, degrees.
    pub max_rotation_deg: f64,
    /// Whether either threshold is exceeded.
    pub drifted: bool,
}

/// Where a result was written back.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WriteTarget {
    /// The controller's TCP (`set_tcp`).
    Tcp,
    /// RTDE registers for a pendant program.
    Registers,
    /// The exports in the run's folder and `current/`.
    Files,
}

impl WriteTarget {
    /// Lower-case name as in JSON and the history.
    pub fn name(self) -> &'static str {
        match self {
            WriteTarget::Tcp => "tcp",
            WriteTarget::Registers => "registers",
            WriteTarget::Files => "files",
        }
    }
}

impl std::fmt::Display for WriteTarget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.name())
    }
}

/// One thing written back.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Written {
    /// `tcp`, `registers` or `files`.
    pub target: WriteTarget,
    /// What exactly (register numbers and sequence, file paths).
    pub detail: String,
}

/// A calibration allowed to move beyond `gate.max_change_*` from the previous one, because
/// the camera was remounted on purpose (`handeye calibrate --accept-change`,
/// `POST /api/calibrate/accept-change`, the page's Accept remount button).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChangeAccepted {
    /// Who or what accepted it: `cli (user alice)`, `api client 127.0.0.1`,
    /// `web page (127.0.0.1)`.
    pub by: String,
    /// How far the result moved from the previous calibration, mm; `None` when there was
    /// none to compare with.
    pub translation_mm: Option<f64>,
    /// How far it turned, degrees.
    pub rotation_deg: Option<f64>,
    /// Whether that was beyond `gate.max_change_*` (otherwise accepting was not needed).
    pub beyond_limits: bool,
}

/// The complete record of one run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    /// Unique id (UTC start time and a random suffix), also the folder of its files.
    pub run_id: String,
    /// Calibrate or check.
    pub mode: RunMode,
    /// Whether nothing was to move.
    pub dry_run: bool,
    /// The configuration's origin (file path).
    pub config: String,
    /// Who asked for it, when it was recorded in the history (rebuilding a damaged history
    /// from the run folders reads it back).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trigger: Option<Trigger>,
    /// Unix time of the start, s.
    pub started_unix_s: f64,
    /// How it ended.
    pub outcome: Outcome,
    /// Why it ended that way (empty when accepted), one sentence each, saying what to do.
    pub reasons: Vec<String>,
    /// What the operator should know whatever the outcome, one sentence each saying what to
    /// do: e.g. that the current calibration was made on another arm.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// The stage that failed, for aborted/error outcomes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub failed_stage: Option<Stage>,
    /// What preflight found.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preflight: Option<PreflightRecord>,
    /// The checked plan.
    pub views: Vec<PlannedView>,
    /// A dry run's forecast of the planned run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub forecast: Option<Forecast>,
    /// What was recorded at each view.
    pub captures: Vec<CaptureRecord>,
    /// Where the raw captures were kept (replay with `handeye solve --capture`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub capture_file: Option<String>,
    /// The result, when one was computed (also when rejected).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub result: Option<ResultRecord>,
    /// Check: the comparison with the current calibration.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drift: Option<DriftRecord>,
    /// Calibrate with `--accept-change` (a deliberate remount): who accepted a result beyond
    /// `gate.max_change_*`, and how far it moved.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub change_accepted: Option<ChangeAccepted>,
    /// What was written back (empty unless accepted in calibrate mode).
    pub written: Vec<Written>,
    /// Whether the arm was moved back to where it started.
    pub returned_to_start: bool,
    /// Time per stage.
    pub timings_ms: RunTimings,
}

impl RunRecord {
    /// A record of a run that starts now: nothing done yet, the outcome `Error` until a stage
    /// says otherwise.
    pub fn starting(run_id: String, mode: RunMode, dry_run: bool, config: String) -> Self {
        Self {
            run_id,
            mode,
            dry_run,
            config,
            trigger: None,
            started_unix_s: crate::calendar::unix_now(),
            outcome: Outcome::Error,
            reasons: Vec::new(),
            warnings: Vec::new(),
            failed_stage: None,
            preflight: None,
            views: Vec::new(),
            forecast: None,
            captures: Vec::new(),
            capture_file: None,
            result: None,
            drift: None,
            change_accepted: None,
            written: Vec::new(),
            returned_to_start: false,
            timings_ms: RunTimings::default(),
        }
    }

    /// What the run says about drift: `Some(true)` when an accepted check measured the
    /// camera beyond a threshold, `Some(false)` within both, `None` when the run is no check
    /// that compared (calibrate, not accepted, or nothing to compare with).
    pub fn drift_found(&self) -> Option<bool> {
        drift_found(
            self.mode,
            Some(self.outcome),
            self.drift.as_ref().map(|d| d.drifted),
        )
    }

    /// The one word every view of the run uses (CLI, API, history, page, picture, log):
    /// a check that measured the camera says `drifted` or `within limits`; any other run its
    /// outcome (`accepted`, `rejected`, `aborted`, `error`, `planned`).
    pub fn verdict(&self) -> &'static str {
        verdict(self.outcome, self.drift_found())
    }

    /// Process exit code: calibrate 0 accepted / 1 rejected / 2 error or aborted; check 0
    /// within thresholds / 1 drifted / 2 anything else; a dry run 0 when planned.
    pub fn exit_code(&self) -> u8 {
        match (self.outcome, self.mode) {
            (Outcome::Planned, _) => 0,
            (Outcome::Accepted, RunMode::Calibrate) => 0,
            (_, RunMode::Check) => match self.drift_found() {
                Some(true) => 1,
                Some(false) => 0,
                None => 2,
            },
            (Outcome::Rejected, RunMode::Calibrate) => 1,
            _ => 2,
        }
    }
}

/// [`RunRecord::verdict`] from the outcome and [`RunRecord::drift_found`] (what the history's
/// columns hold as well).
pub fn verdict(outcome: Outcome, drift_found: Option<bool>) -> &'static str {
    match drift_found {
        Some(true) => "drifted",
        Some(false) => "within limits",
        None => outcome.name(),
    }
}

/// [`RunRecord::drift_found`] from the columns the history keeps: the mode, the outcome (`None`
/// while running) and whether a drift threshold was exceeded (`None` when nothing was compared).
pub fn drift_found(mode: RunMode, outcome: Option<Outcome>, drifted: Option<bool>) -> Option<bool> {
    match (mode, outcome, drifted) {
        (RunMode::Check, Some(Outcome::Accepted), Some(d)) => Some(d),
        _ => None,
    }
}
