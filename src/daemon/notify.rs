//! systemd readiness and watchdog notifications (`sd_notify(3)`), without libsystemd.
//!
//! Under a `Type=notify` unit systemd sets `NOTIFY_SOCKET` (a datagram socket: a path, or an
//! abstract name written `@name`) and, with `WatchdogSec=`, `WATCHDOG_USEC` (and
//! `WATCHDOG_PID`). The daemon tells systemd it is ready (`READY=1`), what it is doing
//! (`STATUS=…`, shown by `systemctl status`), that it is stopping (`STOPPING=1`) and that it is
//! alive (`WATCHDOG=1`, at least once per `WATCHDOG_USEC`, or systemd kills and restarts it).
//!
//! Every send is a single non-blocking datagram from an unbound socket. A failed send is logged
//! (`warn` the first time, `debug` after that) and otherwise ignored: notifications never
//! panic, never block and never stop the daemon. Outside systemd (no `NOTIFY_SOCKET`)
//! [`Notifier::from_env`] returns `None` and there is nothing to call.
//!
//! The environment is left as it is. Child processes (the `exec` camera backend) inherit
//! `NOTIFY_SOCKET`, which is harmless with `NotifyAccess=main` in the unit: systemd ignores
//! messages from any process but ours.

use std::ffi::OsStr;
use std::io;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use tokio_util::sync::CancellationToken;

/// Longest `STATUS=` text sent, in bytes (longer text is cut at a character boundary).
/// `systemctl status` shows one line; systemd accepts datagrams up to 4 kB.
pub(crate) const STATUS_MAX_BYTES: usize = 256;

/// A connection to systemd's notification socket. Cheap to clone (clones share the socket and
/// the "already warned" flag).
#[derive(Debug, Clone)]
pub(crate) struct Notifier {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    /// Unbound, non-blocking; every message is a `send_to` the notification socket.
    socket: UnixDatagram,
    /// `NOTIFY_SOCKET` as systemd gave it, for log messages.
    target: String,
    /// Where to send: a filesystem path or (Linux) an abstract name.
    addr: SocketAddr,
    /// Half of `WATCHDOG_USEC` when the watchdog is meant for this process; `None`: no watchdog.
    watchdog_interval: Option<Duration>,
    /// Set after the first failed send, so a missing socket does not flood the log.
    warned: AtomicBool,
}

impl Notifier {
    /// The notifier systemd asked for through `NOTIFY_SOCKET`, `WATCHDOG_USEC` and
    /// `WATCHDOG_PID`; `None` when not started by systemd as a notify service (no
    /// `NOTIFY_SOCKET`) or when the variable cannot be used (logged).
    pub(crate) fn from_env() -> Option<Notifier> {
        let socket = std::env::var_os("NOTIFY_SOCKET")?;
        let usec = std::env::var_os("WATCHDOG_USEC");
        let pid = std::env::var_os("WATCHDOG_PID");
        Self::from_vars(&socket, usec.as_deref(), pid.as_deref())
    }

