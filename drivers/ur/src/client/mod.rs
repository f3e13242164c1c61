//! Client side: RTDE, script sender and the [`UrRobot`] `Robot` implementation.

mod checks;
mod robot;
mod rtde_client;
mod script;

pub use robot::{UrConfig, UrRobot};
pub use rtde_client::{
    ControllerClock, ControllerVersion, RtdeClient, RtdeConfig, Sample, StreamFault,
    MAX_FROZEN_TIMESTAMP, REORDERED_HOLD,
};
pub use script::{ScriptClient, ScriptOutcome};
