//! The camera backends that need no network protocol, both implementing
//! [`handeye_hal::DepthCamera`] (the pinhole model itself is geometry,
//! [`crate::geometry::Intrinsics`]):
//!
//! - [`FileCamera`] replays PLY/PCD files in order (offline runs, tests, recorded scans).
//! - [`ExecCamera`] runs a configured command once per frame; the command captures and writes a
//!   PLY (or PCD) file, which is read back. This reaches cameras that only have a vendor SDK,
//!   e.g. Zivid through `config/zivid_capture.py`.
//!
//! [`ReconnectingCamera`] wraps any of them (or a driver's camera) and connects it anew after
//! it failed.
//!
//! Both backends read files with [`crate::cloud::read_cloud`], so units follow that reader: metres, or
//! the unit a `comment unit mm` (PLY) / `# unit mm` (PCD) header line names.
//!
//! Errors are [`CameraError`]; the [`DepthCamera`](handeye_hal::DepthCamera) implementations
//! wrap them in [`HalError::Backend`] (downcast its `source` to get the [`CameraError`] back).

mod exec;
mod file;
mod reconnect;

use std::path::PathBuf;
use std::time::Duration;

use handeye_hal::HalError;

use crate::cloud::CloudError;

pub use exec::{ExecCamera, ENV_EXPOSURE_US, ENV_FRAME, ENV_OUTPUT};
pub use file::{FileCamera, WhenExhausted};
pub use reconnect::{Backoff, ReconnectingCamera};

/// Everything that can go wrong in the file and exec camera backends.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CameraError {
    /// A file camera was configured without files.
    #[error("the file camera has no files to replay; give at least one PLY or PCD file")]
    NoFiles,
    /// [`WhenExhausted::Error`] and fewer files are left than frames were asked for.
    #[error(
        "the file camera has replayed {used} of its {total} files and cannot deliver {requested} \
         more frames; give more files, ask for fewer frames or let it wrap around"
    )]
    Exhausted {
        /// Files already delivered.
        used: usize,
        /// Files configured.
        total: usize,
        /// Frames asked for.
        requested: u32,
    },
    /// A replayed file could not be read.
    #[error("cannot replay {}", path.display())]
    ReadFile {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        #[source]
        source: CloudError,
    },
    /// An exec camera was configured with an empty command.
    #[error("the exec camera's command is empty; configure the program and its arguments")]
    EmptyCommand,
    /// An exec camera was configured with a zero timeout.
    #[error("the exec camera's timeout is zero; configure a positive timeout")]
    ZeroTimeout,
    /// The private temporary directory for the command's output could not be created.
    #[error(
        "cannot create a temporary directory under {}; check that it exists and is writable \
         (or set TMPDIR)",
        parent.display()
    )]
    TempDir {
        /// Where we tried.
        parent: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// The capture command could not be started.
    #[error(
        "cannot start the capture command `{command}`; check that the program exists, is \
         executable and is on PATH"
    )]
    Spawn {
        /// The command line.
        command: String,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// Waiting for the capture command failed at the operating-system level.
    #[error("lost track of the capture command `{command}` (frame {frame})")]
    Wait {
        /// The command line.
        command: String,
        /// The frame index (0-based).
        frame: u32,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// The capture command exited unsuccessfully.
    #[error(
        "the capture command `{command}` failed for frame {frame} ({status}); fix what its \
         output says{}",
        tail_suffix(stderr)
    )]
    Exit {
        /// The command line.
        command: String,
        /// The frame index (0-based).
        frame: u32,
        /// How it ended, e.g. `exit code 3` or `killed by signal 9`.
        status: String,
        /// The exit code, when it exited normally.
        code: Option<i32>,
        /// The last lines it wrote to stderr.
        stderr: String,
    },
    /// The capture command ran past its timeout; it was killed with its whole process group.
    #[error(
        "the capture command `{command}` did not finish frame {frame} within {timeout:?} and \
         was killed; check the camera connection, or raise the timeout if captures are that \
         slow{}",
        tail_suffix(stderr)
    )]
    Timeout {
        /// The command line.
        command: String,
        /// The frame index (0-based).
        frame: u32,
        /// The limit per frame.
        timeout: Duration,
        /// The last lines it wrote to stderr before it was killed.
        stderr: String,
    },
    /// The capture was abandoned (its future was dropped); the command was killed.
    #[error("the capture command `{command}` was cancelled during frame {frame} and killed")]
    Cancelled {
        /// The command line.
        command: String,
        /// The frame index (0-based).
        frame: u32,
    },
    /// The capture command succeeded but wrote no file.
    #[error(
        "the capture command `{command}` exited successfully but wrote nothing to {} for frame \
         {frame}; it must write the cloud to the path given by `{{out}}` in its arguments or by \
         the HANDEYE_OUTPUT environment variable{}",
        path.display(),
        tail_suffix(stderr)
    )]
    NoOutput {
        /// The command line.
        command: String,
        /// The frame index (0-based).
        frame: u32,
        /// Where the file was expected.
        path: PathBuf,
        /// The last lines it wrote to stderr.
        stderr: String,
    },
    /// The capture command wrote a file that is not a readable point cloud.
    #[error(
        "the capture command `{command}` wrote an unreadable point cloud for frame {frame}; fix \
         how it writes the file{}",
        tail_suffix(stderr)
    )]
    BadOutput {
        /// The command line.
        command: String,
        /// The frame index (0-based).
        frame: u32,
        /// The last lines it wrote to stderr.
        stderr: String,
        /// What is wrong with the file.
        #[source]
        source: CloudError,
    },
    /// The async runtime shut down while a capture was running on its blocking pool.
    #[error("the capture was abandoned because the program is shutting down")]
    ShuttingDown,
}

