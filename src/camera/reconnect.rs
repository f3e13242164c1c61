//! [`ReconnectingCamera`]: any [`DepthCamera`] connected anew after it failed, and the
//! [`Backoff`] between connection attempts (also the daemon's startup connections).

use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use handeye_hal::{CameraInfo, CaptureSettings, DepthCamera, HalError, PointCloud};

/// Pauses between connection attempts: 1 s, doubling to 30 s, back to 1 s once connected.
#[derive(Debug)]
pub struct Backoff(Duration);

impl Default for Backoff {
    fn default() -> Self {
        Self::new()
    }
}

impl Backoff {
    const FIRST: Duration = Duration::from_secs(1);
    const LONGEST: Duration = Duration::from_secs(30);

    /// The first pause is the shortest.
    pub fn new() -> Self {
        Self(Self::FIRST)
    }

    /// The pause after a failed attempt (the next one is twice as long, up to the longest).
    pub fn failed(&mut self) -> Duration {
        let wait = self.0;
        self.0 = (wait * 2).min(Self::LONGEST);
        wait
    }

    /// A connection succeeded: the next failure waits the shortest pause again.
    pub fn connected(&mut self) {
        self.0 = Self::FIRST;
    }
}

/// A camera connected anew after it failed: a failed request drops the connection and the
/// next request connects again with `connect` (at most once per [`Backoff`] pause), so a
/// camera that was restarted or re-cabled comes back without restarting the daemon. Each lost
/// connection raises the link generation when it is lost (a run in progress then aborts; the
/// next run, which connects again in its preflight, starts with the raised generation), and
/// so does each loss the camera reports itself (its own link generation: the GenTL camera's
/// replaced host process).
pub struct ReconnectingCamera<C, F> {
    connect: F,
    link: tokio::sync::Mutex<Link<C>>,
    generation: AtomicU64,
    /// The largest generation reported (it never goes back).
    reported: AtomicU64,
}

impl<C, F> std::fmt::Debug for ReconnectingCamera<C, F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ReconnectingCamera")
            .field("generation", &self.generation)
            .finish_non_exhaustive()
    }
}

#[derive(Debug)]
struct Link<C> {
    camera: Option<Arc<C>>,
    /// The connected camera's own link generation when it was connected or last seen.
    seen: u64,
    next_attempt: Instant,
    backoff: Backoff,
}

