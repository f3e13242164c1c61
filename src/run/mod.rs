//! The calibration run, from preflight to the return move, over the hal traits only
//! (DESIGN.md, "Data flow of one calibration run"):
//!
//! 1. **Preflight**: robot powered, brakes released, safety normal, remote control, no program
//!    running; speed slider, TCP and the controller's kinematics recorded; camera reachable.
//!    Any failure ends the run before anything moves.
//! 2. **Plan**: configured joint targets or generated views; every target and the joint-space
//!    path to it (and back to the start) checked for limits, self-collision, the floor and the
//!    configured obstacles before the first motion.
//! 3. **Move** (`movej` within the configured caps), **settle**, **capture** (joints and the
//!    controller's flange pose at that instant, N frames, kept on disk for replay).
//! 4. **Register, solve, gate** ([`crate::calib::pipeline::calibrate_frames`]).
//! 5. **Write back** only when the gate passed, in calibrate mode (files, TCP, registers; each
//!    read back), or **compare** with the current calibration in check mode.
//! 6. **Return** to the start, unless a fault or a cancel stopped the arm (never auto-resume).
//!
//! [`run`] returns a [`RunRecord`] whatever happens; a run that did not pass its gate writes
//! nothing but its own record. The [`Recorder`] keeps it: the history row, the record and the
//! report picture in the run's folder (`crate::storage`), pruning.

mod clock;
mod forecast;
pub mod journal;
pub mod recorder;
#[cfg(test)]
mod tests;

use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use handeye_hal::{
    ControllerIdentity, DepthCamera, HalError, Robot, RobotMode, SafetyMode, UrPose,
};
use nalgebra::Isometry3;
use tokio_util::sync::CancellationToken;

use crate::calib::register::elapsed_ms;
use crate::calib::Mount;
use crate::config::{Config, KinematicsSource, ViewTargets};
use crate::frames::to_row_major;
use crate::guard::{self, PATH_STEP_RAD};
use crate::model::RobotModel;
use crate::plan::{
    differs_from_all, joint_span, CancelCheck, PlanError, ViewConstraints, ViewPlanner,
    ViewRejection, FIRST_VIEW_SPAN_RAD, NEARBY_SPAN_RAD,
};
use crate::sim::Intrinsics;

use crate::calendar::unix_now;
pub use crate::calib::pipeline::{calibrate_frames, Calibration, Frame, PipelineOptions};
use crate::record::Trigger;
pub use crate::record::{
    CaptureRecord, ChangeAccepted, DriftRecord, FrameRecord, KinematicsOrigin, KinematicsUsed,
    Outcome, PlannedView, PreflightRecord, ResultRecord, RunMode, RunRecord, RunTimings, Stage,
    WriteTarget, Written,
};
use crate::storage::{self, load_current, new_run_id, CaptureFile};
pub use recorder::{open_history, Recorder};

/// Generated candidates tried per automatic view before the plan gives up.
const AUTO_VIEW_TRIES: usize = 8;
/// Of this many first views drawn within a quarter turn of the base, the one nearest to the
/// start on a safe path.
const FIRST_VIEW_CANDIDATES: usize = 4;
/// Draws for them (most random poses do not see the base).
const FIRST_VIEW_DRAWS: usize = 200_000;
/// Candidates drawn near the first view for each further view.
const NEARBY_CANDIDATES: usize = 6;
/// The arm must not move more than this while the camera exposes, rad.
const MAX_JOINT_CHANGE_DURING_CAPTURE_RAD: f64 = 1e-3;

/// What to run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunRequest {
    /// Calibrate or check.
    pub mode: RunMode,
    /// Preflight and plan only: print the plan, move nothing.
    pub dry_run: bool,
    /// The run's id ([`new_run_id`]), when the caller needs it before the run starts (the
    /// daemon records the start); `None`: a new one.
    pub run_id: Option<String>,
    /// The program running on the controller asked for this run (the pendant handshake) and
    /// hands the arm over: preflight accepts it running. Our first move stops it, as any
    /// remote script does on a UR.
    pub program_handover: bool,
    /// Calibrate only: accept a result beyond `gate.max_change_*` from the previous
    /// calibration (the camera was remounted on purpose), naming who accepted it (`cli (user
    /// alice)`, `api client 127.0.0.1`). The record says who and how far it moved.
    pub accept_change: Option<String>,
}

/// A gate's reason with the way to accept a deliberate remount that works where the run was
/// asked for, after the gate's [`crate::calib::gate::REMOUNT`]: the command line's flag for a
/// command's run (`trigger` `Cli`, or none), the daemon's page and API for the daemon's (a
/// command's `--accept-change` is refused beside the daemon, and the pendant cannot accept a
/// remount). Other reasons are returned as they are.
pub fn with_remount_way_out(reason: &str, trigger: Option<Trigger>, config: &str) -> String {
    if !reason.ends_with(crate::calib::gate::REMOUNT) {
        return reason.to_string();
    }
    match trigger {
        None | Some(Trigger::Cli) => {
            format!("{reason} with `handeye calibrate --config {config} --accept-change`")
        }
        Some(_) => format!(
            "{reason} with the Accept remount button on the daemon's page or POST \
             /api/calibrate/accept-change (with the API token); the pendant cannot accept a remount"
        ),
    }
}

/// How to calibrate from where a run was asked for: ` with \`handeye calibrate --config …\``
/// for a command's run, the daemon's button, route and pendant for the daemon's.
fn calibrate_way_out(trigger: Option<Trigger>, config: &str) -> String {
    match trigger {
        None | Some(Trigger::Cli) => format!(": `handeye calibrate --config {config}`"),
        Some(_) => ": the Calibrate button on the daemon's page, POST /api/calibrate (with the \
                   API token) or the pendant's calibrate request"
            .to_string(),
    }
}

impl RunRequest {
    /// A whole run of `mode` (not a dry run) with a new id, no program handing the arm over,
    /// no change accepted: what a command or a test asks for; the fields say the rest.
    pub fn new(mode: RunMode) -> RunRequest {
        RunRequest {
            mode,
            dry_run: false,
            run_id: None,
            program_handover: false,
            accept_change: None,
        }
    }
}

/// Progress of a run, as it happens: the stage entered and a one-line detail.
pub trait Progress: Send + Sync {
    /// Called when a stage starts (and again with more detail within a stage).
    fn stage(&self, stage: Stage, detail: &str);
}

/// No progress output.
#[derive(Debug, Clone, Copy, Default)]
pub struct Silent;

impl Progress for Silent {
    fn stage(&self, _: Stage, _: &str) {}
}

/// Why a stage failed: the outcome it gives and the operator's message.
#[derive(Debug)]
struct Failure {
    outcome: Outcome,
    stage: Stage,
    message: String,
}

impl Failure {
    fn error(stage: Stage, message: impl Into<String>) -> Self {
        Self {
            outcome: Outcome::Error,
            stage,
            message: message.into(),
        }
    }

    /// A robot error: faults, lost connections and timeouts abort the run; the rest are errors.
    fn robot(stage: Stage, during: &str, e: HalError) -> Self {
        let outcome = match e {
            HalError::ProtectiveStop { .. }
            | HalError::EmergencyStop { .. }
            | HalError::Cancelled { .. }
            | HalError::Timeout { .. }
            | HalError::Connection { .. }
            | HalError::NotInRemoteControl => Outcome::Aborted,
            _ => Outcome::Error,
        };
        Self {
            outcome,
            stage,
            message: format!("{during}: {}", error_chain(&e)),
        }
    }

    fn cancelled(stage: Stage) -> Self {
        // Before the first move nothing has moved; from then on the arm was stopped.
        let arm = match stage {
            Stage::Preflight | Stage::Plan => "nothing moved",
            _ => "the arm was stopped where it is",
        };
        Self {
            outcome: Outcome::Aborted,
            stage,
            message: format!("cancelled during {}; {arm}", stage.name()),
        }
    }

    /// Whether the arm may still be moved back to the start afterwards.
    fn arm_usable(&self) -> bool {
        self.outcome != Outcome::Aborted
    }
}

/// `e` and its sources, `: `-separated.
fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut src = e.source();
    while let Some(c) = src {
        let t = c.to_string();
        if !s.contains(&t) {
            s.push_str(": ");
            s.push_str(&t);
        }
        src = c.source();
    }
    s
}

/// Races `fut` against `cancel`; a cancel drops `fut` (which stops a move) and fails the stage.
async fn cancellable<T>(
    cancel: &CancellationToken,
    stage: Stage,
    fut: impl Future<Output = Result<T, Failure>>,
) -> Result<T, Failure> {
    tokio::select! {
        biased;
        _ = cancel.cancelled() => Err(Failure::cancelled(stage)),
        r = fut => r,
    }
}

