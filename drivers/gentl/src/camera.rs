//! [`GentlCamera`]: a 3D camera reached through its GenTL producer, behind
//! [`handeye_hal::DepthCamera`].
//!
//! The producer is never loaded into this process: a host process (`handeye gentl-host`, see
//! [`crate::host`]) loads it and drives the device, and this side talks to it over a pipe
//! ([`crate::wire`]). The host announces each producer call that may block; a call past its
//! deadline (`call_timeout`, or the frame timeout plus [`FRAME_GRACE`] for `EventGetData`)
//! gets the host killed, the request fails naming the call and the producer, and a new host
//! is started and the device opened again before the next request is served. A producer that
//! aborts or calls `exit()` ends only its host, with the same outcome.

use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use handeye_hal::{CameraInfo, CaptureSettings, DepthCamera, HalError, PointCloud, Trigger};
use tokio::sync::{mpsc, oneshot};
use tokio::time::Instant;

use crate::error::{GentlError, Result};
use crate::producer::DeviceInfo;
use crate::wire::{self, Answer, Message, Request, Tag};

/// The hidden subcommand of the host program that runs [`crate::host::serve`].
pub const HOST_SUBCOMMAND: &str = "gentl-host";
/// Default deadline of one producer call (loading, enumeration, opening, register access,
/// starting and stopping acquisition).
pub const DEFAULT_CALL_TIMEOUT: Duration = Duration::from_secs(10);
/// How long `EventGetData` may run past the frame timeout it was given.
pub const FRAME_GRACE: Duration = Duration::from_secs(1);
/// Largest producer file accepted, bytes (real ones are a few MB to a few hundred).
const MAX_PRODUCER_BYTES: u64 = 2 << 30;

/// How to open and stream.
#[derive(Debug, Clone, PartialEq)]
pub struct GentlOptions {
    /// Which device: its serial number, model name, producer id, or index in the listing
    /// ([`list_devices`]); the first device when `None`.
    pub device: Option<String>,
    /// Also enable the Confidence component when the camera offers it.
    pub confidence: bool,
    /// How frames are started (`camera.trigger`).
    pub trigger: Trigger,
    /// Deadline of each producer call but `EventGetData` (`camera.call_timeout_s`).
    pub call_timeout: Duration,
    /// The program run as the host with [`HOST_SUBCOMMAND`]; this executable when `None`.
    pub host: Option<PathBuf>,
    /// The user set and features written before every capture (`camera.user_set`,
    /// `[camera.features]`).
    pub settings: handeye_hal::CameraSettings,
}

impl Default for GentlOptions {
    fn default() -> Self {
        Self {
            device: None,
            confidence: false,
            trigger: Trigger::default(),
            call_timeout: DEFAULT_CALL_TIMEOUT,
            host: None,
            settings: handeye_hal::CameraSettings::default(),
        }
    }
}

/// Counters of one capture.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct GentlStats {
    /// Complete buffers decoded.
    pub complete: u32,
    /// Buffers the producer flagged incomplete (dropped).
    pub incomplete: u32,
}

/// One interface of a producer and the devices on it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct InterfaceDevices {
    /// The producer's interface id.
    pub interface: String,
    /// Its devices.
    pub devices: Vec<DeviceInfo>,
}

/// The producer file checked as every input is: a regular file (a FIFO or device would block
/// the host's `dlopen` forever), readable, of a sane size.
pub fn check_producer(path: &Path) -> Result<()> {
    handeye_hal::limits::check_regular_file(path, MAX_PRODUCER_BYTES)
        .and_then(|_| std::fs::File::open(path).map(drop))
        .map_err(|e| GentlError::Load {
            path: path.to_owned(),
            detail: e.to_string(),
        })
}

/// List a producer's interfaces and their devices, through a host process (each list update
/// may wait for the producer's discovery, within `options.call_timeout`).
pub async fn list_devices(
    producer: &Path,
    options: &GentlOptions,
) -> Result<Vec<InterfaceDevices>> {
    check_producer(producer)?;
    let mut host = Host::spawn(producer, options)?;
    let request = Request::List {
        producer: producer.display().to_string(),
        call_timeout_ms: millis(options.call_timeout),
    };
    match host.ask(&request, "listing the devices").await? {
        Answer::Listed(list) => Ok(list),
        other => Err(host.unexpected(&other)),
    }
}