impl<C, F, Fut> ReconnectingCamera<C, F>
where
    C: DepthCamera,
    F: Fn() -> Fut + Send + Sync + 'static,
    Fut: Future<Output = anyhow::Result<C>> + Send,
{
    /// Wraps `camera`, connected already; `connect` makes a new one when it fails.
    pub fn new(camera: C, connect: F) -> Self {
        Self {
            connect,
            link: tokio::sync::Mutex::new(Link {
                seen: camera.link_generation(),
                camera: Some(Arc::new(camera)),
                next_attempt: Instant::now(),
                backoff: Backoff::new(),
            }),
            generation: AtomicU64::new(0),
            reported: AtomicU64::new(0),
        }
    }

    /// The connected camera, connecting it if it is not (and the backoff allows).
    async fn connected(&self) -> Result<Arc<C>, HalError> {
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
        match (self.connect)().await {
            Ok(c) => {
                let c = Arc::new(c);
                link.seen = c.link_generation();
                link.camera = Some(c.clone());
                link.backoff.connected();
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

    /// After a request of `camera`: a failure forgets it (unless it was replaced already; the
    /// next request connects again), and the losses it reports itself raise the generation.
    async fn after_request(&self, camera: &Arc<C>, result: Result<(), &HalError>) {
        let mut link = self.link.lock().await;
        if !link.camera.as_ref().is_some_and(|c| Arc::ptr_eq(c, camera)) {
            return;
        }
        let own = camera.link_generation();
        if own > link.seen {
            self.generation
                .fetch_add(own - link.seen, Ordering::Relaxed);
            link.seen = own;
        }
        if let Err(e) = result {
            tracing::warn!("camera request failed ({e}); reconnecting at the next request");
            link.camera = None;
            self.generation.fetch_add(1, Ordering::Relaxed);
        }
    }
}

fn disconnected(detail: String) -> HalError {
    HalError::Connection {
        peer: "camera".into(),
        source: std::io::Error::new(std::io::ErrorKind::NotConnected, detail),
    }
}

impl<C, F, Fut> DepthCamera for ReconnectingCamera<C, F>
where
    C: DepthCamera,
    F: Fn() -> Fut + Send + Sync + 'static,
    Fut: Future<Output = anyhow::Result<C>> + Send,
{
    async fn info(&self) -> Result<CameraInfo, HalError> {
        let camera = self.connected().await?;
        let r = camera.info().await;
        self.after_request(&camera, r.as_ref().map(drop)).await;
        r
    }

    async fn capture(&self, settings: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
        let camera = self.connected().await?;
        let r = camera.capture(settings).await;
        self.after_request(&camera, r.as_ref().map(drop)).await;
        r
    }

    /// Connections lost, including the losses the camera reports itself as they happen (the
    /// GenTL camera's host process killed past a deadline raises it before the next run
    /// starts, even when the run that asked gave up waiting).
    fn link_generation(&self) -> u64 {
        let own = match self.link.try_lock() {
            Ok(link) => link
                .camera
                .as_ref()
                .map_or(0, |c| c.link_generation().saturating_sub(link.seen)),
            Err(_) => 0,
        };
        let now = self.generation.load(Ordering::Relaxed) + own;
        self.reported.fetch_max(now, Ordering::Relaxed).max(now)
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::AtomicUsize;

    use handeye_hal::fake::FakeCamera;
    use nalgebra::Point3;

    use super::*;

    /// Any camera: a failed request drops it, the next connects a new one (raising the link
    /// generation); a failed connection waits its backoff before the next attempt.
    #[tokio::test]
    async fn a_failed_camera_is_connected_anew_at_the_next_request() {
        let cloud = PointCloud::from_points(vec![Point3::new(0.0, 0.0, 1.0)]);
        let first = FakeCamera::new(vec![cloud.clone()]);
        first.stop_answering_after(1);
        let attempts = Arc::new(AtomicUsize::new(0));
        let counted = Arc::clone(&attempts);
        let camera = ReconnectingCamera::new(first, move || {
            let n = counted.fetch_add(1, Ordering::Relaxed);
            let cloud = cloud.clone();
            async move {
                anyhow::ensure!(n > 0, "the first attempt fails");
                Ok(FakeCamera::new(vec![cloud]))
            }
        });
        let settings = CaptureSettings::default();
        assert!(camera.capture(&settings).await.is_ok());
        assert_eq!(camera.link_generation(), 0);
        assert!(camera.capture(&settings).await.is_err(), "stops answering");
        // Raised when the link is lost, not when the next run connects again in its
        // preflight (which then aborted that run as "re-established during the run").
        assert_eq!(camera.link_generation(), 1);
        // The first attempt fails; the next waits out its pause.
        let e = camera.info().await.expect_err("cannot connect");
        assert!(matches!(e, HalError::Connection { .. }), "{e}");
        let e = camera.info().await.expect_err("backing off");
        let why = std::error::Error::source(&e).map(ToString::to_string);
        assert!(
            why.as_deref().unwrap_or("").contains("next attempt"),
            "{why:?}"
        );
        assert_eq!(attempts.load(Ordering::Relaxed), 1);
        camera.link.lock().await.next_attempt = Instant::now();
        assert!(camera.capture(&settings).await.is_ok(), "connected anew");
        assert_eq!(camera.link_generation(), 1, "unchanged by the reconnection");
        assert_eq!(attempts.load(Ordering::Relaxed), 2);
    }

    /// A camera that counts its own lost links (as the GenTL camera counts its replaced host
    /// processes).
    struct Lossy(Arc<AtomicU64>);

    impl DepthCamera for Lossy {
        async fn info(&self) -> Result<CameraInfo, HalError> {
            Ok(CameraInfo::default())
        }
        async fn capture(&self, _: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
            Ok(Vec::new())
        }
        fn link_generation(&self) -> u64 {
            self.0.load(Ordering::Relaxed)
        }
    }

    /// Issue 46: a loss the camera reports itself (a GenTL host killed past its deadline after
    /// the run that asked gave up) raises the generation at once, before the next run records
    /// it, and never goes back.
    #[tokio::test]
    async fn issue_46_the_cameras_own_losses_raise_the_generation_at_once() {
        let lost = Arc::new(AtomicU64::new(0));
        let inner = Arc::clone(&lost);
        let camera = ReconnectingCamera::new(Lossy(Arc::clone(&lost)), move || {
            let inner = Arc::clone(&inner);
            async move { Ok(Lossy(inner)) }
        });
        assert_eq!(camera.link_generation(), 0);
        lost.store(1, Ordering::Relaxed);
        assert_eq!(camera.link_generation(), 1, "before any request");
        assert!(camera.info().await.is_ok());
        assert_eq!(camera.link_generation(), 1, "counted once");
        lost.store(3, Ordering::Relaxed);
        assert!(camera.capture(&CaptureSettings::default()).await.is_ok());
        assert_eq!(camera.link_generation(), 3);
    }

    #[test]
    fn reconnection_waits_double_to_half_a_minute_and_start_over_once_connected() {
        let mut b = Backoff::new();
        let waits: Vec<u64> = (0..7).map(|_| b.failed().as_secs()).collect();
        assert_eq!(waits, [1, 2, 4, 8, 16, 30, 30]);
        b.connected();
        assert_eq!(b.failed(), Duration::from_secs(1));
    }
}
