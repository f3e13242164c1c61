//! The HTTP API's connections, bounded: the accept loop the API serves its router through.
//!
//! - At most [`MAX_CONNECTIONS`] connections at once and [`MAX_PER_CLIENT`] per client address;
//!   a client beyond its share has the new connection closed at once (no file descriptor kept).
//! - At the global limit, the connection idle the longest (no request in progress) is closed to
//!   make room, so a flood of idle connections from many addresses never locks out a request
//!   such as `POST /api/cancel`.
//! - A connection must send a request's headers within [`HEADER_TIMEOUT`] of being accepted or
//!   of its previous answer (idle keep-alive), else it is closed.
//! - When `accept` fails (out of file descriptors), the loop waits a little and goes on.
//! - A connection whose client went away while it waited (for room here, or in the kernel's
//!   backlog) is closed without reading it: a request it left behind (`POST /api/calibrate`)
//!   is not started. "Went away" is the client's close (FIN) or reset; a client that
//!   half-closes after its request is treated as gone.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::extract::ConnectInfo;
use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::net::TcpListener;
use tokio::sync::{Notify, Semaphore};
use tokio_util::sync::CancellationToken;

/// Connections served at once (each one file descriptor; the unit's `LimitNOFILE` leaves room
/// for the robot, the camera and the history).
pub const MAX_CONNECTIONS: usize = 256;
/// Connections one client address may hold at once (a browser opens about 6).
pub const MAX_PER_CLIENT: usize = 16;
/// How long a connection may take to send a request's headers (from its accept, or from its
/// previous answer while kept alive).
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a new connection waits for an idle one to close and make room for it.
const ROOM_WAIT: Duration = Duration::from_secs(2);
/// New connections waiting for room at most; beyond, a new one is closed at once.
pub const MAX_WAITING: usize = 64;
/// How long connections get to finish their answers at shutdown.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(3);

/// One served connection, as the accept loop sees it.
#[derive(Debug)]
struct Slot {
    peer: SocketAddr,
    /// When its last request ended (or it was accepted): the longest idle goes first.
    idle_since: Mutex<Instant>,
    /// Whether it holds one of the [`MAX_CONNECTIONS`] places (else it waits for one).
    serving: AtomicBool,
    /// Whether a request is in progress on it.
    busy: AtomicBool,
    /// Whether it was asked to close to make room (never asked twice).
    evicted: AtomicBool,
    /// Asks its task to close it (gracefully: an answer in progress is finished).
    close: Notify,
}

/// The connections alive, by id.
#[derive(Debug, Default)]
struct Slots {
    by_id: Mutex<HashMap<u64, Arc<Slot>>>,
    next_id: AtomicU64,
}

impl Slots {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<u64, Arc<Slot>>> {
        self.by_id.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Registers a connection from `peer` unless that client holds [`MAX_PER_CLIENT`].
    fn add(&self, peer: SocketAddr) -> Option<(u64, Arc<Slot>)> {
        let mut by_id = self.lock();
        let held = by_id.values().filter(|s| s.peer.ip() == peer.ip()).count();
        if held >= MAX_PER_CLIENT {
            return None;
        }
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let slot = Arc::new(Slot {
            peer,
            idle_since: Mutex::new(Instant::now()),
            serving: AtomicBool::new(false),
            busy: AtomicBool::new(false),
            evicted: AtomicBool::new(false),
            close: Notify::new(),
        });
        by_id.insert(id, Arc::clone(&slot));
        Some((id, slot))
    }

    fn remove(&self, id: u64) {
        self.lock().remove(&id);
    }

    /// Asks the served connection idle the longest (not asked before) to close; `false` when
    /// every one is busy.
    fn evict_idlest(&self) -> bool {
        let by_id = self.lock();
        let idlest = by_id
            .values()
            .filter(|s| {
                s.serving.load(Ordering::Acquire)
                    && !s.busy.load(Ordering::Acquire)
                    && !s.evicted.load(Ordering::Acquire)
            })
            .min_by_key(|s| *s.idle_since.lock().unwrap_or_else(|e| e.into_inner()));
        match idlest {
            Some(slot) => {
                slot.evicted.store(true, Ordering::Release);
                slot.close.notify_one();
                true
            }
            None => false,
        }
    }

