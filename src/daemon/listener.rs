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
    let permits = Arc::new(Semaphore::new(MAX_CONNECTIONS));
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
                    tracing::warn!("HTTP API: {MAX_CONNECTIONS} connections and {MAX_WAITING} waiting; closing new ones");
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