    /// A notifier from the values of `NOTIFY_SOCKET`, `WATCHDOG_USEC` and `WATCHDOG_PID`, as
    /// [`from_env`](Self::from_env) reads them. `None` (logged) when `notify_socket` is neither
    /// an absolute path nor `@abstract-name`, or no socket can be created. A malformed or zero
    /// `WATCHDOG_USEC` means no watchdog (logged); a `WATCHDOG_PID` other than ours means the
    /// watchdog is another process's.
    pub(crate) fn from_vars(
        notify_socket: &OsStr,
        watchdog_usec: Option<&OsStr>,
        watchdog_pid: Option<&OsStr>,
    ) -> Option<Notifier> {
        let target = notify_socket.to_string_lossy().into_owned();
        let addr = match socket_addr(notify_socket) {
            Ok(a) => a,
            Err(e) => {
                tracing::warn!(
                    "NOTIFY_SOCKET={target:?} not usable, no systemd notifications: {e}"
                );
                return None;
            }
        };
        let socket = match UnixDatagram::unbound().and_then(|s| {
            s.set_nonblocking(true)?;
            Ok(s)
        }) {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!("no socket for systemd notifications ({target}): {e}");
                return None;
            }
        };
        let watchdog_interval = watchdog_interval(watchdog_usec, watchdog_pid, std::process::id());
        Some(Notifier {
            inner: Arc::new(Inner {
                socket,
                target,
                addr,
                watchdog_interval,
                warned: AtomicBool::new(false),
            }),
        })
    }

    /// `READY=1`: start-up is finished (systemd's start job completes, `After=` units start).
    pub(crate) fn ready(&self) {
        self.notify("READY=1");
    }

    /// `STATUS=text`: one line for `systemctl status`. Control characters (newlines included,
    /// which would end the field) become spaces; the text is cut to [`STATUS_MAX_BYTES`].
    pub(crate) fn status(&self, text: &str) {
        self.notify(&status_message(text));
    }

    /// `STOPPING=1`: shutdown has begun (sent before stopping the arm and closing connections).
    pub(crate) fn stopping(&self) {
        self.notify("STOPPING=1");
    }

    /// `WATCHDOG=1`: the daemon is alive. systemd restarts the service when it has not heard
    /// this for `WatchdogSec=`. Send it at least every [`watchdog_interval`](Self::watchdog_interval).
    ///
    /// [`feed_watchdog`] sends it from its own task, which proves only that the tokio runtime is
    /// alive. To have a hung main loop detected too, call this from the main loop instead (on
    /// a timer branch of its `select!`), so the feeding stops when the loop does.
    pub(crate) fn watchdog(&self) {
        self.notify("WATCHDOG=1");
    }

    /// How often to send `WATCHDOG=1`: half of `WATCHDOG_USEC`, as `sd_watchdog_enabled(3)`
    /// recommends; `None` when systemd set no watchdog or set it for another process
    /// (`WATCHDOG_PID` not ours).
    pub(crate) fn watchdog_interval(&self) -> Option<Duration> {
        self.inner.watchdog_interval
    }

    /// Sends one message, logging (not returning) a failure.
    fn notify(&self, message: &str) {
        if let Err(e) = self.send(message) {
            let first = !self.inner.warned.swap(true, Ordering::Relaxed);
            let target = &self.inner.target;
            if first {
                tracing::warn!("systemd notification {message:?} to {target} failed: {e} (further failures logged at debug level)");
            } else {
                tracing::debug!("systemd notification {message:?} to {target} failed: {e}");
            }
        }
    }

    /// Sends one datagram without blocking (`WouldBlock` if systemd's queue is full).
    fn send(&self, message: &str) -> io::Result<()> {
        let sent = self
            .inner
            .socket
            .send_to_addr(message.as_bytes(), &self.inner.addr)?;
        if sent != message.len() {
            return Err(io::Error::new(
                io::ErrorKind::WriteZero,
                format!("sent {sent} of {} bytes", message.len()),
            ));
        }
        Ok(())
    }
}

/// Sends `WATCHDOG=1` now and then every [`Notifier::watchdog_interval`] until `shutdown` is
/// cancelled; returns at once when there is no watchdog. The daemon spawns it next to its main
/// loop and cancels `shutdown` when the loop ends, so systemd's watchdog fires if the process
/// stops shutting down in time or the runtime stalls — not if the main loop alone hangs
/// (for that, call [`Notifier::watchdog`] from the loop instead).
pub(crate) async fn feed_watchdog(n: Notifier, shutdown: CancellationToken) {
    let Some(every) = n.watchdog_interval() else {
        return;
    };
    let mut tick = tokio::time::interval(every);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            biased;
            _ = shutdown.cancelled() => return,
            _ = tick.tick() => n.watchdog(),
        }
    }
}

/// The address `NOTIFY_SOCKET` names: an absolute path, or `@name` for an abstract socket.
fn socket_addr(notify_socket: &OsStr) -> io::Result<SocketAddr> {
    let bytes = notify_socket.as_bytes();
    match bytes.first() {
        Some(b'/') => SocketAddr::from_pathname(notify_socket),
        Some(b'@') => abstract_addr(&bytes[1..]),
        _ => Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "expected an absolute path or @abstract-name (vsock is not supported)",
        )),
    }
}

#[cfg(target_os = "linux")]
fn abstract_addr(name: &[u8]) -> io::Result<SocketAddr> {
    use std::os::linux::net::SocketAddrExt;
    SocketAddr::from_abstract_name(name)
}

#[cfg(not(target_os = "linux"))]
fn abstract_addr(_name: &[u8]) -> io::Result<SocketAddr> {
    Err(io::Error::new(
        io::ErrorKind::Unsupported,
        "abstract sockets exist only on Linux",
    ))
}

