//! `handeye daemon --config FILE`: the service on a cell PC. Loads and checks the
//! configuration (a bad one refuses to start, naming key and line), takes the storage's
//! daemon lock (a second daemon on the same storage refuses to start, naming the first) and
//! the arm's claim (a daemon on another storage that drives the same arm: the same), opens
//! the history, and runs `handeye::daemon::run_with` with the HTTP API as its frontend (up
//! from the first second) and a `connect` that reaches the robot and the camera (retrying with
//! backoff, shown in the status) until SIGTERM/Ctrl-C.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::Context;
use handeye::camera::{Backoff, ReconnectingCamera};
use handeye::config::Config;
use handeye::daemon::api::Api;
use handeye::daemon::arm::ArmClaim;
use handeye::daemon::lock::DaemonLock;
use handeye::daemon::DaemonHandle;
use tokio_util::sync::CancellationToken;

use super::wiring::{connect_robot, history_path, load_model, AnyCamera, Registers};

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The cell's configuration (see config/handeye.example.toml, `[daemon]`).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
}

/// Calls `connect` until it succeeds (backoff 1 s doubling to 30 s, each failure logged and
/// shown in the daemon's status as `waiting for WHAT (attempt N, next in S s)`) or
/// `shutdown`; `None` on shutdown.
async fn with_backoff<T, F, Fut>(
    what: &str,
    handle: &DaemonHandle,
    shutdown: &CancellationToken,
    connect: F,
) -> Option<T>
where
    F: Fn() -> Fut,
    Fut: std::future::Future<Output = anyhow::Result<T>>,
{
    let mut backoff = Backoff::new();
    let mut attempt = 0;
    loop {
        attempt += 1;
        let wait = match connect().await {
            Ok(v) => {
                if attempt > 1 {
                    tracing::warn!("{what}: connected at attempt {attempt}");
                }
                return Some(v);
            }
            Err(e) => {
                let wait = backoff.failed();
                tracing::warn!("{what}: {e:#}; retrying in {wait:?} (attempt {attempt})");
                handle.waiting_for(what, attempt, wait, &format!("{e:#}"));
                wait
            }
        };
        tokio::select! {
            _ = shutdown.cancelled() => return None,
            _ = tokio::time::sleep(wait) => {}
        }
    }
}

pub(crate) async fn run(args: Args, shutdown: CancellationToken) -> anyhow::Result<ExitCode> {
    let cfg = Config::load(&args.config)?;
    // Before anything else: a second daemon on the same cell stops here, naming the first.
    // One user owns the storage: the daemon runs as that user, and can open every file in it.
    super::calibrate::storage_owner(&cfg)?;
    handeye::storage::owner::unopenable(&cfg.storage.dir)?;
    let _lock = DaemonLock::acquire(&cfg.storage.dir)?;
    // … and a daemon (or a command) on another storage that holds this arm, naming it.
    let _arm = ArmClaim::take(cfg.robot.host, cfg.robot.ports.dashboard)?;
    raise_fd_limit();
    let model = load_model(&cfg)?;
    let path = history_path(&cfg);
    let store = tokio::task::spawn_blocking(move || handeye::run::open_history(&path))
        .await?
        .context("opening the history")?;
    let api = Api::from_config(&cfg)?;
    tracing::info!(config = %cfg.origin, "handeye daemon starting");
    let listen = cfg.daemon.listen;
    eprintln!(
        "handeye daemon starting (API on http://{listen}); connecting to the robot at {} and \
         the camera",
        cfg.robot.host
    );
    let connect_cfg = cfg.clone();
    let connect_model = Arc::clone(&model);
    let stop = shutdown.clone();
    let connect = |handle: DaemonHandle| async move {
        let cfg = connect_cfg;
        let robot_at = format!("robot at {}", cfg.robot.host);
        let robot = with_backoff(&robot_at, &handle, &stop, || {
            connect_robot(&cfg, &connect_model, Registers::Configured)
        })
        .await?;
        let camera = with_backoff("camera", &handle, &stop, || AnyCamera::connect(&cfg)).await?;
        // Connected anew whenever it failed (a restarted or re-cabled camera comes back).
        let again = Arc::new(cfg.clone());
        let camera = ReconnectingCamera::new(camera, move || {
            let cfg = Arc::clone(&again);
            async move { AnyCamera::connect(&cfg).await }
        });
        Some((robot, camera))
    };
    handeye::daemon::run_with(cfg, model, connect, Arc::new(store), api, shutdown, |_| {
        eprintln!("handeye daemon ready (API on http://{listen})")
    })
    .await;
    eprintln!("handeye daemon stopped");
    Ok(ExitCode::SUCCESS)
}

/// Raises the soft limit on open files to the hard one: the API's connections
/// (`handeye::daemon::listener::MAX_CONNECTIONS` and those waiting) come on top of the
/// robot's, the camera's and the history's. The systemd unit sets both with `LimitNOFILE=`
/// (and forbids this call); a refusal is logged, never fatal.
fn raise_fd_limit() {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit with a valid, initialised struct.
    if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } != 0 {
        return;
    }
    if limit.rlim_cur < limit.rlim_max {
        let wanted = libc::rlimit {
            rlim_cur: limit.rlim_max,
            rlim_max: limit.rlim_max,
        };
        if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &wanted) } != 0 {
            tracing::debug!(
                "open-file limit stays {}: {}",
                limit.rlim_cur,
                std::io::Error::last_os_error()
            );
        }
    }
}
