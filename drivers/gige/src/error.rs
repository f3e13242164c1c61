//! The crate's error type.

use std::net::SocketAddr;
use std::time::Duration;

use handeye_hal::HalError;

/// Everything that can go wrong talking GigE Vision. Messages tell the operator what to do.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GigeError {
    /// A packet or file did not follow the protocol (short, wrong key, absurd length, …).
    #[error("malformed {what}: {detail}")]
    Malformed {
        /// What was being parsed ("GVCP ack", "GVSP leader", "XML URL", …).
        what: &'static str,
        /// What was wrong with it.
        detail: String,
    },
    /// The device answered a command with an error status.
    #[error("camera refused {command}: {name} (status 0x{status:04x}); {hint}")]
    DeviceStatus {
        /// The command that was refused (e.g. "WRITEREG 0x00000a00").
        command: String,
        /// GigE Vision status code.
        status: u16,
        /// Symbolic name of the status code.
        name: &'static str,
        /// What the operator can do about it.
        hint: &'static str,
    },
    /// The device did not answer in time (after all retries).
    #[error("camera at {peer} did not answer {what} within {timeout:?} ({tries} tries); check the address, the cable and that no firewall drops UDP port 3956")]
    Timeout {
        /// The device's control address.
        peer: SocketAddr,
        /// What was asked.
        what: String,
        /// Time allowed per try.
        timeout: Duration,
        /// Number of tries.
        tries: u32,
    },
    /// The device kept answering "pending" (PENDING_ACK) past the hard ceiling of one
    /// command ([`crate::client::MAX_COMMAND_WAIT`]), or a multi-block read took longer than
    /// [`crate::client::MAX_BULK_READ`].
    #[error("camera at {peer} kept {what} waiting for {waited:?} (PENDING_ACK or too slow) without finishing it; power-cycle the camera or check its firmware")]
    Stalled {
        /// The device's control address.
        peer: SocketAddr,
        /// What was asked.
        what: String,
        /// How long we waited.
        waited: Duration,
    },
    /// A socket operation failed.
    #[error("network error talking to {peer}: {source}; check the address and the interface")]
    Io {
        /// Peer or local address involved.
        peer: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// Another application controls the camera, or we lost control (heartbeat).
    #[error("control of the camera at {peer} is not ours: {detail}; close other GigE Vision applications (viewer, SDK) and retry")]
    ControlLost {
        /// The device's control address.
        peer: SocketAddr,
        /// Details.
        detail: String,
    },
    /// A setting from the configuration (`camera.user_set`, `[camera.features]`) the camera
    /// refused.
    #[error("{setting}: the camera {camera} refuses it: {detail}; change it in the configuration (`handeye camera probe` lists what the camera accepts)")]
    Setting {
        /// The setting as configured (`camera.features.ExposureTime = 5`).
        setting: String,
        /// The camera (`VendorName ModelName`).
        camera: String,
        /// Why (the feature's refusal, with what it accepts).
        detail: String,
    },
    /// A GenICam feature is missing, of the wrong type or refused a value.
    #[error("GenICam feature `{feature}`: {detail}")]
    Feature {
        /// Feature name.
        feature: String,
        /// What went wrong.
        detail: String,
    },
    /// The stream did not deliver a complete frame in time.
    #[error("no complete frame within {timeout:?} ({detail}); check the camera is acquiring and that UDP packets reach this host")]
    FrameTimeout {
        /// The frame timeout.
        timeout: Duration,
        /// What was received.
        detail: String,
    },
    /// The camera streams a pixel format this driver cannot turn into points.
    #[error("pixel format 0x{format:08x} ({name}) is not a 3D format this driver reads; select a Coord3D_ABC or Coord3D_C pixel format in the camera (`handeye camera xml` lists the ones the driver reads)")]
    UnsupportedFormat {
        /// PFNC code.
        format: u32,
        /// Name, when known.
        name: &'static str,
    },
    /// Bad argument from the caller.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}

impl GigeError {
    pub(crate) fn malformed(what: &'static str, detail: impl Into<String>) -> Self {
        // A detail often quotes what the device sent: never pass its control characters on.
        Self::Malformed {
            what,
            detail: handeye_hal::limits::sanitize_message(&detail.into()),
        }
    }

    pub(crate) fn io(peer: impl ToString, source: std::io::Error) -> Self {
        Self::Io {
            peer: peer.to_string(),
            source,
        }
    }

    pub(crate) fn feature(feature: &str, detail: impl Into<String>) -> Self {
        Self::Feature {
            feature: feature.to_owned(),
            detail: detail.into(),
        }
    }
}

impl From<GigeError> for HalError {
    fn from(e: GigeError) -> Self {
        match e {
            GigeError::Timeout { what, timeout, .. } => HalError::Timeout { what, timeout },
            GigeError::Stalled { what, waited, .. } => HalError::Timeout {
                what: format!("{what} (the camera stalled: PENDING_ACK or too slow)"),
                timeout: waited,
            },
            GigeError::FrameTimeout { timeout, detail } => HalError::Timeout {
                what: format!("camera frame ({detail})"),
                timeout,
            },
            GigeError::Io { peer, source } => HalError::Connection { peer, source },
            GigeError::InvalidArgument(s) => HalError::InvalidArgument(s),
            other @ (GigeError::DeviceStatus { .. }
            | GigeError::ControlLost { .. }
            | GigeError::Feature { .. }
            | GigeError::Setting { .. }
            | GigeError::UnsupportedFormat { .. }) => HalError::Refused {
                device: "GigE Vision camera".into(),
                request: "camera operation".into(),
                reason: other.to_string(),
            },
            other => HalError::Protocol {
                peer: "GigE Vision camera".into(),
                detail: other.to_string(),
            },
        }
    }
}

/// Result alias of this crate.
pub type Result<T, E = GigeError> = std::result::Result<T, E>;