/// Position and rotation difference of two poses of the same unknown: mm, degrees.
pub fn pose_difference(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    (
        (a.translation.vector - b.translation.vector).norm() * 1e3,
        d.rotation.angle().to_degrees(),
    )
}

/// What the run's record says while the result is written to the controller: it stays so
/// when the program stops before the final record is written.
const WRITING_REASON: &str = "interrupted while writing the result above to the controller (the TCP and/or the registers, as configured); check the TCP on the pendant";

/// What the controller held before a run wrote its result: put back when the result cannot be
/// recorded (the record and `current/` must describe what the controller holds).
#[derive(Debug, Clone)]
pub(crate) struct Previous {
    /// The TCP read at preflight, when the run set the TCP.
    pub(crate) tcp: Option<Isometry3<f64>>,
    /// The result registers read just before they were written, when the run wrote them.
    pub(crate) registers: Option<(crate::config::RegisterMap, [f64; 6])>,
}

/// Writes `previous` back to the controller: the TCP, then the registers with a new sequence
/// number (so a pendant program that applied the unrecorded result applies the previous values
/// again). Returns what was done, for the run's reasons, or why it could not be done.
pub(crate) async fn put_back<R: Robot>(robot: &R, previous: &Previous) -> Result<String, String> {
    let mut done = Vec::new();
    if let Some(tcp) = &previous.tcp {
        robot
            .set_tcp(tcp)
            .await
            .map_err(|e| format!("setting the previous TCP back failed: {}", error_chain(&e)))?;
        done.push(format!(
            "the previous TCP ({}) was set back",
            UrPose::from(tcp)
        ));
    }
    if let Some((map, values)) = &previous.registers {
        let failed = |e: HalError| {
            format!(
                "writing the previous result registers back failed: {}",
                error_chain(&e)
            )
        };
        for (k, v) in values.iter().enumerate() {
            robot
                .write_double_register(map.double_start + k as u32, *v)
                .await
                .map_err(failed)?;
        }
        let seq = robot
            .read_int_register(map.sequence_int)
            .await
            .map_err(failed)?
            .wrapping_add(1)
            .max(1);
        robot
            .write_int_register(map.sequence_int, seq)
            .await
            .map_err(failed)?;
        done.push(format!(
            "the previous values of input_double_register_{}..{} were written back (input_int_register_{} = {seq})",
            map.double_start,
            map.double_start + 5,
            map.sequence_int
        ));
    }
    Ok(done.join("; "))
}

/// Puts `previous` back on the controller and says so: on success `record.written` loses its
/// TCP and register entries (the controller holds what it held before the run).
async fn restore_sentence<R: Robot>(
    robot: &R,
    previous: &Previous,
    record: &mut RunRecord,
) -> String {
    match put_back(robot, previous).await {
        Ok(done) => {
            record
                .written
                .retain(|w| !matches!(w.target, WriteTarget::Tcp | WriteTarget::Registers));
            tracing::warn!("result not recorded, controller restored: {done}");
            format!("so it was undone: {done}")
        }
        Err(why) => {
            tracing::error!("result not recorded and the controller not restored: {why}");
            format!("{why}; the controller keeps the unrecorded result: check the TCP and the registers on the pendant")
        }
    }
}

/// The DH set a reported flange is checked against exactly: the controller's own (it computes
/// its flange pose with it); a calibration file's or the nominal URDF's only loosely.
fn reference_dh(k: &KinematicsUsed) -> Option<handeye_hal::ur_dh::DhParams> {
    match k.source {
        KinematicsOrigin::Controller => k.dh,
        KinematicsOrigin::File | KinematicsOrigin::Nominal => None,
    }
}

/// Everything a run works with, resolved once.
struct Context<'a, R, C> {
    robot: &'a R,
    camera: &'a C,
    model: &'a Arc<RobotModel>,
    cfg: &'a Config,
    req: RunRequest,
    cancel: &'a CancellationToken,
    progress: &'a dyn Progress,
    /// `model_from_base`: the controller's `base` frame in the model root.
    model_from_base: Isometry3<f64>,
    record: RunRecord,
    run_dir: PathBuf,
    /// Whether a move was commanded (the arm may have moved even if the move failed).
    moved: bool,
    /// The scans the report picture shows (the first registered frame of each view).
    pictures: Vec<PictureScan>,
    /// The robot's and the camera's link generations when the run started.
    links: (u64, u64),
    /// The current calibration was made on another arm, or on other kinematics of this one
    /// ([`ControllerIdentity::calibration_mismatch`]): a calibrate's gate does not compare
    /// with it.
    other_arm: bool,
    /// What the controller held before the write-back, once the run changed it.
    previous: Option<Previous>,
    /// Held from the write-back journal's write until the recorder removes it.
    journal: Option<storage::JournalLock>,
}

/// A scan a run's report picture shows: a view's first registered frame, that frame's
/// registration and the kinematics the model was posed with.
#[derive(Debug)]
struct PictureScan {
    frame: Frame,
    registration: crate::calib::Registration,
    controller_dh: Option<handeye_hal::ur_dh::DhParams>,
}

/// Runs one calibration or check on `robot` and `camera` for `model` as `cfg` says and keeps
/// its files (record, report picture) without a history row; the daemon and the commands run
/// through a [`Recorder`] with the history. Returns the complete record whatever happens;
/// cancelling `cancel` stops the arm and aborts the run.
pub async fn run<R: Robot, C: DepthCamera>(
    robot: &R,
    camera: &C,
    model: &Arc<RobotModel>,
    cfg: &Config,
    req: RunRequest,
    cancel: &CancellationToken,
    progress: &dyn Progress,
) -> RunRecord {
    Recorder::files_only()
        .run(robot, camera, model, cfg, req, cancel, progress)
        .await
}

/// The run's steps from preflight to the return move, filling `record` (as
/// [`RunRecord::starting`] made it); files go into `run_dir`. Returns the record and the scans
/// its report picture shows.
#[allow(clippy::too_many_arguments)]
async fn execute<R: Robot, C: DepthCamera>(
    robot: &R,
    camera: &C,
    model: &Arc<RobotModel>,
    cfg: &Config,
    req: RunRequest,
    record: RunRecord,
    run_dir: PathBuf,
    cancel: &CancellationToken,
    progress: &dyn Progress,
) -> (RunRecord, Vec<PictureScan>, Option<storage::JournalLock>) {
    let t0 = Instant::now();
    let run_id = record.run_id.clone();
    let model_from_base = guard::model_from_base(model);
    let mut cx = Context {
        robot,
        camera,
        model,
        cfg,
        req,
        cancel,
        progress,
        model_from_base,
        record,
        run_dir,
        moved: false,
        pictures: Vec::new(),
        links: (robot.link_generation(), camera.link_generation()),
        other_arm: false,
        previous: None,
        journal: None,
    };
    let span = tracing::info_span!("calibration", run_id = %run_id);
    let result = tracing::Instrument::instrument(cx.steps(), span).await;
    if let Err(f) = result {
        // The stage that failed never recorded its time: it is what the run spent beyond
        // the stages that finished (a summary showed it as 0 ms).
        let spent: f64 = cx.record.timings_ms.stages().iter().map(|(_, ms)| ms).sum();
        cx.record
            .timings_ms
            .add(f.stage, (elapsed_ms(t0) - spent).max(0.0));
        cx.record.outcome = f.outcome;
        cx.record.failed_stage = Some(f.stage);
        let arm_usable = f.arm_usable();
        cx.record.reasons.push(f.message);
        if arm_usable {
            cx.return_to_start().await;
        }
    }
    cx.record.timings_ms.total = elapsed_ms(t0);
    (cx.record, cx.pictures, cx.journal)
}

