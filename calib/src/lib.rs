//! `handeye-calib`: the calibration core of `handeye` — everything from a robot model and a
//! scan to a gated camera pose, with no service around it (no async runtime, no database, no
//! HTTP; the only I/O is reading model, mesh and cloud files).
//!
//! # Floors
//! A module uses only its own floor and the ones below, never a higher one (no circles);
//! the `handeye` crate's `floors.rs` test reads these sources too and fails when one climbs.
//!
//! ```text
//! calib, plan, bench    registration, solve, gate, pipeline | views | benchmark
//!   sim                 the scan simulator
//!     geometry          the pinhole model and the ray caster
//!       model, cloud    the robot model | point clouds
//!         frames        frame names and fixed transforms
//! ```
//! Below them all, `handeye-hal` (the traits and shared types).
//!
//! # Layout
//! - [`frames`]: frame names and the fixed transforms between them (UR `base` vs URDF `base_link`).
//! - [`model`]: the robot model from URDF + meshes: kinematics, joint limits, posed meshes.
//! - [`cloud`]: point-cloud file formats (PLY, PCD) and cloud utilities.
//! - [`geometry`]: the pinhole model of a 3D camera and exact ray casting of meshes through it.
//! - [`sim`]: the 3D scan simulator (pinhole camera ray-casting the posed robot and its cell,
//!   with the imperfections of real scans).
//! - [`plan`]: view generation: joint configurations from which the camera sees the base,
//!   checked for joint limits and collisions.
//! - [`calib`]: registration of a scan against the posed model, the hand-eye solve, the
//!   pass/fail gate, the report and the pipeline from frames to a gated result.
//! - [`mod@bench`]: the accuracy benchmark (the paper's protocol) on simulated scans.

/// Tests measure the largest allocation a parser makes (the fuzz targets' memory bound).
#[cfg(test)]
#[global_allocator]
static ALLOC: handeye_hal::fuzz::TrackingAlloc = handeye_hal::fuzz::TrackingAlloc;

pub mod bench;
pub mod calib;
pub mod cloud;
pub mod frames;
pub mod geometry;
pub mod model;
pub mod plan;
pub mod sim;

#[cfg(any(test, feature = "testutil"))]
pub mod testutil;