impl CameraError {
    /// Which backend this error comes from (`file camera` or `exec camera`).
    pub fn backend(&self) -> &'static str {
        match self {
            CameraError::NoFiles | CameraError::Exhausted { .. } | CameraError::ReadFile { .. } => {
                "file camera"
            }
            CameraError::ShuttingDown => "camera",
            _ => "exec camera",
        }
    }
}

impl From<CameraError> for HalError {
    fn from(e: CameraError) -> Self {
        HalError::Backend {
            backend: e.backend().to_owned(),
            source: Box::new(e),
        }
    }
}

/// `; its stderr ended with: …` or nothing when stderr was empty.
fn tail_suffix(stderr: &str) -> String {
    if stderr.trim().is_empty() {
        " (it wrote nothing to stderr)".to_owned()
    } else {
        format!("; its stderr ended with:\n{stderr}")
    }
}

/// Runs blocking work on tokio's blocking pool; a panic there is re-raised here.
async fn blocking<T, F>(f: F) -> Result<T, CameraError>
where
    F: FnOnce() -> Result<T, CameraError> + Send + 'static,
    T: Send + 'static,
{
    match tokio::task::spawn_blocking(f).await {
        Ok(v) => v,
        Err(e) if e.is_panic() => std::panic::resume_unwind(e.into_panic()),
        Err(_) => Err(CameraError::ShuttingDown),
    }
}

/// A directory only we can read (mode 0700 on Unix), removed with everything in it on drop.
#[derive(Debug)]
pub(crate) struct PrivateDir {
    path: PathBuf,
}

impl PrivateDir {
    /// Creates a fresh directory `handeye-<purpose>-…` under the system temp directory.
    pub(crate) fn new(purpose: &str) -> Result<Self, CameraError> {
        use std::sync::atomic::{AtomicU64, Ordering};
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let parent = std::env::temp_dir();
        let mut builder = std::fs::DirBuilder::new();
        #[cfg(unix)]
        std::os::unix::fs::DirBuilderExt::mode(&mut builder, 0o700);
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let mut attempt = 0;
        loop {
            let n = COUNTER.fetch_add(1, Ordering::Relaxed);
            let path = parent.join(format!(
                "handeye-{purpose}-{}-{n}-{nanos:08x}",
                std::process::id()
            ));
            // `create` (not `create_all`) fails when the name exists: never reuse a directory
            // someone else made.
            match builder.create(&path) {
                Ok(()) => return Ok(Self { path }),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && attempt < 100 => {
                    attempt += 1;
                }
                Err(source) => return Err(CameraError::TempDir { parent, source }),
            }
        }
    }

    /// The directory.
    pub(crate) fn path(&self) -> &std::path::Path {
        &self.path
    }
}

impl Drop for PrivateDir {
    fn drop(&mut self) {
        if let Err(e) = std::fs::remove_dir_all(&self.path) {
            tracing::warn!(path = %self.path.display(), error = %e, "cannot remove temporary directory");
        }
    }
}