impl<R: Robot, C: DepthCamera> Context<'_, R, C> {
    /// Fails when the robot's or the camera's connection was re-established since the run
    /// started: what was measured before the drop and after it are not combined.
    fn links_intact(&self, stage: Stage) -> Result<(), Failure> {
        let now = (self.robot.link_generation(), self.camera.link_generation());
        let which = match (now.0 != self.links.0, now.1 != self.links.1) {
            (false, false) => return Ok(()),
            (true, false) => "the robot",
            (false, true) => "the camera",
            (true, true) => "the robot and the camera",
        };
        Err(Failure {
            outcome: Outcome::Aborted,
            stage,
            message: format!(
                "the connection to {which} dropped and was re-established during the run; nothing measured before the drop is used; run again"
            ),
        })
    }

    async fn steps(&mut self) -> Result<(), Failure> {
        let t = Instant::now();
        self.progress
            .stage(Stage::Preflight, "checking robot and camera");
        let (controller_dh, reference) = self.preflight().await?;
        self.record.timings_ms.preflight = elapsed_ms(t);

        let t = Instant::now();
        self.progress
            .stage(Stage::Plan, "choosing views and checking paths");
        self.plan()?;
        self.record.timings_ms.plan = elapsed_ms(t);
        if self.req.dry_run {
            self.forecast().await?;
            self.record.outcome = Outcome::Planned;
            return Ok(());
        }

        self.check_room()?;
        let frames = self.move_and_capture().await?;

        let t = Instant::now();
        let n = frames.len();
        self.progress
            .stage(Stage::Register, &format!("registering {n} frame(s)"));
        let opts = self.pipeline_options(controller_dh, reference.as_ref());
        let picture_dh = opts.controller_dh;
        let model = self.model.clone();
        // The first registered frame of each view comes back for the report picture, with its
        // registration's index (no copy of a scan is made).
        let (calibration, shown) = cancellable(self.cancel, Stage::Register, async move {
            let (calibration, shown) = tokio::task::spawn_blocking(move || {
                let calibration = calibrate_frames(&model, &frames, &opts);
                let mut frames: Vec<Option<Frame>> = frames.into_iter().map(Some).collect();
                let mut views = Vec::new();
                let mut shown = Vec::new();
                if let Ok(c) = &calibration {
                    for (r, &i) in c.frames.iter().enumerate() {
                        let Some(frame) = frames.get_mut(i).and_then(Option::take) else {
                            continue;
                        };
                        if !views.contains(&frame.view) {
                            views.push(frame.view);
                            shown.push((frame, r));
                        }
                    }
                }
                (calibration, shown)
            })
            .await
            .map_err(|e| Failure::error(Stage::Register, format!("registration panicked: {e}")))?;
            let calibration =
                calibration.map_err(|e| Failure::error(Stage::Register, error_chain(&e)))?;
            Ok((calibration, shown))
        })
        .await?;
        self.pictures = shown
            .into_iter()
            .filter_map(|(frame, r)| {
                Some(PictureScan {
                    frame,
                    registration: calibration.registrations.get(r)?.clone(),
                    controller_dh: picture_dh,
                })
            })
            .collect();
        let reg_ms: f64 = calibration
            .registrations
            .iter()
            .map(|r| r.timings_ms.total)
            .sum();
        self.record.timings_ms.register = reg_ms;
        self.record.timings_ms.solve = (elapsed_ms(t) - reg_ms).max(0.0);
        self.progress.stage(
            Stage::Solve,
            if calibration.verdict.passed() {
                "the gate passed"
            } else {
                "the gate refused the result"
            },
        );
        let estimate = calibration.solution.estimate;
        let unknown = match self.cfg.mount.mount {
            Mount::EyeInHand => estimate,
            Mount::EyeToHand => calibration.base_from_model * estimate,
        };
        self.record.result = Some(ResultRecord {
            mount: self.cfg.mount.mount,
            flange_from_camera: calibration
                .solution
                .flange_from_camera()
                .map(|t| to_row_major(&t)),
            base_from_camera: to_row_major(&calibration.base_from_camera),
            ur_pose: UrPose::from(&unknown).values(),
            uncertainty: calibration.report.uncertainty,
            report: calibration.report.clone(),
        });
        if !calibration.verdict.passed() {
            self.record.outcome = Outcome::Rejected;
            let trigger = self.record.trigger;
            self.record.reasons = calibration
                .verdict
                .reasons
                .iter()
                .map(|r| with_remount_way_out(r, trigger, &self.cfg.origin))
                .collect();
            self.return_to_start().await;
            return Ok(());
        }
        self.record.outcome = Outcome::Accepted;
        match self.req.mode {
            RunMode::Check => self.compare(&unknown, reference),
            RunMode::Calibrate => {
                self.accept_change(&unknown, reference.as_ref());
                self.links_intact(Stage::WriteBack)?;
                let t = Instant::now();
                self.progress.stage(Stage::WriteBack, "writing the result");
                let written = self.write_back(&unknown).await;
                self.record.timings_ms.write_back = elapsed_ms(t);
                written?;
            }
        }
        self.return_to_start().await;
        Ok(())
    }

    /// Checks that the robot may move and the camera answers; records the start state.
    /// Returns the controller's kinematics (when used) and the current calibration.
    async fn preflight(
        &mut self,
    ) -> Result<
        (
            Option<handeye_hal::ur_dh::DhParams>,
            Option<(Isometry3<f64>, String)>,
        ),
        Failure,
    > {
        let stage = Stage::Preflight;
        let robot = self.robot;
        let camera = self.camera;
        let allow_power_on = self.cfg.robot.allow_power_on;
        let (status, start, tcp, flange, powered_on) = cancellable(self.cancel, stage, async {
            let mut status = robot
                .status()
                .await
                .map_err(|e| Failure::robot(stage, "reading the robot's state", e))?;
            // Only when the configuration says so explicitly; never past a stop of any kind.
            let powerable =
                matches!(
                    status.robot_mode,
                    RobotMode::PowerOff | RobotMode::PowerOn | RobotMode::Idle
                ) && matches!(status.safety_mode, SafetyMode::Normal | SafetyMode::Reduced)
                    && status.remote_control;
            let powered_on = powerable && allow_power_on;
            if powered_on {
                tracing::warn!(
                    "the robot is {:?}: powering it on and releasing the brakes \
                     (robot.allow_power_on = true)",
                    status.robot_mode
                );
                robot.power_on().await.map_err(|e| {
                    Failure::robot(stage, "powering the robot on (robot.allow_power_on)", e)
                })?;
                status = robot
                    .status()
                    .await
                    .map_err(|e| Failure::robot(stage, "reading the robot's state", e))?;
            }
            let start = robot
                .joint_positions()
                .await
                .map_err(|e| Failure::robot(stage, "reading the joints", e))?;
            let tcp = robot
                .tcp_offset()
                .await
                .map_err(|e| Failure::robot(stage, "reading the TCP", e))?;
            let flange = robot
                .flange_pose()
                .await
                .map_err(|e| Failure::robot(stage, "reading the flange pose", e))?;
            Ok((status, start, tcp, flange, powered_on))
        })
        .await?;
        let identity =
            match cancellable(self.cancel, stage, async { Ok(robot.identity().await) }).await? {
                Ok(id) => Some(id),
                Err(e) => {
                    let w = format!(
                        "cannot ask the controller who it is ({}): the arm is not compared with \
                     the one the current calibration was made on; check the dashboard \
                     connection (port 29999)",
                        error_chain(&e)
                    );
                    tracing::warn!("{w}");
                    self.record.warnings.push(w);
                    None
                }
            };
        if start.len() != self.model.dof() {
            return Err(Failure::error(
                stage,
                format!(
                    "the robot reports {} joints but the model {} has {}; configure the right robot model",
                    start.len(),
                    self.model.name(),
                    self.model.dof()
                ),
            ));
        }
        // Without the controller's kinematics: posed by `robot.calibration` when given, else
        // the nominal URDF.
        let fallback = |why: Option<String>| match &self.cfg.robot.calibration {
            Some(file) => KinematicsUsed {
                source: KinematicsOrigin::File,
                note: Some(format!(
                    "{}posed by the calibration file {}",
                    why.map_or_else(String::new, |w| format!("{w}; ")),
                    file.display()
                )),
                dh: None,
            },
            None => KinematicsUsed {
                source: KinematicsOrigin::Nominal,
                note: why.map(|w| format!("{w}; posed by the nominal URDF")),
                dh: None,
            },
        };
        let mut kinematics = match self.cfg.robot.kinematics {
            KinematicsSource::Nominal => fallback(None),
            KinematicsSource::Controller => {
                match cancellable(self.cancel, stage, async { Ok(robot.kinematics().await) })
                    .await?
                {
                    Ok(Some(k)) => KinematicsUsed {
                        source: KinematicsOrigin::Controller,
                        note: (!k.calibrated).then(|| {
                            "the controller says its arm is not factory calibrated".to_string()
                        }),
                        dh: Some(k.dh),
                    },
                    Ok(None) => fallback(Some("the controller publishes no kinematics".into())),
                    // Values no arm has: no pose this controller reports is trusted.
                    Err(e @ HalError::Protocol { .. }) => {
                        return Err(Failure::error(
                            stage,
                            format!(
                                "the controller's kinematics: {}; nothing moved and nothing was \
                                 written",
                                error_chain(&e)
                            ),
                        ))
                    }
                    Err(e) => fallback(Some(format!(
                        "cannot read the controller's kinematics ({})",
                        error_chain(&e)
                    ))),
                }
            }
        };
        if let Some(note) = &kinematics.note {
            tracing::warn!("{note}");
        }
        if let (Some(file), KinematicsOrigin::File) =
            (&self.cfg.robot.calibration, kinematics.source)
        {
            // The file's DH set poses the model as the controller's would.
            let dh = crate::model::UrCalibration::load(file)
                .map_err(|e| e.to_string())
                .and_then(|c| c.dh(&self.cfg.robot.model.dh()))
                .map_err(|e| {
                    Failure::error(
                        stage,
                        format!("robot.calibration: {e}; fix the file or remove the key"),
                    )
                })?;
            kinematics.dh = Some(dh);
        }
        let reported_model = identity.as_ref().and_then(|i| i.model.as_deref());
        let model_check = check_model_matches(
            self.cfg.robot.model,
            reported_model,
            kinematics.dh.as_ref().map(|dh| (dh, kinematics.source)),
        );
        let camera_info = cancellable(self.cancel, stage, async {
            camera.info().await.map_err(|e| {
                let what = match e {
                    // It answered, and refuses what was asked (a configured setting its
                    // description cannot take, issue 44): the message says what to change.
                    handeye_hal::HalError::Refused { .. } => {
                        format!("the camera refuses: {}", error_chain(&e))
                    }
                    _ => format!(
                        "the camera does not answer: {}; check its power, cable and address",
                        error_chain(&e)
                    ),
                };
                Failure::error(stage, what)
            })
        })
        .await;
        let controller_dh = kinematics.dh;
        // Before anything moves: the controller's joints and flange must belong together.
        let flange_check = self.check_flange(
            stage,
            &start,
            &flange,
            reference_dh(&kinematics).as_ref(),
            "at the start",
        );
        let reference = self.reference(&tcp, identity.as_ref());
        self.record.preflight = Some(PreflightRecord {
            status: status.clone(),
            camera: camera_info.as_ref().cloned().unwrap_or_default(),
            start_joints: start,
            tcp_offset: to_row_major(&tcp),
            kinematics,
            powered_on,
            controller: identity,
        });
        model_check.map_err(|m| Failure::error(stage, m))?;
        flange_check?;
        preflight_status(&status, self.req.program_handover, allow_power_on)?;
        camera_info?;
        Ok((controller_dh, reference))
    }

    /// The calibration a check compares with, and a calibrate's previous result: the last
    /// accepted result in storage, else (check, eye-in-hand with TCP write-back) the
    /// controller's TCP. When the stored result was made on another arm, or on other
    /// kinematics of this one (`identity` against the one it was made with), the record
    /// warns: a check still compares, a calibrate's gate does not.
    fn reference(
        &mut self,
        tcp: &Isometry3<f64>,
        identity: Option<&ControllerIdentity>,
    ) -> Option<(Isometry3<f64>, String)> {
        if let Some(current) = load_current(&self.cfg.storage.dir, self.cfg.mount.mount) {
            let mismatch = identity
                .zip(current.controller.as_ref())
                .and_then(|(now, then)| now.calibration_mismatch(then));
            if let Some(m) = mismatch {
                let w = match self.req.mode {
                    RunMode::Check => {
                        format!("{m}; the drift is measured from that arm's calibration")
                    }
                    RunMode::Calibrate => format!(
                        "{m}; this run does, and its gate does not compare with that arm's \
                         result"
                    ),
                };
                tracing::warn!("{w}");
                self.record.warnings.push(w);
                self.other_arm = true;
            }
            return Some((current.pose, current.source));
        }
        let tcp_is_camera = self.cfg.mount.mount == Mount::EyeInHand
            && self.cfg.write_back.tcp
            && (tcp.translation.vector.norm() > 1e-9 || tcp.rotation.angle() > 1e-9);
        (self.req.mode == RunMode::Check && tcp_is_camera)
            .then(|| (*tcp, "the controller's active TCP".to_string()))
    }

    fn planner(&self) -> ViewPlanner<'_> {
        let constraints = ViewConstraints {
            floor_clearance_m: self.cfg.views.floor_clearance_m,
            ..match &self.cfg.views.targets {
                ViewTargets::Auto {
                    min_distance_m,
                    max_distance_m,
                    ..
                } => ViewConstraints {
                    min_distance_m: *min_distance_m,
                    max_distance_m: *max_distance_m,
                    ..ViewConstraints::default()
                },
                ViewTargets::Joints(_) => ViewConstraints::default(),
            }
        };
        let flange_from_camera = guard::configured_flange_from_camera(self.cfg);
        let obstacles = guard::configured_obstacles(self.cfg, &self.model_from_base);
        let cancel = self.cancel.clone();
        ViewPlanner::new(
            self.model,
            flange_from_camera,
            Intrinsics::compact_1280x960(),
            constraints,
        )
        .with_obstacles(obstacles)
        .with_cancel(CancelCheck::new(move || cancel.is_cancelled()))
    }

    /// A wrist camera's views, generated: the first, of a few that see the base and are
    /// reached on a safe path, the one nearest to where the arm stands; the others near the
    /// first ([`ViewPlanner::nearby`]: the base and upper arm turn a little, the wrist far),
    /// each the one that turns the flange most from every view before it (what separates the
    /// mount from the base's housing when the views are fitted together) among those reached
    /// on a safe path from the view before. Short moves, the flange turned between views.
    fn auto_views(
        &self,
        planner: &ViewPlanner<'_>,
        start: &[f64],
        count: usize,
        seed: u64,
    ) -> Result<Vec<Vec<f64>>, Failure> {
        let stage = Stage::Plan;
        let plan_error = |e: PlanError| match e {
            PlanError::Cancelled => Failure::cancelled(stage),
            e => Failure::error(
                stage,
                format!("{}; configure joint targets under [views]", error_chain(&e)),
            ),
        };
        let min_change = ViewConstraints::default().min_joint_change_rad;
        let mut last_refusal = None;
        // Whether the path from `from` to `to` is safe (a refusal is remembered for the error).
        let mut safe = |from: &[f64], to: &[f64]| -> Result<bool, Failure> {
            match planner.check_path(from, to, PATH_STEP_RAD) {
                Ok(Ok(_)) => Ok(true),
                Ok(Err(ViewRejection::Cancelled)) => Err(Failure::cancelled(stage)),
                Ok(Err(r)) => {
                    last_refusal = Some(r.to_string());
                    Ok(false)
                }
                Err(e) => Err(Failure::error(stage, error_chain(&e))),
            }
        };
        let mut next_seed = seed;
        // The first view: of a few within a quarter turn of the base, the nearest on a safe path.
        let mut first: Option<Vec<f64>> = None;
        for _ in 0..AUTO_VIEW_TRIES {
            let mut candidates = planner
                .nearby(
                    start,
                    &FIRST_VIEW_SPAN_RAD,
                    FIRST_VIEW_CANDIDATES,
                    FIRST_VIEW_DRAWS,
                    next_seed,
                )
                .map_err(plan_error)?;
            next_seed = next_seed.wrapping_add(1);
            candidates.sort_by(|a, b| joint_span(start, a).total_cmp(&joint_span(start, b)));
            for q in candidates {
                if safe(start, &q)? {
                    first = Some(q);
                    break;
                }
            }
            if first.is_some() {
                break;
            }
        }
        let not_found = |n: usize, last_refusal: Option<String>| {
            Failure::error(
                stage,
                format!(
                    "no generated view {n} of {count} is reachable on a safe path ({}); move the arm to a free start pose or configure joint targets",
                    last_refusal.unwrap_or_else(|| "views too alike".into())
                ),
            )
        };
        let Some(first) = first else {
            return Err(not_found(1, last_refusal));
        };
        let mut views = vec![first];
        while views.len() < count {
            let mut picked = None;
            for _ in 0..AUTO_VIEW_TRIES {
                let candidates = planner
                    .nearby(
                        &views[0],
                        &NEARBY_SPAN_RAD,
                        NEARBY_CANDIDATES,
                        20 * NEARBY_CANDIDATES,
                        next_seed,
                    )
                    .map_err(plan_error)?;
                next_seed = next_seed.wrapping_add(1);
                let mut scored = Vec::new();
                for q in candidates {
                    let distinct = differs_from_all(&views, &q, min_change);
                    if !distinct {
                        continue;
                    }
                    let mut turn = f64::INFINITY;
                    for v in &views {
                        let t = planner
                            .flange_turn(v, &q)
                            .map_err(|e| Failure::error(stage, error_chain(&e)))?;
                        turn = turn.min(t);
                    }
                    scored.push((turn, q));
                }
                scored.sort_by(|a, b| b.0.total_cmp(&a.0));
                let from = views.last().cloned().unwrap_or_default();
                for (_, q) in scored {
                    if safe(&from, &q)? {
                        picked = Some(q);
                        break;
                    }
                }
                if picked.is_some() {
                    break;
                }
            }
            let Some(q) = picked else {
                return Err(not_found(views.len() + 1, last_refusal));
            };
            views.push(q);
        }
        Ok(views)
    }

    /// Chooses the views and checks every target and path (out, between views and back).
    fn plan(&mut self) -> Result<(), Failure> {
        let stage = Stage::Plan;
        let planner = self.planner();
        let start = self
            .record
            .preflight
            .as_ref()
            .map(|p| p.start_joints.clone())
            .unwrap_or_default();
        let targets: Vec<Vec<f64>> = match (&self.cfg.views.targets, self.cfg.mount.mount) {
            (ViewTargets::Joints(list), _) => list.iter().map(|q| q.to_vec()).collect(),
            // A camera fixed in the cell: measure from where the arm stands (no motion); give
            // joint targets to show it the base and first links from a better pose.
            (ViewTargets::Auto { .. }, Mount::EyeToHand) => vec![start.clone()],
            (ViewTargets::Auto { count, seed, .. }, Mount::EyeInHand) => {
                self.auto_views(&planner, &start, *count, *seed)?
            }
        };
        let mut from = start.clone();
        let mut views = Vec::new();
        let fk = |e: crate::model::ModelError| Failure::error(stage, error_chain(&e));
        for (i, q) in targets.iter().enumerate() {
            let path = planner
                .check_path(&from, q, PATH_STEP_RAD)
                .map_err(fk)?
                .map_err(|r| match r {
                    ViewRejection::Cancelled => Failure::cancelled(stage),
                    r => Failure::error(
                        stage,
                        format!(
                            "the path to view {} is not safe: {r}; change the view's joints or the obstacles",
                            i + 1
                        ),
                    ),
                })?;
            let seen = match (self.cfg.mount.mount, self.cfg.mount.prior) {
                (Mount::EyeInHand, Some(_)) => Some(planner.check(q).map_err(fk)?),
                _ => None,
            };
            views.push(PlannedView {
                joints: q.clone(),
                distance_to_base_m: seen.as_ref().and_then(|s| s.as_ref().ok().copied()),
                path,
                not_seeing_base: seen.and_then(|s| s.err()).map(|r| r.to_string()),
            });
            from = q.clone();
        }
        if self.cfg.views.return_to_start {
            planner
                .check_path(&from, &start, PATH_STEP_RAD)
                .map_err(fk)?
                .map_err(|r| match r {
                    ViewRejection::Cancelled => Failure::cancelled(stage),
                    r => Failure::error(
                        stage,
                        format!("the path back to the start is not safe: {r}; move the arm to a free start pose"),
                    ),
                })?;
        }
        self.progress.stage(
            stage,
            &format!(
                "{} view(s); every target and path checked for limits and collisions",
                views.len()
            ),
        );
        self.record.views = views;
        Ok(())
    }

    /// A dry run's forecast of the run it planned ([`forecast`]): the σ of its views simulated
    /// at the mount prior (a wrist camera) and its time at the configured caps.
    async fn forecast(&mut self) -> Result<(), Failure> {
        let start = self
            .record
            .preflight
            .as_ref()
            .map(|p| p.start_joints.clone())
            .unwrap_or_default();
        let views: Vec<Vec<f64>> = self.record.views.iter().map(|v| v.joints.clone()).collect();
        let model = Arc::clone(self.model);
        let cfg = self.cfg;
        let (limits, settle, frames, back, sensor) = (
            cfg.robot.limits,
            cfg.camera.settle.as_secs_f64(),
            cfg.camera.capture.frames as usize,
            cfg.views.return_to_start,
            cfg.camera.sensor,
        );
        let prior = match cfg.mount.mount {
            Mount::EyeInHand => cfg.mount.prior,
            Mount::EyeToHand => None,
        };
        self.progress.stage(
            Stage::Plan,
            "forecast: the views simulated at the mount prior, the moves timed",
        );
        let f = cancellable(self.cancel, Stage::Plan, async move {
            tokio::task::spawn_blocking(move || {
                forecast::forecast(
                    &model, &start, &views, back, &limits, settle, frames, prior, sensor,
                )
            })
            .await
            .map_err(|e| Failure::error(Stage::Plan, format!("the forecast panicked: {e}")))
        })
        .await?;
        self.record.forecast = Some(f);
        Ok(())
    }

    /// Checks, before the first move, that the storage has room for everything the run keeps
    /// (its raw scans at the camera's resolution × frames × views, when kept).
    fn check_room(&self) -> Result<(), Failure> {
        let (width, height) = self
            .record
            .preflight
            .as_ref()
            .map_or((0, 0), |p| (p.camera.width, p.camera.height));
        let frames = self.record.views.len() * self.cfg.camera.capture.frames as usize;
        let needed = storage::run_bytes(width, height, frames, self.cfg.storage.keep_captures);
        // Blocking I/O of a few ms (one small file flushed), like the run's other small writes.
        storage::check_room(&self.cfg.storage.dir, needed).map_err(|e| {
            Failure::error(
                Stage::Preflight,
                format!("{e}; nothing moved and nothing was written to the controller"),
            )
        })
    }

    /// Moves to every view, settles, records joints and flange pose and captures frames.
    async fn move_and_capture(&mut self) -> Result<Vec<Frame>, Failure> {
        let mut frames = Vec::new();
        let views: Vec<Vec<f64>> = self.record.views.iter().map(|v| v.joints.clone()).collect();
        let keep = self.cfg.storage.keep_captures;
        let start = self
            .record
            .preflight
            .as_ref()
            .map(|p| p.start_joints.clone());
        let mut capture_file = CaptureFile {
            model: self.model.name().to_string(),
            mount: self.cfg.mount.mount,
            base_frame: "base".into(),
            prior: self.cfg.mount.prior.as_ref().map(to_row_major),
            controller_dh: self.record.preflight.as_ref().and_then(|p| p.kinematics.dh),
            dh_from_controller: self
                .record
                .preflight
                .as_ref()
                .is_some_and(|p| reference_dh(&p.kinematics).is_some()),
            views: Vec::new(),
        };
        for (v, q) in views.iter().enumerate() {
            let t = Instant::now();
            self.progress.stage(
                Stage::Move,
                &format!("moving to view {} of {}", v + 1, views.len()),
            );
            // A view at the start joints (eye-to-hand without targets: measure where the arm
            // stands) needs no motion at all.
            if !(v == 0 && start.as_deref() == Some(q.as_slice())) {
                self.moved = true;
                let moved = self
                    .move_to(q, Stage::Move, &format!("move to view {}", v + 1))
                    .await;
                // Also an aborted move took its time.
                self.record.timings_ms.moves += elapsed_ms(t);
                moved?;
                self.links_intact(Stage::Move)?;
            }

            let t = Instant::now();
            self.progress.stage(Stage::Settle, "letting the arm settle");
            let settle = self.cfg.camera.settle;
            cancellable(self.cancel, Stage::Settle, async {
                tokio::time::sleep(settle).await;
                Ok(())
            })
            .await?;
            self.record.timings_ms.settle += elapsed_ms(t);

            let t = Instant::now();
            let n = self.cfg.camera.capture.frames;
            self.progress.stage(
                Stage::Capture,
                &format!("capturing {n} frame(s) at view {}", v + 1),
            );
            let (capture, clouds) = self.capture(v).await?;
            self.links_intact(Stage::Capture)?;
            self.record.timings_ms.capture += elapsed_ms(t);
            let base_from_flange = crate::frames::from_row_major(&capture.base_from_flange)
                .ok_or_else(|| {
                    Failure::error(
                        Stage::Capture,
                        format!(
                            "the controller's flange pose at view {} is not a rigid transform; \
                             check the controller (nothing was written)",
                            v + 1
                        ),
                    )
                })?;
            let dh = self
                .record
                .preflight
                .as_ref()
                .and_then(|p| reference_dh(&p.kinematics));
            self.check_flange(
                Stage::Capture,
                &capture.joints,
                &base_from_flange,
                dh.as_ref(),
                &format!("at view {}", v + 1),
            )?;
            let mut record = capture;
            for (k, cloud) in clouds.into_iter().enumerate() {
                let path = if keep {
                    match storage::save_frame(&self.run_dir, v, k, &cloud) {
                        Ok(p) => Some(p),
                        Err(e) => {
                            tracing::warn!("cannot keep the raw capture: {e}");
                            None
                        }
                    }
                } else {
                    None
                };
                record.frames.push(FrameRecord {
                    path: path.as_ref().map(|p| p.display().to_string()),
                    width: cloud.width,
                    height: cloud.height,
                    valid_points: cloud.valid_count(),
                });
                frames.push(Frame {
                    view: v,
                    source: path.as_ref().map_or_else(
                        || format!("view {v} frame {k}"),
                        |p| p.display().to_string(),
                    ),
                    cloud,
                    joints: record.joints.clone(),
                    model_from_flange: Some(self.model_from_base * base_from_flange),
                });
            }
            // The capture file names its scans relative to itself: a run folder can move.
            let mut portable = record.clone();
            for f in &mut portable.frames {
                f.path = f.path.as_deref().map(|p| {
                    std::path::Path::new(p)
                        .file_name()
                        .map_or_else(|| p.to_string(), |n| n.to_string_lossy().into_owned())
                });
            }
            capture_file.views.push(portable);
            self.record.captures.push(record);
        }
        if keep {
            match storage::write_capture_file(&self.run_dir, &capture_file) {
                Ok(p) => self.record.capture_file = Some(p.display().to_string()),
                Err(e) => tracing::warn!("cannot keep the capture description: {e}"),
            }
        }
        Ok(frames)
    }

    async fn move_to(&self, q: &[f64], stage: Stage, what: &str) -> Result<(), Failure> {
        let robot = self.robot;
        let limits = self.cfg.robot.limits;
        let r = cancellable(self.cancel, stage, async {
            robot
                .move_joints(q, limits)
                .await
                .map_err(|e| Failure::robot(stage, what, e))
        })
        .await;
        if r.is_err() && self.cancel.is_cancelled() {
            // The dropped move future stops the arm; say so to the controller as well.
            if let Err(e) = robot.stop().await {
                tracing::error!("could not stop the arm after a cancel: {e}");
            }
        }
        r
    }

    /// Refuses a flange pose (`base_from_flange`, as the controller reported it with `joints`)
    /// that is not the forward kinematics of those joints: by the controller's own DH
    /// (`controller_dh`, tight) or else the nominal URDF. A corrupt or inconsistent controller
    /// value would become a wrong TCP: nothing moves or is written after this fails.
    fn check_flange(
        &self,
        stage: Stage,
        joints: &[f64],
        base_from_flange: &Isometry3<f64>,
        controller_dh: Option<&handeye_hal::ur_dh::DhParams>,
        when: &str,
    ) -> Result<(), Failure> {
        use crate::model::reported::{check_reported_flange, FlangeReference};
        let reference = match controller_dh {
            Some(dh) => FlangeReference::ControllerDh {
                dh,
                model_from_base: &self.model_from_base,
            },
            None => FlangeReference::Nominal,
        };
        let model_from_flange = self.model_from_base * base_from_flange;
        match check_reported_flange(self.model, joints, &model_from_flange, reference) {
            Ok(Ok(())) => Ok(()),
            Ok(Err(m)) => Err(Failure::error(
                stage,
                format!(
                    "the controller's flange pose {when} {m}: the controller reports joints and \
                     a flange that do not belong together (corrupt data, or another robot \
                     model than robot.model); check the controller and the network — nothing \
                     was written"
                ),
            )),
            Err(e) => Err(Failure::error(
                stage,
                format!("the controller's joints {when}: {e}"),
            )),
        }
    }

    /// Records joints and flange pose, captures the frames, checks the arm stood still.
    async fn capture(
        &self,
        view: usize,
    ) -> Result<(CaptureRecord, Vec<handeye_hal::PointCloud>), Failure> {
        let stage = Stage::Capture;
        let robot = self.robot;
        let camera = self.camera;
        let settings = self.cfg.camera.capture.clone();
        // A hard ceiling on the whole capture, whatever the camera does.
        let ceiling = settings.frame_timeout * settings.frames.max(1) + Duration::from_secs(5);
        cancellable(self.cancel, stage, async {
            let joints = robot
                .joint_positions()
                .await
                .map_err(|e| Failure::robot(stage, "reading the joints", e))?;
            let base_from_flange = robot
                .flange_pose()
                .await
                .map_err(|e| Failure::robot(stage, "reading the flange pose", e))?;
            let at = unix_now();
            let clouds = match tokio::time::timeout(ceiling, camera.capture(&settings)).await {
                Ok(Ok(c)) => c,
                Ok(Err(e)) => {
                    return Err(Failure::error(
                        stage,
                        format!(
                            "the camera failed to capture at view {}: {}; check the camera",
                            view + 1,
                            error_chain(&e)
                        ),
                    ))
                }
                Err(_) => {
                    return Err(Failure::error(
                        stage,
                        format!(
                            "the camera delivered no frames within {ceiling:?} at view {}; check the camera",
                            view + 1
                        ),
                    ))
                }
            };
            if clouds.len() != settings.frames as usize {
                return Err(Failure::error(
                    stage,
                    format!(
                        "the camera delivered {} frames instead of {}",
                        clouds.len(),
                        settings.frames
                    ),
                ));
            }
            let after = robot
                .joint_positions()
                .await
                .map_err(|e| Failure::robot(stage, "reading the joints", e))?;
            let change = joints
                .iter()
                .zip(&after)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            if change > MAX_JOINT_CHANGE_DURING_CAPTURE_RAD {
                return Err(Failure {
                    outcome: Outcome::Aborted,
                    stage,
                    message: format!(
                        "the arm moved by {change:.4} rad while the camera captured view {}; something else is moving the arm",
                        view + 1
                    ),
                });
            }
            Ok((
                CaptureRecord {
                    view,
                    joints,
                    base_from_flange: to_row_major(&base_from_flange),
                    unix_time_s: at,
                    joint_change_during_capture_rad: change,
                    frames: Vec::new(),
                },
                clouds,
            ))
        })
        .await
    }

    fn pipeline_options(
        &self,
        controller_dh: Option<handeye_hal::ur_dh::DhParams>,
        reference: Option<&(Isometry3<f64>, String)>,
    ) -> PipelineOptions {
        let mount = self.cfg.mount.mount;
        let mut opts = PipelineOptions::new(mount);
        opts.register = opts.register.for_sensor(self.cfg.camera.sensor);
        // The gate's largest-change check compares with our own last result only (a TCP on
        // the controller may be a gripper's).
        let model_from_base = self.model_from_base;
        let to_estimate_frame = |p: Isometry3<f64>| match mount {
            Mount::EyeInHand => p,
            Mount::EyeToHand => model_from_base * p,
        };
        opts.prior = self.cfg.mount.prior.map(to_estimate_frame);
        opts.controller_dh = controller_dh;
        opts.register.max_camera_flange_distance_m = match mount {
            Mount::EyeInHand => self.cfg.mount.max_camera_flange_distance_m,
            Mount::EyeToHand => None,
        };
        opts.gate = self.cfg.gate;
        opts.previous = match self.previous_result(reference) {
            // A deliberate remount: the change is measured and recorded after the gate
            // (`Self::accept_change`), not gated.
            Some(_) if self.req.accept_change.is_some() => None,
            p => p.map(to_estimate_frame),
        };
        opts.base_frame = Some("base".into());
        opts
    }

    /// Calibrate mode: the previous result the gate's largest-change check compares with (our
    /// own last result on this arm; a TCP on the controller may be a gripper's).
    fn previous_result(
        &self,
        reference: Option<&(Isometry3<f64>, String)>,
    ) -> Option<Isometry3<f64>> {
        match (self.req.mode, reference) {
            (RunMode::Calibrate, Some((p, source)))
                if source.starts_with("result") && !self.other_arm =>
            {
                Some(*p)
            }
            _ => None,
        }
    }

    /// Calibrate with `accept_change`: records who accepted the result and how far it moved
    /// from the previous calibration, and says so among the warnings when that was beyond
    /// `gate.max_change_*`.
    fn accept_change(
        &mut self,
        unknown: &Isometry3<f64>,
        reference: Option<&(Isometry3<f64>, String)>,
    ) {
        let Some(by) = self.req.accept_change.clone() else {
            return;
        };
        let g = &self.cfg.gate;
        let moved = self
            .previous_result(reference)
            .map(|p| pose_difference(&p, unknown));
        let beyond = moved.is_some_and(|(mm, deg)| {
            mm > g.max_change_translation_mm || deg > g.max_change_rotation_deg
        });
        if let (true, Some((mm, deg))) = (beyond, moved) {
            let line = format!(
                "the result moved {mm:.2} mm / {deg:.3}° from the previous calibration (max {:.2} mm / {:.3}°) and was accepted as a deliberate remount by {by}",
                g.max_change_translation_mm, g.max_change_rotation_deg
            );
            tracing::warn!("{line}");
            self.record.warnings.push(line);
        }
        self.record.change_accepted = Some(ChangeAccepted {
            by,
            translation_mm: moved.map(|m| m.0),
            rotation_deg: moved.map(|m| m.1),
            beyond_limits: beyond,
        });
    }

    /// Check mode: compares the measured unknown with the current calibration.
    fn compare(&mut self, measured: &Isometry3<f64>, reference: Option<(Isometry3<f64>, String)>) {
        let Some((pose, source)) = reference else {
            self.record.outcome = Outcome::Error;
            self.record.failed_stage = Some(Stage::Solve);
            self.record.reasons.push(format!(
                "nothing to compare with: no accepted calibration in {} and no camera TCP on the controller; calibrate first{}",
                self.cfg.storage.dir.display(),
                calibrate_way_out(self.record.trigger, &self.cfg.origin),
            ));
            return;
        };
        let (mm, deg) = pose_difference(&pose, measured);
        let c = &self.cfg.check;
        let drifted = mm > c.max_drift_translation_mm || deg > c.max_drift_rotation_deg;
        if drifted {
            tracing::warn!(
                translation_mm = mm,
                rotation_deg = deg,
                "the camera has drifted from its calibration"
            );
        }
        self.record.drift = Some(DriftRecord {
            reference: source,
            reference_pose: to_row_major(&pose),
            translation_mm: mm,
            rotation_deg: deg,
            max_translation_mm: c.max_drift_translation_mm,
            max_rotation_deg: c.max_drift_rotation_deg,
            drifted,
        });
    }

    /// Writes the accepted result as a transaction ([`journal`]). Write-ahead first: the
    /// result files (staged for `current/`), a record saying the result is being written to
    /// the controller, and the intent journal (what the controller holds now, what is about
    /// to be written, the record once it is) are durably on disk before the controller
    /// changes, so a full disk stops the run with nothing written and a kill at any later
    /// instant is reconciled at the next start. Then the TCP, then the registers (the
    /// sequence number last, so a pendant program applies nothing half-written, and the set
    /// read back), then the record saying they were written, then `current/` is replaced, so
    /// it only ever holds a calibration the controller has confirmed. From the journal on,
    /// a cancel or a shutdown waits for these few requests: they never stop half-way. When a
    /// write, the record or `current/` fails, the controller gets back the TCP read at
    /// preflight and the registers read before writing them ([`put_back`]), and the error
    /// says so. The journal goes once the recorder has kept the run's end.
    async fn write_back(&mut self, unknown: &Isometry3<f64>) -> Result<(), Failure> {
        let stage = Stage::WriteBack;
        let wb = self.cfg.write_back;
        let mount = self.cfg.mount.mount;
        let robot = self.robot;
        let storage_dir = self.cfg.storage.dir.clone();
        let kept = |what: &str, e: std::io::Error| {
            Failure::error(
                stage,
                format!("cannot keep {what} before writing it to the controller: {e}; nothing was written to the controller; free space in the storage directory (`[storage] dir`) and run again"),
            )
        };
        // The journal's lock first: no other process takes this run's staging or journal
        // for a crash's leftovers.
        let lock = match storage::JournalLock::try_acquire(&storage_dir) {
            Ok(Some(lock)) => lock,
            Ok(None) => {
                return Err(Failure::error(
                    stage,
                    "another handeye process is writing a result to the controller from the same storage directory; nothing was written; run again once it has ended",
                ))
            }
            Err(e) => return Err(kept("the write-back journal's lock", e)),
        };
        let staged = if wb.files {
            let result = self.record.result.clone();
            let staged = storage::stage_result(
                &storage_dir,
                &self.run_dir,
                unknown,
                mount,
                &self.record,
                result.as_ref(),
            )
            .map_err(|e| kept("the result files", e))?;
            Some(staged)
        } else {
            None
        };
        let mut pending = self.record.clone();
        pending.outcome = Outcome::Aborted;
        pending.failed_stage = Some(stage);
        pending.reasons.push(WRITING_REASON.to_string());
        storage::write_record(&self.run_dir, &pending).map_err(|e| kept("the run record", e))?;
        // What to put back if the result cannot be recorded: the TCP read at preflight and
        // the registers as they are now.
        let set_tcp = wb.tcp && mount == Mount::EyeInHand;
        let previous_tcp = set_tcp
            .then(|| {
                self.record
                    .preflight
                    .as_ref()
                    .and_then(|p| crate::frames::from_row_major(&p.tcp_offset))
            })
            .flatten();
        let p = UrPose::from(unknown).values();
        let registers = match wb.registers {
            Some(map) => {
                let (previous, previous_sequence) = cancellable(self.cancel, stage, async {
                    let failed = |e| Failure::robot(stage, "reading the result registers", e);
                    let mut values = [0.0; 6];
                    for (k, v) in values.iter_mut().enumerate() {
                        *v = robot
                            .read_double_register(map.double_start + k as u32)
                            .await
                            .map_err(failed)?;
                    }
                    let seq = robot
                        .read_int_register(map.sequence_int)
                        .await
                        .map_err(failed)?;
                    Ok((values, seq))
                })
                .await?;
                Some(journal::RegisterChange {
                    double_start: map.double_start,
                    sequence_int: map.sequence_int,
                    previous,
                    previous_sequence,
                    new: p,
                    sequence: previous_sequence.wrapping_add(1).max(1),
                })
            }
            None => None,
        };
        let tcp_written = Written {
            target: WriteTarget::Tcp,
            detail: format!(
                "set_tcp(p[{:.6}, {:.6}, {:.6}, {:.6}, {:.6}, {:.6}]), read back over RTDE",
                p[0], p[1], p[2], p[3], p[4], p[5]
            ),
        };
        let registers_written = registers.as_ref().map(|r| Written {
            target: WriteTarget::Registers,
            detail: format!(
                "input_double_register_{}..{} = x,y,z,rx,ry,rz (m, rad); input_int_register_{} = {}; read back",
                r.double_start,
                r.double_start + 5,
                r.sequence_int,
                r.sequence
            ),
        });
        let current_files = staged.as_ref().map(|s| s.file_names()).unwrap_or_default();
        let files_written = staged.as_ref().map(|_| Written {
            target: WriteTarget::Files,
            detail: current_files
                .iter()
                .map(|n| {
                    storage_dir
                        .join(storage::CURRENT_DIR)
                        .join(n)
                        .display()
                        .to_string()
                })
                .collect::<Vec<_>>()
                .join(", "),
        });
        // The record as it reads once everything is written: what the next start completes
        // when the program stops after the controller took the result.
        let mut done = self.record.clone();
        done.written.extend(
            set_tcp
                .then(|| tcp_written.clone())
                .into_iter()
                .chain(registers_written.clone())
                .chain(files_written.clone()),
        );
        let intent = journal::Intent {
            run_id: self.record.run_id.clone(),
            written_unix_s: unix_now(),
            tcp: previous_tcp.as_ref().map(|prev| journal::TcpChange {
                previous: UrPose::from(prev).values(),
                new: p,
            }),
            registers: registers.clone(),
            current_files,
            record: done,
        };
        intent
            .write(&storage_dir)
            .map_err(|e| kept("the write-back journal", e))?;
        self.journal = Some(lock);
        self.previous = Some(intent.previous());
        journal::pause_point("journal").await;
        if set_tcp {
            if let Err(e) = robot.set_tcp(unknown).await {
                return Err(self.undo(Failure::robot(stage, "setting the TCP", e)).await);
            }
            self.record.written.push(tcp_written);
            journal::pause_point("tcp").await;
        }
        if let (Some(r), Some(w)) = (&registers, registers_written) {
            if let Err(f) = self.write_registers(r).await {
                return Err(self.undo(f).await);
            }
            self.record.written.push(w);
        }
        // The record that describes what the controller now holds, before `current/` says so;
        // when it cannot be kept, the controller gets back what it held.
        if let Err(e) = storage::write_record(&self.run_dir, &self.record) {
            let undone = self.put_back().await;
            return Err(Failure::error(
                stage,
                format!("the result was written to the controller but the run record could not be written: {e}; {undone}; free space in the storage directory (`[storage] dir`) and run again"),
            ));
        }
        journal::pause_point("record").await;
        if let (Some(staged), Some(w)) = (staged, files_written) {
            match staged.commit() {
                Ok(_) => self.record.written.push(w),
                Err(e) => {
                    let what = format!("`current/` could not be replaced after the result was written to the controller: {e}");
                    let put_back = self.put_back().await;
                    return Err(Failure::error(stage, format!("{what}; {put_back}")));
                }
            }
            journal::pause_point("current").await;
        }
        Ok(())
    }

    /// Writes the result registers of `r`: the six doubles, then the sequence number (a
    /// pendant program waits for it, so it never applies a half-written set), then reads the
    /// set back. Not cancellable: it is a few requests and never stops half-way.
    async fn write_registers(&self, r: &journal::RegisterChange) -> Result<(), Failure> {
        let stage = Stage::WriteBack;
        let robot = self.robot;
        let failed = |what: &'static str| move |e: HalError| Failure::robot(stage, what, e);
        for (k, v) in r.new.iter().enumerate() {
            robot
                .write_double_register(r.double_start + k as u32, *v)
                .await
                .map_err(failed("writing the result registers"))?;
            journal::pause_point(&format!("register-{k}")).await;
        }
        robot
            .write_int_register(r.sequence_int, r.sequence)
            .await
            .map_err(failed("writing the sequence register"))?;
        journal::pause_point("sequence").await;
        let mut back = [0.0; 6];
        for (k, v) in back.iter_mut().enumerate() {
            *v = robot
                .read_double_register(r.double_start + k as u32)
                .await
                .map_err(failed("reading the result registers back"))?;
        }
        let seq = robot
            .read_int_register(r.sequence_int)
            .await
            .map_err(failed("reading the sequence register back"))?;
        if back != r.new || seq != r.sequence {
            return Err(Failure::error(
                stage,
                format!(
                    "the result registers read back {back:?} (sequence {seq}) instead of {:?} (sequence {}): another RTDE client writes them?",
                    r.new, r.sequence
                ),
            ));
        }
        Ok(())
    }

    /// `f` with what [`Self::put_back`] did about the partly written result.
    async fn undo(&mut self, mut f: Failure) -> Failure {
        let undone = self.put_back().await;
        f.message = format!("{}; {undone}", f.message);
        f
    }

    /// Puts back what the controller held before the write-back (see [`put_back`]); on
    /// success the record no longer lists the TCP and registers as written. Returns the
    /// sentence for the run's reasons.
    async fn put_back(&mut self) -> String {
        let Some(previous) = self.previous.take() else {
            return "nothing had been written to the controller".into();
        };
        restore_sentence(self.robot, &previous, &mut self.record).await
    }

    /// Moves back to the start when configured and the arm was commanded to move: from
    /// wherever it is now, along a path checked like every other. Never after a fault or a
    /// cancel (the caller does not call it then).
    async fn return_to_start(&mut self) {
        if !self.cfg.views.return_to_start || !self.moved {
            return;
        }
        let Some(start) = self
            .record
            .preflight
            .as_ref()
            .map(|p| p.start_joints.clone())
        else {
            return;
        };
        let t = Instant::now();
        self.progress
            .stage(Stage::Return, "moving back to the start");
        let here = match self.robot.joint_positions().await {
            Ok(q) => q,
            Err(e) => {
                self.record.reasons.push(format!(
                    "not moved back to the start: cannot read the joints: {}; the arm was left \
                     where the failed step stopped it: check where on the pendant",
                    error_chain(&e)
                ));
                return;
            }
        };
        journal::pause_point("return").await;
        let checked = self.planner().check_path(&here, &start, PATH_STEP_RAD);
        let result = match checked {
            Ok(Ok(_)) => {
                self.move_to(&start, Stage::Return, "move back to the start")
                    .await
            }
            Ok(Err(r)) => Err(Failure::error(
                Stage::Return,
                format!("not moved back to the start: the path is not safe ({r}); move the arm on the pendant"),
            )),
            Err(e) => Err(Failure::error(Stage::Return, error_chain(&e))),
        };
        match result {
            Ok(()) => self.record.returned_to_start = true,
            Err(f) => self.record.reasons.push(f.message),
        }
        self.record.timings_ms.return_move = elapsed_ms(t);
    }
}

