//! The 3D scan simulator.

mod camera;
pub mod cell;
mod noise;
pub mod raycast;

pub use camera::Intrinsics;
pub use cell::{CellOptions, CellPart};
pub use noise::ScanNoise;
