//! The daemon (mini-redis shape): one task owns the robot and camera and runs one calibration
//! run at a time; triggers — startup, the schedule, the HTTP API, the CLI — ask through a
//! cloneable [`DaemonHandle`]. A trigger while a run is going is refused with who is busy since
//! when, or queued behind it (`daemon.when_busy`). Every run is recorded in the history store
//! before it starts and when it ends, so a crash leaves it marked as interrupted. One shutdown token stops everything: a running move
//! is stopped, the run recorded as aborted.
//!
//! State that survives restarts: at startup the last run, the last calibration, the last check
//! and the drift alarm are derived from the history (the same transition as a live run's end,
//! `State::apply`), so a restart shows what was true before it. The frontend serves from the
//! first second; while the robot or the camera is not reached yet (`waiting`) or known down
//! (the idle health check), runs are refused ([`Refusal::Unavailable`]).
//!
//! The binary builds the concrete robot and camera from the configuration (every move through
//! [`crate::guard::MotionGuard`]) and calls [`run_with`], whose `connect` reaches them; tests
//! with devices at hand call [`run`].

pub mod api;
pub mod arm;
pub mod control;
pub mod listener;
pub mod lock;
mod metrics;
mod notify;
mod pendant;

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use handeye_hal::{DepthCamera, Robot};
use serde::{Deserialize, Serialize};
use tokio::sync::Notify;
use tokio_util::sync::CancellationToken;

use crate::calendar::{unix_now, utc_text};
use crate::config::{Config, WhenBusy, QUEUE_LIMIT};
use crate::model::RobotModel;
use crate::record::{Outcome, RunMode, RunRecord, Stage, Trigger};
use crate::run::{Progress, Recorder, RunRequest};
use crate::storage::new_run_id;
use crate::store::Store;

/// The run in progress.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Current {
    /// Its id (also in the history).
    pub run_id: String,
    /// Calibrate or check.
    pub mode: RunMode,
    /// Who asked.
    pub trigger: Trigger,
    /// Unix time it was accepted, s.
    pub since_unix_s: f64,
    /// The stage it is in.
    pub stage: Option<Stage>,
    /// The stage's last progress line.
    pub detail: String,
}

/// A run's end, as the status shows it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Finished {
    /// Its id.
    pub run_id: String,
    /// Calibrate or check.
    pub mode: RunMode,
    /// Who asked.
    pub trigger: Trigger,
    /// How it ended.
    pub outcome: Outcome,
    /// The word every view uses for it ([`RunRecord::verdict`]): a check that measured the
    /// camera is `drifted` or `within limits`, any other run its outcome.
    #[serde(default)]
    pub verdict: String,
    /// Why (empty when accepted).
    pub reasons: Vec<String>,
    /// What the operator should know whatever the outcome ([`RunRecord::warnings`]): e.g. the
    /// current calibration was made on another arm.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// Unix time it ended, s.
    pub finished_unix_s: f64,
    /// The whole run, ms.
    pub duration_ms: f64,
    /// Check: the camera's change from the current calibration.
    pub drift: Option<Drift>,
}

impl Finished {
    /// How `record` (a `mode` run asked for by `trigger`) ended, as the status shows it.
    fn of(mode: RunMode, trigger: Trigger, record: &RunRecord) -> Finished {
        Finished {
            run_id: record.run_id.clone(),
            mode,
            trigger,
            outcome: record.outcome,
            verdict: record.verdict().to_string(),
            reasons: record.reasons.clone(),
            warnings: record.warnings.clone(),
            finished_unix_s: unix_now(),
            duration_ms: record.timings_ms.total,
            drift: record.drift.as_ref().map(|d| Drift {
                translation_mm: d.translation_mm,
                rotation_deg: d.rotation_deg,
                exceeded: d.drifted,
            }),
        }
    }
}

/// A check's measured change of the camera pose from the current calibration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Drift {
    /// Camera position change, mm.
    pub translation_mm: f64,
    /// Camera rotation change, degrees.
    pub rotation_deg: f64,
    /// Whether either of `[check]`'s thresholds is exceeded.
    pub exceeded: bool,
}

/// Whether the daemon runs something.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DaemonState {
    /// Waiting for a trigger.
    Idle,
    /// A run is going.
    Running,
    /// Shutting down.
    Stopping,
}

impl DaemonState {
    /// Lower-case name as in JSON.
    pub fn name(self) -> &'static str {
        match self {
            DaemonState::Idle => "idle",
            DaemonState::Running => "running",
            DaemonState::Stopping => "stopping",
        }
    }
}

