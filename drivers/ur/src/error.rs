//! The one error type of this crate.

use std::time::Duration;

use handeye_hal::HalError;

/// Everything that can go wrong talking to (or serving as) a UR controller.
/// Every message says what the operator should do.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum UrError {
    /// The peer sent bytes that do not follow the protocol; the connection is closed.
    #[error("malformed {protocol} data from the peer: {detail}; is this the right port and a UR controller/client? (connection closed)")]
    Malformed {
        /// Which protocol (`RTDE`, `primary`, `dashboard`, `URScript`).
        protocol: &'static str,
        /// What exactly was wrong.
        detail: String,
    },
    /// The controller does not know an RTDE field (wrong name or too old a PolyScope).
    #[error("RTDE field `{name}` is not known by this controller (NOT_FOUND); check the spelling or update PolyScope")]
    FieldNotFound {
        /// The field name.
        name: String,
    },
    /// An RTDE input field is owned by another client or a fieldbus adapter.
    #[error("RTDE input `{name}` is already in use (IN_USE){hint}; disable that adapter/URCap or use another register")]
    FieldInUse {
        /// The field name.
        name: String,
        /// Who usually holds it.
        hint: &'static str,
    },
    /// The controller refused a request.
    #[error("{device} refused `{request}`: {reason}")]
    Refused {
        /// `RTDE`, `dashboard`, `primary`.
        device: &'static str,
        /// The request, as sent.
        request: String,
        /// The reply or reason, verbatim where possible.
        reason: String,
    },
    /// A connection could not be opened or was lost.
    #[error("connection to {peer} failed; check that the controller is on, reachable and that the interface is enabled (Settings → Security → Services)")]
    Io {
        /// `host:port`.
        peer: String,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// No reply in time.
    #[error("{what} did not answer within {after:?}; check the network and the controller")]
    Timeout {
        /// What we waited for.
        what: String,
        /// How long we waited.
        after: Duration,
    },
    /// A caller passed something the controller cannot do.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// The RTDE data stream as a whole cannot be trusted (the controller's timestamp stands
    /// still or went back); nothing read from it now is used.
    #[error("{0}; nothing read from it now is used: check the network between this PC and the controller (a switch, gateway or VPN that buffers, repeats or reorders packets)")]
    Stream(crate::client::StreamFault),
}

impl UrError {
    #[allow(dead_code)]
    pub(crate) fn malformed(protocol: &'static str, detail: impl Into<String>) -> Self {
        // A detail often quotes what the peer sent: never pass its control characters on.
        UrError::Malformed {
            protocol,
            detail: handeye_hal::limits::sanitize_message(&detail.into()),
        }
    }

    #[allow(dead_code)]
    pub(crate) fn in_use(name: &str) -> Self {
        UrError::FieldInUse {
            name: name.to_string(),
            hint: in_use_hint(name),
        }
    }
}

/// Who usually holds an RTDE input register (for error messages).
#[allow(dead_code)]
pub(crate) fn in_use_hint(name: &str) -> &'static str {
    let index = name.rsplit('_').next().and_then(|s| s.parse::<u32>().ok());
    let is_reg =
        name.starts_with("input_int_register_") || name.starts_with("input_double_register_");
    if name.starts_with("input_bit_registers") || (is_reg && index.is_some_and(|i| i < 24)) {
        " — registers 0–23 (and bits 0–63) are taken by fieldbus adapters (EtherNet/IP, PROFINET, MODBUS) when enabled in the installation, or by another RTDE client such as ur_rtde"
    } else {
        " — held by another RTDE client: a running handeye daemon holds its configured registers (`handeye status`), or ur_rtde, a URCap or the ROS driver"
    }
}

impl From<UrError> for HalError {
    fn from(e: UrError) -> Self {
        match e {
            UrError::FieldInUse { name, .. } => HalError::RegisterInUse { name },
            UrError::Io { peer, source } => HalError::Connection { peer, source },
            UrError::Timeout { what, after } => HalError::Timeout {
                what,
                timeout: after,
            },
            UrError::InvalidArgument(s) => HalError::InvalidArgument(s),
            UrError::Refused {
                device,
                request,
                reason,
            } => HalError::Refused {
                device: device.to_string(),
                request,
                reason,
            },
            e @ UrError::Stream(_) => HalError::Protocol {
                peer: "RTDE".into(),
                detail: e.to_string(),
            },
            e @ (UrError::Malformed { .. } | UrError::FieldNotFound { .. }) => HalError::Protocol {
                peer: "UR controller".into(),
                detail: e.to_string(),
            },
        }
    }
}
