//! The one list of what the driver turns into points: range pixel formats, the
//! `Scan3dOutputMode`s each goes with, and intensity / confidence formats. The decoder
//! ([`super`]) and the offline check of a description ([`crate::describe`]) both judge by it.

use crate::error::{GigeError, Result};

/// PFNC codes this crate knows.
pub mod pfnc {
    /// Coord3D_ABC32f (X, Y, Z float32 per pixel).
    pub const COORD3D_ABC32F: u32 = 0x026000C0;
    /// Coord3D_ABC32f_Planar (all X, then all Y, then all Z, float32).
    pub const COORD3D_ABC32F_PLANAR: u32 = 0x026000C1;
    /// Coord3D_ABC16 (X, Y, Z uint16 per pixel; scale and offset make them distances).
    pub const COORD3D_ABC16: u32 = 0x023000B9;
    /// Lucid's Coord3D_ABCY16 (X, Y, Z, intensity uint16 per pixel; a custom PFNC code,
    /// `LUCID_Coord3D_ABCY16` in Lucid's headers).
    pub const COORD3D_ABCY16: u32 = 0x8240_0403;
    /// Coord3D_A32f (X plane alone, float32; a multipart payload's part).
    pub const COORD3D_A32F: u32 = 0x012000BD;
    /// Coord3D_B32f (Y plane alone).
    pub const COORD3D_B32F: u32 = 0x012000BE;
    /// Coord3D_C16 (depth, uint16).
    pub const COORD3D_C16: u32 = 0x011000B8;
    /// Coord3D_C32f (depth, float32).
    pub const COORD3D_C32F: u32 = 0x012000BF;
    /// Confidence8.
    pub const CONFIDENCE8: u32 = 0x010800C6;
    /// Confidence16.
    pub const CONFIDENCE16: u32 = 0x011000C7;
    /// Confidence32f.
    pub const CONFIDENCE32F: u32 = 0x012000C8;
    /// Mono8.
    pub const MONO8: u32 = 0x01080001;
    /// Mono10 (unpacked, 16 bits per pixel).
    pub const MONO10: u32 = 0x01100003;
    /// Mono10p (LSB-first bit-packed: 4 pixels in 5 bytes).
    pub const MONO10P: u32 = 0x010A0046;
    /// Mono12 (unpacked, 16 bits).
    pub const MONO12: u32 = 0x01100005;
    /// Mono12p (LSB-first bit-packed: 2 pixels in 3 bytes).
    pub const MONO12P: u32 = 0x010C0047;
    /// Mono16.
    pub const MONO16: u32 = 0x01100007;

    /// Name of a known format ("unknown" otherwise).
    pub fn name(code: u32) -> &'static str {
        match code {
            COORD3D_ABC32F => "Coord3D_ABC32f",
            COORD3D_ABC32F_PLANAR => "Coord3D_ABC32f_Planar",
            COORD3D_ABC16 => "Coord3D_ABC16",
            COORD3D_ABCY16 => "Coord3D_ABCY16",
            COORD3D_A32F => "Coord3D_A32f",
            COORD3D_B32F => "Coord3D_B32f",
            COORD3D_C16 => "Coord3D_C16",
            COORD3D_C32F => "Coord3D_C32f",
            CONFIDENCE8 => "Confidence8",
            CONFIDENCE16 => "Confidence16",
            CONFIDENCE32F => "Confidence32f",
            MONO8 => "Mono8",
            MONO10 => "Mono10",
            MONO10P => "Mono10p",
            MONO12 => "Mono12",
            MONO12P => "Mono12p",
            MONO16 => "Mono16",
            _ => "unknown",
        }
    }
}

/// How a range format's values become points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Geometry {
    /// A, B and C per pixel (an organized XYZ grid).
    Points,
    /// C alone (a depth map): x and y come from the pixel and the intrinsics.
    DepthMap,
}

/// A pixel format the driver turns into points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RangeFormat {
    /// PFNC code (the `PixelFormat` entry's value).
    pub code: u32,
    /// PFNC name.
    pub name: &'static str,
    /// Points or a depth map.
    pub geometry: Geometry,
}

impl RangeFormat {
    /// The coordinates (0 = A, 1 = B, 2 = C) the format carries: whose scale, offset and
    /// invalid value the driver reads through `Scan3dCoordinateSelector`.
    pub fn coordinates(&self) -> &'static [usize] {
        match self.geometry {
            Geometry::Points => &[0, 1, 2],
            Geometry::DepthMap => &[2],
        }
    }

    /// The `Scan3dOutputMode`s whose values this format's frames carry as the driver reads
    /// them.
    pub fn output_modes(&self) -> &'static [&'static str] {
        match self.geometry {
            Geometry::Points => POINT_OUTPUT_MODES,
            Geometry::DepthMap => DEPTH_OUTPUT_MODES,
        }
    }
}

