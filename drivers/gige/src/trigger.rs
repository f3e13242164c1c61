//! How frames are started: the camera's trigger features set for [`Trigger`] before
//! `AcquisitionStart`, and `TriggerSoftware` once per frame wanted. Shared by the GigE
//! Vision and GenTL backends.

use handeye_hal::Trigger;

use crate::error::{GigeError, Result};
use crate::genicam::{NodeMap, RegisterPort};

/// Select the frame-start trigger where the camera has a `TriggerSelector`.
fn select_frame_start(n: &mut NodeMap, p: &mut impl RegisterPort) -> Result<()> {
    let frame_start = n
        .enum_entries("TriggerSelector")
        .is_ok_and(|e| e.iter().any(|s| s == "FrameStart"));
    if frame_start {
        n.set_enum(p, "TriggerSelector", "FrameStart")?;
    }
    Ok(())
}

/// Set the camera's trigger for `trigger` (before `AcquisitionStart`): free clears
/// `TriggerMode` to `Off` when the camera has it and it is not off (Photoneo's examples leave
/// it `On` with `TriggerSource = Software`, and nothing is sent then); software sets
/// `TriggerMode = On` and `TriggerSource = Software`.
pub fn prepare(n: &mut NodeMap, p: &mut impl RegisterPort, trigger: Trigger) -> Result<()> {
    match trigger {
        Trigger::Free => {
            if !n.has("TriggerMode") {
                return Ok(());
            }
            select_frame_start(n, p)?;
            if n.enum_symbol(p, "TriggerMode")? != "Off" {
                n.set_enum(p, "TriggerMode", "Off")?;
                tracing::info!("TriggerMode was on; set to Off (camera.trigger = \"free\")");
            }
            Ok(())
        }
        Trigger::Software => {
            let lacks: Vec<&str> = ["TriggerMode", "TriggerSource", "TriggerSoftware"]
                .into_iter()
                .filter(|f| !n.has(f))
                .collect();
            if !lacks.is_empty() {
                return Err(GigeError::feature(
                    lacks[0],
                    format!(
                        "camera.trigger = \"software\" needs {}, which the camera lacks; set \
                         camera.trigger = \"free\"",
                        lacks.join(", ")
                    ),
                ));
            }
            select_frame_start(n, p)?;
            n.set_enum(p, "TriggerMode", "On")?;
            n.set_enum(p, "TriggerSource", "Software")
        }
    }
}

/// Ask for one frame: `TriggerSoftware` with the software trigger, nothing when free.
pub fn fire(n: &mut NodeMap, p: &mut impl RegisterPort, trigger: Trigger) -> Result<()> {
    match trigger {
        Trigger::Free => Ok(()),
        Trigger::Software => n.execute(p, "TriggerSoftware"),
    }
}