/// What the daemon is doing: the API's `GET /api/status`, read back by `handeye status`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// `idle`, `running` or `stopping`.
    pub state: DaemonState,
    /// The run in progress.
    pub current: Option<Current>,
    /// Runs accepted behind it (`daemon.when_busy = "queue"`), next first.
    pub queued: Vec<Current>,
    /// The last run that ended.
    pub last: Option<Finished>,
    /// The last calibrate run that was accepted.
    pub last_calibration: Option<Finished>,
    /// The last check run that measured a drift.
    pub last_check: Option<Finished>,
    /// Whether the last check found drift (an alarm until a run clears it).
    pub drift_alarm: bool,
    /// Whether the robot answered its last status request.
    pub robot_connected: bool,
    /// Whether the camera answered its last request.
    pub camera_connected: bool,
    /// How often the robot's connection was re-established since the daemon started.
    pub robot_reconnects: u64,
    /// How often the camera's connection was re-established since the daemon started.
    pub camera_reconnects: u64,
    /// Unix time the daemon started, s.
    pub started_unix_s: f64,
    /// Why the storage directory cannot take a run (full, read-only); runs are refused
    /// until it can. `None`: it can.
    #[serde(default)]
    pub storage_problem: Option<String>,
    /// The damaged history file set aside when the daemon started (a new history was
    /// rebuilt from the run folders).
    #[serde(default)]
    pub history_set_aside: Option<crate::store::SetAside>,
    /// While the daemon has not reached the robot or the camera yet: what it waits for
    /// (`waiting for robot at 192.168.0.10 (attempt 4, next in 8 s): …`); runs are refused.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub waiting: Option<String>,
}

/// Why a trigger was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Refusal {
    /// A run is going.
    #[error(
        "busy: {mode} run {run_id} (asked by {trigger}) since {since}; cancel it \
         (`handeye cancel`) or wait",
        mode = mode.name(),
        trigger = trigger.name(),
        since = utc_text(*since_unix_s)
    )]
    Busy {
        /// The running run.
        run_id: String,
        /// Its mode.
        mode: RunMode,
        /// Who asked for it.
        trigger: Trigger,
        /// When it was accepted (unix s).
        since_unix_s: f64,
    },
    /// The daemon is shutting down.
    #[error("the daemon is shutting down; try again once it runs again")]
    ShuttingDown,
    /// The storage directory cannot take a run (full, read-only): nothing would be recorded.
    #[error("refused: {0}")]
    StorageUnusable(String),
    /// The robot or the camera is known to be down: the run would abort before moving.
    #[error("{reason}; the run would abort before moving, so it is not started")]
    Unavailable {
        /// What is down (`waiting for robot at …`, `the camera does not answer`).
        reason: String,
    },
    /// `when_busy = "queue"` and the queue is full.
    #[error("busy: {running} running and {queued} queued behind it (the most the daemon queues); cancel or wait")]
    QueueFull {
        /// The running run's id.
        running: String,
        /// How many wait.
        queued: usize,
    },
}

/// How often an idle daemon asks the robot and the camera whether they answer.
const HEALTH_EVERY: Duration = Duration::from_secs(5);
/// How long such a question may take.
const HEALTH_TIMEOUT: Duration = Duration::from_secs(3);
#[derive(Debug)]
struct State {
    /// The one queue: every run accepted and not ended, in order. The first is the current
    /// one (running, or about to); the others wait behind it.
    runs: VecDeque<Job>,
    last: Option<Finished>,
    last_calibration: Option<Finished>,
    last_check: Option<Finished>,
    drift_alarm: bool,
    robot_connected: bool,
    camera_connected: bool,
    links: (u64, u64),
    /// Why the storage directory cannot take a run, as last checked.
    storage_problem: Option<String>,
    /// The camera's resolution, once it answered: what a run keeps depends on it.
    camera_size: Option<(u32, u32)>,
    /// What the daemon waits for before it has the robot and the camera.
    waiting: Option<Waiting>,
    metrics: metrics::Metrics,
}

/// A device the daemon has not reached yet, and its next attempt.
#[derive(Debug, Clone)]
struct Waiting {
    /// `robot at 192.168.0.10`.
    what: String,
    /// Attempts so far.
    attempt: u32,
    /// When the next one starts.
    next: Instant,
    /// Why the last one failed.
    error: String,
}

impl Waiting {
    fn text(&self) -> String {
        let next = self.next.saturating_duration_since(Instant::now());
        format!(
            "waiting for {} (attempt {}, next in {} s): {}",
            self.what,
            self.attempt,
            next.as_secs_f64().ceil(),
            self.error
        )
    }
}

#[derive(Debug)]
struct Shared {
    state: Mutex<State>,
    /// Wakes the worker ([`run`]) when a run is accepted.
    wake: Notify,
    when_busy: WhenBusy,
    store: Arc<Store>,
    shutdown: CancellationToken,
    started_unix_s: f64,
}

/// One accepted trigger.
#[derive(Debug, Clone)]
struct Job {
    /// What the status shows of it (id, mode, trigger, stage).
    entry: Current,
    /// The program on the controller asked for the run (preflight accepts it running).
    handover: bool,
    /// A calibration that accepts a change beyond `gate.max_change_*` (a deliberate remount),
    /// and who accepted it.
    accept_change: Option<String>,
    /// Cancels it (a child of the shutdown token).
    cancel: CancellationToken,
}

