//! The 3D scan simulator: a pinhole 3D camera ray-casting the posed robot (true kinematics)
//! and its cell, with the imperfections of real scans (see [`ScanNoise`], [`CellOptions`],
//! [`KinematicError`]).

mod albedo;
mod camera;
pub mod cell;
mod colour;
mod noise;
mod scan;
mod settings;

pub use crate::geometry::{Intrinsics, SensorClass};
pub use crate::model::KinematicError;
pub use camera::look_at;
pub use cell::{CellOptions, CellPart};
pub use noise::{ScanNoise, TOF_REFERENCE_ALBEDO};
pub use scan::{simulate_scan, GroundTruth, Placement, ScanRequest, SimError, SimulatedScan};
pub use settings::{SettingsError, SimSettings};