/// Open the device `options.device` names (the first when `None`) through a host process and
/// read what it is and the features a user would set (`camera probe --gentl --device`).
pub async fn probe_device(
    producer: &Path,
    options: &GentlOptions,
) -> Result<(CameraInfo, Vec<handeye_gige::genicam::FeatureState>)> {
    check_producer(producer)?;
    let mut host = open_host(producer, options).await?;
    let info = match host
        .ask(&Request::Info, "reading the camera's identity")
        .await?
    {
        Answer::Info(info) => info,
        other => return Err(host.unexpected(&other)),
    };
    match host
        .ask(&Request::Features, "reading the camera's features")
        .await?
    {
        Answer::Features(features) => Ok((info, features)),
        other => Err(host.unexpected(&other)),
    }
}

fn millis(d: Duration) -> u64 {
    u64::try_from(d.as_millis()).unwrap_or(u64::MAX)
}

/// The host process and what it says.
struct Host {
    child: Option<Child>,
    stdin: Option<ChildStdin>,
    messages: mpsc::UnboundedReceiver<std::io::Result<Message>>,
    producer: PathBuf,
    call_timeout: Duration,
}

impl Host {
    /// Start a host for `producer`.
    fn spawn(producer: &Path, options: &GentlOptions) -> Result<Self> {
        let program = match &options.host {
            Some(p) => p.clone(),
            None => std::env::current_exe().map_err(|e| {
                GentlError::Closed(format!(
                    "cannot find this program to host the producer: {e}"
                ))
            })?,
        };
        let mut child = Command::new(&program)
            .arg(HOST_SUBCOMMAND)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| {
                GentlError::Closed(format!(
                    "cannot start the GenTL host `{} {HOST_SUBCOMMAND}`: {e}",
                    program.display()
                ))
            })?;
        let (stdin, stdout) = (child.stdin.take(), child.stdout.take());
        let (tx, messages) = mpsc::unbounded_channel();
        if let Some(mut out) = stdout {
            std::thread::Builder::new()
                .name("gentl-host-output".into())
                .spawn(move || loop {
                    let m = wire::read_frame(&mut out).and_then(|f| {
                        f.map(|(tag, body)| wire::decode_message(tag, &body))
                            .transpose()
                    });
                    match m {
                        Ok(Some(m)) => {
                            if tx.send(Ok(m)).is_err() {
                                return;
                            }
                        }
                        Ok(None) => return,
                        Err(e) => {
                            let _ = tx.send(Err(e));
                            return;
                        }
                    }
                })
                .map_err(|e| GentlError::Closed(format!("cannot start a reader thread: {e}")))?;
        }
        Ok(Self {
            child: Some(child),
            stdin,
            messages,
            producer: producer.to_owned(),
            call_timeout: options.call_timeout,
        })
    }

    /// Send `request` and wait for its answer, each announced producer call within its budget
    /// and the host's own work between them within the call timeout. Past a deadline, or
    /// when the host ends, the host is killed and the error names the call.
    async fn ask(&mut self, request: &Request, doing: &str) -> Result<Answer> {
        let sent = self
            .stdin
            .as_mut()
            .ok_or_else(|| std::io::Error::other("no host"))
            .and_then(|w| wire::write_frame(w, Tag::Request, &wire::json(request)));
        if let Err(e) = sent {
            return Err(self.ended(doing, &format!("its input: {e}")).await);
        }
        match self.next(doing).await? {
            Message::Answer(Answer::Failed(f)) => Err(GentlError::Host {
                message: f.message,
                class: f.class,
            }),
            Message::Answer(a) => Ok(a),
            Message::Cloud(_) => Err(self.broken("a cloud without a capture")),
            Message::Begin { .. } | Message::End => {
                Err(self.broken("a call announced out of turn"))
            }
        }
    }

    /// The next answer or cloud, watching the announced calls on the way.
    async fn next(&mut self, doing: &str) -> Result<Message> {
        let mut call = doing.to_owned();
        let mut budget = self.call_timeout;
        let mut deadline = Instant::now() + budget;
        loop {
            match tokio::time::timeout_at(deadline, self.messages.recv()).await {
                Err(_) => {
                    self.kill();
                    return Err(GentlError::Deadline {
                        call,
                        producer: self.producer.clone(),
                        deadline: budget,
                    });
                }
                Ok(None) => return Err(self.ended(&call, "").await),
                Ok(Some(Err(e))) => return Err(self.broken(&e.to_string())),
                Ok(Some(Ok(Message::Begin { call: c, budget: b }))) => {
                    call = c;
                    budget = b;
                    deadline = Instant::now() + b;
                }
                Ok(Some(Ok(Message::End))) => {
                    call = format!("{doing} (after {call})");
                    budget = self.call_timeout;
                    deadline = Instant::now() + budget;
                }
                Ok(Some(Ok(m))) => return Ok(m),
            }
        }
    }

    /// The host ended by itself (the producer aborted or called `exit()`): its status.
    async fn ended(&mut self, call: &str, detail: &str) -> GentlError {
        let mut status = None;
        if let Some(child) = self.child.as_mut() {
            for _ in 0..50 {
                if let Ok(Some(s)) = child.try_wait() {
                    status = Some(s);
                    break;
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        }
        self.kill();
        let status = match status {
            Some(s) => describe_exit(s),
            None => format!(
                "it closed {}",
                if detail.is_empty() {
                    "its output"
                } else {
                    detail
                }
            ),
        };
        GentlError::HostEnded {
            call: call.to_owned(),
            producer: self.producer.clone(),
            status,
        }
    }

    /// The host sent something this side cannot read: it is killed.
    fn broken(&mut self, detail: &str) -> GentlError {
        self.kill();
        GentlError::garbage("the GenTL host", format!("its pipe: {detail}"))
    }

    fn unexpected(&mut self, a: &Answer) -> GentlError {
        self.broken(&format!("an unexpected answer {a:?}"))
    }

    /// Kill the host now (SIGKILL) and reap it on a thread of its own.
    fn kill(&mut self) {
        self.stdin = None;
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            reap(child);
        }
    }

    /// Whether the host is gone (killed after a failure).
    fn is_dead(&self) -> bool {
        self.child.is_none()
    }
}