/// A cheap, cloneable handle on the daemon: ask for runs, cancel, read the state.
#[derive(Debug, Clone)]
pub struct DaemonHandle {
    shared: Arc<Shared>,
}

impl DaemonHandle {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.shared.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Asks for a run. Returns its id at once (it runs in the background), or why not: one
    /// run at a time; while one runs, the next is refused or queued (`daemon.when_busy`).
    pub fn request(&self, mode: RunMode, trigger: Trigger) -> Result<String, Refusal> {
        self.enqueue(mode, trigger, false, None)
    }

    /// Asks for a calibration that accepts a result beyond `gate.max_change_*` from the
    /// previous one, because the camera was remounted on purpose; `by` says who accepted it
    /// (`api client 127.0.0.1`), for the record and the history.
    pub fn request_accepting_change(
        &self,
        trigger: Trigger,
        by: String,
    ) -> Result<String, Refusal> {
        self.enqueue(RunMode::Calibrate, trigger, false, Some(by))
    }

    /// Like [`Self::request`], for a program on the controller that asked for the run and
    /// hands the arm over (preflight accepts the program running).
    fn request_with_handover(&self, mode: RunMode, trigger: Trigger) -> Result<String, Refusal> {
        self.enqueue(mode, trigger, true, None)
    }

    fn enqueue(
        &self,
        mode: RunMode,
        trigger: Trigger,
        handover: bool,
        accept_change: Option<String>,
    ) -> Result<String, Refusal> {
        if self.shared.shutdown.is_cancelled() {
            return Err(Refusal::ShuttingDown);
        }
        let mut st = self.lock();
        if let Some(reason) = st.unavailable() {
            return Err(Refusal::Unavailable { reason });
        }
        if let Some(problem) = &st.storage_problem {
            return Err(Refusal::StorageUnusable(problem.clone()));
        }
        if let Some(Job { entry: c, .. }) = st.runs.front() {
            match self.shared.when_busy {
                WhenBusy::Refuse => {
                    return Err(Refusal::Busy {
                        run_id: c.run_id.clone(),
                        mode: c.mode,
                        trigger: c.trigger,
                        since_unix_s: c.since_unix_s,
                    })
                }
                WhenBusy::Queue if st.runs.len() > QUEUE_LIMIT => {
                    return Err(Refusal::QueueFull {
                        running: c.run_id.clone(),
                        queued: st.runs.len() - 1,
                    })
                }
                WhenBusy::Queue => {}
            }
        }
        let run_id = new_run_id();
        let entry = Current {
            run_id: run_id.clone(),
            mode,
            trigger,
            since_unix_s: unix_now(),
            stage: None,
            detail: "queued".into(),
        };
        if st.runs.is_empty() {
            tracing::info!(run_id = %run_id, trigger = trigger.name(), ?mode, "run accepted");
        } else {
            tracing::info!(run_id = %run_id, trigger = trigger.name(), ?mode, position = st.runs.len(), "run queued");
        }
        st.runs.push_back(Job {
            entry,
            handover,
            accept_change,
            cancel: self.shared.shutdown.child_token(),
        });
        self.shared.wake.notify_one();
        Ok(run_id)
    }

    /// Cancels the run in progress (the arm is stopped) and every queued one (recorded as
    /// aborted without moving); `false` when nothing runs.
    pub fn cancel(&self) -> bool {
        let st = self.lock();
        for job in &st.runs {
            job.cancel.cancel();
        }
        !st.runs.is_empty()
    }

    /// What the daemon is doing.
    pub fn status(&self) -> Status {
        let st = self.lock();
        Status {
            state: if self.shared.shutdown.is_cancelled() {
                DaemonState::Stopping
            } else if st.runs.is_empty() {
                DaemonState::Idle
            } else {
                DaemonState::Running
            },
            current: st.runs.front().map(|j| j.entry.clone()),
            queued: st.runs.iter().skip(1).map(|j| j.entry.clone()).collect(),
            last: st.last.clone(),
            last_calibration: st.last_calibration.clone(),
            last_check: st.last_check.clone(),
            drift_alarm: st.drift_alarm,
            robot_connected: st.robot_connected,
            camera_connected: st.camera_connected,
            robot_reconnects: st.links.0,
            camera_reconnects: st.links.1,
            started_unix_s: self.shared.started_unix_s,
            storage_problem: st.storage_problem.clone(),
            history_set_aside: self.shared.store.set_aside().cloned(),
            waiting: st.waiting.as_ref().map(Waiting::text),
        }
    }