/// Whether the arm can be the configured `model`: the name the controller reports
/// (`reported`, dashboard `get robot model`: the family, so it tells a UR10e from a UR5e but
/// not a UR5 from a UR5e), then its kinematics (`kinematics`: the controller's or the
/// calibration file's DH and which): they must be a calibration of the model's nominal ones.
/// Else what to configure, naming both.
pub fn check_model_matches(
    model: handeye_hal::ur_dh::UrModel,
    reported: Option<&str>,
    kinematics: Option<(&handeye_hal::ur_dh::DhParams, KinematicsOrigin)>,
) -> Result<(), String> {
    use handeye_hal::ur_dh::UrModel;
    if let Some(name) = reported {
        if !model.fits_reported_name(name) {
            // The reported family's models, narrowed by the kinematics when there are any.
            let by_kinematics = kinematics.map(|(dh, _)| UrModel::matching(dh));
            let fits: Vec<&str> = UrModel::ALL
                .into_iter()
                .filter(|m| m.fits_reported_name(name))
                .filter(|m| {
                    by_kinematics
                        .as_ref()
                        .is_none_or(|list| list.iter().any(|(k, _)| k == m))
                })
                .map(|m| m.name())
                .collect();
            let set = if fits.is_empty() {
                "set robot.model to the arm's model".to_string()
            } else {
                format!("set robot.model = \"{}\"", fits.join("\" or \""))
            };
            return Err(format!(
                "robot.model is {model} but the controller says the arm is a {} (dashboard \
                 `get robot model`); {set} (nothing moved)",
                handeye_hal::limits::Quoted(name)
            ));
        }
    }
    let Some((dh, source)) = kinematics else {
        return Ok(());
    };
    let matching = UrModel::matching(dh);
    if matching.iter().any(|(m, _)| *m == model) {
        return Ok(());
    }
    let off = model.dh().flange_distance(dh);
    let whose = if source == KinematicsOrigin::File {
        "the calibration file's kinematics are"
    } else {
        "the controller's kinematics are"
    };
    Err(match matching.first() {
        Some((found, _)) => format!(
            "robot.model is {model} but {whose} a {}'s (the flange {:.0} mm from a nominal \
             {model}'s); set robot.model = \"{found}\" (nothing moved)",
            matching
                .iter()
                .map(|(m, _)| m.name())
                .collect::<Vec<_>>()
                .join(" or "),
            off * 1e3
        ),
        None => format!(
            "robot.model is {model} but {whose} no UR model's (the flange {:.0} mm from a \
             nominal {model}'s); check the robot and its calibration (nothing moved)",
            off * 1e3
        ),
    })
}

