//! The exec camera: runs a configured command once per frame; the command captures and writes
//! a point-cloud file, which is read back.

use std::ffi::OsString;
use std::io::Read;
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

use handeye_hal::{CameraInfo, CaptureSettings, DepthCamera, HalError, PointCloud};

use super::{blocking, CameraError, PrivateDir};
use crate::cloud::read_cloud;

/// Environment variable holding the path the command must write the frame to.
pub const ENV_OUTPUT: &str = "HANDEYE_OUTPUT";
/// Environment variable holding the 0-based frame index.
pub const ENV_FRAME: &str = "HANDEYE_FRAME";
/// Environment variable holding the requested exposure in whole microseconds (set only when
/// [`CaptureSettings::exposure`] is).
pub const ENV_EXPOSURE_US: &str = "HANDEYE_EXPOSURE_US";

/// How much of the command's stderr/stdout is kept for error messages.
const TAIL_BYTES: usize = 8 * 1024;
/// Lines of stderr quoted in an error message.
const TAIL_LINES: usize = 20;
/// How often the child is checked for exit, timeout and cancellation.
const POLL: Duration = Duration::from_millis(5);
/// How long to wait for the pipes to close after the command exited (a background process it
/// left behind may hold them open).
const PIPE_GRACE: Duration = Duration::from_secs(1);

/// A camera reached through an external command, run once per frame.
///
/// The command is a program and its arguments (no shell involved; use `sh -c '…'` for one).
/// In every argument, `{out}` is replaced by the path the frame must be written to and
/// `{frame}` by the 0-based frame index; the same values are in the environment as
/// `HANDEYE_OUTPUT` and `HANDEYE_FRAME` (and `HANDEYE_EXPOSURE_US` when an exposure is
/// requested). The file may be PLY or PCD whatever its extension (`.ply`); it is read with
/// [`read_cloud`], so it must be in metres or say its unit (`comment unit mm`).
///
/// A capture of N frames runs the command N times, one after the other, each with its own
/// timeout (the camera's, not [`CaptureSettings::frame_timeout`]: vendor SDKs take seconds to
/// connect). Output goes to a private temporary directory (mode 0700) that is removed after the
/// capture. The command's stdin is empty; its stdout is logged at debug level; the tail of its
/// stderr is quoted in errors. The command runs in its own process group: on timeout, or when
/// the capture's future is dropped, the whole group is killed (SIGKILL), so helper processes it
/// started die too. Captures of one camera (and its clones) never overlap.
///
/// Blocking work runs on tokio's blocking pool; the async runtime is never blocked.
#[derive(Debug, Clone)]
pub struct ExecCamera {
    argv: Arc<[String]>,
    timeout: Duration,
    /// Serializes captures: two invocations must not fight over one device.
    busy: Arc<Mutex<()>>,
}

impl ExecCamera {
    /// A camera running `argv` (program first) with `timeout` per frame.
    pub fn new(argv: Vec<String>, timeout: Duration) -> Result<Self, CameraError> {
        if argv.first().is_none_or(|p| p.is_empty()) {
            return Err(CameraError::EmptyCommand);
        }
        if timeout.is_zero() {
            return Err(CameraError::ZeroTimeout);
        }
        Ok(Self {
            argv: argv.into(),
            timeout,
            busy: Arc::new(Mutex::new(())),
        })
    }

    /// The command template (program first), placeholders unreplaced.
    pub fn command(&self) -> &[String] {
        &self.argv
    }

    /// The limit for one invocation (one frame).
    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    /// Describes the camera without running anything: vendor `exec`, model = the program's
    /// file name, firmware = the command line. Width and height are 0: unknown until a frame
    /// is captured.
    pub fn describe(&self) -> CameraInfo {
        let program = Path::new(&self.argv[0]).file_name().map_or_else(
            || self.argv[0].clone(),
            |n| n.to_string_lossy().into_owned(),
        );
        CameraInfo {
            vendor: "exec".to_owned(),
            model: program,
            serial: String::new(),
            firmware: command_line(&self.argv),
            width: 0,
            height: 0,
            pixel_formats: Vec::new(),
        }
    }

