use std::future::Future;
use std::time::Duration;

use crate::{HalError, PointCloud};

/// What a camera says it is.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CameraInfo {
    /// Manufacturer name as the device reports it.
    pub vendor: String,
    /// Model name.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// Firmware/device version string.
    pub firmware: String,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Pixel formats the device offers (PFNC names, e.g. `Coord3D_ABC32f`).
    pub pixel_formats: Vec<String>,
}

/// How to capture.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureSettings {
    /// Number of frames to capture (fused later by the solver).
    pub frames: u32,
    /// Give up on one frame after this long.
    pub frame_timeout: Duration,
    /// Exposure time when the camera supports setting it.
    pub exposure: Option<Duration>,
}

impl Default for CaptureSettings {
    fn default() -> Self {
        Self {
            frames: 1,
            frame_timeout: Duration::from_secs(10),
            exposure: None,
        }
    }
}

/// How frames are started (`camera.trigger`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Trigger {
    /// The camera runs free: the driver turns `TriggerMode` off where the camera has it (a
    /// camera left in trigger mode would send nothing).
    #[default]
    Free,
    /// `TriggerMode = On`, `TriggerSource = Software`, and `TriggerSoftware` executed once
    /// per frame wanted.
    Software,
}

impl Trigger {
    /// The name in the configuration.
    pub fn name(self) -> &'static str {
        match self {
            Trigger::Free => "free",
            Trigger::Software => "software",
        }
    }
}

/// A 3D camera that delivers point clouds in its own frame (metres, OpenCV axes).
///
/// Capture is blocking I/O in most backends; implementations run it off the async runtime.
pub trait DepthCamera: Send + Sync + 'static {
    /// Identify the device.
    fn info(&self) -> impl Future<Output = Result<CameraInfo, HalError>> + Send;

    /// Capture `settings.frames` frames; every frame is a complete cloud or the call fails.
    fn capture(
        &self,
        settings: &CaptureSettings,
    ) -> impl Future<Output = Result<Vec<PointCloud>, HalError>> + Send;

    /// How many times the connection to the device had to be re-established since this handle
    /// was made (see [`crate::Robot::link_generation`]); the default 0 for backends that never
    /// reconnect.
    fn link_generation(&self) -> u64 {
        0
    }
}
