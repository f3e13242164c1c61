//! The local control socket: `<storage.dir>/daemon.sock`, a Unix socket the CLI's `handeye
//! cancel` reaches the daemon through, apart from the HTTP API
//! and its connection limits — any local process can hold the HTTP API's per-address share
//! (every local client is 127.0.0.1), never this path to stop the arm.
//!
//! - The socket file is mode 0600 in the storage directory: only the daemon's user (and root)
//!   can connect; the peer's credentials (`SO_PEERCRED`) are checked again on every
//!   connection, and another user's connection is closed unread.
//! - One request per connection: a line `cancel` or `status` (at most [`MAX_REQUEST`] bytes,
//!   within [`REQUEST_TIMEOUT`]); the answer is one line of JSON (`{"cancelled":true}`, the
//!   status as `GET /api/status` gives it, or `{"error":"…"}`), then the connection closes.
//! - Every connection is served on its own task with its own time limit: no number of idle
//!   connections holds another one up.
//!
//! No token: the socket's permissions are the authentication, and it only stops and reads.

use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio_util::sync::CancellationToken;

use super::DaemonHandle;

/// File name of the socket in the storage directory.
pub const SOCKET_FILE: &str = "daemon.sock";
/// Longest request line, bytes.
pub const MAX_REQUEST: usize = 64;
/// How long a connection may take to send its request.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(2);

/// The control socket of the daemon on `storage`.
pub fn socket_path(storage: &Path) -> PathBuf {
    storage.join(SOCKET_FILE)
}

/// Serves the control socket in `storage` until `shutdown`; removes it then. A socket that
/// cannot be made is logged (the HTTP API still serves cancel).
#[cfg(unix)]
pub(crate) async fn serve(storage: PathBuf, handle: DaemonHandle, shutdown: CancellationToken) {
    use std::os::unix::fs::PermissionsExt as _;
    let path = socket_path(&storage);
    // The daemon lock makes this daemon the only one on the storage: a socket file left by a
    // killed one (or anything else by that name) goes. `remove_file` never follows a link.
    let _ = std::fs::remove_file(&path);
    let listener = match tokio::net::UnixListener::bind(&path) {
        Ok(l) => l,
        Err(e) => {
            tracing::error!(
                "cannot make the control socket {}: {e}; `handeye cancel` goes through the HTTP API only",
                path.display()
            );
            return;
        }
    };
    if let Err(e) = std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)) {
        tracing::error!("cannot restrict {} to this user: {e}", path.display());
        let _ = std::fs::remove_file(&path);
        return;
    }
    // SAFETY: geteuid has no preconditions and cannot fail.
    let me = unsafe { libc::geteuid() };
    loop {
        let stream = tokio::select! {
            _ = shutdown.cancelled() => break,
            accepted = listener.accept() => match accepted {
                Ok((s, _)) => s,
                Err(e) => {
                    tracing::warn!("control socket: accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
        };
        let allowed = stream
            .peer_cred()
            .is_ok_and(|c| c.uid() == me || c.uid() == 0);
        if !allowed {
            tracing::warn!("control socket: a connection from another user was closed");
            continue;
        }
        let handle = handle.clone();
        tokio::spawn(async move {
            if let Err(e) = answer(stream, &handle).await {
                tracing::debug!("control socket: {e}");
            }
        });
    }
    let _ = std::fs::remove_file(&path);
}

/// Without Unix sockets there is no control socket.
#[cfg(not(unix))]
pub(crate) async fn serve(_: PathBuf, _: DaemonHandle, shutdown: CancellationToken) {
    shutdown.cancelled().await;
}

#[cfg(unix)]
async fn answer(mut stream: tokio::net::UnixStream, handle: &DaemonHandle) -> std::io::Result<()> {
    use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
    let mut buf = Vec::with_capacity(MAX_REQUEST);
    let read = async {
        let mut byte = [0u8; 1];
        while buf.len() < MAX_REQUEST {
            if stream.read(&mut byte).await? == 0 || byte[0] == b'\n' {
                break;
            }
            buf.push(byte[0]);
        }
        Ok::<_, std::io::Error>(())
    };
    tokio::time::timeout(REQUEST_TIMEOUT, read)
        .await
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::TimedOut, "no request in time"))??;
    let body = match String::from_utf8_lossy(&buf).trim() {
        "cancel" => {
            let cancelled = handle.cancel();
            tracing::info!(cancelled, "cancel asked through the control socket");
            serde_json::json!({ "cancelled": cancelled }).to_string()
        }
        "status" => serde_json::to_string(&handle.status())
            .unwrap_or_else(|e| serde_json::json!({ "error": e.to_string() }).to_string()),
        other => serde_json::json!({
            "error": format!("unknown request `{}`: `cancel` or `status`", handeye_hal::limits::sanitize_message(other))
        })
        .to_string(),
    };
    tokio::time::timeout(REQUEST_TIMEOUT, async {
        stream.write_all(body.as_bytes()).await?;
        stream.write_all(b"\n").await?;
        stream.shutdown().await
    })
    .await
    .map_err(|_| std::io::Error::new(std::io::ErrorKind::TimedOut, "answer not taken in time"))?
}

/// Sends `request` (`cancel`, `status`) to the daemon's control socket in `storage` and
/// returns its answer (one line of JSON). Blocking, at most a few seconds.
#[cfg(unix)]
pub fn request(storage: &Path, request: &str) -> std::io::Result<String> {
    use std::io::{Read as _, Write as _};
    let mut s = std::os::unix::net::UnixStream::connect(socket_path(storage))?;
    s.set_read_timeout(Some(Duration::from_secs(5)))?;
    s.set_write_timeout(Some(Duration::from_secs(5)))?;
    s.write_all(format!("{request}\n").as_bytes())?;
    let mut answer = String::new();
    s.take(16 << 20).read_to_string(&mut answer)?;
    if answer.trim().is_empty() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::UnexpectedEof,
            "the daemon closed the control socket without answering",
        ));
    }
    Ok(answer)
}

/// Without Unix sockets there is no control socket.
#[cfg(not(unix))]
pub fn request(_: &Path, _: &str) -> std::io::Result<String> {
    Err(std::io::Error::new(
        std::io::ErrorKind::Unsupported,
        "no control socket on this platform",
    ))
}