impl Drop for Host {
    /// The host closes the device and ends when its input closes; one that has not ended
    /// after its grace is killed.
    fn drop(&mut self) {
        self.stdin = None;
        if let Some(mut child) = self.child.take() {
            let _ = std::thread::Builder::new()
                .name("gentl-host-close".into())
                .spawn(move || {
                    let end = std::time::Instant::now() + crate::host::CLOSE_GRACE * 2;
                    while std::time::Instant::now() < end {
                        if let Ok(Some(_)) = child.try_wait() {
                            return;
                        }
                        std::thread::sleep(Duration::from_millis(20));
                    }
                    let _ = child.kill();
                    let _ = child.wait();
                });
        }
    }
}

fn reap(mut child: Child) {
    let _ = std::thread::Builder::new()
        .name("gentl-host-reap".into())
        .spawn(move || {
            let _ = child.wait();
        });
}

/// "exit code 0", "killed by signal 6 (SIGABRT)".
fn describe_exit(s: std::process::ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (s.code(), s.signal()) {
        (Some(c), _) => format!("it exited with code {c}"),
        (None, Some(sig)) => {
            let name = match sig {
                libc::SIGABRT => " (SIGABRT)",
                libc::SIGSEGV => " (SIGSEGV)",
                libc::SIGKILL => " (SIGKILL)",
                libc::SIGBUS => " (SIGBUS)",
                _ => "",
            };
            format!("it was killed by signal {sig}{name}")
        }
        _ => "it ended".into(),
    }
}

/// A request to the task that owns the host.
enum Job {
    Info(oneshot::Sender<Result<CameraInfo>>),
    Capture(
        CaptureSettings,
        oneshot::Sender<Result<(Vec<PointCloud>, GentlStats)>>,
    ),
}

/// What the clones of one camera share.
#[derive(Debug)]
struct Shared {
    producer: PathBuf,
    /// Hosts lost (killed past a deadline, or ended by the producer) since the camera was
    /// connected: [`DepthCamera::link_generation`].
    lost: AtomicU64,
}

/// A camera behind a GenTL producer loaded in a host process. Cloning shares the one task
/// that owns the host; the host closes the device and ends when the last clone is dropped.
/// Requests are served one at a time, in order; a request whose caller went away is still
/// finished (or abandoned at its deadline), so the next one finds a host in a known state.
#[derive(Debug, Clone)]
pub struct GentlCamera {
    jobs: mpsc::UnboundedSender<Job>,
    shared: Arc<Shared>,
}

impl GentlCamera {
    /// Start a host for `producer`, open the device `options.device` names (the first one when
    /// `None`), read its GenICam XML and open its data stream.
    pub async fn connect(producer: &Path, options: GentlOptions) -> Result<Self> {
        check_producer(producer)?;
        let host = open_host(producer, &options).await?;
        let shared = Arc::new(Shared {
            producer: producer.to_owned(),
            lost: AtomicU64::new(0),
        });
        let (jobs, rx) = mpsc::unbounded_channel();
        tokio::spawn(serve(host, rx, options, Arc::clone(&shared)));
        Ok(Self { jobs, shared })
    }