/// Whether the robot may move: powered with brakes released, safety normal or reduced, in
/// remote control, no program running unless that program asked for the run (`handover`).
/// `allow_power_on`: whether the configuration lets handeye power the arm on (then a robot
/// still not running here could not be powered on).
fn preflight_status(
    st: &handeye_hal::RobotStatus,
    handover: bool,
    allow_power_on: bool,
) -> Result<(), Failure> {
    let stage = Stage::Preflight;
    let fail = |m: String| Err(Failure::error(stage, m));
    match st.safety_mode {
        SafetyMode::Normal | SafetyMode::Reduced => {}
        SafetyMode::ProtectiveStop => {
            return fail("the robot is in a protective stop; find out why, clear it on the pendant, then run again (handeye never clears it by itself)".into())
        }
        SafetyMode::RobotEmergencyStop | SafetyMode::SystemEmergencyStop => {
            return fail("an emergency stop is active; release it and re-enable the arm on the pendant".into())
        }
        other => {
            return fail(format!(
                "the robot's safety mode is {other:?}; bring it back to normal on the pendant"
            ))
        }
    }
    if st.robot_mode != RobotMode::Running {
        let or = if allow_power_on {
            ""
        } else {
            " (or set robot.allow_power_on = true to let handeye power it on and release the \
             brakes)"
        };
        return fail(format!(
            "the robot is not ready to move ({:?}); power it on and release the brakes on the \
             pendant{or}",
            st.robot_mode
        ));
    }
    if !st.remote_control {
        return fail(
            "the robot is in local control; enable Remote Control on the teach pendant".into(),
        );
    }
    if st.program_running && !handover {
        return fail(
            "a program is running on the controller; stop it on the pendant before calibrating"
                .into(),
        );
    }
    Ok(())
}
