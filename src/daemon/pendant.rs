//! The pendant trigger: a program on the teach pendant asks for a run through RTDE registers
//! (`daemon.pendant`): 1 calibrate, 2 check in its request register (`output_int_register_N`),
//! answered in its status register (`input_int_register_N`): 0 idle, 1 busy, 2 done, 3 failed,
//! 4 refused.

use std::time::Duration;

use handeye_hal::Robot;

use super::DaemonHandle;
use crate::config::PendantConfig;
use crate::record::{Outcome, RunMode, Trigger};

/// How often the pendant's request register is read.
pub(super) const POLL: Duration = Duration::from_millis(200);
/// Answers in the pendant's status register.
const IDLE: i32 = 0;
const BUSY: i32 = 1;
const DONE: i32 = 2;
const FAILED: i32 = 3;
const REFUSED: i32 = 4;

/// Reads the pendant program's request register; a new request (1 calibrate, 2 check) starts
/// a run and is answered busy (or refused, when another run is going); a request cleared to 0
/// resets the answer. Returns the value seen.
pub(super) async fn poll<R: Robot>(
    robot: &R,
    handle: &DaemonHandle,
    p: PendantConfig,
    last: i32,
) -> i32 {
    let v = match robot.read_output_int_register(p.request_register).await {
        Ok(v) => v,
        Err(e) => {
            tracing::debug!("cannot read the pendant's request register: {e}");
            return last;
        }
    };
    if v == last {
        return v;
    }
    let mode = match v {
        1 => Some(RunMode::Calibrate),
        2 => Some(RunMode::Check),
        _ => None,
    };
    match mode {
        Some(mode) => {
            let value = match handle.request_with_handover(mode, Trigger::Pendant) {
                Ok(_) => BUSY,
                Err(e) => {
                    tracing::warn!("pendant request refused: {e}");
                    REFUSED
                }
            };
            answer(robot, p.status_register, value).await;
        }
        None if v == 0 => answer(robot, p.status_register, IDLE).await,
        None => tracing::warn!(
            "pendant request register output_int_register_{} = {v}: expected 1 (calibrate), 2 (check) or 0",
            p.request_register
        ),
    }
    v
}

/// Writes the pendant's status register (`input_int_register_N`).
async fn answer<R: Robot>(robot: &R, register: u32, value: i32) {
    if let Err(e) = robot.write_int_register(register, value).await {
        tracing::warn!("cannot answer the pendant in input_int_register_{register}: {e}");
    }
}

/// Answers the pendant that asked for a run with how it ended: done when accepted, failed
/// otherwise.
pub(super) async fn finished<R: Robot>(robot: &R, p: PendantConfig, outcome: Outcome) {
    let value = if outcome == Outcome::Accepted {
        DONE
    } else {
        FAILED
    };
    answer(robot, p.status_register, value).await;
}