    /// Runs the command `settings.frames` times and returns one cloud per run (0 frames: an
    /// empty result, nothing run). The first failing run fails the capture.
    pub async fn capture_frames(
        &self,
        settings: &CaptureSettings,
    ) -> Result<Vec<PointCloud>, CameraError> {
        let cancel = Arc::new(AtomicBool::new(false));
        // Dropping this future (e.g. a caller's timeout) tells the blocking thread to kill the
        // command instead of letting it run on unobserved.
        let _guard = CancelOnDrop(cancel.clone());
        let cam = self.clone();
        let frames = settings.frames;
        let exposure = settings.exposure;
        blocking(move || {
            let _busy = cam.busy.lock().unwrap_or_else(|e| e.into_inner());
            if frames == 0 {
                return Ok(Vec::new());
            }
            let dir = PrivateDir::new("exec")?;
            let mut clouds = Vec::with_capacity(frames as usize);
            for frame in 0..frames {
                let out = dir.path().join(format!("frame_{frame}.ply"));
                let run = Run {
                    argv: &cam.argv,
                    timeout: cam.timeout,
                    frame,
                    out: &out,
                    exposure,
                    cancel: &cancel,
                };
                clouds.push(run.execute()?);
                if let Err(e) = std::fs::remove_file(&out) {
                    tracing::warn!(path = %out.display(), error = %e, "cannot remove capture output");
                }
            }
            Ok(clouds)
        })
        .await
    }
}

impl DepthCamera for ExecCamera {
    async fn info(&self) -> Result<CameraInfo, HalError> {
        Ok(self.describe())
    }

    async fn capture(&self, settings: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
        Ok(self.capture_frames(settings).await?)
    }
}

/// Sets the flag when dropped.
struct CancelOnDrop(Arc<AtomicBool>);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// One invocation of the command.
struct Run<'a> {
    argv: &'a [String],
    timeout: Duration,
    frame: u32,
    out: &'a Path,
    exposure: Option<Duration>,
    cancel: &'a AtomicBool,
}

impl Run<'_> {
    fn execute(&self) -> Result<PointCloud, CameraError> {
        let command = command_line(self.argv);
        let frame = self.frame;
        let args: Vec<OsString> = self
            .argv
            .iter()
            .map(|a| substitute(a, self.out, frame))
            .collect();
        let mut cmd = Command::new(&args[0]);
        cmd.args(&args[1..])
            .env(ENV_OUTPUT, self.out)
            .env(ENV_FRAME, frame.to_string())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        match self.exposure {
            Some(e) => cmd.env(ENV_EXPOSURE_US, e.as_micros().to_string()),
            None => cmd.env_remove(ENV_EXPOSURE_US),
        };
        #[cfg(unix)]
        std::os::unix::process::CommandExt::process_group(&mut cmd, 0);

        tracing::debug!(%command, frame, out = %self.out.display(), "running capture command");
        let mut child = cmd.spawn().map_err(|source| CameraError::Spawn {
            command: command.clone(),
            source,
        })?;
        let stderr = Tail::spawn(child.stderr.take(), "stderr");
        let stdout = Tail::spawn(child.stdout.take(), "stdout");

        let deadline = Instant::now() + self.timeout;
        let status = loop {
            match child.try_wait() {
                Ok(Some(status)) => break status,
                Ok(None) => {}
                Err(source) => {
                    kill_group(&mut child);
                    return Err(CameraError::Wait {
                        command,
                        frame,
                        source,
                    });
                }
            }
            if self.cancel.load(Ordering::Relaxed) {
                kill_group(&mut child);
                return Err(CameraError::Cancelled { command, frame });
            }
            let now = Instant::now();
            if now >= deadline {
                kill_group(&mut child);
                return Err(CameraError::Timeout {
                    command,
                    frame,
                    timeout: self.timeout,
                    stderr: stderr.finish(PIPE_GRACE),
                });
            }
            std::thread::sleep(POLL.min(deadline - now));
        };

        let stderr = stderr.finish(PIPE_GRACE);
        let stdout = stdout.finish(PIPE_GRACE);
        if !stdout.is_empty() {
            tracing::debug!(%command, frame, %stdout, "capture command stdout (tail)");
        }
        if !status.success() {
            return Err(CameraError::Exit {
                command,
                frame,
                status: describe_status(status),
                code: status.code(),
                stderr,
            });
        }
        if !self.out.exists() {
            return Err(CameraError::NoOutput {
                command,
                frame,
                path: self.out.to_path_buf(),
                stderr,
            });
        }
        read_cloud(self.out).map_err(|source| CameraError::BadOutput {
            command,
            frame,
            stderr,
            source,
        })
    }
}

