//! Universal Robots driver: RTDE, dashboard and script clients implementing
//! [`handeye_hal::Robot`], and a UR controller simulator that real clients (`ur-rtde`) accept.
//!
//! Layout:
//! - [`rtde`]: RTDE wire format and field table (shared by client and simulator);
//! - [`primary`]: primary/secondary (30001/30002) package format;
//! - [`dashboard`]: dashboard (29999) client and reply parsing;
//! - [`client`]: RTDE client with reconnect, script sender, and [`UrRobot`] (the `Robot` impl);
//! - [`sim`]: the controller simulator (`handeye sim robot`);
//! - [`UrPose`]: UR's `p[x,y,z,rx,ry,rz]`, re-exported from `handeye-hal` (the only place that
//!   converts it; the core uses it too).
#![deny(missing_docs)]

/// Tests measure the largest allocation a parser makes (the fuzz targets' memory bound).
#[cfg(test)]
#[global_allocator]
static ALLOC: handeye_hal::fuzz::TrackingAlloc = handeye_hal::fuzz::TrackingAlloc;

pub mod client;
pub mod dashboard;
mod error;
pub mod primary;
pub mod rtde;
pub mod sim;

pub use client::{UrConfig, UrRobot};
pub use error::UrError;
pub use handeye_hal::{UrPose, UrPoseParseError};

/// Standard controller ports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ports {
    /// Dashboard server (29999).
    pub dashboard: u16,
    /// Primary interface (30001).
    pub primary: u16,
    /// Secondary interface (30002).
    pub secondary: u16,
    /// Real-time interface (30003).
    pub realtime: u16,
    /// RTDE (30004).
    pub rtde: u16,
}

impl Ports {
    /// The ports a real controller uses.
    pub const STANDARD: Ports = Ports {
        dashboard: 29999,
        primary: 30001,
        secondary: 30002,
        realtime: 30003,
        rtde: 30004,
    };
}

impl Default for Ports {
    fn default() -> Self {
        Ports::STANDARD
    }
}

/// Opens a TCP connection to a controller port within `timeout`; `what` names the interface in
/// the timeout error (e.g. "RTDE connect to 192.168.56.101:30004").
pub(crate) async fn connect_within(
    addr: std::net::SocketAddr,
    timeout: std::time::Duration,
    what: impl FnOnce() -> String,
) -> Result<tokio::net::TcpStream, UrError> {
    tokio::time::timeout(timeout, tokio::net::TcpStream::connect(addr))
        .await
        .map_err(|_| UrError::Timeout {
            what: what(),
            after: timeout,
        })?
        .map_err(|source| UrError::Io {
            peer: addr.to_string(),
            source,
        })
}
