//! The tests' skip registry ([`handeye_hal::skips`], where every crate of the workspace finds
//! it): a test that cannot run here records why, `.ci/run` counts and prints the skips and
//! fails on any under `CI=1`.

pub use handeye_hal::skips::{path, record, FILE};
