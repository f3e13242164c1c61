//! A simulated GigE Vision 3D camera: GVCP server and GVSP streamer on a given address.
//!
//! It serves a GenApi XML (validated with the EMVA reference GenApi in the tests), the
//! bootstrap registers, Coord3D_ABC32f (mm, NaN = invalid) or Coord3D_C16 (0.1 mm, 0 = invalid)
//! frames, and optionally a Confidence16 part (multi-part payload, when the host enables
//! multi-part in SCCFG and `ComponentEnable[Confidence]`). Frames come from a pluggable
//! [`FrameSource`]; [`SceneSource`] is a built-in analytic test pattern. Packet loss can be
//! injected; lost packets are served again on PACKETRESEND.

mod device;
mod encode;
mod gvcp_server;
mod habits;
mod scene;
mod sim_device;
mod stream;

pub use device::{SimOptions, SimStats};
pub use gvcp_server::SimCamera;
pub use habits::{VendorHabits, IMITATIONS};
pub use scene::SceneSource;
pub use sim_device::{PortError, SimDevice};

use handeye_hal::PointCloud;

/// Error of a frame source, shown to whoever watches the simulator.
pub type SourceError = Box<dyn std::error::Error + Send + Sync>;

/// Where the simulated camera gets its frames.
pub trait FrameSource: Send + 'static {
    /// The next frame: an organized cloud of `size()` (metres, camera frame, OpenCV axes,
    /// NaN = no measurement). Called from the streaming thread before each frame.
    fn next_frame(&mut self) -> Result<PointCloud, SourceError>;
    /// Sensor size (width, height) in pixels.
    fn size(&self) -> (u32, u32);
    /// Pinhole intrinsics (focal length px, principal point u, v px) published as
    /// Scan3dFocalLength / Scan3dPrincipalPointU/V and used for the Coord3D_C16 depth map.
    fn intrinsics(&self) -> (f64, f64, f64) {
        let (w, h) = self.size();
        (f64::from(w), f64::from(w) / 2.0, f64::from(h) / 2.0)
    }
    /// The vertical focal length over the horizontal one (1 = square pixels), SFNC's
    /// `Scan3dAspectRatio`. Published as `Scan3dAspectRatio` with
    /// [`VendorHabits::aspect_ratio`].
    fn aspect_ratio(&self) -> f64 {
        1.0
    }
}
