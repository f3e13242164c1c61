//! Hardware abstraction for `handeye`: the [`Robot`] and [`DepthCamera`] traits that separate
//! the drivers (`handeye-ur`, `handeye-gige`, …) from the calibration core, and the types they
//! exchange, among them [`UrPose`], UR's `p[x, y, z, rx, ry, rz]` (the only code that converts,
//! parses or prints it).
//!
//! Conventions (see the workspace README): lengths in metres, angles in radians, durations as
//! [`std::time::Duration`]. Transforms are `Isometry3<f64>` named `<to>_from_<from>`.
//! Joint order is the URDF chain order (for UR: base, shoulder, elbow, wrist 1, 2, 3).
#![deny(missing_docs)]

mod camera;
mod cloud;
mod error;
#[cfg(feature = "fake")]
pub mod fake;
#[cfg(feature = "fuzz")]
pub mod fuzz;
pub mod limits;
mod pose;
mod robot;
pub mod skips;
pub mod ur_dh;
pub mod ur_limits;

pub use camera::{
    set_by_handeye, CameraInfo, CameraSettings, CaptureSettings, DepthCamera, FeatureValue,
    Trigger, FEATURES_SET_BY_HANDEYE,
};
pub use cloud::PointCloud;
pub use error::HalError;
pub use pose::{UrPose, UrPoseParseError};
pub use robot::{
    ControllerIdentity, JointPositions, MotionLimits, Robot, RobotMode, RobotStatus, SafetyMode,
};
pub use ur_dh::ControllerKinematics;

/// Re-exported so users of the traits name the same math types.
pub use nalgebra;
