//! GigE Vision driver: GVCP/GVSP client with GenICam implementing [`handeye_hal::DepthCamera`],
//! and a simulated GigE Vision 3D camera ([`sim`]).
//!
//! Layout: [`gvcp`] (control packets), [`client`] (control channel, discovery, heartbeat),
//! [`genicam`] (XML fetch and node map), [`gvsp`] (stream packets and the frame receiver),
//! [`decode`] (PFNC 3D formats to point clouds), [`camera`] (the `DepthCamera`), [`describe`]
//! (what the driver makes of a description, offline), [`settings`] (camera settings from the
//! configuration), [`trigger`] (how frames are started), [`sim`]
//! (a simulated 3D camera that speaks the same protocols).
#![deny(missing_docs)]

/// Tests measure the largest allocation a parser makes (the fuzz targets' memory bound).
#[cfg(test)]
#[global_allocator]
static ALLOC: handeye_hal::fuzz::TrackingAlloc = handeye_hal::fuzz::TrackingAlloc;

pub mod camera;
pub mod client;
pub mod decode;
pub mod describe;
mod error;
pub mod genicam;
pub mod gvcp;
pub mod gvsp;
pub mod settings;
pub mod sim;
pub mod trigger;
mod udp_batch;

pub use camera::{CaptureStats, GigeCamera, StreamOptions};
pub use client::{discover, ControlConfig, ControlGuard, Discovered, GvcpClient};
pub use error::{GigeError, Result};
