//! The crate's error type.

use std::path::PathBuf;
use std::time::Duration;

use handeye_gige::GigeError;
use handeye_hal::HalError;

use crate::wire::FailureClass;

/// Everything that can go wrong with a GenTL producer. Messages tell the operator what to do.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GentlError {
    /// The `.cti` could not be loaded or is not a GenTL producer.
    #[error("cannot load the GenTL producer {path}: {detail}; give the vendor's 64-bit .cti for this platform (camera.producer or --gentl)")]
    Load {
        /// The file.
        path: PathBuf,
        /// Why.
        detail: String,
    },
    /// No producer was given and none was found on `GENICAM_GENTL64_PATH`.
    #[error("no GenTL producer: {0}")]
    NoProducer(String),
    /// A producer function returned an error code.
    #[error("the GenTL producer failed {function}: {name} ({code}){message}")]
    Call {
        /// The C function.
        function: &'static str,
        /// `GC_ERROR` code.
        code: i32,
        /// The standard's name of the code.
        name: &'static str,
        /// The producer's own text (`GCGetLastError`), prefixed with `: ` when there is one.
        message: String,
    },
    /// The producer returned something that breaks the standard (null handle, impossible size,
    /// a pointer outside the buffer we gave it, …).
    #[error("the GenTL producer returned garbage from {function}: {detail}; update the producer or report it to its vendor")]
    Garbage {
        /// The C function.
        function: &'static str,
        /// What was wrong.
        detail: String,
    },
    /// The requested device is not among the producer's devices.
    #[error("no GenTL device matches `{wanted}`; the producer has: {available}")]
    NoDevice {
        /// The serial, model, id or index asked for.
        wanted: String,
        /// What the producer lists.
        available: String,
    },
    /// No buffer arrived in time.
    #[error("no complete frame within {timeout:?} ({detail}); check that the camera is acquiring (trigger settings) and the producer's own log")]
    FrameTimeout {
        /// The frame timeout.
        timeout: Duration,
        /// What happened.
        detail: String,
    },
    /// The producer delivers data of a kind this driver does not read (a GenDC container).
    #[error("{0}")]
    Unsupported(String),
    /// The camera's features or frames (GenApi node map, PFNC decoding).
    #[error(transparent)]
    Camera(#[from] GigeError),
    /// The camera's host process is gone or cannot be reached.
    #[error("the GenTL camera's host process is not available ({0}); reconnect the camera")]
    Closed(String),
    /// A producer call did not return within its deadline: its host process was killed.
    #[error("the GenTL producer {} did not return from {call} within {deadline:?}; its host process was killed and a new one opens the camera for the next request; check the camera and its producer (the vendor's log), or raise camera.call_timeout_s if the camera is that slow", producer.display())]
    Deadline {
        /// The call (or the step of the host between calls).
        call: String,
        /// The producer file.
        producer: PathBuf,
        /// The deadline passed.
        deadline: Duration,
    },
    /// The producer ended its host process (it aborted, crashed or called `exit()`).
    #[error("the GenTL producer {} ended its host process during {call} ({status}); a new one opens the camera for the next request; check the producer (the vendor's log) and the camera", producer.display())]
    HostEnded {
        /// The call (or the step of the host) in progress.
        call: String,
        /// The producer file.
        producer: PathBuf,
        /// How the process ended.
        status: String,
    },
    /// An error the host process reported.
    #[error("{message}")]
    Host {
        /// Its text.
        message: String,
        /// What it becomes for the daemon.
        class: FailureClass,
    },
}

impl GentlError {
    pub(crate) fn garbage(function: &'static str, detail: impl Into<String>) -> Self {
        // A detail may quote what the producer sent: never pass control characters on.
        Self::Garbage {
            function,
            detail: handeye_hal::limits::sanitize_message(&detail.into()),
        }
    }
}

impl From<GentlError> for HalError {
    fn from(e: GentlError) -> Self {
        match e {
            GentlError::Camera(e) => e.into(),
            GentlError::FrameTimeout { timeout, detail } => HalError::Timeout {
                what: format!("GenTL camera frame ({detail})"),
                timeout,
            },
            GentlError::Host {
                message,
                class: FailureClass::FrameTimeout { timeout_ms },
            } => HalError::Timeout {
                what: format!("GenTL camera frame ({message})"),
                timeout: Duration::from_millis(timeout_ms),
            },
            other @ (GentlError::Closed(_)
            | GentlError::Call { .. }
            | GentlError::Deadline { .. }
            | GentlError::HostEnded { .. }
            | GentlError::Host {
                class: FailureClass::Connection,
                ..
            }) => HalError::Connection {
                peer: "GenTL camera".into(),
                source: std::io::Error::other(other.to_string()),
            },
            other => HalError::Protocol {
                peer: "GenTL camera".into(),
                detail: other.to_string(),
            },
        }
    }
}

/// Result alias of this crate.
pub type Result<T, E = GentlError> = std::result::Result<T, E>;
