//! What the driver would make of a camera's GenICam description, offline (no camera):
//! `handeye camera xml`.
//!
//! Features whose value is written in the description (a `<Value>`, a formula over constants)
//! are evaluated; those that live in the camera's registers are reported as read at run time.

use crate::camera::DRIVER_FEATURES;
use crate::decode::pfnc;
use crate::genicam::{FeatureKind, NodeMap};

/// Features without which the driver cannot stream at all.
pub const REQUIRED_FEATURES: &[&str] = &[
    "Width",
    "Height",
    "PixelFormat",
    "AcquisitionStart",
    "AcquisitionStop",
];

/// Pixel formats the driver turns into points (PFNC codes, the `PixelFormat` entries' values).
pub const RANGE_FORMATS: &[u32] = &[pfnc::COORD3D_ABC32F, pfnc::COORD3D_C16, pfnc::COORD3D_C32F];

/// What the driver would use, and whether it would work.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Description {
    /// `VendorName` of the description.
    pub vendor: String,
    /// `ModelName` of the description.
    pub model: String,
    /// All `PixelFormat` entries.
    pub pixel_formats: Vec<String>,
    /// The entries the driver decodes into points.
    pub range_formats: Vec<String>,
    /// `ComponentSelector` entries (3D components: Range, Intensity, Confidence, …).
    pub components: Vec<String>,
    /// Whether the driver asks for a multi-part payload (the camera offers a Range component).
    pub multipart: bool,
    /// Scan3d features the description has: (name, value when written in the description,
    /// `None` when read from the camera at run time).
    pub scan3d: Vec<(String, Option<String>)>,
    /// `Scan3dOutputMode` entries.
    pub output_modes: Vec<String>,
    /// The GenApi interface of `TLParamsLocked` (`None` when absent).
    pub tl_params_locked: Option<String>,
    /// Driver features the description lacks, with what the driver does without them.
    pub missing: Vec<(String, &'static str)>,
    /// `Ok(())` when the driver could stream points from this camera, else why not.
    pub verdict: Result<(), String>,
}

/// A port for a description without its camera: every register access fails.
#[derive(Debug)]
struct NoCamera;

type DevResult = std::result::Result<(), Box<dyn std::error::Error + Send + Sync>>;

impl cameleon_genapi::Device for NoCamera {
    fn read_mem(&mut self, address: i64, _: &mut [u8]) -> DevResult {
        Err(format!("offline: register {address:#x} is in the camera").into())
    }

    fn write_mem(&mut self, address: i64, _: &[u8]) -> DevResult {
        Err(format!("offline: register {address:#x} is in the camera").into())
    }
}

/// What the driver does without a feature.
fn without(name: &str) -> &'static str {
    match name {
        "Width" | "Height" | "PixelFormat" | "AcquisitionStart" | "AcquisitionStop" => {
            "required: the driver cannot stream"
        }
        "Scan3dDistanceUnit" => "values taken as millimetres",
        "Scan3dCoordinateScale" => "scale 1",
        "Scan3dCoordinateOffset" => "offset 0",
        "Scan3dInvalidDataValue" | "Scan3dInvalidDataFlag" => "only NaN marks invalid points",
        "Scan3dFocalLength" | "Scan3dPrincipalPointU" | "Scan3dPrincipalPointV" => {
            "depth maps (Coord3D_C16/C32f) cannot become points"
        }
        "Scan3dAspectRatio" => "pixels taken as square",
        "Scan3dCoordinateSelector" => "one scale and offset for all coordinates",
        "ComponentSelector" | "ComponentEnable" => "single-part range images only",
        "ExposureTime" => "an exposure setting is ignored",
        "TLParamsLocked" | "AcquisitionMode" => "not set (fine)",
        "GevSCPSPacketSize" => "not used (the packet size goes to the bootstrap register)",
        "Scan3dOutputMode" => "the output is taken as calibrated",
        _ => "not used",
    }
}

/// Reads a feature's value from the description alone. The node map logs each failed
/// register access as an error; offline they are expected, so nothing is logged meanwhile.
fn offline_value(nm: &mut NodeMap, name: &str) -> Option<String> {
    tracing::dispatcher::with_default(&tracing::Dispatch::none(), || offline_value_quiet(nm, name))
}

