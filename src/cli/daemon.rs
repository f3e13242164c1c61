//! `handeye daemon --config FILE`: the service on a cell PC. Loads and checks the
//! configuration (a bad one refuses to start, naming key and line), opens the history,
//! connects the robot and the camera (retrying with backoff until they answer), and hands them
//! to `handeye::daemon::run` with the HTTP API as its frontend, until SIGTERM/Ctrl-C.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::Context;
use handeye::camera::{Backoff, ReconnectingCamera};
use handeye::config::Config;
use handeye::daemon::api::Api;
use tokio_util::sync::CancellationToken;

use super::wiring::{connect_robot, history_path, load_model, AnyCamera};

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The cell's configuration (see config/handeye.example.toml, `[daemon]`).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
}

/// Calls `connect` until it succeeds (backoff 1 s doubling to 30 s, each failure logged) or
/// `shutdown`; `None` on shutdown.
async fn with_backoff<T, F, Fut>(what: &str, shutdown: &CancellationToken, connect: F) -> Option<T>
where
    F: Fn() -> Fut,
    Fut: std::future::Future<Output = anyhow::Result<T>>,
{
    let mut backoff = Backoff::new();
    loop {
        let wait = match connect().await {
            Ok(v) => return Some(v),
            Err(e) => {
                let wait = backoff.failed();
                tracing::warn!("{what}: {e:#}; retrying in {wait:?}");
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
    raise_fd_limit();
    let model = load_model(&cfg)?;
    let path = history_path(&cfg);
    let store = tokio::task::spawn_blocking(move || handeye::run::open_history(&path))
        .await?
        .context("opening the history")?;
    let api = Api::from_config(&cfg)?;
    tracing::info!(config = %cfg.origin, "handeye daemon starting");
    let Some(robot) = with_backoff("robot", &shutdown, || connect_robot(&cfg)).await else {
        return Ok(ExitCode::SUCCESS);
    };
    let Some(camera) = with_backoff("camera", &shutdown, || AnyCamera::connect(&cfg)).await else {
        return Ok(ExitCode::SUCCESS);
    };
    // Connected anew whenever it failed (a restarted or re-cabled camera comes back).
    let again = Arc::new(cfg.clone());
    let camera = ReconnectingCamera::new(camera, move || {
        let cfg = Arc::clone(&again);
        async move { AnyCamera::connect(&cfg).await }
    });
    let listen = cfg.daemon.listen;
    handeye::daemon::run(
        cfg,
        model,
        robot,
        camera,
        Arc::new(store),
        api,
        shutdown,
        |_| eprintln!("handeye daemon ready (API on http://{listen})"),
    )
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
