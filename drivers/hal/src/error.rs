use std::time::Duration;

/// Errors a robot or camera backend reports. Every message tells the operator what to do.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum HalError {
    /// The controller is in local mode; remote commands are refused.
    #[error("robot is in local control; enable Remote Control on the teach pendant")]
    NotInRemoteControl,
    /// A protective stop happened while we were doing something.
    #[error("protective stop during {during}; clear it on the pendant, then retry")]
    ProtectiveStop {
        /// What was in progress (e.g. "move to view 2").
        during: String,
    },
    /// An emergency stop is active.
    #[error(
        "emergency stop during {during}; release the e-stop and re-enable the arm on the pendant"
    )]
    EmergencyStop {
        /// What was in progress.
        during: String,
    },
    /// The arm is not powered / brakes not released / not in a state that can move.
    #[error(
        "robot is not ready to move ({state}); power it on and release the brakes on the pendant"
    )]
    NotReady {
        /// The mode the controller reported.
        state: String,
    },
    /// An operation did not complete in time.
    #[error("{what} did not complete within {timeout:?}")]
    Timeout {
        /// What timed out.
        what: String,
        /// The limit that was exceeded.
        timeout: Duration,
    },
    /// The caller cancelled the operation; motion was stopped.
    #[error("{what} was cancelled; the arm was stopped")]
    Cancelled {
        /// What was cancelled.
        what: String,
    },
    /// An RTDE/fieldbus register is held by another client.
    #[error("RTDE input `{name}` is claimed by another client (a running handeye daemon, EtherNet/IP, PROFINET, MODBUS, a URCap); free it or use another register")]
    RegisterInUse {
        /// The RTDE field name.
        name: String,
    },
    /// A request was refused by the device, with its reason.
    #[error("{device} refused {request}: {reason}")]
    Refused {
        /// Which device refused.
        device: String,
        /// What was asked.
        request: String,
        /// The device's reason, verbatim where possible.
        reason: String,
    },
    /// The peer sent something that does not follow the protocol.
    #[error("protocol error from {peer}: {detail}")]
    Protocol {
        /// Address or name of the peer.
        peer: String,
        /// What was wrong.
        detail: String,
    },
    /// The connection was lost or could not be opened.
    #[error("lost connection to {peer}; check the cable, the address and that the device is on")]
    Connection {
        /// Address or name of the peer.
        peer: String,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A caller passed an invalid argument (wrong joint count, out-of-range value, …).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// A backend that is not a network device (replayed files, an external capture command, a
    /// vendor SDK) failed. Its own error, the `source`, says what went wrong and what to do;
    /// downcast it for the details.
    #[error("{backend} failed")]
    Backend {
        /// Which backend, e.g. `file camera` or `exec camera`.
        backend: String,
        /// The backend's own error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync + 'static>,
    },
    /// A read-back after a write did not match what was written.
    #[error("read-back mismatch for {what}: wrote {wrote}, read {read}")]
    ReadBackMismatch {
        /// What was written.
        what: String,
        /// The written value, formatted.
        wrote: String,
        /// The value read back, formatted.
        read: String,
    },
}

impl HalError {
    /// This error, raised before a move was commanded, saying so: a protocol error (corrupt or
    /// stale data from the device) gets "; the move was not started", so the operator knows
    /// the arm stands where it stood. Other errors pass unchanged (they say it already, or
    /// are not about data).
    pub fn before_move(self) -> Self {
        match self {
            HalError::Protocol { peer, detail } => HalError::Protocol {
                peer,
                detail: format!("{detail}; the move was not started"),
            },
            other => other,
        }
    }
}
