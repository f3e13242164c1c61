//! `handeye`: target-free hand-eye calibration of a Universal Robots arm's 3D camera.
//!
//! # Layout
//! - [`frames`]: frame names and the fixed transforms between them (UR `base` vs URDF `base_link`).
//! - [`model`]: the robot model from URDF + meshes: kinematics, joint limits, posed meshes.
//! - [`cloud`]: point-cloud file formats (PLY, PCD) and cloud utilities.
//! - [`camera`]: camera backends without a network protocol: file replay and external command.
//! - [`sim`]: the 3D scan simulator (pinhole camera ray-casting the posed robot and its cell,
//!   with the imperfections of real scans).
//! - [`plan`]: view generation: joint configurations from which the camera sees the base,
//!   checked for joint limits and collisions.
//! - [`bench`]: the accuracy benchmark (the paper's protocol) on simulated scans.
//! - [`calib`]: registration of a scan against the posed model, the hand-eye solve, the
//!   pass/fail gate and the benchmark protocol.
//! - [`config`]: the TOML configuration of a cell, validated.
//! - [`run`]: the calibration run over the hal `Robot` and `DepthCamera` traits, from
//!   preflight to the return move, returning one record.
//! - [`daemon`]: the service: triggers (startup, schedule, API), one run at a time, state,
//!   metrics, systemd readiness and watchdog.
//! - [`report`]: the report picture of a run (scan, distances, outline, numbers) and the
//!   drift chart, as PNG.
//! - [`store`]: the history of every run (SQLite).
//!
//! The binary (`src/main.rs` and its `src/cli/` modules, which the library does not use) wires
//! concrete drivers (`handeye-ur`, `handeye-gige`) to this core; the core only knows the traits
//! in `handeye-hal`.

pub mod bench;
pub mod calendar;
pub mod calib;
pub mod camera;
pub mod cloud;
pub mod config;
pub mod daemon;
pub mod frames;
pub mod model;
pub mod plan;
pub mod record;
pub mod report;
pub mod run;
pub mod sim;
pub mod storage;
pub mod store;

#[cfg(test)]
mod floors;
#[cfg(test)]
mod testutil;
