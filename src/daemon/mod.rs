//! The daemon (mini-redis shape): one task owns the robot and camera and runs one calibration
//! run at a time; triggers — startup, the schedule, the HTTP API, the CLI — ask through a
//! cloneable [`DaemonHandle`]. A trigger while a run is going is refused with who is busy since
//! when, or queued behind it (`daemon.when_busy`). Every run is recorded in the history store
//! before it starts and when it ends, so a crash leaves it marked as interrupted. One shutdown token stops everything: a running move
//! is stopped, the run recorded as aborted.
//!
//! The binary builds the concrete robot and camera from the configuration and calls [`run`].

pub mod api;
mod notify;

use std::fmt::Write as _;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use handeye_hal::{DepthCamera, Robot};
use serde::Serialize;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

use crate::calendar::{unix_now, utc_text};
use crate::config::{Config, WhenBusy};
use crate::model::RobotModel;
use crate::record::{Outcome, RunMode, RunRecord, Stage, Trigger};
use crate::run::{Progress, Recorder, RunRequest};
use crate::storage::new_run_id;
use crate::store::Store;

/// The run in progress.
#[derive(Debug, Clone, PartialEq, Serialize)]
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
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Finished {
    /// Its id.
    pub run_id: String,
    /// Calibrate or check.
    pub mode: RunMode,
    /// Who asked.
    pub trigger: Trigger,
    /// How it ended.
    pub outcome: Outcome,
    /// Why (empty when accepted).
    pub reasons: Vec<String>,
    /// Unix time it ended, s.
    pub finished_unix_s: f64,
    /// The whole run, ms.
    pub duration_ms: f64,
    /// Check: the drift, mm and degrees, and whether it exceeds the thresholds.
    pub drift: Option<(f64, f64, bool)>,
}

/// What the daemon is doing; the API's `/api/status`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Status {
    /// `idle`, `running` or `stopping`.
    pub state: &'static str,
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
}

/// Why a trigger was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Refusal {
    /// A run is going.
    #[error("busy: {mode:?} run {run_id} (asked by {trigger}) since {since_unix_s:.0}; cancel it or wait", trigger = trigger.name())]
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
    #[error("the daemon is shutting down")]
    ShuttingDown,
    /// `when_busy = "queue"` and the queue is full.
    #[error("busy: {running} running and {queued} queued behind it (the most the daemon queues); cancel or wait")]
    QueueFull {
        /// The running run's id.
        running: String,
        /// How many wait.
        queued: usize,
    },
}

/// The most runs `daemon.when_busy = "queue"` keeps waiting behind the running one.
pub const QUEUE_LIMIT: usize = 4;

/// Counters for `/metrics`.
#[derive(Debug, Default, Clone)]
struct Metrics {
    /// Runs by (trigger, outcome).
    runs: Vec<((Trigger, Outcome), u64)>,
    /// Durations of every finished run, s, bucketed.
    duration_buckets: [u64; DURATION_BUCKETS.len()],
    duration_sum_s: f64,
    duration_count: u64,
    last_uncertainty_mm: Option<f64>,
    last_uncertainty_deg: Option<f64>,
    last_drift_mm: Option<f64>,
    last_drift_deg: Option<f64>,
    alarms: u64,
}

/// How often an idle daemon asks the robot and the camera whether they answer.
const HEALTH_EVERY: Duration = Duration::from_secs(5);
/// How long such a question may take.
const HEALTH_TIMEOUT: Duration = Duration::from_secs(3);
/// Upper bounds of the run-duration histogram, s.
const DURATION_BUCKETS: [f64; 8] = [1.0, 2.5, 5.0, 10.0, 20.0, 30.0, 60.0, 120.0];

#[derive(Debug)]
struct State {
    /// The run in progress and the token that cancels it.
    current: Option<(Current, CancellationToken)>,
    /// Accepted behind `current`, in the order the job channel delivers them.
    queued: std::collections::VecDeque<(Current, CancellationToken)>,
    last: Option<Finished>,
    last_calibration: Option<Finished>,
    last_check: Option<Finished>,
    drift_alarm: bool,
    robot_connected: bool,
    camera_connected: bool,
    links: (u64, u64),
    metrics: Metrics,
}

