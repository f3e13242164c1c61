//! `handeye daemon --config FILE`: the service on a cell PC. Loads and checks the
//! configuration (a bad one refuses to start, naming key and line), opens the history,
//! connects the robot and the camera (retrying with backoff until they answer), and hands them
//! to `handeye::daemon::run` with the HTTP API as its frontend, until SIGTERM/Ctrl-C.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use handeye::config::Config;
use handeye::daemon::api::Api;
use handeye::store::Store;
use handeye_hal::{CameraInfo, CaptureSettings, DepthCamera, HalError, PointCloud};
use tokio_util::sync::CancellationToken;

use super::calibrate::{connect_robot, load_model, AnyCamera};

/// Pauses between connection attempts: 1 s, doubling to 30 s, back to 1 s once connected.
#[derive(Debug)]
struct Backoff(Duration);

impl Backoff {
    const FIRST: Duration = Duration::from_secs(1);
    const LONGEST: Duration = Duration::from_secs(30);

    fn new() -> Self {
        Self(Self::FIRST)
    }

    /// The pause after a failed attempt (the next one is twice as long, up to the longest).
    fn failed(&mut self) -> Duration {
        let wait = self.0;
        self.0 = (wait * 2).min(Self::LONGEST);
        wait
    }

    fn connected(&mut self) {
        self.0 = Self::FIRST;
    }
}

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The cell's configuration (see config/handeye.example.toml, `[daemon]`).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
}

/// The history database of a configuration.
pub(crate) fn history_path(cfg: &Config) -> PathBuf {
    cfg.storage.dir.join("history.sqlite")
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
    let model = load_model(&cfg)?;
    let path = history_path(&cfg);
    let store = tokio::task::spawn_blocking(move || Store::open(&path))
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
    let camera = ReconnectingCamera::new(cfg.clone(), camera);
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

/// The configured camera, connected anew after it failed: a failed request drops the
/// connection and the next request connects again (at most once per backoff, 1 s doubling to
/// 30 s), so a camera that was restarted or re-cabled comes back without restarting the daemon.
/// Each new connection raises the link generation, which makes a run in progress abort.
#[derive(Debug)]
struct ReconnectingCamera {
    cfg: Config,
    link: tokio::sync::Mutex<Link>,
    generation: AtomicU64,
}

#[derive(Debug)]
struct Link {
    camera: Option<Arc<AnyCamera>>,
    next_attempt: Instant,
    backoff: Backoff,
}

impl ReconnectingCamera {
    fn new(cfg: Config, camera: AnyCamera) -> Self {
        Self {
            cfg,
            link: tokio::sync::Mutex::new(Link {
                camera: Some(Arc::new(camera)),
                next_attempt: Instant::now(),
                backoff: Backoff::new(),
            }),
            generation: AtomicU64::new(0),
        }
    }

    /// The connected camera, connecting it if it is not (and the backoff allows).
    async fn connected(&self) -> Result<Arc<AnyCamera>, HalError> {
        let mut link = self.link.lock().await;
        if let Some(c) = &link.camera {
            return Ok(c.clone());
        }
        let now = Instant::now();
        if now < link.next_attempt {
            return Err(disconnected(format!(
                "the camera is not connected; next attempt in {:.0} s",
                (link.next_attempt - now).as_secs_f64()
            )));
        }
        match AnyCamera::connect(&self.cfg).await {
            Ok(c) => {
                let c = Arc::new(c);
                link.camera = Some(c.clone());
                link.backoff.connected();
                self.generation.fetch_add(1, Ordering::Relaxed);
                tracing::info!("camera connected again");
                Ok(c)
            }
            Err(e) => {
                let wait = link.backoff.failed();
                link.next_attempt = now + wait;
                tracing::warn!("camera: {e:#}; retrying in {wait:?}");
                Err(disconnected(format!("{e:#}")))
            }
        }
    }

    /// Forgets `failed` (unless it was replaced already): the next request connects again.
    async fn drop_link(&self, failed: &Arc<AnyCamera>, e: &HalError) {
        let mut link = self.link.lock().await;
        if link.camera.as_ref().is_some_and(|c| Arc::ptr_eq(c, failed)) {
            tracing::warn!("camera request failed ({e}); reconnecting at the next request");
            link.camera = None;
        }
    }
}

fn disconnected(detail: String) -> HalError {
    HalError::Connection {
        peer: "camera".into(),
        source: std::io::Error::new(std::io::ErrorKind::NotConnected, detail),
    }
}

impl DepthCamera for ReconnectingCamera {
    async fn info(&self) -> Result<CameraInfo, HalError> {
        let camera = self.connected().await?;
        let r = camera.info().await;
        if let Err(e) = &r {
            self.drop_link(&camera, e).await;
        }
        r
    }

    async fn capture(&self, settings: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
        let camera = self.connected().await?;
        let r = camera.capture(settings).await;
        if let Err(e) = &r {
            self.drop_link(&camera, e).await;
        }
        r
    }

    fn link_generation(&self) -> u64 {
        self.generation.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reconnection_waits_double_to_half_a_minute_and_start_over_once_connected() {
        let mut b = Backoff::new();
        let waits: Vec<u64> = (0..7).map(|_| b.failed().as_secs()).collect();
        assert_eq!(waits, [1, 2, 4, 8, 16, 30, 30]);
        b.connected();
        assert_eq!(b.failed(), Duration::from_secs(1));
    }
}
