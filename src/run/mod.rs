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

mod capture;
mod clock;
mod forecast;
pub mod journal;
mod preflight;
pub mod recorder;
#[cfg(test)]
mod tests;
mod views;
mod writeback;

pub(crate) use writeback::{put_back, Previous};

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
    joint_span, CancelCheck, PlanError, ViewConstraints, ViewPlanner, ViewRejection,
    FIRST_VIEW_SPAN_RAD,
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
    /// Where the arm stood at preflight; `None` before it.
    fn start_joints(&self) -> Option<Vec<f64>> {
        self.record
            .preflight
            .as_ref()
            .map(|p| p.start_joints.clone())
    }

    /// The planned views' joint targets, in order.
    fn planned_joints(&self) -> Vec<Vec<f64>> {
        self.record.views.iter().map(|v| v.joints.clone()).collect()
    }

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

    /// Moves back to the start when configured and the arm was commanded to move: from
    /// wherever it is now, along a path checked like every other. Never after a fault or a
    /// cancel (the caller does not call it then).
    async fn return_to_start(&mut self) {
        if !self.cfg.views.return_to_start || !self.moved {
            return;
        }
        let Some(start) = self.start_joints() else {
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