/// Every range format the decoder reads (a multipart payload's separate `Coord3D_A32f`,
/// `B32f` and `C32f` planes are read together as one grid; `C32f` alone is a depth map).
pub const RANGE_FORMATS: &[RangeFormat] = &[
    RangeFormat {
        code: pfnc::COORD3D_ABC32F,
        name: "Coord3D_ABC32f",
        geometry: Geometry::Points,
    },
    RangeFormat {
        code: pfnc::COORD3D_ABC32F_PLANAR,
        name: "Coord3D_ABC32f_Planar",
        geometry: Geometry::Points,
    },
    RangeFormat {
        code: pfnc::COORD3D_ABC16,
        name: "Coord3D_ABC16",
        geometry: Geometry::Points,
    },
    RangeFormat {
        code: pfnc::COORD3D_ABCY16,
        name: "Coord3D_ABCY16",
        geometry: Geometry::Points,
    },
    RangeFormat {
        code: pfnc::COORD3D_C16,
        name: "Coord3D_C16",
        geometry: Geometry::DepthMap,
    },
    RangeFormat {
        code: pfnc::COORD3D_C32F,
        name: "Coord3D_C32f",
        geometry: Geometry::DepthMap,
    },
];

/// The range format of a PFNC code, if the decoder reads it.
pub fn range_format(code: u32) -> Option<&'static RangeFormat> {
    RANGE_FORMATS.iter().find(|f| f.code == code)
}

/// Intensity formats decoded into [`handeye_hal::PointCloud::intensity`] (normalized to
/// [0, 1] by their bit depth).
pub const INTENSITY_FORMATS: &[u32] = &[
    pfnc::MONO8,
    pfnc::MONO10,
    pfnc::MONO10P,
    pfnc::MONO12,
    pfnc::MONO12P,
    pfnc::MONO16,
];

/// Confidence formats decoded into [`handeye_hal::PointCloud::confidence`].
pub const CONFIDENCE_FORMATS: &[u32] =
    &[pfnc::CONFIDENCE8, pfnc::CONFIDENCE16, pfnc::CONFIDENCE32F];

/// Output modes of organized XYZ grids (`Coord3D_ABC*` formats).
pub const POINT_OUTPUT_MODES: &[&str] = &["CalibratedABC_Grid"];

/// Output modes of pinhole depth maps (`Coord3D_C*` formats) that the published intrinsics
/// turn into points (see [`super::Scan3d`] for the formula).
pub const DEPTH_OUTPUT_MODES: &[&str] = &["ProjectedC", "CalibratedC", "RectifiedC"];

/// Components whose presence means a `ProjectedC` depth map's pixels are not the pinhole
/// grid: Photoneo ships per-pixel coordinate maps for it (its `u`, `v` are their values).
pub const COORDINATE_MAP_COMPONENTS: &[&str] = &["CoordinateMapA", "CoordinateMapB"];

/// Whether frames of `mode` (with the range in `format`, when known) become points, and if
/// not, which setting would make them: `offered` are the camera's `Scan3dOutputMode`
/// entries (to name one it has), `components` its `ComponentSelector` entries.
pub fn check_output_mode(
    mode: &str,
    format: Option<&RangeFormat>,
    offered: &[String],
    components: &[String],
) -> Result<()> {
    let fix = |modes: &[&str]| {
        let has: Vec<&str> = modes
            .iter()
            .copied()
            .filter(|m| offered.iter().any(|o| o == m))
            .collect();
        match has.as_slice() {
            [] => format!("one of {}", modes.join(", ")),
            [m, ..] => (*m).to_owned(),
        }
    };
    let refuse = |why: String| {
        Err(GigeError::feature(
            "Scan3dOutputMode",
            format!(
                "{why} (in the vendor's tool, or [camera.features] in handeye's configuration)"
            ),
        ))
    };
    let coordinate_maps = components
        .iter()
        .any(|c| COORDINATE_MAP_COMPONENTS.contains(&c.as_str()));
    if mode == "ProjectedC" && coordinate_maps {
        return refuse(format!(
            "is ProjectedC and the camera sends CoordinateMapA/B: its depth pixels become points \
             only through those maps, which this driver does not read; set Scan3dOutputMode to \
             {} with a Coord3D_ABC pixel format",
            fix(POINT_OUTPUT_MODES)
        ));
    }
    let known = POINT_OUTPUT_MODES.contains(&mode) || DEPTH_OUTPUT_MODES.contains(&mode);
    let setting = match format.map(|f| f.geometry) {
        Some(Geometry::Points) => fix(POINT_OUTPUT_MODES),
        Some(Geometry::DepthMap) => format!("{} (with Scan3dFocalLength)", fix(DEPTH_OUTPUT_MODES)),
        None => format!(
            "{} (Coord3D_ABC32f), or {} with a Coord3D_C format and Scan3dFocalLength",
            fix(POINT_OUTPUT_MODES),
            fix(DEPTH_OUTPUT_MODES)
        ),
    };
    if !known {
        return refuse(format!(
            "is {mode}: its values become points only with the camera's coordinate maps (or \
             disparity calibration), which this driver does not read; set Scan3dOutputMode to \
             {setting}"
        ));
    }
    match format {
        Some(f) if !f.output_modes().contains(&mode) => refuse(format!(
            "is {mode}, which {} frames do not carry; set Scan3dOutputMode to {setting}",
            f.name
        )),
        _ => Ok(()),
    }
}
