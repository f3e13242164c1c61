//! Camera settings from the configuration (`camera.user_set`, `[camera.features]`), applied
//! before every capture, and the features `handeye camera probe` lists as the ones a user would
//! set. Shared by the GigE Vision and GenTL backends.

use handeye_hal::{set_by_handeye, CameraSettings, FeatureValue};

use crate::error::{GigeError, Result};
use crate::genicam::{takes, FeatureKind, FeatureState, NodeMap, RegisterPort};

/// Features a user of a 3D camera sets (SFNC's, then the operating modes of the vendors whose
/// habits the simulator imitates), in the order `handeye camera probe` lists those the camera
/// has.
pub const USER_FEATURES: &[&str] = &[
    "PixelFormat",
    "Scan3dOutputMode",
    "Scan3dDistanceUnit",
    "ComponentSelector",
    "ComponentEnable",
    "TriggerSelector",
    "TriggerMode",
    "TriggerSource",
    "ExposureAuto",
    "ExposureTime",
    "AcquisitionFrameRateEnable",
    "AcquisitionFrameRate",
    "GainAuto",
    "Gain",
    // Operating modes: Basler blaze (OperatingMode), Photoneo (OperationMode), Lucid Helios2
    // (Scan3dOperatingMode), SICK Visionary and others (DeviceOperationMode).
    "OperatingMode",
    "OperationMode",
    "Scan3dOperatingMode",
    "DeviceOperationMode",
    "DepthMin",
    "DepthMax",
    "UserSetSelector",
    "UserSetDefault",
];

/// The camera's name for messages: `VendorName ModelName` of its description.
fn camera_name(n: &NodeMap) -> String {
    format!("{} {}", n.vendor_name(), n.model_name())
        .trim()
        .to_owned()
}

/// What can be checked of the settings from the description alone, without the camera's
/// registers (so before the arm moves: the drivers' `info`, which preflight calls, runs it):
/// the user set is a `UserSetSelector` entry and `UserSetLoad` exists; each feature exists,
/// is none handeye sets itself, takes a value of the configured kind and, for an enumeration,
/// has the entry. Ranges and access are checked when writing ([`apply`]).
pub fn check(n: &NodeMap, settings: &CameraSettings) -> Result<()> {
    let camera = camera_name(n);
    let refuse = |setting: String, detail: String| GigeError::Setting {
        setting,
        camera: camera.clone(),
        detail,
    };
    if let Some(set) = &settings.user_set {
        let setting = format!("camera.user_set = \"{set}\"");
        let entries = n
            .enum_entries("UserSetSelector")
            .map_err(|_| refuse(setting.clone(), "the camera has no UserSetSelector".into()))?;
        if !entries.iter().any(|e| e == set) {
            return Err(refuse(
                setting,
                format!(
                    "UserSetSelector has no entry `{set}`; entries: {}",
                    entries.join(", ")
                ),
            ));
        }
        if !n.has("UserSetLoad") {
            return Err(refuse(setting, "the camera has no UserSetLoad".into()));
        }
    }
    for (name, value) in &settings.features {
        let setting = format!("camera.features.{name} = {value}");
        if let Some(why) = set_by_handeye(name) {
            return Err(refuse(
                setting,
                format!("handeye sets {name} itself ({why})"),
            ));
        }
        let Some(kind) = n.kind(name) else {
            return Err(refuse(setting, "the camera has no such feature".into()));
        };
        if let Err(wants) = takes(kind, value) {
            let entries = match kind {
                FeatureKind::Enumeration => {
                    format!(": one of {}", n.enum_entries(name)?.join(", "))
                }
                _ => String::new(),
            };
            return Err(refuse(
                setting,
                format!("{name} is {kind:?} and takes {wants}{entries}"),
            ));
        }
        if let (FeatureKind::Enumeration, FeatureValue::Text(t)) = (kind, value) {
            let entries = n.enum_entries(name)?;
            if !entries.iter().any(|e| e == t) {
                return Err(refuse(
                    setting,
                    format!("{name} has no entry `{t}`; entries: {}", entries.join(", ")),
                ));
            }
        }
    }
    Ok(())
}

/// Load the user set, then write each feature in the configured order, through the GenApi's
/// ranges and access checks. The first refusal stops it, with an error naming the setting,
/// the camera and what the feature accepts.
pub fn apply(n: &mut NodeMap, p: &mut impl RegisterPort, settings: &CameraSettings) -> Result<()> {
    check(n, settings)?;
    let camera = camera_name(n);
    if let Some(set) = &settings.user_set {
        n.set_enum(p, "UserSetSelector", set)
            .and_then(|()| n.execute(p, "UserSetLoad"))
            .map_err(|e| GigeError::Setting {
                setting: format!("camera.user_set = \"{set}\""),
                camera: camera.clone(),
                detail: e.to_string(),
            })?;
        tracing::info!(user_set = %set, "loaded the camera's user set");
    }
    for (name, value) in &settings.features {
        let setting = format!("camera.features.{name} = {value}");
        n.write_value(p, name, value).map_err(|e| {
            let e = e.to_string();
            // What the feature accepts, unless the refusal says it already.
            let accepts = n
                .allowed(p, name)
                .filter(|a| !e.contains(a.trim_start_matches("one of ")))
                .map(|a| format!("; it accepts {a}"))
                .unwrap_or_default();
            GigeError::Setting {
                setting: setting.clone(),
                camera: camera.clone(),
                detail: format!("{e}{accepts}"),
            }
        })?;
        tracing::debug!(%setting, "camera feature set");
    }
    Ok(())
}

/// The [`USER_FEATURES`] the camera has, with their value, range or entries and access now.
pub fn probe(n: &mut NodeMap, p: &mut impl RegisterPort) -> Vec<FeatureState> {
    USER_FEATURES.iter().filter_map(|f| n.state(p, f)).collect()
}