    /// The producer this camera was opened through.
    pub fn producer(&self) -> &Path {
        &self.shared.producer
    }

    async fn ask<T>(&self, make: impl FnOnce(oneshot::Sender<Result<T>>) -> Job) -> Result<T> {
        let (tx, rx) = oneshot::channel();
        self.jobs
            .send(make(tx))
            .map_err(|_| GentlError::Closed("it ended".into()))?;
        rx.await
            .map_err(|_| GentlError::Closed("it dropped the request".into()))?
    }

    /// Capture `settings.frames` frames, with the capture's counters.
    pub async fn capture_with_stats(
        &self,
        settings: &CaptureSettings,
    ) -> Result<(Vec<PointCloud>, GentlStats)> {
        let settings = settings.clone();
        self.ask(|reply| Job::Capture(settings, reply)).await
    }
}

/// A host with the device open.
async fn open_host(producer: &Path, options: &GentlOptions) -> Result<Host> {
    let mut host = Host::spawn(producer, options)?;
    let request = Request::Open {
        producer: producer.display().to_string(),
        device: options.device.clone(),
        confidence: options.confidence,
        trigger: options.trigger,
        settings: options.settings.clone(),
        call_timeout_ms: millis(options.call_timeout),
    };
    match host
        .ask(&request, "loading the producer (dlopen, GCInitLib)")
        .await?
    {
        Answer::Opened => Ok(host),
        other => Err(host.unexpected(&other)),
    }
}

/// The task that owns the host: serves jobs in order; a host lost to a failure is replaced at
/// once (before the next job), and again at the next job while that fails.
async fn serve(
    host: Host,
    mut jobs: mpsc::UnboundedReceiver<Job>,
    options: GentlOptions,
    shared: Arc<Shared>,
) {
    let mut host = Some(host);
    let mut last_loss: Option<String> = None;
    while let Some(job) = jobs.recv().await {
        if host.is_none() {
            match open_host(&shared.producer, &options).await {
                Ok(h) => {
                    tracing::warn!(
                        "GenTL camera: a new host process opened the device again ({})",
                        last_loss.as_deref().unwrap_or("the previous one was lost")
                    );
                    host = Some(h);
                }
                Err(e) => {
                    let e = GentlError::Closed(format!(
                        "the host process that replaces the lost one cannot open the device: {e}"
                    ));
                    match job {
                        Job::Info(reply) => drop(reply.send(Err(e))),
                        Job::Capture(_, reply) => drop(reply.send(Err(e))),
                    }
                    continue;
                }
            }
        }
        let Some(h) = host.as_mut() else { continue };
        match job {
            Job::Info(reply) => {
                let r = match h.ask(&Request::Info, "reading the camera's identity").await {
                    Ok(Answer::Info(i)) => Ok(i),
                    Ok(other) => Err(h.unexpected(&other)),
                    Err(e) => Err(e),
                };
                let _ = reply.send(r);
            }
            Job::Capture(settings, reply) => {
                let r = capture(h, &settings).await;
                let _ = reply.send(r);
            }
        }
        if host.as_ref().is_some_and(Host::is_dead) {
            shared.lost.fetch_add(1, Ordering::Relaxed);
            last_loss = Some("the previous one was killed or ended".into());
            tracing::warn!(
                "GenTL camera: the host process of {} was lost; starting a new one",
                shared.producer.display()
            );
            host = match open_host(&shared.producer, &options).await {
                Ok(h) => {
                    last_loss = None;
                    tracing::info!("GenTL camera: the new host process has the device open");
                    Some(h)
                }
                Err(e) => {
                    tracing::warn!("GenTL camera: the new host cannot open the device yet: {e}");
                    None
                }
            };
        }
    }
}

async fn capture(h: &mut Host, s: &CaptureSettings) -> Result<(Vec<PointCloud>, GentlStats)> {
    let request = Request::Capture {
        frames: s.frames,
        frame_timeout_ms: millis(s.frame_timeout),
        exposure_us: s
            .exposure
            .map(|e| u64::try_from(e.as_micros()).unwrap_or(u64::MAX)),
    };
    let (n, stats) = match h.ask(&request, "configuring the capture").await? {
        Answer::Captured { clouds, stats } => (clouds, stats),
        other => return Err(h.unexpected(&other)),
    };
    if n != s.frames {
        return Err(h.broken(&format!("{n} clouds for {} frames", s.frames)));
    }
    let mut clouds = Vec::with_capacity(n as usize);
    for _ in 0..n {
        match h.next("sending the clouds").await? {
            Message::Cloud(c) => clouds.push(c),
            _ => return Err(h.broken("an answer instead of a cloud")),
        }
    }
    Ok((clouds, stats))
}