    /// Says that the daemon waits for `what` (`robot at 192.168.0.10`): attempt `attempt`
    /// failed with `error`, the next starts in `retry_in`. The status shows it and runs are
    /// refused until [`run_with`]'s `connect` has returned the devices.
    pub fn waiting_for(&self, what: &str, attempt: u32, retry_in: Duration, error: &str) {
        let mut st = self.lock();
        st.waiting = Some(Waiting {
            what: what.to_string(),
            attempt,
            next: Instant::now() + retry_in,
            error: error.to_string(),
        });
    }

    /// The history.
    pub fn store(&self) -> &Arc<Store> {
        &self.shared.store
    }

    /// Whether the daemon is stopping.
    pub fn is_shutting_down(&self) -> bool {
        self.shared.shutdown.is_cancelled()
    }

    /// The metrics in the Prometheus text exposition format.
    pub fn metrics(&self) -> String {
        let st = self.lock();
        st.metrics.exposition(&metrics::Live {
            drift_alarm: st.drift_alarm,
            robot: (st.robot_connected, st.links.0),
            camera: (st.camera_connected, st.links.1),
            busy: !st.runs.is_empty(),
            queued: st.runs.len().saturating_sub(1),
            storage_usable: st.storage_problem.is_none(),
            last_check_unix_s: st.last_check.as_ref().map(|f| f.finished_unix_s),
            last_calibration_unix_s: st.last_calibration.as_ref().map(|f| f.finished_unix_s),
        })
    }

    /// The current run (the first in the queue), to be run next by the worker.
    fn next_job(&self) -> Option<Job> {
        self.lock().runs.front().cloned()
    }

    fn set_connections(&self, robot: bool, camera: bool, links: (u64, u64)) {
        let mut st = self.lock();
        if links.0 > st.links.0 {
            tracing::warn!(
                "the robot's connection was re-established ({} time(s) since the start)",
                links.0
            );
        }
        if links.1 > st.links.1 {
            tracing::warn!(
                "the camera's connection was re-established ({} time(s) since the start)",
                links.1
            );
        }
        st.links = links;
        if st.robot_connected != robot {
            tracing::warn!(
                "robot {}",
                if robot {
                    "answers again"
                } else {
                    "does not answer"
                }
            );
        }
        if st.camera_connected != camera {
            tracing::warn!(
                "camera {}",
                if camera {
                    "answers again"
                } else {
                    "does not answer"
                }
            );
        }
        st.robot_connected = robot;
        st.camera_connected = camera;
    }

    /// Notes whether the storage directory can take a run (logged when that changes).
    fn set_storage(&self, problem: Option<String>) {
        let mut st = self.lock();
        match (&st.storage_problem, &problem) {
            (None, Some(p)) => tracing::error!("storage unusable, runs are refused: {p}"),
            (Some(_), None) => tracing::warn!("storage usable again; runs are accepted"),
            _ => {}
        }
        st.storage_problem = problem;
    }

    fn set_stage(&self, stage: Stage, detail: &str) {
        let mut st = self.lock();
        if let Some(job) = st.runs.front_mut() {
            job.entry.stage = Some(stage);
            job.entry.detail = detail.to_string();
        }
    }

    /// Records how the current run ended; the next in the queue becomes the current one.
    fn finished(&self, job: &Job, record: &RunRecord) {
        let mut st = self.lock();
        let (mode, trigger) = (job.entry.mode, job.entry.trigger);
        let f = Finished::of(mode, trigger, record);
        st.metrics.record(trigger, record);
        if record.drift_found() == Some(true) {
            tracing::error!(
                run_id = %record.run_id,
                drift_mm = f.drift.map_or(f64::NAN, |d| d.translation_mm),
                drift_deg = f.drift.map_or(f64::NAN, |d| d.rotation_deg),
                "{ALARM} {RECALIBRATE}"
            );
        }
        st.apply(f, record.drift_found());
        if st
            .runs
            .front()
            .is_some_and(|j| j.entry.run_id == job.entry.run_id)
        {
            st.runs.pop_front();
        }
        if !st.runs.is_empty() {
            self.shared.wake.notify_one();
        }
    }

    /// Derives the last run, the last calibration, the last check and the drift alarm from
    /// the history, as they stood when the daemon (or any process on this storage) recorded
    /// its last run: a restart shows what was true before it. Reads the newest runs until
    /// both the newest accepted calibration and the newest check that measured drift are
    /// found (or the history ends).
    /// The shown runs' warnings come from their records in `storage` (the history keeps none).
    /// Shows the run whose interrupted write-back was just reconciled as the last one (it
    /// was, when the daemon stopped).
    fn reconciled(&self, record: &RunRecord) {
        let trigger = record.trigger.unwrap_or(Trigger::Cli);
        let f = Finished::of(record.mode, trigger, record);
        self.lock().apply(f, record.drift_found());
    }

