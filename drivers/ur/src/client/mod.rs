//! Client side: RTDE, script sender and the [`UrRobot`] `Robot` implementation.

mod robot;
mod rtde_client;
mod script;

pub use robot::{UrConfig, UrRobot};
pub use rtde_client::{ControllerVersion, RtdeClient, RtdeConfig, Sample};
pub use script::{ScriptClient, ScriptOutcome};
