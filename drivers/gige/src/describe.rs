//! What the driver would make of a camera's GenICam description, offline (no camera):
//! `handeye camera xml`.
//!
//! Features whose value is written in the description (a `<Value>`, a formula over constants)
//! are evaluated; those that live in the camera's registers are reported as read at run time.

use crate::camera::DRIVER_FEATURES;
use crate::decode::scan3d::{has_intrinsics, DISTANCE_UNITS, INTRINSICS_FEATURES};
use crate::decode::{check_output_mode, range_format, Geometry, RangeFormat, RANGE_FORMATS};
use crate::genicam::{FeatureKind, NodeMap};

/// Features without which the driver cannot stream at all.
pub const REQUIRED_FEATURES: &[&str] = &[
    "Width",
    "Height",
    "PixelFormat",
    "AcquisitionStart",
    "AcquisitionStop",
];

/// What the driver would use, and whether it would work.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Description {
    /// `VendorName` of the description.
    pub vendor: String,
    /// `ModelName` of the description.
    pub model: String,
    /// All `PixelFormat` entries.
    pub pixel_formats: Vec<String>,
    /// The entries the driver decodes into points (the decoder's list,
    /// [`RANGE_FORMATS`]).
    pub range_formats: Vec<String>,
    /// The range formats that would work with this description, each with the
    /// `Scan3dOutputMode`s it works in (none listed when the camera has no such feature).
    pub usable: Vec<String>,
    /// What to set in the camera for the driver to stream points (it sets neither
    /// `PixelFormat` nor `Scan3dOutputMode` itself).
    pub settings: Vec<String>,
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
            "depth maps (Coord3D_C16/C32f) need CalibFocalLengthX and CalibOpticalCenterX/Y instead"
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

