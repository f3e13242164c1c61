//! The cloneable handle on the daemon and what it guards: the one queue of accepted runs, the
//! state the status shows, the refusals of a trigger and the drift alarm's words.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::sync::Notify;
use tokio_util::sync::CancellationToken;

use super::metrics;
use super::status::{Current, DaemonState, Drift, Finished, Status};
use crate::calendar::{unix_now, utc_text};
use crate::config::{WhenBusy, QUEUE_LIMIT};
use crate::record::{Outcome, RunMode, RunRecord, Stage, Trigger};
use crate::storage::new_run_id;
use crate::store::Store;

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

#[derive(Debug)]
pub(super) struct State {
    /// The one queue: every run accepted and not ended, in order. The first is the current
    /// one (running, or about to); the others wait behind it.
    pub(super) runs: VecDeque<Job>,
    pub(super) last: Option<Finished>,
    pub(super) last_calibration: Option<Finished>,
    pub(super) last_check: Option<Finished>,
    pub(super) drift_alarm: bool,
    pub(super) robot_connected: bool,
    pub(super) camera_connected: bool,
    pub(super) links: (u64, u64),
    /// Why the storage directory cannot take a run, as last checked.
    pub(super) storage_problem: Option<String>,
    /// The camera's resolution, once it answered: what a run keeps depends on it.
    pub(super) camera_size: Option<(u32, u32)>,
    /// What the daemon waits for before it has the robot and the camera.
    pub(super) waiting: Option<Waiting>,
    pub(super) metrics: metrics::Metrics,
}

/// A device the daemon has not reached yet, and its next attempt.
#[derive(Debug, Clone)]
pub(super) struct Waiting {
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
pub(super) struct Shared {
    pub(super) state: Mutex<State>,
    /// Wakes the worker ([`run`](super::run)) when a run is accepted.
    pub(super) wake: Notify,
    pub(super) when_busy: WhenBusy,
    pub(super) store: Arc<Store>,
    pub(super) shutdown: CancellationToken,
    pub(super) started_unix_s: f64,
}

/// One accepted trigger.
#[derive(Debug, Clone)]
pub(super) struct Job {
    /// What the status shows of it (id, mode, trigger, stage).
    pub(super) entry: Current,
    /// The program on the controller asked for the run (preflight accepts it running).
    pub(super) handover: bool,
    /// A calibration that accepts a change beyond `gate.max_change_*` (a deliberate remount),
    /// and who accepted it.
    pub(super) accept_change: Option<String>,
    /// Cancels it (a child of the shutdown token).
    pub(super) cancel: CancellationToken,
}

/// A cheap, cloneable handle on the daemon: ask for runs, cancel, read the state.
#[derive(Debug, Clone)]
pub struct DaemonHandle {
    pub(super) shared: Arc<Shared>,
}

impl DaemonHandle {
    pub(super) fn lock(&self) -> MutexGuard<'_, State> {
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
    pub(super) fn request_with_handover(
        &self,
        mode: RunMode,
        trigger: Trigger,
    ) -> Result<String, Refusal> {
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
    /// refused until [`run_with`](super::run_with)'s `connect` has returned the devices.
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
    pub(super) fn next_job(&self) -> Option<Job> {
        self.lock().runs.front().cloned()
    }

    pub(super) fn set_connections(&self, robot: bool, camera: bool, links: (u64, u64)) {
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
    pub(super) fn set_storage(&self, problem: Option<String>) {
        let mut st = self.lock();
        match (&st.storage_problem, &problem) {
            (None, Some(p)) => tracing::error!("storage unusable, runs are refused: {p}"),
            (Some(_), None) => tracing::warn!("storage usable again; runs are accepted"),
            _ => {}
        }
        st.storage_problem = problem;
    }

    pub(super) fn set_stage(&self, stage: Stage, detail: &str) {
        let mut st = self.lock();
        if let Some(job) = st.runs.front_mut() {
            job.entry.stage = Some(stage);
            job.entry.detail = detail.to_string();
        }
    }

    /// Records how the current run ended; the next in the queue becomes the current one.
    pub(super) fn finished(&self, job: &Job, record: &RunRecord) {
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
    pub(super) fn reconciled(&self, record: &RunRecord) {
        let trigger = record.trigger.unwrap_or(Trigger::Cli);
        let f = Finished::of(record.mode, trigger, record);
        self.lock().apply(f, record.drift_found());
    }

    pub(super) fn restore_from_history(
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

/// Creates the handle and the job queue (the worker side is [`run`](super::run)).
pub(super) fn handle(
    store: Arc<Store>,
    when_busy: WhenBusy,
    shutdown: CancellationToken,
) -> DaemonHandle {
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