/// Replaces `{frame}` and `{out}` in one argument.
fn substitute(template: &str, out: &Path, frame: u32) -> OsString {
    let with_frame = template.replace("{frame}", &frame.to_string());
    let mut arg = OsString::new();
    for (i, piece) in with_frame.split("{out}").enumerate() {
        if i > 0 {
            arg.push(out.as_os_str());
        }
        arg.push(piece);
    }
    arg
}

/// The command line as a shell would need it quoted (for messages).
fn command_line(argv: &[String]) -> String {
    shlex::try_join(argv.iter().map(String::as_str)).unwrap_or_else(|_| argv.join(" "))
}

fn describe_status(status: ExitStatus) -> String {
    if let Some(code) = status.code() {
        return format!("exit code {code}");
    }
    #[cfg(unix)]
    if let Some(signal) = std::os::unix::process::ExitStatusExt::signal(&status) {
        return format!("killed by signal {signal}");
    }
    status.to_string()
}

/// Kills the child's whole process group (it leads one: `process_group(0)`), then reaps it.
fn kill_group(child: &mut Child) {
    #[cfg(unix)]
    match i32::try_from(child.id()) {
        Ok(pid) => {
            // SAFETY: kill(2) touches no memory of ours. The group id is the pid of our child,
            // which is not reaped yet, so neither the pid nor the group can have been reused.
            let rc = unsafe { libc::kill(-pid, libc::SIGKILL) };
            if rc != 0 {
                let e = std::io::Error::last_os_error();
                if e.raw_os_error() != Some(libc::ESRCH) {
                    tracing::warn!(pid, error = %e, "cannot kill the capture command's process group");
                }
            }
        }
        Err(_) => tracing::warn!(pid = child.id(), "process id out of range for kill(2)"),
    }
    // Also covers non-Unix targets; harmless when the group kill already ended it.
    if let Err(e) = child.kill() {
        tracing::debug!(error = %e, "kill after group kill");
    }
    if let Err(e) = child.wait() {
        tracing::warn!(error = %e, "cannot reap the killed capture command");
    }
}

/// The last bytes read from a pipe by a background thread.
struct Tail {
    buf: Arc<Mutex<Vec<u8>>>,
    /// Disconnects when the reader thread ends (the pipe closed).
    done: Option<mpsc::Receiver<()>>,
}

impl Tail {
    fn spawn<R: Read + Send + 'static>(pipe: Option<R>, name: &str) -> Self {
        let buf = Arc::new(Mutex::new(Vec::new()));
        let Some(mut pipe) = pipe else {
            return Self { buf, done: None };
        };
        let (tx, rx) = mpsc::channel::<()>();
        let shared = buf.clone();
        let spawned = std::thread::Builder::new()
            .name(format!("exec-{name}"))
            .spawn(move || {
                let _tx = tx;
                let mut chunk = [0u8; 4096];
                loop {
                    match pipe.read(&mut chunk) {
                        Ok(0) => break,
                        Ok(n) => {
                            let mut b = shared.lock().unwrap_or_else(|e| e.into_inner());
                            b.extend_from_slice(&chunk[..n]);
                            if b.len() > TAIL_BYTES {
                                let excess = b.len() - TAIL_BYTES;
                                b.drain(..excess);
                            }
                        }
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                        Err(e) => {
                            tracing::debug!(error = %e, "reading the capture command's output");
                            break;
                        }
                    }
                }
            });
        match spawned {
            Ok(_) => Self {
                buf,
                done: Some(rx),
            },
            Err(e) => {
                tracing::warn!(error = %e, "cannot start a thread to read the capture command's {name}");
                Self { buf, done: None }
            }
        }
    }

    /// Waits up to `grace` for the pipe to close, then returns the last lines read.
    fn finish(self, grace: Duration) -> String {
        if let Some(done) = &self.done {
            // Disconnected = the reader finished; Timeout = something still holds the pipe.
            let _ = done.recv_timeout(grace);
        }
        let b = self.buf.lock().unwrap_or_else(|e| e.into_inner());
        let text = String::from_utf8_lossy(&b);
        let lines: Vec<&str> = text.trim_end().lines().collect();
        let start = lines.len().saturating_sub(TAIL_LINES);
        lines[start..]
            .iter()
            .map(|l| format!("  | {l}"))
            .collect::<Vec<_>>()
            .join("\n")
    }
}

#[cfg(test)]
mod tests;