    fn restore_from_history(
        &self,
        storage: &std::path::Path,
    ) -> Result<(), crate::store::StoreError> {
        // Newest first by the history's sequence, not the clock: more of it until both the
        // last calibration and the last check are in.
        let store = self.store();
        let mut newest_first = Vec::new();
        for limit in [200, 20_000, usize::MAX] {
            let page = store.list(limit, None)?;
            let done = page.len() < limit;
            newest_first = page;
            newest_first.retain(|r| r.outcome.outcome().is_some());
            let calibration = newest_first.iter().any(|r| {
                r.mode == RunMode::Calibrate && r.outcome.outcome() == Some(Outcome::Accepted)
            });
            let check = newest_first.iter().any(|r| r.drift_found().is_some());
            if done || (calibration && check) {
                break;
            }
        }
        let mut st = self.lock();
        for r in newest_first.iter().rev() {
            let Some(outcome) = r.outcome.outcome() else {
                continue;
            };
            st.metrics.restore(r);
            let drift = match (r.drift_translation_mm, r.drift_rotation_deg, r.drifted) {
                (Some(translation_mm), Some(rotation_deg), Some(exceeded)) => Some(Drift {
                    translation_mm,
                    rotation_deg,
                    exceeded,
                }),
                _ => None,
            };
            let f = Finished {
                run_id: r.run_id.clone(),
                mode: r.mode,
                trigger: r.trigger,
                outcome,
                verdict: r.verdict().to_string(),
                reasons: r.reason.iter().cloned().collect(),
                // The history keeps no warnings; the shown runs' records do (below).
                warnings: Vec::new(),
                finished_unix_s: r
                    .finished_unix_s
                    .unwrap_or(r.started_unix_s + r.duration_ms.unwrap_or(0.0) / 1e3),
                duration_ms: r.duration_ms.unwrap_or(0.0),
                drift,
            };
            st.apply(f, r.drift_found());
        }
        let st = &mut *st;
        for f in [&mut st.last, &mut st.last_calibration, &mut st.last_check]
            .into_iter()
            .flatten()
        {
            if let Some(record) = crate::storage::read_run_record(storage, &f.run_id) {
                f.warnings = record.warnings;
            }
        }
        if st.drift_alarm {
            let check = st.last_check.as_ref().map_or("", |c| c.run_id.as_str());
            tracing::error!(
                run_id = check,
                "ALARM (from the history): the last check found the camera drifted and no \
                 calibration was accepted since; {RECALIBRATE}"
            );
        }
        Ok(())
    }
}

/// The drift alarm's log line, before [`RECALIBRATE`].
pub const ALARM: &str = "ALARM: the camera has drifted from its calibration;";

/// The way out of the drift alarm, as the daemon can take it: the daemon's own triggers (a
/// command's `calibrate` is refused beside it, and its gate rejects a remount beyond
/// `gate.max_change_*` unless it is accepted as one).
pub const RECALIBRATE: &str = "recalibrate through the daemon: the Calibrate button on its \
     page, POST /api/calibrate (with the API token) or the pendant's calibrate request; if the \
     camera was remounted on purpose, the Accept remount button or POST \
     /api/calibrate/accept-change";

/// Whether the health check's `camera.info()` found the camera answering: it did when it
/// described itself, and when it refused what the configuration asks of it (a setting its
/// description cannot take, issue 44: a run's preflight then says what the camera refuses and
/// what to change, where "does not answer" would send the user to its power and cable).
fn camera_answers<E>(
    info: &Result<Result<handeye_hal::CameraInfo, handeye_hal::HalError>, E>,
) -> bool {
    matches!(
        info,
        Ok(Ok(_)) | Ok(Err(handeye_hal::HalError::Refused { .. }))
    )
}

impl State {
    /// Why a run cannot start now: the daemon still waits for a device, or the last health
    /// check found one not answering.
    fn unavailable(&self) -> Option<String> {
        if let Some(w) = &self.waiting {
            return Some(w.text());
        }
        match (self.robot_connected, self.camera_connected) {
            (true, true) => None,
            (false, true) => Some("the robot does not answer (see `handeye status`)".into()),
            (true, false) => Some("the camera does not answer (see `handeye status`)".into()),
            (false, false) => {
                Some("neither the robot nor the camera answers (see `handeye status`)".into())
            }
        }
    }

    /// What an ended run changes in the state: the last run; an accepted calibration is the
    /// new reference (no drift from it, the alarm goes off); a check that measured drift
    /// sets the alarm on or off. `drift_found` is [`RunRecord::drift_found`]. Live runs and
    /// the history replayed at startup both go through here.
    fn apply(&mut self, f: Finished, drift_found: Option<bool>) {
        if f.outcome == Outcome::Accepted && f.mode == RunMode::Calibrate {
            self.last_calibration = Some(f.clone());
            self.drift_alarm = false;
        }
        if let Some(drifted) = drift_found {
            self.drift_alarm = drifted;
            self.last_check = Some(f.clone());
        }
        self.last = Some(f);
    }
}

