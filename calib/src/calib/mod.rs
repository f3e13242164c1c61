//! Registration of a scan against the posed robot model, the hand-eye solve, the pass/fail
//! gate and the report.
//!
//! - [`fn@register`] / [`register_posed`]: one scan (camera frame) + the model posed at the measured
//!   joints → `camera_from_model` with covariance, quality and timings. Works without a prior.
//! - [`fn@solve`]: closes the kinematic chain per frame and fuses frames and views
//!   (eye-in-hand `flange_from_camera`, eye-to-hand `model_from_camera`).
//! - [`fn@gate`]: pass/fail with configurable thresholds and reasons.
//! - [`report`]: the JSON report of a calibration.
//!
//! Frames: `model` is the URDF root link (for UR `base_link`), `camera` the optical frame
//! (OpenCV axes), `flange` the link the caller names. Units: metres and radians inside; reports
//! say mm/deg in field names.

mod coarse;
pub mod export;
mod fine;
mod fuse;
pub mod gate;
mod kdtree;
mod links;
pub(crate) mod outline;
pub mod pipeline;
pub mod range;
pub mod register;
pub mod report;
pub mod solve;
pub mod surface;
mod verify;

/// Whether `b` is within `metres` and `degrees` of `a`, measured in `a`'s frame (for
/// `camera_from_model` poses: the model origin's displacement and the relative rotation).
pub(crate) fn within(
    a: &nalgebra::Isometry3<f64>,
    b: &nalgebra::Isometry3<f64>,
    metres: f64,
    degrees: f64,
) -> bool {
    let d = a.inverse() * b;
    d.translation.vector.norm() < metres && d.rotation.angle() < degrees.to_radians()
}

#[cfg(test)]
mod probe;
#[cfg(test)]
pub(crate) mod testutil;

pub use gate::{gate, GateThresholds, Verdict};
pub use links::LinkFit;
pub use register::{
    posed_model, posed_model_with_controller_kinematics, posed_model_with_kinematics, register,
    register_posed, Quality, RegisterOptions, Registration, StageTimings, Uncertainty,
    WorkspaceSigma,
};
pub use report::{CalibrationReport, OutlineReport, SplitHalf};
pub use solve::{solve, FrameInput, HandEyeSolution, Mount, Residual, SolveOptions};
pub use surface::{PosedJoint, PosedModel, PosedPart};

/// How a calibration ended: the gate's verdict, a benchmark trial, a run. One type for every
/// consumer (reports, CLI exit codes, the benchmark, the daemon's history).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// The gate passed. Calibrate: written back as configured. Check: see the drift.
    Accepted,
    /// The run completed but the gate refused the result; nothing was written.
    Rejected,
    /// Stopped by a robot fault (protective/emergency stop), a lost connection, a timeout or
    /// a cancel; nothing was written.
    Aborted,
    /// Could not be carried out (preflight, planning, camera, registration); nothing written.
    Error,
    /// Dry run: preflight and planning done, nothing moved.
    Planned,
}

impl Outcome {
    /// Lower-case name as in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Outcome::Accepted => "accepted",
            Outcome::Rejected => "rejected",
            Outcome::Aborted => "aborted",
            Outcome::Error => "error",
            Outcome::Planned => "planned",
        }
    }
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Errors of registration and solving; each message tells the operator what to do.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CalibError {
    /// The scan has (almost) no valid points.
    #[error("the scan has only {valid_points} valid points; check the camera exposure and that the scan file is not empty")]
    EmptyScan {
        /// Number of valid (finite) points found.
        valid_points: usize,
    },
    /// The scan's `points.len()` does not match `width × height`.
    #[error("the scan is malformed: {width}×{height} grid but {points} points")]
    MalformedScan {
        /// Grid width.
        width: u32,
        /// Grid height.
        height: u32,
        /// Number of points present.
        points: usize,
    },
    /// The joint vector does not match the robot model.
    #[error("{got} joint values given but the robot model has {expected} joints; pass one value per joint in URDF order")]
    JointCountMismatch {
        /// Joints of the model.
        expected: usize,
        /// Joint values given.
        got: usize,
    },
    /// The model has no geometry for the links registration uses.
    #[error("the robot model has no meshes on its base and first links; check the URDF's <visual> meshes")]
    NoModelGeometry,
    /// No pose of the robot explains the scan.
    #[error("the robot was not found in the scan ({detail}); make sure the base and the first links are in view (0.3–1.2 m from a wrist camera, 0.8–2 m from a fixed one)")]
    RobotNotFound {
        /// What the search saw (best coverage, planes, …).
        detail: String,
    },
    /// The robot model could not be posed.
    #[error(transparent)]
    Model(crate::model::ModelError),
    /// The kinematics the model is posed by (the controller's, a calibration file's) put a link
    /// far from anywhere a calibration of this model can: they are another arm's.
    #[error("the arm's kinematics (the controller's or the calibration file's) put {link} {off_mm:.0} mm / {turn_deg:.1}° from where the {model} model has it (a calibration moves links by a few mm): they are another arm's; check robot.model against the controller's robot type, or the calibration file")]
    KinematicsNotThisArm {
        /// The link furthest off.
        link: String,
        /// How far its origin is off, mm.
        off_mm: f64,
        /// How far it is turned, degrees.
        turn_deg: f64,
        /// The model's name.
        model: String,
    },
    /// Nothing to solve.
    #[error("no registered frames to solve from")]
    NoFrames,
    /// A frame's input is inconsistent (e.g. eye-in-hand without a flange pose).
    #[error("frame {frame}: {detail}")]
    BadFrame {
        /// Index of the frame in the input.
        frame: usize,
        /// What is wrong.
        detail: String,
    },
}
