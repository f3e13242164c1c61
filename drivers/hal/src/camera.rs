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

/// A value for a camera feature (`[camera.features]`), as written in the configuration: the
/// driver writes it through the camera's GenApi, which decides what it means (an entry's name
/// for an enumeration, a number for an integer or float, `true`/`false` for a boolean).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(untagged)]
pub enum FeatureValue {
    /// `true` / `false`.
    Bool(bool),
    /// A whole number.
    Int(i64),
    /// A number with a fraction or exponent.
    Float(f64),
    /// Text: an enumeration entry's symbolic name or a string feature's value.
    Text(String),
}

impl std::fmt::Display for FeatureValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FeatureValue::Bool(b) => write!(f, "{b}"),
            FeatureValue::Int(i) => write!(f, "{i}"),
            FeatureValue::Float(x) => write!(f, "{x}"),
            FeatureValue::Text(t) => write!(f, "\"{t}\""),
        }
    }
}

/// Camera settings from the configuration, applied before every capture: the user set is
/// loaded first (`UserSetSelector` + `UserSetLoad`), then each feature is written in the
/// configured order, through the camera's GenApi with its ranges and access checks.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CameraSettings {
    /// `camera.user_set`: the `UserSetSelector` entry to load (`"Default"`, `"UserSet1"`, …).
    pub user_set: Option<String>,
    /// `[camera.features]`: feature name and value, in the order written.
    pub features: Vec<(String, FeatureValue)>,
}

impl CameraSettings {
    /// Nothing to set.
    pub fn is_empty(&self) -> bool {
        self.user_set.is_none() && self.features.is_empty()
    }
}

/// Features the drivers set themselves, which `[camera.features]` may not name, each with the
/// configuration key (or the reason) that decides it.
pub const FEATURES_SET_BY_HANDEYE: &[(&str, &str)] = &[
    ("TriggerSelector", "camera.trigger"),
    ("TriggerMode", "camera.trigger"),
    ("TriggerSource", "camera.trigger"),
    ("TriggerSoftware", "camera.trigger"),
    ("ExposureTime", "camera.exposure_us"),
    ("UserSetSelector", "camera.user_set"),
    ("UserSetLoad", "camera.user_set"),
    (
        "AcquisitionMode",
        "handeye sets it for every capture (Continuous)",
    ),
    ("AcquisitionStart", "handeye starts and stops every capture"),
    ("AcquisitionStop", "handeye starts and stops every capture"),
    (
        "TLParamsLocked",
        "handeye locks and unlocks it around every capture",
    ),
];

/// Why `[camera.features]` may not name `feature` (`None`: it may).
pub fn set_by_handeye(feature: &str) -> Option<&'static str> {
    FEATURES_SET_BY_HANDEYE
        .iter()
        .find(|(f, _)| *f == feature)
        .map(|(_, why)| *why)
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