/// Progress of the current run into the daemon's state (and the log).
struct StageReporter<'a> {
    handle: &'a DaemonHandle,
}

impl Progress for StageReporter<'_> {
    fn stage(&self, stage: Stage, detail: &str) {
        tracing::debug!(stage = stage.name(), "{detail}");
        self.handle.set_stage(stage, detail);
    }
}

/// Creates the handle and the job queue (the worker side is [`run`]).
fn handle(store: Arc<Store>, when_busy: WhenBusy, shutdown: CancellationToken) -> DaemonHandle {
    let shared = Arc::new(Shared {
        state: Mutex::new(State {
            runs: VecDeque::new(),
            last: None,
            last_calibration: None,
            last_check: None,
            drift_alarm: false,
            robot_connected: true,
            camera_connected: true,
            links: (0, 0),
            storage_problem: None,
            camera_size: None,
            waiting: None,
            metrics: metrics::Metrics::default(),
        }),
        wake: Notify::new(),
        when_busy,
        store,
        shutdown,
        started_unix_s: unix_now(),
    });
    DaemonHandle { shared }
}

/// What the daemon serves besides the runs (the binary's HTTP server); started with the handle
/// once the daemon is up.
pub trait Frontend: Send + 'static {
    /// Serves until `shutdown`.
    fn serve(
        self,
        handle: DaemonHandle,
        shutdown: CancellationToken,
    ) -> impl std::future::Future<Output = ()> + Send;
}

/// No frontend (tests).
#[derive(Debug, Clone, Copy, Default)]
pub struct NoFrontend;

impl Frontend for NoFrontend {
    async fn serve(self, _: DaemonHandle, shutdown: CancellationToken) {
        shutdown.cancelled().await;
    }
}

/// Runs the daemon until `shutdown` on a robot and a camera already connected: [`run_with`]
/// with a `connect` that hands them over at once.
#[allow(clippy::too_many_arguments)]
pub async fn run<R: Robot, C: DepthCamera, F: Frontend>(
    cfg: Config,
    model: Arc<RobotModel>,
    robot: R,
    camera: C,
    store: Arc<Store>,
    frontend: F,
    shutdown: CancellationToken,
    ready: impl FnOnce(&DaemonHandle),
) {
    let devices = |_: DaemonHandle| async move { Some((robot, camera)) };
    run_with(cfg, model, devices, store, frontend, shutdown, ready).await;
}

