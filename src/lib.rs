//! `handeye`: target-free hand-eye calibration of a Universal Robots arm's 3D camera.
//!
//! # Floors
//! The core is built in floors; a module uses only its own floor and the ones below, never a
//! higher one (no circles). `floors.rs` (a test) reads the sources and fails when one climbs.
//!
//! ```text
//! daemon            (+ api, the web page, metrics, pendant, schedule, systemd notify)
//!   run             (+ the recorder: history row, record, picture, pruning)
//!     storage, store        the run folder (one owner) | the history (SQLite only)
//!       report, guard       the report picture and the drift chart | every move checked
//!         config            the cell's TOML, validated
//!           record, calendar        the run record, its words | dates, times, schedules
//!             calib, plan, bench    registration, solve, gate, pipeline | views | benchmark
//!               sim                 the scan simulator
//!                 camera            the pinhole model (and the camera backends without a protocol)
//!                   model, cloud    the robot model | point clouds
//!                     frames        frame names and fixed transforms
//! ```
//! Below them all, `handeye-hal` (the traits and shared types). Above them, the binary
//! (`src/main.rs` and `src/cli/`, which the library does not use): it wires the concrete
//! drivers (`handeye-ur`, `handeye-gige`) in one place, `cli/wiring.rs`; the core only knows the
//! traits.
//!
//! # Layout
//! - [`frames`]: frame names and the fixed transforms between them (UR `base` vs URDF `base_link`).
//! - [`model`]: the robot model from URDF + meshes: kinematics, joint limits, posed meshes.
//! - [`cloud`]: point-cloud file formats (PLY, PCD) and cloud utilities.
//! - [`camera`]: the pinhole model, camera backends without a network protocol (file replay,
//!   external command) and the reconnecting decorator for any camera.
//! - [`sim`]: the 3D scan simulator (pinhole camera ray-casting the posed robot and its cell,
//!   with the imperfections of real scans).
//! - [`plan`]: view generation: joint configurations from which the camera sees the base,
//!   checked for joint limits and collisions.
//! - [`calib`]: registration of a scan against the posed model, the hand-eye solve, the
//!   pass/fail gate, the report and the pipeline from frames to a gated result.
//! - [`bench`]: the accuracy benchmark (the paper's protocol) on simulated scans.
//! - [`record`]: the record of a run and the words for it (mode, trigger, stage, outcome,
//!   drift, what a mount solves for).
//! - [`calendar`]: the wall clock, civil dates, UTC text and the calendar times of checks.
//! - [`config`]: the TOML configuration of a cell, validated.
//! - [`guard`]: [`guard::MotionGuard`], the decorator that checks every move of any robot
//!   (joint limits, floor, self-collision, obstacles) and caps its speed.
//! - [`report`]: the report picture of a run (scan, distances, outline, numbers) and the
//!   drift chart, as PNG.
//! - [`storage`]: the run folder: layout, run ids, the durable atomic write, pruning.
//! - [`store`]: the history of every run (SQLite).
//! - [`run`]: the calibration run over the hal `Robot` and `DepthCamera` traits, from
//!   preflight to the return move, returning one record; its [`run::Recorder`] keeps it.
//! - [`daemon`]: the service: triggers (startup, schedule, API, pendant), one queue, one run
//!   at a time, state, metrics, the HTTP API and the page, systemd readiness and watchdog.

pub mod bench;
pub mod calendar;
pub mod calib;
pub mod camera;
pub mod cloud;
pub mod config;
pub mod daemon;
pub mod frames;
pub mod guard;
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