impl DepthCamera for GentlCamera {
    async fn info(&self) -> Result<CameraInfo, HalError> {
        Ok(self.ask(Job::Info).await?)
    }

    async fn capture(&self, settings: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
        Ok(self.capture_with_stats(settings).await?.0)
    }

    fn link_generation(&self) -> u64 {
        self.shared.lost.load(Ordering::Relaxed)
    }
}

/// The producers the GenTL standard's search finds: every `*.cti` in the directories of
/// `GENICAM_GENTL64_PATH` (`:`-separated; `;` on Windows), in order, each directory's files
/// sorted by name.
pub fn producers_on_path() -> Vec<PathBuf> {
    let Some(var) = std::env::var_os("GENICAM_GENTL64_PATH") else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for dir in std::env::split_paths(&var) {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut ctis: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("cti")) && p.is_file())
            .collect();
        ctis.sort();
        out.extend(ctis);
    }
    out
}

/// The producer to use: `given`, else the only one (or the first one) on
/// `GENICAM_GENTL64_PATH`.
pub fn resolve_producer(given: Option<&Path>) -> Result<PathBuf> {
    if let Some(p) = given {
        return Ok(p.to_owned());
    }
    let found = producers_on_path();
    match found.as_slice() {
        [] => Err(GentlError::NoProducer(
            "GENICAM_GENTL64_PATH names no directory with a .cti; install the vendor's GenTL producer or give its path (camera.producer, --gentl)".into(),
        )),
        [one] => Ok(one.clone()),
        [first, rest @ ..] => {
            tracing::warn!(
                "GENICAM_GENTL64_PATH has {} producers; using {} (set camera.producer to choose)",
                rest.len() + 1,
                first.display()
            );
            Ok(first.clone())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn producers_are_searched_on_the_standard_variable() {
        let dir = std::env::temp_dir().join(format!("handeye-gentl-path-{}", std::process::id()));
        let (a, b) = (dir.join("a"), dir.join("b"));
        std::fs::create_dir_all(&a).expect("dir");
        std::fs::create_dir_all(&b).expect("dir");
        for f in [
            a.join("z.cti"),
            a.join("y.CTI"),
            a.join("x.so"),
            b.join("w.cti"),
        ] {
            std::fs::write(&f, b"").expect("file");
        }
        let var = std::env::join_paths([&a, &dir.join("missing"), &b]).expect("join");
        // No other test of this crate reads or writes this variable.
        std::env::set_var("GENICAM_GENTL64_PATH", &var);
        assert_eq!(
            producers_on_path(),
            vec![a.join("y.CTI"), a.join("z.cti"), b.join("w.cti")]
        );
        assert_eq!(resolve_producer(None).expect("first"), a.join("y.CTI"));
        assert_eq!(
            resolve_producer(Some(Path::new("/x.cti"))).expect("given"),
            Path::new("/x.cti")
        );
        std::env::set_var("GENICAM_GENTL64_PATH", dir.join("missing"));
        let e = resolve_producer(None).expect_err("none").to_string();
        assert!(e.contains("GENICAM_GENTL64_PATH"), "{e}");
        std::env::remove_var("GENICAM_GENTL64_PATH");
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }

    /// Issue 46: a producer that is a FIFO (whose dlopen would block forever), a directory
    /// or a missing file is refused before any host is started, naming the file.
    #[test]
    fn issue_46_the_producer_must_be_a_readable_regular_file() {
        let dir = std::env::temp_dir().join(format!("handeye-gentl-fifo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let fifo = dir.join("p.cti");
        let c = std::ffi::CString::new(fifo.to_str().expect("utf-8")).expect("path");
        // SAFETY: a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let t = std::time::Instant::now();
        let e = check_producer(&fifo).expect_err("a FIFO").to_string();
        assert!(e.contains("a FIFO (named pipe), not a regular file"), "{e}");
        assert!(e.contains("cannot load the GenTL producer"), "{e}");
        assert!(t.elapsed() < std::time::Duration::from_secs(1));
        let e = check_producer(&dir).expect_err("a directory").to_string();
        assert!(e.contains("a directory"), "{e}");
        let e = check_producer(&dir.join("missing.cti"))
            .expect_err("missing")
            .to_string();
        assert!(e.contains("missing.cti"), "{e}");
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }
}