/// Runs the daemon until `shutdown`: the history's last state, the frontend (serving from
/// the first second), then `connect` for the robot and the camera (it reports its attempts
/// through [`DaemonHandle::waiting_for`] and returns `None` on shutdown), then the startup run,
/// the schedule and every accepted trigger, one run at a time, each recorded in `store`.
/// `ready` is called once the devices are there. Returns when the run in progress (if any)
/// has ended and been recorded.
pub async fn run_with<R, C, F, Fut>(
    cfg: Config,
    model: Arc<RobotModel>,
    connect: impl FnOnce(DaemonHandle) -> Fut,
    store: Arc<Store>,
    frontend: F,
    shutdown: CancellationToken,
    ready: impl FnOnce(&DaemonHandle),
) where
    R: Robot,
    C: DepthCamera,
    F: Frontend,
    Fut: std::future::Future<Output = Option<(R, C)>>,
{
    let handle = handle(store, cfg.daemon.when_busy, shutdown.clone());
    if let Err(e) = handle.restore_from_history(&cfg.storage.dir) {
        tracing::error!(
            "cannot read the last runs from the history ({e}); the status starts empty and the \
             drift alarm off until the next check"
        );
    }
    check_storage(&cfg, &handle).await;
    let notifier = notify::Notifier::from_env();
    let frontend_task = tokio::spawn(frontend.serve(handle.clone(), shutdown.clone()));
    let control_task = tokio::spawn(control::serve(
        cfg.storage.dir.clone(),
        handle.clone(),
        shutdown.clone(),
    ));
    if let Some(n) = &notifier {
        if n.watchdog_interval().is_some() {
            if let Some(w) = notify::Notifier::from_env() {
                tokio::spawn(notify::feed_watchdog(w, shutdown.clone()));
            }
        }
        n.ready();
    }
    {
        let mut st = handle.lock();
        st.robot_connected = false;
        st.camera_connected = false;
    }
    let Some((robot, camera)) = connect(handle.clone()).await else {
        if let Some(n) = &notifier {
            n.stopping();
        }
        let _ = frontend_task.await;
        let _ = control_task.await;
        return;
    };
    {
        let mut st = handle.lock();
        st.waiting = None;
        st.robot_connected = true;
        st.camera_connected = true;
    }
    tracing::info!("robot and camera connected");
    // What a run keeps depends on the camera's resolution: the storage is checked for it.
    if let Ok(Ok(info)) = tokio::time::timeout(HEALTH_TIMEOUT, camera.info()).await {
        handle.lock().camera_size = Some((info.width, info.height));
        check_storage(&cfg, &handle).await;
    }
    // A write-back interrupted by the last stop is reconciled before anything else runs.
    match crate::run::journal::reconcile(
        &robot,
        &cfg.storage.dir,
        cfg.write_back.registers,
        Some(handle.store().as_ref()),
    )
    .await
    {
        Ok(Some(record)) => handle.reconciled(&record),
        Ok(None) => {}
        Err(e) => tracing::error!("{e}"),
    }
    ready(&handle);
    if let Some(mode) = cfg.daemon.startup {
        if let Err(e) = handle.request(mode, Trigger::Startup) {
            tracing::warn!("startup run not started: {e}");
        }
    }
    let schedule = cfg.daemon.check_interval.map(|every| {
        let mut t = tokio::time::interval_at(tokio::time::Instant::now() + every, every);
        t.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        t
    });
    let mut schedule = schedule;
    let next_calendar = || {
        crate::calendar::next_after(
            &cfg.daemon.check_at,
            unix_now().floor() as i64,
            crate::calendar::local_offset_s,
        )
    };
    let mut calendar_due = next_calendar();
    if let Some(due) = calendar_due {
        tracing::info!(
            "next scheduled check at {} (daemon.check_at)",
            utc_text(due as f64)
        );
    }
    let mut pendant_poll = tokio::time::interval(pendant::POLL);
    pendant_poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut pendant = cfg.daemon.pendant.map(pendant::Pendant::new);
    let mut health = tokio::time::interval(HEALTH_EVERY);
    health.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        let tick = async {
            match &mut schedule {
                Some(t) => {
                    t.tick().await;
                }
                None => std::future::pending::<()>().await,
            }
        };
        // The wall clock is asked again at least every 30 s: a clock set forward or back (NTP,
        // daylight saving) moves the calendar's next check with it.
        let calendar = async {
            match calendar_due {
                Some(due) => {
                    let wait = (due as f64 - unix_now()).clamp(0.0, 30.0);
                    tokio::time::sleep(Duration::from_secs_f64(wait)).await;
                }
                None => std::future::pending::<()>().await,
            }
        };
        tokio::select! {
            biased;
            _ = shutdown.cancelled() => break,
            _ = handle.shared.wake.notified() => {
                let Some(job) = handle.next_job() else { continue };
                // The pendant is served while the run goes: a request then is answered at once.
                let record = {
                    let run = execute(&cfg, &model, &robot, &camera, &handle, &job);
                    let serve_pendant = async {
                        match &mut pendant {
                            Some(p) => loop {
                                pendant_poll.tick().await;
                                p.poll(&robot, &handle).await;
                            },
                            None => std::future::pending::<RunRecord>().await,
                        }
                    };
                    tokio::select! {
                        biased;
                        record = run => record,
                        never = serve_pendant => never,
                    }
                };
                if let Some(n) = &notifier {
                    n.status(&format!("last run {}: {}", record.run_id, record.outcome));
                }
                if let Some(p) = &mut pendant {
                    p.finished(&robot, &record.run_id, record.outcome).await;
                }
                if job.entry.trigger == Trigger::Schedule
                    && record.drift_found() == Some(true)
                    && cfg.daemon.recalibrate_on_drift
                    && !shutdown.is_cancelled()
                {
                    if let Err(e) = handle.request(RunMode::Calibrate, Trigger::Drift) {
                        tracing::warn!("recalibration after drift not started: {e}");
                    }
                }
            }
            _ = pendant_poll.tick(), if pendant.is_some() => {
                if let Some(p) = &mut pendant {
                    p.poll(&robot, &handle).await;
                }
            }
            _ = health.tick() => {
                check_storage(&cfg, &handle).await;
                if handle.status().current.is_none() {
                    let robot_up = tokio::time::timeout(HEALTH_TIMEOUT, robot.status()).await.is_ok_and(|r| r.is_ok());
                    let info = tokio::time::timeout(HEALTH_TIMEOUT, camera.info()).await;
                    let camera_up = camera_answers(&info);
                    if let Ok(Ok(info)) = info {
                        handle.lock().camera_size = Some((info.width, info.height));
                    }
                    handle.set_connections(robot_up, camera_up, (robot.link_generation(), camera.link_generation()));
                }
            }
            _ = tick => scheduled_check(&robot, &handle).await,
            _ = calendar => {
                if calendar_due.is_some_and(|due| unix_now() >= due as f64) {
                    scheduled_check(&robot, &handle).await;
                    calendar_due = next_calendar();
                }
            }
        }
    }
    if let Some(n) = &notifier {
        n.stopping();
    }
    // A job accepted just before the shutdown is recorded as never started.
    while let Some(job) = handle.next_job() {
        let record = execute(&cfg, &model, &robot, &camera, &handle, &job).await;
        tracing::info!(run_id = %record.run_id, "run accepted before the shutdown: {}", record.outcome);
        if let Some(p) = &mut pendant {
            p.finished(&robot, &record.run_id, record.outcome).await;
        }
    }
    let _ = frontend_task.await;
    let _ = control_task.await;
}