fn offline_value_quiet(nm: &mut NodeMap, name: &str) -> Option<String> {
    let mut dev = NoCamera;
    match nm.kind(name)? {
        FeatureKind::Integer => nm.integer(&mut dev, name).ok().map(|v| v.to_string()),
        FeatureKind::Float => nm.float(&mut dev, name).ok().map(|v| v.to_string()),
        FeatureKind::Boolean => nm.boolean(&mut dev, name).ok().map(|v| v.to_string()),
        FeatureKind::Enumeration => nm.enum_symbol(&mut dev, name).ok(),
        FeatureKind::String => nm.string(&mut dev, name).ok(),
        FeatureKind::Command | FeatureKind::Other => None,
    }
}

/// Describe a loaded node map.
pub fn describe(nm: &mut NodeMap) -> Description {
    let entries = |nm: &NodeMap, n: &str| nm.enum_entries_with_values(n).unwrap_or_default();
    let pf = entries(nm, "PixelFormat");
    let range_formats: Vec<String> = pf
        .iter()
        .filter(|(_, v)| u32::try_from(*v).is_ok_and(|c| RANGE_FORMATS.contains(&c)))
        .map(|(s, _)| s.clone())
        .collect();
    let components: Vec<String> = entries(nm, "ComponentSelector")
        .into_iter()
        .map(|(s, _)| s)
        .collect();
    let present: Vec<&str> = DRIVER_FEATURES
        .iter()
        .copied()
        .filter(|f| f.starts_with("Scan3d") && nm.has(f))
        .collect();
    let scan3d = present
        .into_iter()
        .map(|f| (f.to_owned(), offline_value(nm, f)))
        .collect();
    let missing: Vec<(String, &'static str)> = DRIVER_FEATURES
        .iter()
        .filter(|f| !nm.has(f))
        .map(|f| (f.to_string(), without(f)))
        .collect();
    let output_modes: Vec<String> = entries(nm, "Scan3dOutputMode")
        .into_iter()
        .map(|(s, _)| s)
        .collect();
    let lacks: Vec<&str> = REQUIRED_FEATURES
        .iter()
        .copied()
        .filter(|f| !nm.has(f))
        .collect();
    let verdict = if !lacks.is_empty() {
        Err(format!(
            "not a camera the driver can stream from: no {}",
            lacks.join(", ")
        ))
    } else if range_formats.is_empty() {
        Err(format!(
            "no pixel format the driver turns into points (it reads Coord3D_ABC32f, Coord3D_C16, \
             Coord3D_C32f); PixelFormat offers {}",
            pf.iter()
                .map(|(s, _)| s.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ))
    } else if range_formats.iter().all(|f| f != "Coord3D_ABC32f")
        && [
            "Scan3dFocalLength",
            "Scan3dPrincipalPointU",
            "Scan3dPrincipalPointV",
        ]
        .iter()
        .any(|f| !nm.has(f))
    {
        Err(format!(
            "only depth maps ({}) and no Scan3dFocalLength/Scan3dPrincipalPointU/V to make \
             points of them",
            range_formats.join(", ")
        ))
    } else {
        Ok(())
    };
    Description {
        vendor: nm.vendor_name().to_owned(),
        model: nm.model_name().to_owned(),
        multipart: components.iter().any(|c| c == "Range"),
        pixel_formats: pf.into_iter().map(|(s, _)| s).collect(),
        range_formats,
        components,
        scan3d,
        output_modes,
        tl_params_locked: nm.kind("TLParamsLocked").map(|k| format!("{k:?}")),
        missing,
        verdict,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{SimCamera, SimOptions};

    #[test]
    fn the_simulated_camera_would_work() {
        let mut nm = NodeMap::from_xml(&SimCamera::xml(&SimOptions::default())).expect("xml");
        let d = describe(&mut nm);
        assert_eq!(d.verdict, Ok(()));
        assert_eq!(d.range_formats, ["Coord3D_ABC32f", "Coord3D_C16"]);
        assert!(d.multipart, "{d:?}");
        assert_eq!(d.tl_params_locked.as_deref(), Some("Integer"));
        assert!(d.missing.iter().all(|(f, _)| f != "Width"));
    }

    #[test]
    fn a_2d_camera_would_not() {
        let xml = SimCamera::xml(&SimOptions::default())
            .replace("Coord3D_ABC32f", "Mono8")
            .replace("Coord3D_C16", "Mono16")
            .replace("0x026000C0", "0x01080001")
            .replace("0x011000B8", "0x01100007");
        let mut nm = NodeMap::from_xml(&xml).expect("xml");
        let why = describe(&mut nm).verdict.expect_err("2D");
        assert!(
            why.contains("no pixel format the driver turns into points"),
            "{why}"
        );
        assert!(why.contains("Mono8"), "{why}");
    }
}