/// Which range formats work with this description, by the decoder's rules (the output mode
/// each goes with, the intrinsics a depth map needs), with what to set; else why none does.
fn judge(
    nm: &mut NodeMap,
    formats: &[&'static RangeFormat],
    components: &[String],
) -> Result<(Vec<String>, Vec<String>), String> {
    let names = |v: &[&str]| v.join(", ");
    let offered: Vec<String> = nm.enum_entries("Scan3dOutputMode").unwrap_or_default();
    let has_mode = nm.has("Scan3dOutputMode");
    let intrinsics = has_intrinsics(|f| nm.has(f));
    let mut usable: Vec<(&RangeFormat, Vec<&str>)> = Vec::new();
    let mut reasons = Vec::new();
    for &f in formats {
        if f.geometry == Geometry::DepthMap && !intrinsics {
            reasons.push(format!(
                "{} is a depth map and the description has no {} to make points of it",
                f.name,
                INTRINSICS_FEATURES
                    .iter()
                    .map(|set| names(set))
                    .collect::<Vec<_>>()
                    .join(" (or ")
                    + ")"
            ));
            continue;
        }
        if !has_mode {
            usable.push((f, Vec::new()));
            continue;
        }
        let modes: Vec<&str> = f
            .output_modes()
            .iter()
            .copied()
            .filter(|m| {
                offered.iter().any(|o| o == m)
                    && check_output_mode(m, Some(f), &offered, components).is_ok()
            })
            .collect();
        if modes.is_empty() {
            reasons.push(format!(
                "{} needs Scan3dOutputMode {}, which the description does not offer (it offers \
                 {})",
                f.name,
                names(f.output_modes()),
                offered.join(", ")
            ));
        } else {
            usable.push((f, modes));
        }
    }
    let Some((first, first_modes)) = usable.first() else {
        return Err(reasons.join("; "));
    };
    let mut settings = vec![format!(
        "set PixelFormat to {}",
        usable
            .iter()
            .map(|(f, _)| f.name)
            .collect::<Vec<_>>()
            .join(" or ")
    )];
    if let Some(mode) = first_modes.first() {
        // A value written in the description is the camera's until someone changes it.
        match offline_value(nm, "Scan3dOutputMode") {
            Some(cur) if !usable.iter().any(|(_, m)| m.contains(&cur.as_str())) => {
                return Err(format!(
                    "Scan3dOutputMode is {cur}, which none of {} carries; set \
                     Scan3dOutputMode to {mode} (with PixelFormat {}; in handeye's \
                     configuration: [camera.features] PixelFormat = \"{}\", \
                     Scan3dOutputMode = \"{mode}\")",
                    usable
                        .iter()
                        .map(|(f, _)| f.name)
                        .collect::<Vec<_>>()
                        .join(", "),
                    first.name,
                    first.name
                ));
            }
            _ => settings.push(format!(
                "set Scan3dOutputMode to {}",
                usable
                    .iter()
                    .map(|(f, m)| format!("{} for {}", m.join(" or "), f.name))
                    .collect::<Vec<_>>()
                    .join("; ")
            )),
        }
    }
    // handeye sets them itself when configured so (issue 44).
    let mut features = vec![format!("PixelFormat = \"{}\"", first.name)];
    if let Some(mode) = first_modes.first() {
        features.push(format!("Scan3dOutputMode = \"{mode}\""));
    }
    settings.push(format!(
        "or let handeye set them before every capture: [camera.features] {}",
        features.join(", ")
    ));
    if nm.has("Scan3dDistanceUnit") {
        let units = nm.enum_entries("Scan3dDistanceUnit").unwrap_or_default();
        let known = |u: &str| DISTANCE_UNITS.iter().any(|(n, _)| *n == u);
        match offline_value(nm, "Scan3dDistanceUnit") {
            Some(cur) if !known(&cur) => {
                return Err(format!(
                    "Scan3dDistanceUnit is {cur}, a unit the driver does not read; set \
                     Scan3dDistanceUnit to {}",
                    units
                        .iter()
                        .find(|u| known(u))
                        .map_or("Millimeter", String::as_str)
                ))
            }
            _ if !units.iter().any(|u| known(u)) => {
                return Err(format!(
                    "Scan3dDistanceUnit offers {}, none of which the driver reads ({})",
                    units.join(", "),
                    DISTANCE_UNITS
                        .iter()
                        .map(|(n, _)| *n)
                        .collect::<Vec<_>>()
                        .join(", ")
                ))
            }
            _ => {}
        }
    }
    let usable = usable
        .iter()
        .map(|(f, m)| {
            if m.is_empty() {
                f.name.to_owned()
            } else {
                format!("{} (Scan3dOutputMode {})", f.name, m.join(" or "))
            }
        })
        .collect();
    Ok((usable, settings))
}

/// Describe a loaded node map, judged by the decoder's rules.
pub fn describe(nm: &mut NodeMap) -> Description {
    let entries = |nm: &NodeMap, n: &str| nm.enum_entries_with_values(n).unwrap_or_default();
    let pf = entries(nm, "PixelFormat");
    let formats: Vec<&'static RangeFormat> = pf
        .iter()
        .filter_map(|(_, v)| u32::try_from(*v).ok().and_then(range_format))
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
    let judged = if !lacks.is_empty() {
        Err(format!(
            "not a camera the driver can stream from: no {}",
            lacks.join(", ")
        ))
    } else if formats.is_empty() {
        Err(format!(
            "no pixel format the driver turns into points (it reads {}); PixelFormat offers {}",
            RANGE_FORMATS
                .iter()
                .map(|f| f.name)
                .collect::<Vec<_>>()
                .join(", "),
            pf.iter()
                .map(|(s, _)| s.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ))
    } else {
        judge(nm, &formats, &components)
    };
    let (usable, settings, verdict) = match judged {
        Ok((u, s)) => (u, s, Ok(())),
        Err(why) => (Vec::new(), Vec::new(), Err(why)),
    };
    Description {
        vendor: nm.vendor_name().to_owned(),
        model: nm.model_name().to_owned(),
        multipart: components.iter().any(|c| c == "Range"),
        pixel_formats: pf.into_iter().map(|(s, _)| s).collect(),
        range_formats: formats.iter().map(|f| f.name.to_owned()).collect(),
        usable,
        settings,
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
        assert_eq!(
            d.usable,
            [
                "Coord3D_ABC32f (Scan3dOutputMode CalibratedABC_Grid)",
                "Coord3D_C16 (Scan3dOutputMode RectifiedC)"
            ]
        );
        assert!(d.multipart, "{d:?}");
        assert_eq!(d.tl_params_locked.as_deref(), Some("Integer"));
        assert!(d.missing.iter().all(|(f, _)| f != "Width"));
    }

    /// The simulator's description with only `entry` (name, PFNC code) as pixel format.
    fn only_format(name: &str, code: &str) -> String {
        let xml = SimCamera::xml(&SimOptions::default());
        let c16 = xml
            .find("<EnumEntry Name=\"Coord3D_C16\"")
            .expect("C16 entry");
        let end = c16 + xml[c16..].find("</EnumEntry>").expect("end") + "</EnumEntry>".len();
        let mut xml = xml.clone();
        xml.replace_range(c16..end, "");
        xml.replace("\"Coord3D_ABC32f\"", &format!("\"{name}\""))
            .replace("0x026000C0", code)
    }

    /// Issue 44: `handeye camera xml` knew fewer formats than the decoder and ignored
    /// Scan3dOutputMode: the EMVA reference producer's viky camera (Coord3D_ABC32f_Planar,
    /// CalibratedABC_Grid) was said not to work. Now it judges by the decoder's list and
    /// says which setting would make a camera work.
    #[test]
    fn issue_44_describe_judges_by_the_decoders_formats_and_output_modes() {
        let mut nm =
            NodeMap::from_xml(&only_format("Coord3D_ABC32f_Planar", "0x026000C1")).expect("xml");
        let d = describe(&mut nm);
        assert_eq!(d.verdict, Ok(()), "{d:?}");
        assert_eq!(
            d.usable,
            ["Coord3D_ABC32f_Planar (Scan3dOutputMode CalibratedABC_Grid)"]
        );
        assert!(
            d.settings.iter().any(
                |s| s == "set Scan3dOutputMode to CalibratedABC_Grid for Coord3D_ABC32f_Planar"
            ),
            "{:?}",
            d.settings
        );
        // Issue 44: handeye can set them itself; the advice says how.
        assert!(
            d.settings.iter().any(|s| s
                == "or let handeye set them before every capture: [camera.features] \
                    PixelFormat = \"Coord3D_ABC32f_Planar\", Scan3dOutputMode = \"CalibratedABC_Grid\""),
            "{:?}",
            d.settings
        );
        // The output mode written in the description as RectifiedC: an XYZ format does not
        // carry it, and the verdict names the setting that would.
        let xml = only_format("Coord3D_ABC32f", "0x026000C0")
            .replace("<pValue>Scan3dOutputModeReg</pValue>", "<Value>1</Value>");
        let mut nm = NodeMap::from_xml(&xml).expect("xml");
        let why = describe(&mut nm).verdict.expect_err("RectifiedC");
        assert!(
            why.contains("set Scan3dOutputMode to CalibratedABC_Grid")
                && why.contains("[camera.features] PixelFormat = \"Coord3D_ABC32f\", Scan3dOutputMode = \"CalibratedABC_Grid\""),
            "{why}"
        );
        // A depth map without intrinsics does not work; Lucid's Calib* features would do.
        let xml = only_format("Coord3D_C16", "0x011000B8");
        let no_intrinsics = xml
            .replace("\"Scan3dFocalLength\"", "\"VendorFocalLength\"")
            .replace("<pFeature>Scan3dFocalLength</pFeature>", "");
        let mut nm = NodeMap::from_xml(&no_intrinsics).expect("xml");
        let why = describe(&mut nm).verdict.expect_err("no intrinsics");
        assert!(why.contains("CalibFocalLengthX"), "{why}");
        // ProjectedC is a depth map's output mode now (SICK's Visionary).
        let projected = xml.replace("\"RectifiedC\"", "\"ProjectedC\"");
        let mut nm = NodeMap::from_xml(&projected).expect("xml");
        let d = describe(&mut nm);
        assert_eq!(d.verdict, Ok(()), "{d:?}");
        assert_eq!(d.usable, ["Coord3D_C16 (Scan3dOutputMode ProjectedC)"]);
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
