//! `handeye`: target-free hand-eye calibration of a Universal Robots arm's 3D camera.
//!
//! # Floors
//! The code is built in floors; a module uses only its own floor and the ones below, never a
//! higher one (no circles). `floors.rs` (a test) reads the sources and fails when one climbs.
//!
//! ```text
//! handeye (this crate: the service)
//!   daemon            (+ api and its listener, the control socket, the web page, metrics, pendant, schedule, systemd notify)
//!     run             (+ the recorder: history row, record, picture, pruning; the write-back journal)
//!       storage, store        the run folder (one owner) | the history (SQLite only)
//!         report, guard       the report picture and the drift chart | every move checked
//!           config            the cell's TOML, validated
//!             record, calendar        the run record, its words | dates, times, schedules
//!               camera, lockfile      the camera backends without a protocol | lock files and their holders
//! handeye-calib (the calibration core, its own crate: no tokio, rusqlite or axum)
//!                 calib, plan, bench    registration, solve, gate, pipeline | views | benchmark
//!                   sim                 the scan simulator
//!                     geometry          the pinhole model and the ray caster
//!                       model, cloud    the robot model | point clouds
//!                         frames        frame names and fixed transforms
//! ```
//! Below them all, `handeye-hal` (the traits and shared types). The core's modules are
//! re-exported here under their own names (`handeye::model` is `handeye_calib::model`). Above
//! them, the binary (`src/main.rs` and `src/cli/`, which the library does not use): it wires the
//! concrete drivers (`handeye-ur`, `handeye-gige`) in one place, `cli/wiring.rs`; the library
//! only knows the traits.
//!
//! # Layout
//! - The calibration core, [`handeye_calib`]: [`frames`], [`model`], [`cloud`], [`geometry`],
//!   [`sim`], [`plan`], [`calib`], [`mod@bench`].
//! - [`camera`]: camera backends without a network protocol (file replay, external command)
//!   and the reconnecting decorator for any camera.
//! - [`lockfile`]: lock files opened without following links, `flock`, and the holder of a
//!   lock named from the kernel's table.
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

pub use handeye_calib::{bench, calib, cloud, frames, geometry, model, plan, sim};

/// Tests measure the largest allocation a parser makes (the fuzz targets' memory bound).
#[cfg(test)]
#[global_allocator]
static ALLOC: handeye_hal::fuzz::TrackingAlloc = handeye_hal::fuzz::TrackingAlloc;

pub mod calendar;
pub mod camera;
pub mod config;
pub mod daemon;
pub mod guard;
pub mod lockfile;
pub mod record;
pub mod report;
pub mod run;
#[doc(hidden)]
pub mod skips;
pub mod storage;
pub mod store;

#[cfg(test)]
mod floors;
#[cfg(test)]
use handeye_calib::testutil;
