//! Subcommands of the `handeye` binary. Each module has an `Args` (clap) and a `run`.
//! `run` returns the process exit code: 0 success, 1 a completed run whose result was rejected,
//! 2 an error (bad input, unreachable device, …).

pub(crate) mod args;
pub(crate) mod bench;
pub(crate) mod calibrate;
pub(crate) mod camera;
pub(crate) mod cancel;
pub(crate) mod config;
pub(crate) mod daemon;
pub(crate) mod demo;
pub(crate) mod history;
pub(crate) mod robot;
pub(crate) mod sim_camera;
pub(crate) mod sim_rig;
pub(crate) mod sim_robot;
pub(crate) mod simulate_scan;
pub(crate) mod solve;
pub(crate) mod status;
pub(crate) mod wiring;