/// Half of `WATCHDOG_USEC` (µs), unless it is absent, malformed or zero, or `WATCHDOG_PID` is
/// set to a process other than `our_pid`.
fn watchdog_interval(usec: Option<&OsStr>, pid: Option<&OsStr>, our_pid: u32) -> Option<Duration> {
    let usec = usec?;
    if let Some(pid) = pid {
        if pid.to_str().and_then(|p| p.trim().parse::<u32>().ok()) != Some(our_pid) {
            tracing::debug!("WATCHDOG_PID={pid:?} is not this process ({our_pid}): no watchdog");
            return None;
        }
    }
    match usec.to_str().and_then(|u| u.trim().parse::<u64>().ok()) {
        Some(u) if u > 0 => Some(Duration::from_micros(u / 2)),
        _ => {
            tracing::warn!("WATCHDOG_USEC={usec:?} is not a positive integer: no watchdog");
            None
        }
    }
}

/// `STATUS=` and the text on one line, at most [`STATUS_MAX_BYTES`] of it.
fn status_message(text: &str) -> String {
    let mut out = String::with_capacity(7 + text.len().min(STATUS_MAX_BYTES));
    out.push_str("STATUS=");
    let mut len = 0;
    for c in text.trim().chars() {
        let c = if c.is_control() { ' ' } else { c };
        len += c.len_utf8();
        if len > STATUS_MAX_BYTES {
            break;
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    /// A bound datagram socket in a fresh directory (removed on drop), standing in for systemd.
    struct Listener {
        dir: PathBuf,
        path: PathBuf,
        socket: UnixDatagram,
    }

    impl Listener {
        fn new(test: &str) -> Self {
            let dir =
                std::env::temp_dir().join(format!("handeye-notify-{test}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).expect("create temp dir");
            let path = dir.join("notify");
            let socket = UnixDatagram::bind(&path).expect("bind listener");
            socket
                .set_read_timeout(Some(Duration::from_secs(5)))
                .expect("socket option");
            Self { dir, path, socket }
        }

        fn recv(&self) -> String {
            let mut buf = [0u8; 4096];
            let n = self.socket.recv(&mut buf).expect("a datagram within 5 s");
            String::from_utf8(buf[..n].to_vec()).expect("UTF-8 datagram")
        }

        fn assert_empty(&self) {
            self.socket.set_nonblocking(true).expect("socket option");
            let mut buf = [0u8; 4096];
            let r = self.socket.recv(&mut buf);
            assert!(
                matches!(&r, Err(e) if e.kind() == io::ErrorKind::WouldBlock),
                "unexpected datagram: {:?}",
                r.map(|n| String::from_utf8_lossy(&buf[..n]).into_owned())
            );
            self.socket.set_nonblocking(false).expect("socket option");
        }
    }

    impl Drop for Listener {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }

    fn os(s: &str) -> &OsStr {
        OsStr::new(s)
    }

    #[test]
    fn sends_exact_datagrams() {
        let l = Listener::new("exact");
        let n = Notifier::from_vars(l.path.as_os_str(), None, None).expect("notifier");
        n.ready();
        assert_eq!(l.recv(), "READY=1");
        n.status("idle; last run 42: passed");
        assert_eq!(l.recv(), "STATUS=idle; last run 42: passed");
        n.stopping();
        assert_eq!(l.recv(), "STOPPING=1");
        n.watchdog();
        assert_eq!(l.recv(), "WATCHDOG=1");
        // Clones share the socket.
        n.clone().ready();
        assert_eq!(l.recv(), "READY=1");
        l.assert_empty();
    }

    #[test]
    fn status_is_one_bounded_line() {
        let l = Listener::new("status");
        let n = Notifier::from_vars(l.path.as_os_str(), None, None).expect("notifier");
        n.status("run failed:\ncamera timeout\r\nREADY=1\n");
        assert_eq!(l.recv(), "STATUS=run failed: camera timeout  READY=1");
        // Multi-byte characters are never split: 200 × "é" (2 bytes) → 128 of them.
        n.status(&"é".repeat(200));
        let got = l.recv();
        assert_eq!(got, format!("STATUS={}", "é".repeat(STATUS_MAX_BYTES / 2)));
        n.status(&"x".repeat(10_000));
        assert_eq!(l.recv().len(), "STATUS=".len() + STATUS_MAX_BYTES);
        l.assert_empty();
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn abstract_socket() {
        use std::os::linux::net::SocketAddrExt;
        let name = format!("handeye-notify-test-{}", std::process::id());
        let addr = SocketAddr::from_abstract_name(name.as_bytes()).expect("abstract name");
        let listener = UnixDatagram::bind_addr(&addr).expect("bind abstract listener");
        listener
            .set_read_timeout(Some(Duration::from_secs(5)))
            .expect("socket option");
        let n = Notifier::from_vars(os(&format!("@{name}")), None, None).expect("notifier");
        n.ready();
        let mut buf = [0u8; 64];
        let len = listener.recv(&mut buf).expect("a datagram within 5 s");
        assert_eq!(&buf[..len], b"READY=1");
    }

    #[test]
    fn watchdog_interval_is_half_for_us_only() {
        let me = std::process::id();
        let other = me.wrapping_add(1).to_string();
        let mine = me.to_string();
        let n = |usec: Option<&str>, pid: Option<&str>| {
            Notifier::from_vars(os("/run/systemd/notify"), usec.map(os), pid.map(os))
                .expect("notifier")
                .watchdog_interval()
        };
        assert_eq!(n(Some("30000000"), None), Some(Duration::from_secs(15)));
        assert_eq!(
            n(Some("30000000"), Some(&mine)),
            Some(Duration::from_secs(15))
        );
        assert_eq!(n(Some("30000000"), Some(&other)), None);
        assert_eq!(n(Some("30000000"), Some("not-a-pid")), None);
        assert_eq!(n(None, None), None);
        assert_eq!(n(Some("0"), None), None);
        assert_eq!(n(Some("soon"), None), None);
    }

    #[test]
    fn unusable_socket_names_give_none() {
        assert!(Notifier::from_vars(os(""), None, None).is_none());
        assert!(Notifier::from_vars(os("relative/notify"), None, None).is_none());
        assert!(Notifier::from_vars(os("vsock:2:1234"), None, None).is_none());
        let too_long = format!("/{}", "x".repeat(200));
        assert!(Notifier::from_vars(os(&too_long), None, None).is_none());
    }

    #[test]
    fn missing_socket_does_not_panic_or_block() {
        let dir =
            std::env::temp_dir().join(format!("handeye-notify-missing-{}", std::process::id()));
        let n = Notifier::from_vars(dir.join("gone").as_os_str(), Some(os("1000")), None)
            .expect("notifier");
        let t = std::time::Instant::now();
        for _ in 0..3 {
            n.ready();
            n.status("still here");
            n.watchdog();
            n.stopping();
        }
        assert!(n.send("READY=1").is_err());
        assert!(n.inner.warned.load(Ordering::Relaxed));
        assert!(t.elapsed() < Duration::from_secs(1));
    }

    #[test]
    fn feed_watchdog_until_shutdown() {
        let l = Listener::new("feed");
        // WATCHDOG_USEC = 40 ms → a WATCHDOG=1 every 20 ms, the first at once.
        let n = Notifier::from_vars(l.path.as_os_str(), Some(os("40000")), None).expect("notifier");
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_time()
            .build()
            .expect("runtime");
        let shutdown = CancellationToken::new();
        let task = rt.spawn(feed_watchdog(n, shutdown.clone()));
        for _ in 0..3 {
            assert_eq!(l.recv(), "WATCHDOG=1");
        }
        shutdown.cancel();
        rt.block_on(async {
            tokio::time::timeout(Duration::from_secs(5), task)
                .await
                .expect("feed_watchdog ends on shutdown")
                .expect("feed_watchdog does not panic");
        });
        // Drain what was sent before the cancel; nothing comes after.
        l.socket.set_nonblocking(true).expect("socket option");
        let mut buf = [0u8; 64];
        while l.socket.recv(&mut buf).is_ok() {}
        std::thread::sleep(Duration::from_millis(60));
        l.assert_empty();
    }

    #[test]
    fn feed_watchdog_without_watchdog_returns() {
        let n = Notifier::from_vars(os("/run/systemd/notify"), None, None).expect("notifier");
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .expect("runtime");
        rt.block_on(async {
            tokio::time::timeout(
                Duration::from_secs(5),
                feed_watchdog(n, CancellationToken::new()),
            )
            .await
            .expect("returns at once without a watchdog");
        });
    }
}