#[derive(Debug)]
struct Shared {
    state: Mutex<State>,
    queue: mpsc::Sender<Job>,
    when_busy: WhenBusy,
    store: Arc<Store>,
    shutdown: CancellationToken,
    started_unix_s: f64,
}

/// One accepted trigger.
#[derive(Debug)]
struct Job {
    run_id: String,
    mode: RunMode,
    trigger: Trigger,
    /// The program on the controller asked for the run (preflight accepts it running).
    handover: bool,
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
        self.enqueue(mode, trigger, false)
    }

    /// Like [`Self::request`], for a program on the controller that asked for the run and
    /// hands the arm over (preflight accepts the program running).
    fn request_with_handover(&self, mode: RunMode, trigger: Trigger) -> Result<String, Refusal> {
        self.enqueue(mode, trigger, true)
    }

    fn enqueue(&self, mode: RunMode, trigger: Trigger, handover: bool) -> Result<String, Refusal> {
        if self.shared.shutdown.is_cancelled() {
            return Err(Refusal::ShuttingDown);
        }
        let mut st = self.lock();
        if let Some((c, _)) = &st.current {
            match self.shared.when_busy {
                WhenBusy::Refuse => {
                    return Err(Refusal::Busy {
                        run_id: c.run_id.clone(),
                        mode: c.mode,
                        trigger: c.trigger,
                        since_unix_s: c.since_unix_s,
                    })
                }
                WhenBusy::Queue if st.queued.len() >= QUEUE_LIMIT => {
                    return Err(Refusal::QueueFull {
                        running: c.run_id.clone(),
                        queued: st.queued.len(),
                    })
                }
                WhenBusy::Queue => {}
            }
        }
        let run_id = new_run_id();
        let cancel = self.shared.shutdown.child_token();
        let job = Job {
            run_id: run_id.clone(),
            mode,
            trigger,
            handover,
            cancel: cancel.clone(),
        };
        // The channel holds the running job and the queue; the state above bounds both.
        self.shared
            .queue
            .try_send(job)
            .map_err(|_| Refusal::ShuttingDown)?;
        let entry = Current {
            run_id: run_id.clone(),
            mode,
            trigger,
            since_unix_s: unix_now(),
            stage: None,
            detail: "queued".into(),
        };
        if st.current.is_some() {
            tracing::info!(run_id = %run_id, trigger = trigger.name(), ?mode, position = st.queued.len() + 1, "run queued");
            st.queued.push_back((entry, cancel));
        } else {
            tracing::info!(run_id = %run_id, trigger = trigger.name(), ?mode, "run accepted");
            st.current = Some((entry, cancel));
        }
        Ok(run_id)
    }

    /// Cancels the run in progress (the arm is stopped) and every queued one (recorded as
    /// aborted without moving); `false` when nothing runs.
    pub fn cancel(&self) -> bool {
        let st = self.lock();
        for (_, c) in st.current.iter().chain(&st.queued) {
            c.cancel();
        }
        st.current.is_some()
    }

    /// What the daemon is doing.
    pub fn status(&self) -> Status {
        let st = self.lock();
        Status {
            state: if self.shared.shutdown.is_cancelled() {
                "stopping"
            } else if st.current.is_some() {
                "running"
            } else {
                "idle"
            },
            current: st.current.as_ref().map(|(c, _)| c.clone()),
            queued: st.queued.iter().map(|(c, _)| c.clone()).collect(),
            last: st.last.clone(),
            last_calibration: st.last_calibration.clone(),
            last_check: st.last_check.clone(),
            drift_alarm: st.drift_alarm,
            robot_connected: st.robot_connected,
            camera_connected: st.camera_connected,
            robot_reconnects: st.links.0,
            camera_reconnects: st.links.1,
            started_unix_s: self.shared.started_unix_s,
        }
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
        let m = &st.metrics;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# HELP handeye_runs_total Calibration runs by trigger and outcome."
        );
        let _ = writeln!(s, "# TYPE handeye_runs_total counter");
        for ((trigger, outcome), n) in &m.runs {
            let _ = writeln!(
                s,
                "handeye_runs_total{{trigger=\"{}\",outcome=\"{}\"}} {n}",
                trigger.name(),
                outcome.name()
            );
        }
        let _ = writeln!(
            s,
            "# HELP handeye_run_duration_seconds Duration of a run, start to end."
        );
        let _ = writeln!(s, "# TYPE handeye_run_duration_seconds histogram");
        let mut cumulative = 0;
        for (le, n) in DURATION_BUCKETS.iter().zip(m.duration_buckets) {
            cumulative += n;
            let _ = writeln!(
                s,
                "handeye_run_duration_seconds_bucket{{le=\"{le}\"}} {cumulative}"
            );
        }
        let _ = writeln!(
            s,
            "handeye_run_duration_seconds_bucket{{le=\"+Inf\"}} {}",
            m.duration_count
        );
        let _ = writeln!(s, "handeye_run_duration_seconds_sum {}", m.duration_sum_s);
        let _ = writeln!(s, "handeye_run_duration_seconds_count {}", m.duration_count);
        let gauge = |s: &mut String, name: &str, help: &str, v: Option<f64>| {
            let _ = writeln!(s, "# HELP {name} {help}");
            let _ = writeln!(s, "# TYPE {name} gauge");
            let _ = writeln!(s, "{name} {}", v.unwrap_or(f64::NAN));
        };
        gauge(
            &mut s,
            "handeye_last_calibration_uncertainty_mm",
            "Reported 1-sigma translation uncertainty of the last accepted calibration, mm.",
            m.last_uncertainty_mm,
        );
        gauge(
            &mut s,
            "handeye_last_calibration_uncertainty_degrees",
            "Reported 1-sigma rotation uncertainty of the last accepted calibration, degrees.",
            m.last_uncertainty_deg,
        );
        gauge(
            &mut s,
            "handeye_last_drift_mm",
            "Camera position drift found by the last check, mm.",
            m.last_drift_mm,
        );
        gauge(
            &mut s,
            "handeye_last_drift_degrees",
            "Camera rotation drift found by the last check, degrees.",
            m.last_drift_deg,
        );
        gauge(
            &mut s,
            "handeye_drift_alarm",
            "1 while the last check found drift beyond the thresholds.",
            Some(f64::from(u8::from(st.drift_alarm))),
        );
        let _ = writeln!(s, "# HELP handeye_alarms_total Drift alarms raised.");
        let _ = writeln!(s, "# TYPE handeye_alarms_total counter");
        let _ = writeln!(s, "handeye_alarms_total {}", m.alarms);
        for (name, up, reconnects) in [
            ("robot", st.robot_connected, st.links.0),
            ("camera", st.camera_connected, st.links.1),
        ] {
            let _ = writeln!(
                s,
                "# HELP handeye_{name}_connected 1 when the {name} answers."
            );
            let _ = writeln!(s, "# TYPE handeye_{name}_connected gauge");
            let _ = writeln!(s, "handeye_{name}_connected {}", u8::from(up));
            let _ = writeln!(
                s,
                "# HELP handeye_{name}_reconnects_total Times the {name}'s connection was re-established."
            );
            let _ = writeln!(s, "# TYPE handeye_{name}_reconnects_total counter");
            let _ = writeln!(s, "handeye_{name}_reconnects_total {reconnects}");
        }
        let _ = writeln!(s, "# HELP handeye_busy 1 while a run is going.");
        let _ = writeln!(s, "# TYPE handeye_busy gauge");
        let _ = writeln!(s, "handeye_busy {}", u8::from(st.current.is_some()));
        let _ = writeln!(
            s,
            "# HELP handeye_queued Runs waiting behind the running one."
        );
        let _ = writeln!(s, "# TYPE handeye_queued gauge");
        let _ = writeln!(s, "handeye_queued {}", st.queued.len());
        s
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

    fn set_stage(&self, stage: Stage, detail: &str) {
        let mut st = self.lock();
        if let Some((c, _)) = &mut st.current {
            c.stage = Some(stage);
            c.detail = detail.to_string();
        }
    }

    fn finished(&self, job: &Job, record: &RunRecord) {
        let mut st = self.lock();
        let drift = record
            .drift
            .as_ref()
            .map(|d| (d.translation_mm, d.rotation_deg, d.drifted));
        let f = Finished {
            run_id: record.run_id.clone(),
            mode: job.mode,
            trigger: job.trigger,
            outcome: record.outcome,
            reasons: record.reasons.clone(),
            finished_unix_s: unix_now(),
            duration_ms: record.timings_ms.total,
            drift,
        };
        let m = &mut st.metrics;
        match m
            .runs
            .iter_mut()
            .find(|((t, o), _)| *t == job.trigger && *o == record.outcome)
        {
            Some((_, n)) => *n += 1,
            None => m.runs.push(((job.trigger, record.outcome), 1)),
        }
        let secs = record.timings_ms.total / 1e3;
        if let Some(k) = DURATION_BUCKETS.iter().position(|le| secs <= *le) {
            m.duration_buckets[k] += 1;
        }
        m.duration_sum_s += secs;
        m.duration_count += 1;
        if record.outcome == Outcome::Accepted {
            match job.mode {
                RunMode::Calibrate => {
                    if let Some(r) = &record.result {
                        m.last_uncertainty_mm = Some(r.uncertainty.translation_mm);
                        m.last_uncertainty_deg = Some(r.uncertainty.rotation_deg);
                    }
                    st.last_calibration = Some(f.clone());
                    // A fresh calibration is the new reference: no drift from it.
                    st.drift_alarm = false;
                }
                RunMode::Check => {
                    if let (Some((mm, deg, _)), Some(drifted)) = (drift, record.drift_found()) {
                        st.metrics.last_drift_mm = Some(mm);
                        st.metrics.last_drift_deg = Some(deg);
                        if drifted {
                            st.metrics.alarms += 1;
                            tracing::error!(
                                run_id = %record.run_id,
                                drift_mm = mm,
                                drift_deg = deg,
                                "ALARM: the camera has drifted from its calibration"
                            );
                        }
                        st.drift_alarm = drifted;
                    }
                    st.last_check = Some(f.clone());
                }
            }
        }
        st.last = Some(f);
        // The next queued run (the job channel delivers it next) becomes the current one.
        st.current = st.queued.pop_front();
    }
}