/// Checks that the storage directory can take a run ([`crate::storage::check_room`] for
/// [`crate::storage::RUN_BASE_BYTES`]) and notes it in the state: runs are refused while it
/// cannot (each run checks again for its scans before it moves).
async fn check_storage(cfg: &Config, handle: &DaemonHandle) {
    let dir = cfg.storage.dir.clone();
    let needed = run_bytes(cfg, handle.lock().camera_size);
    let checked =
        tokio::task::spawn_blocking(move || crate::storage::check_room(&dir, needed)).await;
    let problem = match checked {
        Ok(Ok(())) => None,
        Ok(Err(e)) => Some(e.to_string()),
        Err(e) => Some(format!("the storage check failed: {e}")),
    };
    handle.set_storage(problem);
}

/// The journal's one line on how a run ended: verdict, duration, and the drift (a check),
/// the uncertainty (an accepted calibration) or the first reason (anything not accepted).
/// What the configured run keeps in storage at most ([`crate::storage::run_bytes`]): its raw
/// scans at the camera's resolution (`camera_size`, once known) × frames × views, plus the
/// record, exports and picture.
fn run_bytes(cfg: &Config, camera_size: Option<(u32, u32)>) -> u64 {
    let views = match &cfg.views.targets {
        crate::config::ViewTargets::Joints(q) => q.len(),
        crate::config::ViewTargets::Auto { count, .. } => *count,
    };
    let frames = views * cfg.camera.capture.frames as usize;
    let (width, height) = camera_size.unwrap_or((0, 0));
    crate::storage::run_bytes(width, height, frames, cfg.storage.keep_captures)
}

fn outcome_line(record: &RunRecord, took: Duration) -> String {
    let mut line = format!(
        "run {} ended: {} {} in {:.1} s",
        record.run_id,
        record.mode.name(),
        record.verdict(),
        took.as_secs_f64()
    );
    if let Some(d) = &record.drift {
        line += &format!(
            "; drift {:.3} mm / {:.4}° (limits {} mm / {}°)",
            d.translation_mm, d.rotation_deg, d.max_translation_mm, d.max_rotation_deg
        );
    }
    if let (Outcome::Accepted, Some(r)) = (record.outcome, &record.result) {
        line += &format!(
            "; uncertainty {:.3} mm / {:.4}°{}",
            r.uncertainty.translation_mm,
            r.uncertainty.rotation_deg,
            r.uncertainty.workspace_note()
        );
    }
    if let Some(reason) = record.reasons.first() {
        line += &format!("; {reason}");
    }
    line
}

/// A scheduled drift check: started when the robot is idle, else skipped (logged).
async fn scheduled_check<R: Robot>(robot: &R, handle: &DaemonHandle) {
    if robot_idle(robot).await {
        if let Err(e) = handle.request(RunMode::Check, Trigger::Schedule) {
            tracing::info!("scheduled check skipped: {e}");
        }
    } else {
        tracing::info!("scheduled check skipped: a program is running on the controller");
    }
}

/// Whether no program is running on the controller (scheduled checks wait for that).
async fn robot_idle<R: Robot>(robot: &R) -> bool {
    matches!(robot.status().await, Ok(s) if !s.program_running)
}

/// One job, run by the recorder (history row, record, picture, pruning).
async fn execute<R: Robot, C: DepthCamera>(
    cfg: &Config,
    model: &Arc<RobotModel>,
    robot: &R,
    camera: &C,
    handle: &DaemonHandle,
    job: &Job,
) -> RunRecord {
    let t0 = Instant::now();
    let req = RunRequest {
        mode: job.entry.mode,
        dry_run: false,
        run_id: Some(job.entry.run_id.clone()),
        program_handover: job.handover,
        accept_change: job.accept_change.clone(),
    };
    let trigger = job.entry.trigger;
    tracing::info!(
        "run {} started: {} asked by {}",
        job.entry.run_id,
        job.entry.mode.name(),
        trigger.name()
    );
    let span = tracing::info_span!("run", trigger = trigger.name());
    let progress = StageReporter { handle };
    let recorder = Recorder::new(Arc::clone(handle.store()), trigger);
    let record = tracing::Instrument::instrument(
        recorder.run(robot, camera, model, cfg, req, &job.cancel, &progress),
        span,
    )
    .await;
    let line = outcome_line(&record, t0.elapsed());
    match record.outcome {
        Outcome::Accepted | Outcome::Planned => tracing::info!("{line}"),
        _ => tracing::warn!("{line}"),
    }
    handle.finished(job, &record);
    record
}

#[cfg(test)]
mod tests;