    fn count(&self) -> usize {
        self.lock().len()
    }
}

/// Serves `app` on `listener` until `shutdown`, within the limits of the module docs.
pub(crate) async fn serve(listener: TcpListener, app: Router, shutdown: CancellationToken) {
    serve_at_most(MAX_CONNECTIONS, listener, app, shutdown).await;
}

/// [`serve`] with `max_connections` places (tests use a few).
async fn serve_at_most(
    max_connections: usize,
    listener: TcpListener,
    app: Router,
    shutdown: CancellationToken,
) {
    let permits = Arc::new(Semaphore::new(max_connections));
    let slots = Arc::new(Slots::default());
    let tasks = tokio_util::task::TaskTracker::new();
    let waiting = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let mut refused_logged = Instant::now() - Duration::from_secs(60);
    loop {
        let accepted = tokio::select! {
            _ = shutdown.cancelled() => break,
            a = listener.accept() => a,
        };
        let (stream, peer) = match accepted {
            Ok(a) => a,
            Err(e) => {
                // Out of file descriptors (or a connection reset before accept): wait, go on.
                tracing::warn!("HTTP API: cannot accept a connection: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let Some((id, slot)) = slots.add(peer) else {
            if refused_logged.elapsed() > Duration::from_secs(10) {
                tracing::warn!(%peer, "HTTP API: the client holds {MAX_PER_CLIENT} connections already; closing its new ones");
                refused_logged = Instant::now();
            }
            drop(stream);
            continue;
        };
        let permit = match Arc::clone(&permits).try_acquire_owned() {
            Ok(p) => Some(p),
            // Full: this one waits while the longest-idle ones make room, unless too many
            // wait already (each waiting connection holds a file descriptor too).
            Err(_) if waiting.load(Ordering::Acquire) < MAX_WAITING => None,
            Err(_) => {
                slots.remove(id);
                if refused_logged.elapsed() > Duration::from_secs(10) {
                    tracing::warn!("HTTP API: {max_connections} connections and {MAX_WAITING} waiting; closing new ones");
                    refused_logged = Instant::now();
                }
                drop(stream);
                continue;
            }
        };
        tracing::trace!(connections = slots.count(), "HTTP API connection accepted");
        let (permits, slots, app, shutdown, waiting) = (
            Arc::clone(&permits),
            Arc::clone(&slots),
            app.clone(),
            shutdown.clone(),
            Arc::clone(&waiting),
        );
        tasks.spawn(async move {
            let permit = match permit {
                Some(p) => p,
                None => {
                    waiting.fetch_add(1, Ordering::AcqRel);
                    let room = make_room(&permits, &slots).await;
                    waiting.fetch_sub(1, Ordering::AcqRel);
                    match room {
                        Some(p) => p,
                        None => {
                            slots.remove(id);
                            return;
                        }
                    }
                }
            };
            if client_gone(&stream) {
                tracing::debug!(%peer, "HTTP API: the client went away while waiting; its request is not started");
                slots.remove(id);
                return;
            }
            slot.serving.store(true, Ordering::Release);
            serve_connection(stream, peer, app, &slot, shutdown).await;
            slots.remove(id);
            drop(permit);
        });
    }
    tasks.close();
    let _ = tokio::time::timeout(SHUTDOWN_GRACE, tasks.wait()).await;
}

/// A place for a new connection when all are taken: the longest-idle connection is asked to
/// close, again every 50 ms while none frees up, for at most [`ROOM_WAIT`].
async fn make_room(
    permits: &Arc<Semaphore>,
    slots: &Slots,
) -> Option<tokio::sync::OwnedSemaphorePermit> {
    let deadline = Instant::now() + ROOM_WAIT;
    while Instant::now() < deadline {
        slots.evict_idlest();
        let wait = Duration::from_millis(50);
        if let Ok(Ok(p)) = tokio::time::timeout(wait, Arc::clone(permits).acquire_owned()).await {
            return Some(p);
        }
    }
    None
}

/// Whether the client closed its side of the connection (FIN) or reset it: Linux reports
/// `POLLRDHUP` even while the request it sent before leaving is still unread.
fn client_gone(stream: &tokio::net::TcpStream) -> bool {
    use std::os::fd::AsRawFd as _;
    let mut p = libc::pollfd {
        fd: stream.as_raw_fd(),
        events: libc::POLLRDHUP,
        revents: 0,
    };
    // SAFETY: one valid, initialised pollfd for an open socket; a zero timeout never blocks.
    let n = unsafe { libc::poll(&mut p, 1, 0) };
    n > 0 && p.revents & (libc::POLLRDHUP | libc::POLLHUP | libc::POLLERR) != 0
}

/// One connection: HTTP/1 with the header timeout; each request gets the peer's address
/// (`ConnectInfo`) and marks the connection busy while it runs.
async fn serve_connection(
    stream: tokio::net::TcpStream,
    peer: SocketAddr,
    app: Router,
    slot: &Arc<Slot>,
    shutdown: CancellationToken,
) {
    let _ = stream.set_nodelay(true);
    let service_slot = Arc::clone(slot);
    let service =
        hyper::service::service_fn(move |mut req: hyper::Request<hyper::body::Incoming>| {
            req.extensions_mut().insert(ConnectInfo(peer));
            let mut app = app.clone();
            let slot = Arc::clone(&service_slot);
            slot.busy.store(true, Ordering::Release);
            async move {
                let answer = tower_service::Service::call(&mut app, req).await;
                *slot.idle_since.lock().unwrap_or_else(|e| e.into_inner()) = Instant::now();
                slot.busy.store(false, Ordering::Release);
                answer
            }
        });
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(HEADER_TIMEOUT)
        .max_buf_size(64 << 10);
    let conn = builder.serve_connection(TokioIo::new(stream), service);
    let mut conn = std::pin::pin!(conn);
    tokio::select! {
        r = conn.as_mut() => {
            if let Err(e) = r {
                tracing::debug!(%peer, "HTTP API connection ended: {e}");
            }
            return;
        }
        _ = slot.close.notified() => {}
        _ = shutdown.cancelled() => {}
    }
    conn.as_mut().graceful_shutdown();
    let _ = tokio::time::timeout(SHUTDOWN_GRACE, conn).await;
}

/// Which client address an answer is for, to limit expensive routes per client.
#[derive(Debug, Default)]
pub(crate) struct RateLimit {
    /// Tokens left and when they were counted, by client address.
    buckets: Mutex<HashMap<IpAddr, (f64, Instant)>>,
}

impl RateLimit {
    /// Requests a client may make at once.
    pub(crate) const BURST: f64 = 8.0;
    /// Requests per second a client may make after the burst.
    pub(crate) const PER_SECOND: f64 = 2.0;
    /// Clients remembered at most (the oldest buckets go first beyond it).
    const CLIENTS: usize = 4096;

    /// Takes one request from `client`'s allowance: `Err(seconds to wait)` when none is left.
    pub(crate) fn take(&self, client: IpAddr) -> Result<(), f64> {
        let now = Instant::now();
        let mut buckets = self.buckets.lock().unwrap_or_else(|e| e.into_inner());
        if buckets.len() >= Self::CLIENTS && !buckets.contains_key(&client) {
            // Full buckets are the same as none: forget those.
            buckets.retain(|_, (tokens, at)| {
                *tokens + at.elapsed().as_secs_f64() * Self::PER_SECOND < Self::BURST
            });
            if buckets.len() >= Self::CLIENTS {
                return Err(1.0 / Self::PER_SECOND);
            }
        }
        let (tokens, at) = buckets.entry(client).or_insert((Self::BURST, now));
        *tokens =
            (*tokens + now.duration_since(*at).as_secs_f64() * Self::PER_SECOND).min(Self::BURST);
        *at = now;
        if *tokens >= 1.0 {
            *tokens -= 1.0;
            Ok(())
        } else {
            Err((1.0 - *tokens) / Self::PER_SECOND)
        }
    }
}

/// Refused authorisations (a wrong, missing or malformed token) per client address: at most
/// [`Self::MAX_FAILURES`] in a [`Self::WINDOW`]; beyond, the client's requests that need the
/// token are refused (429) without looking at the token until the window ends, and its
/// refusals are logged once per window, so guessing is slow and the log stays small.
#[derive(Debug, Default)]
pub(crate) struct AuthLimit {
    /// By client: when its window started, its refusals in it, and those of the last window
    /// (reported with the next log line).
    clients: Mutex<HashMap<IpAddr, AuthWindow>>,
}

#[derive(Debug, Clone, Copy)]
struct AuthWindow {
    start: Instant,
    failures: u32,
    refused: u64,
}

impl AuthLimit {
    /// Refusals a client may have in a window before it has to wait for the next one.
    pub(crate) const MAX_FAILURES: u32 = 20;
    /// The window, and the longest a client waits.
    pub(crate) const WINDOW: Duration = Duration::from_secs(10);
    /// Clients remembered at most (windows that ended go first beyond it).
    const CLIENTS: usize = 4096;

    /// Whether `client` may try a token now: `Err(seconds to wait)` after its refusals used
    /// up the window (the attempt is counted, not logged).
    pub(crate) fn check(&self, client: IpAddr) -> Result<(), f64> {
        let mut clients = self.clients.lock().unwrap_or_else(|e| e.into_inner());
        match clients.get_mut(&client) {
            Some(w) if w.start.elapsed() < Self::WINDOW && w.failures >= Self::MAX_FAILURES => {
                w.refused += 1;
                Err((Self::WINDOW - w.start.elapsed()).as_secs_f64())
            }
            _ => Ok(()),
        }
    }

    /// Counts a refusal of `client`; returns the log line to write (once per window: the
    /// first refusal of a window, with how many the previous one had), else `None`.
    pub(crate) fn failed(&self, client: IpAddr) -> Option<String> {
        let now = Instant::now();
        let mut clients = self.clients.lock().unwrap_or_else(|e| e.into_inner());
        if clients.len() >= Self::CLIENTS && !clients.contains_key(&client) {
            clients.retain(|_, w| w.start.elapsed() < Self::WINDOW);
        }
        let w = clients.entry(client).or_insert(AuthWindow {
            start: now,
            failures: 0,
            refused: 0,
        });
        let mut before = None;
        if now.duration_since(w.start) >= Self::WINDOW {
            before = Some(u64::from(w.failures) + w.refused);
            *w = AuthWindow {
                start: now,
                failures: 0,
                refused: 0,
            };
        }
        w.failures += 1;
        (w.failures == 1).then(|| match before {
            Some(n) if n > 1 => format!(
                " ({n} refused in the previous {} s; after {} in {} s a client waits for the next window, logged once per window)",
                Self::WINDOW.as_secs(),
                Self::MAX_FAILURES,
                Self::WINDOW.as_secs()
            ),
            _ => String::new(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refused_tokens_are_limited_and_logged_once_per_window() {
        let limit = AuthLimit::default();
        let a: IpAddr = [127, 0, 0, 1].into();
        let b: IpAddr = [127, 0, 0, 2].into();
        let mut lines = 0;
        for _ in 0..AuthLimit::MAX_FAILURES {
            assert!(limit.check(a).is_ok());
            lines += usize::from(limit.failed(a).is_some());
        }
        assert_eq!(lines, 1, "one log line per window");
        let wait = limit.check(a).expect_err("over the limit");
        assert!(
            wait > 0.0 && wait <= AuthLimit::WINDOW.as_secs_f64(),
            "{wait}"
        );
        assert!(limit.check(b).is_ok(), "another client is not affected");
    }

    #[test]
    fn a_client_gets_its_burst_then_its_rate() {
        let limit = RateLimit::default();
        let a: IpAddr = [127, 0, 0, 1].into();
        let b: IpAddr = [127, 0, 0, 2].into();
        for _ in 0..RateLimit::BURST as usize {
            assert!(limit.take(a).is_ok());
        }
        let wait = limit.take(a).expect_err("over the burst");
        assert!(wait > 0.0 && wait <= 1.0 / RateLimit::PER_SECOND, "{wait}");
        // Another client is not affected.
        assert!(limit.take(b).is_ok());
        std::thread::sleep(Duration::from_secs_f64(1.1 / RateLimit::PER_SECOND));
        assert!(limit.take(a).is_ok(), "refilled");
    }

    /// `client_gone` tells a client that closed after sending its request (the request still
    /// unread in the buffer) from one that is still there.
    #[tokio::test]
    async fn a_client_that_closed_is_gone_with_its_request_unread() {
        use tokio::io::AsyncWriteExt as _;
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        let mut stays = tokio::net::TcpStream::connect(addr).await.expect("connect");
        let (stays_here, _) = listener.accept().await.expect("accept");
        stays
            .write_all(b"POST /x HTTP/1.1\r\n\r\n")
            .await
            .expect("send");
        let mut leaves = tokio::net::TcpStream::connect(addr).await.expect("connect");
        let (leaves_here, _) = listener.accept().await.expect("accept");
        leaves
            .write_all(b"POST /x HTTP/1.1\r\n\r\n")
            .await
            .expect("send");
        drop(leaves);
        tokio::time::sleep(Duration::from_millis(50)).await;
        assert!(!client_gone(&stays_here));
        assert!(client_gone(&leaves_here));
    }

    /// Issue 23: a `POST` whose client went away while its connection waited for room is not
    /// started; one whose client stays is. (hyper itself drops a request whose connection
    /// reads as closed before the request is dispatched; `client_gone` closes such a
    /// connection before hyper reads it at all.) Two places: both held by requests in progress, a
    /// third connection sends its `POST` and closes; when the places free up, the request it
    /// left in the buffer must not run.
    #[tokio::test]
    async fn issue_23_a_request_whose_client_went_away_is_not_started() {
        use std::sync::atomic::AtomicUsize;
        use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};

        let started = Arc::new(AtomicUsize::new(0));
        let release = Arc::new(Notify::new());
        let (s, r) = (Arc::clone(&started), Arc::clone(&release));
        let app = Router::new()
            .route(
                "/hold",
                axum::routing::get(move || {
                    let r = Arc::clone(&r);
                    async move { r.notified().await }
                }),
            )
            .route(
                "/start",
                axum::routing::post(move |body: String| {
                    assert_eq!(body, "{}");
                    s.fetch_add(1, Ordering::SeqCst);
                    async {}
                }),
            );
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        let shutdown = CancellationToken::new();
        let server = tokio::spawn(serve_at_most(2, listener, app, shutdown.clone()));
        let request = |method: &str, path: &str| {
            format!("{method} {path} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 2\r\n\r\n{{}}")
        };
        let mut holders = Vec::new();
        for _ in 0..2 {
            let mut c = tokio::net::TcpStream::connect(addr).await.expect("connect");
            c.write_all(request("GET", "/hold").as_bytes())
                .await
                .expect("send");
            holders.push(c);
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
        // Waits for room, sends its request, gives up.
        let mut gone = tokio::net::TcpStream::connect(addr).await.expect("connect");
        gone.write_all(request("POST", "/start").as_bytes())
            .await
            .expect("send");
        tokio::time::sleep(Duration::from_millis(100)).await;
        drop(gone);
        // Waits for room and stays.
        let mut stays = tokio::net::TcpStream::connect(addr).await.expect("connect");
        stays
            .write_all(request("POST", "/start").as_bytes())
            .await
            .expect("send");
        tokio::time::sleep(Duration::from_millis(100)).await;
        release.notify_waiters();
        let mut answer = vec![0u8; 256];
        let n = tokio::time::timeout(Duration::from_secs(5), stays.read(&mut answer))
            .await
            .expect("answered in time")
            .expect("read");
        let answer = String::from_utf8_lossy(&answer[..n]).into_owned();
        assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
        // The client that stayed was served; the one that left was not.
        tokio::time::sleep(Duration::from_millis(200)).await;
        assert_eq!(started.load(Ordering::SeqCst), 1);
        shutdown.cancel();
        drop(holders);
        let _ = server.await;
    }
}
