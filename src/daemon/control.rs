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
//! - A storage path too long for a socket's address (108 bytes on Linux) still gets its socket
//!   in the same place: the daemon binds, and the client connects, through
//!   `/proc/self/fd/<the storage folder>/daemon.sock`.
//! - A socket file removed while the daemon runs is made again within [`RECHECK`].
//! - The client believes only the daemon: the peer's credentials (`SO_PEERCRED`) must be the
//!   process holding the storage's lock (`daemon.lock`, its holder from the kernel) and the
//!   socket file's owner; another process listening there (even of the daemon's user) is
//!   refused, and `handeye cancel` goes through the HTTP API.
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
/// How often the daemon checks that its socket file is still there (made again if not).
pub const RECHECK: Duration = Duration::from_secs(1);
/// Longest socket path bound or connected as is; a longer one goes through `/proc/self/fd`.
const MAX_SOCKET_PATH: usize = 100;

/// The control socket of the daemon on `storage`.
pub fn socket_path(storage: &Path) -> PathBuf {
    storage.join(SOCKET_FILE)
}

/// Serves the control socket in `storage` until `shutdown`; removes it then. A socket that
/// cannot be made is logged (the HTTP API still serves cancel), and tried again every
/// [`RECHECK`], as is one whose file was removed.
#[cfg(unix)]
pub(crate) async fn serve(storage: PathBuf, handle: DaemonHandle, shutdown: CancellationToken) {
    let path = socket_path(&storage);
    // SAFETY: geteuid has no preconditions and cannot fail.
    let me = unsafe { libc::geteuid() };
    let mut bound: Option<(tokio::net::UnixListener, (u64, u64))> = None;
    let mut failed = false;
    let mut recheck = tokio::time::interval(RECHECK);
    recheck.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        let accepted = match &bound {
            Some((listener, _)) => tokio::select! {
                _ = shutdown.cancelled() => break,
                _ = recheck.tick() => None,
                accepted = listener.accept() => Some(accepted),
            },
            None => tokio::select! {
                _ = shutdown.cancelled() => break,
                _ = recheck.tick() => None,
            },
        };
        let Some(accepted) = accepted else {
            // The file is still this socket's, or it is made (again).
            let ours = bound.as_ref().map(|(_, id)| *id);
            if ours.is_none() || file_id(&path) != ours {
                if ours.is_some() {
                    tracing::warn!(
                        "the control socket {} was removed or replaced; making it again",
                        path.display()
                    );
                }
                bound = None;
                match bind(&storage) {
                    Ok(b) => {
                        if failed {
                            tracing::info!("control socket {} made", path.display());
                        }
                        failed = false;
                        bound = Some(b);
                    }
                    Err(e) if !failed => {
                        failed = true;
                        tracing::error!(
                            "cannot make the control socket {}: {e}; `handeye cancel` goes \
                             through the HTTP API only (tried again every {RECHECK:?})",
                            path.display()
                        );
                    }
                    Err(_) => {}
                }
            }
            continue;
        };
        let stream = match accepted {
            Ok((s, _)) => s,
            Err(e) => {
                tracing::warn!("control socket: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
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
    if bound.is_some() {
        let _ = std::fs::remove_file(&path);
    }
}

/// Binds the socket in `storage`, mode 0600: whatever had its name goes first (the daemon
/// lock makes this daemon the only one on the storage; `remove_file` never follows a link).
/// Returns the listener and the file's device and inode.
#[cfg(unix)]
fn bind(storage: &Path) -> std::io::Result<(tokio::net::UnixListener, (u64, u64))> {
    use std::os::unix::fs::PermissionsExt as _;
    let path = socket_path(storage);
    match std::fs::remove_file(&path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e),
        _ => {}
    }
    let listener = short_path(storage, |p| {
        let l = std::os::unix::net::UnixListener::bind(p)?;
        std::fs::set_permissions(p, std::fs::Permissions::from_mode(0o600))?;
        Ok(l)
    })?;
    listener.set_nonblocking(true)?;
    let id = file_id(&path).ok_or_else(|| {
        std::io::Error::new(std::io::ErrorKind::NotFound, "the socket vanished at once")
    })?;
    Ok((tokio::net::UnixListener::from_std(listener)?, id))
}

/// The device and inode of the socket file at `path` (`None`: none, or not a socket).
#[cfg(unix)]
fn file_id(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::{FileTypeExt as _, MetadataExt as _};
    let m = std::fs::symlink_metadata(path).ok()?;
    m.file_type().is_socket().then(|| (m.dev(), m.ino()))
}

/// Calls `f` with a path of the socket in `storage` short enough for a socket address: the
/// path itself, or `/proc/self/fd/<fd of the folder>/daemon.sock` (the folder opened without
/// following a link at its end).
#[cfg(unix)]
fn short_path<T>(
    storage: &Path,
    f: impl FnOnce(&Path) -> std::io::Result<T>,
) -> std::io::Result<T> {
    use std::os::fd::AsRawFd as _;
    use std::os::unix::fs::OpenOptionsExt as _;
    let path = socket_path(storage);
    if path.as_os_str().len() <= MAX_SOCKET_PATH {
        return f(&path);
    }
    let dir = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_DIRECTORY | libc::O_NOFOLLOW | libc::O_CLOEXEC)
        .open(storage)?;
    f(&Path::new("/proc/self/fd")
        .join(dir.as_raw_fd().to_string())
        .join(SOCKET_FILE))
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
/// returns its answer (one line of JSON). The peer must be the daemon: the process holding
/// the storage's lock, and the socket file's owner (else `PermissionDenied`, nothing sent).
/// Blocking, at most a few seconds.
#[cfg(unix)]
pub fn request(storage: &Path, request: &str) -> std::io::Result<String> {
    use std::io::{Read as _, Write as _};
    let mut s = short_path(storage, |p| std::os::unix::net::UnixStream::connect(p))?;
    check_peer(storage, &s)?;
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

/// Whether the peer of `stream` is the daemon of `storage`: its pid the holder of
/// `daemon.lock` (from the kernel), its uid the socket file's owner.
#[cfg(unix)]
fn check_peer(storage: &Path, stream: &std::os::unix::net::UnixStream) -> std::io::Result<()> {
    use std::os::fd::AsRawFd as _;
    use std::os::unix::fs::MetadataExt as _;
    let mut cred = libc::ucred {
        pid: 0,
        uid: 0,
        gid: 0,
    };
    let mut len = std::mem::size_of::<libc::ucred>() as libc::socklen_t;
    // SAFETY: a valid socket and an out-parameter of the size given.
    let r = unsafe {
        libc::getsockopt(
            stream.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_PEERCRED,
            (&mut cred as *mut libc::ucred).cast(),
            &mut len,
        )
    };
    if r != 0 {
        return Err(std::io::Error::last_os_error());
    }
    let refuse = |why: String| {
        Err(std::io::Error::new(
            std::io::ErrorKind::PermissionDenied,
            format!(
                "the process listening on {} (pid {}, uid {}) is not the daemon: {why}",
                socket_path(storage).display(),
                cred.pid,
                cred.uid
            ),
        ))
    };
    let lock = {
        use std::os::unix::fs::OpenOptionsExt as _;
        std::fs::OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK | libc::O_CLOEXEC)
            .open(storage.join(super::lock::LOCK_FILE))?
    };
    match crate::lockfile::holder(&lock) {
        Some(h) if i64::from(h.pid) == i64::from(cred.pid) => {}
        Some(h) => return refuse(format!("pid {} holds the storage's lock", h.pid)),
        None => return refuse("no process holds the storage's lock".into()),
    }
    let owner = std::fs::symlink_metadata(socket_path(storage))?.uid();
    if owner != cred.uid {
        return refuse(format!("the socket file is uid {owner}'s"));
    }
    Ok(())
}

/// Without Unix sockets there is no control socket.
#[cfg(not(unix))]
pub fn request(_: &Path, _: &str) -> std::io::Result<String> {
    Err(std::io::Error::new(
        std::io::ErrorKind::Unsupported,
        "no control socket on this platform",
    ))
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::config::WhenBusy;

    /// A storage folder `name` under a path of `len` bytes at least.
    fn storage(tag: &str, len: usize) -> PathBuf {
        let mut dir =
            std::env::temp_dir().join(format!("handeye-control-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        while dir.as_os_str().len() < len {
            dir = dir.join("a-long-folder-name-to-pass-the-socket-path-limit");
        }
        std::fs::create_dir_all(&dir).expect("dir");
        dir
    }

    /// Issue 46: a storage path beyond the socket path limit still gets its socket (it was not
    /// made); a socket file removed while the daemon runs is made again (it was not, and
    /// `cancel` fell back to HTTP); a process listening in its place while another holds the
    /// storage's lock is not believed (it was, being of the daemon's user).
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn issue_46_the_socket_survives_long_paths_and_removal_and_only_the_daemon_is_believed() {
        let dir = storage("long", 150);
        assert!(socket_path(&dir).as_os_str().len() > 108);
        let lock = super::super::lock::DaemonLock::acquire(&dir).expect("lock");
        let store = crate::store::Store::open(&dir.join("history.sqlite")).expect("store");
        let handle =
            super::super::handle(Arc::new(store), WhenBusy::Refuse, CancellationToken::new());
        let stop = CancellationToken::new();
        let task = tokio::spawn(serve(dir.clone(), handle, stop.clone()));
        let ask = |d: PathBuf| async move {
            tokio::task::spawn_blocking(move || request(&d, "status"))
                .await
                .expect("join")
        };
        let answered = |d: &PathBuf| {
            let d = d.clone();
            async move {
                for _ in 0..50 {
                    if ask(d.clone()).await.is_ok() {
                        return true;
                    }
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
                false
            }
        };
        assert!(answered(&dir).await, "no answer on a long path");
        std::fs::remove_file(socket_path(&dir)).expect("remove the socket");
        assert!(
            answered(&dir).await,
            "the removed socket was not made again"
        );
        stop.cancel();
        task.await.expect("served");
        assert!(
            !socket_path(&dir).exists(),
            "the socket stays after the stop"
        );

        // An impostor of the same user listens while another process holds the lock.
        drop(lock);
        let mut holder = std::process::Command::new("flock")
            .arg("-x")
            .arg(dir.join(super::super::lock::LOCK_FILE))
            .args(["sleep", "30"])
            .spawn()
            .expect("flock(1)");
        std::thread::sleep(Duration::from_millis(300));
        let _impostor =
            short_path(&dir, |p| std::os::unix::net::UnixListener::bind(p)).expect("bind");
        let e = ask(dir.clone()).await.expect_err("an impostor");
        assert_eq!(e.kind(), std::io::ErrorKind::PermissionDenied, "{e}");
        assert!(
            e.to_string()
                .contains(&format!("is not the daemon: pid {} holds", holder.id())),
            "{e}"
        );
        let _ = holder.kill();
        let _ = holder.wait();
        let _ = std::fs::remove_dir_all(
            std::env::temp_dir().join(format!("handeye-control-{}-long", std::process::id())),
        );
    }
}