/// Progress of the current run into the daemon's state (and the log).
struct StageReporter<'a> {
    handle: &'a DaemonHandle,
}

impl Progress for StageReporter<'_> {
    fn stage(&self, stage: Stage, detail: &str) {
        tracing::info!(stage = stage.name(), "{detail}");
        self.handle.set_stage(stage, detail);
    }
}

/// Creates the handle and the job queue (the worker side is [`run`]).
fn handle(
    store: Arc<Store>,
    when_busy: WhenBusy,
    shutdown: CancellationToken,
) -> (DaemonHandle, mpsc::Receiver<Job>) {
    let (tx, rx) = mpsc::channel(1 + QUEUE_LIMIT);
    let shared = Arc::new(Shared {
        state: Mutex::new(State {
            current: None,
            queued: std::collections::VecDeque::new(),
            last: None,
            last_calibration: None,
            last_check: None,
            drift_alarm: false,
            robot_connected: true,
            camera_connected: true,
            links: (0, 0),
            metrics: Metrics::default(),
        }),
        queue: tx,
        when_busy,
        store,
        shutdown,
        started_unix_s: unix_now(),
    });
    (DaemonHandle { shared }, rx)
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

/// Runs the daemon until `shutdown`: the startup run, the schedule, the frontend, and every
/// accepted trigger, one run at a time, each recorded in `store`. Returns when the run in
/// progress (if any) has ended and been recorded.
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
    let (handle, mut jobs) = handle(store, cfg.daemon.when_busy, shutdown.clone());
    let notifier = notify::Notifier::from_env();
    let frontend_task = tokio::spawn(frontend.serve(handle.clone(), shutdown.clone()));
    if let Some(n) = &notifier {
        if n.watchdog_interval().is_some() {
            if let Some(w) = notify::Notifier::from_env() {
                tokio::spawn(notify::feed_watchdog(w, shutdown.clone()));
            }
        }
        n.ready();
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
    let mut pendant = tokio::time::interval(PENDANT_POLL);
    pendant.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut last_request = 0;
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
            Some(job) = jobs.recv() => {
                let record = execute(&cfg, &model, &robot, &camera, &handle, &job).await;
                if let Some(n) = &notifier {
                    n.status(&format!("last run {}: {}", record.run_id, record.outcome));
                }
                if let (Trigger::Pendant, Some(p)) = (job.trigger, cfg.daemon.pendant) {
                    let answer = if record.outcome == Outcome::Accepted {
                        PENDANT_DONE
                    } else {
                        PENDANT_FAILED
                    };
                    answer_pendant(&robot, p.status_register, answer).await;
                }
                if job.trigger == Trigger::Schedule
                    && record.drift_found() == Some(true)
                    && cfg.daemon.recalibrate_on_drift
                    && !shutdown.is_cancelled()
                {
                    if let Err(e) = handle.request(RunMode::Calibrate, Trigger::Drift) {
                        tracing::warn!("recalibration after drift not started: {e}");
                    }
                }
            }
            _ = pendant.tick(), if cfg.daemon.pendant.is_some() => {
                if let Some(p) = cfg.daemon.pendant {
                    last_request = poll_pendant(&robot, &handle, p, last_request).await;
                }
            }
            _ = health.tick() => {
                if handle.status().current.is_none() {
                    let robot_up = tokio::time::timeout(HEALTH_TIMEOUT, robot.status()).await.is_ok_and(|r| r.is_ok());
                    let camera_up = tokio::time::timeout(HEALTH_TIMEOUT, camera.info()).await.is_ok_and(|r| r.is_ok());
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
    while let Ok(job) = jobs.try_recv() {
        let record = execute(&cfg, &model, &robot, &camera, &handle, &job).await;
        tracing::info!(run_id = %record.run_id, "run accepted before the shutdown: {}", record.outcome);
    }
    let _ = frontend_task.await;
}

/// How often the pendant's request register is read.
const PENDANT_POLL: Duration = Duration::from_millis(200);
/// Answers in the pendant's status register.
const PENDANT_IDLE: i32 = 0;
const PENDANT_BUSY: i32 = 1;
const PENDANT_DONE: i32 = 2;
const PENDANT_FAILED: i32 = 3;
const PENDANT_REFUSED: i32 = 4;

/// Reads the pendant program's request register; a new request (1 calibrate, 2 check) starts
/// a run and is answered busy (or refused, when another run is going); a request cleared to 0
/// resets the answer. Returns the value seen.
async fn poll_pendant<R: Robot>(
    robot: &R,
    handle: &DaemonHandle,
    p: crate::config::PendantConfig,
    last: i32,
) -> i32 {
    let v = match robot.read_output_int_register(p.request_register).await {
        Ok(v) => v,
        Err(e) => {
            tracing::debug!("cannot read the pendant's request register: {e}");
            return last;
        }
    };
    if v == last {
        return v;
    }
    let mode = match v {
        1 => Some(RunMode::Calibrate),
        2 => Some(RunMode::Check),
        _ => None,
    };
    match mode {
        Some(mode) => {
            let answer = match handle.request_with_handover(mode, Trigger::Pendant) {
                Ok(_) => PENDANT_BUSY,
                Err(e) => {
                    tracing::warn!("pendant request refused: {e}");
                    PENDANT_REFUSED
                }
            };
            answer_pendant(robot, p.status_register, answer).await;
        }
        None if v == 0 => answer_pendant(robot, p.status_register, PENDANT_IDLE).await,
        None => tracing::warn!(
            "pendant request register output_int_register_{} = {v}: expected 1 (calibrate), 2 (check) or 0",
            p.request_register
        ),
    }
    v
}

/// Writes the pendant's status register (`input_int_register_N`).
async fn answer_pendant<R: Robot>(robot: &R, register: u32, value: i32) {
    if let Err(e) = robot.write_int_register(register, value).await {
        tracing::warn!("cannot answer the pendant in input_int_register_{register}: {e}");
    }
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
        mode: job.mode,
        dry_run: false,
        run_id: Some(job.run_id.clone()),
        program_handover: job.handover,
    };
    let span = tracing::info_span!("run", trigger = job.trigger.name());
    let progress = StageReporter { handle };
    let recorder = Recorder::new(Arc::clone(handle.store()), job.trigger);
    let record = tracing::Instrument::instrument(
        recorder.run(robot, camera, model, cfg, req, &job.cancel, &progress),
        span,
    )
    .await;
    tracing::info!(
        outcome = record.outcome.name(),
        duration_ms = t0.elapsed().as_secs_f64() * 1e3,
        "run ended"
    );
    handle.finished(job, &record);
    record
}

#[cfg(test)]
mod tests {
    use super::*;

    fn store(tag: &str) -> (Arc<Store>, std::path::PathBuf) {
        let dir = std::env::temp_dir().join(format!("handeye-daemon-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("dir");
        let s = Store::open(&dir.join("history.sqlite")).expect("store");
        (Arc::new(s), dir)
    }

    #[test]
    fn a_busy_daemon_refuses_or_queues_as_configured() {
        let (s, dir) = store("refuse");
        let (h, _jobs) = handle(s, WhenBusy::Refuse, CancellationToken::new());
        let first = h
            .request(RunMode::Check, Trigger::Api)
            .expect("idle: accepted");
        let e = h
            .request(RunMode::Calibrate, Trigger::Pendant)
            .expect_err("busy");
        assert!(
            matches!(&e, Refusal::Busy { run_id, .. } if *run_id == first),
            "{e}"
        );
        assert!(e.to_string().starts_with("busy: Check run "), "{e}");
        let _ = std::fs::remove_dir_all(dir);

        let (s, dir) = store("queue");
        let (h, mut jobs) = handle(s, WhenBusy::Queue, CancellationToken::new());
        let running = h
            .request(RunMode::Calibrate, Trigger::Api)
            .expect("accepted");
        let queued: Vec<String> = (0..QUEUE_LIMIT)
            .map(|_| {
                h.request(RunMode::Check, Trigger::Schedule)
                    .expect("queued")
            })
            .collect();
        let e = h
            .request(RunMode::Check, Trigger::Api)
            .expect_err("queue full");
        assert!(
            matches!(
                e,
                Refusal::QueueFull {
                    queued: QUEUE_LIMIT,
                    ..
                }
            ),
            "{e}"
        );
        let st = h.status();
        assert_eq!(st.current.as_ref().map(|c| &c.run_id), Some(&running));
        let ids: Vec<&String> = st.queued.iter().map(|c| &c.run_id).collect();
        assert_eq!(ids, queued.iter().collect::<Vec<_>>());

        // The channel delivers them in the same order; a finished run promotes the next.
        let job = jobs.try_recv().expect("running job");
        assert_eq!(job.run_id, running);
        let mut record =
            RunRecord::starting(running.clone(), RunMode::Calibrate, false, "test".into());
        record.outcome = Outcome::Rejected;
        h.finished(&job, &record);
        let st = h.status();
        assert_eq!(st.current.as_ref().map(|c| &c.run_id), Some(&queued[0]));
        assert_eq!(st.queued.len(), QUEUE_LIMIT - 1);

        // Cancel stops the running one and every queued one.
        let waiting: Vec<Job> = std::iter::from_fn(|| jobs.try_recv().ok()).collect();
        assert_eq!(waiting.len(), QUEUE_LIMIT);
        assert!(waiting.iter().all(|j| !j.cancel.is_cancelled()));
        assert!(h.cancel());
        assert!(waiting.iter().all(|j| j.cancel.is_cancelled()));
        let _ = std::fs::remove_dir_all(dir);
    }
}
