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
mod handle;
pub mod listener;
pub mod lock;
mod metrics;
mod notify;
mod pendant;
mod status;

use std::sync::Arc;
use std::time::{Duration, Instant};

use handeye_hal::{DepthCamera, Robot};
use tokio_util::sync::CancellationToken;

use crate::calendar::{unix_now, utc_text};
use crate::config::Config;
use crate::model::RobotModel;
use crate::record::{Outcome, RunMode, RunRecord, Stage, Trigger};
use crate::run::{Progress, Recorder, RunRequest};
use crate::store::Store;
use handle::{handle, Job};

pub use handle::{DaemonHandle, Refusal, ALARM, RECALIBRATE};
pub use status::{Current, DaemonState, Drift, Finished, Status};

/// How often an idle daemon asks the robot and the camera whether they answer.
const HEALTH_EVERY: Duration = Duration::from_secs(5);
/// How long such a question may take.
const HEALTH_TIMEOUT: Duration = Duration::from_secs(3);

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
