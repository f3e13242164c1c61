//! [`Scan3d`]: what turns a camera's raw 3D values into metres, read from its features.

use crate::error::{GigeError, Result};
use crate::genicam::{NodeMap, RegisterPort};

use super::formats::{check_output_mode, range_format, RangeFormat};

/// `Scan3dCoordinateSelector` entries, by coordinate index (A = 0, B = 1, C = 2).
pub const COORDINATE_NAMES: [&str; 3] = ["CoordinateA", "CoordinateB", "CoordinateC"];

/// `Scan3dDistanceUnit` entries the driver reads, with metres per unit.
pub const DISTANCE_UNITS: &[(&str, f64)] =
    &[("Millimeter", 0.001), ("Inch", 0.0254), ("Meter", 1.0)];

/// Feature sets that give a depth map's pinhole intrinsics, in the order the driver tries
/// them: SFNC's, then Lucid's factory calibration (Helios2 publishes only these).
pub const INTRINSICS_FEATURES: &[&[&str]] = &[
    &[
        "Scan3dFocalLength",
        "Scan3dPrincipalPointU",
        "Scan3dPrincipalPointV",
    ],
    &[
        "CalibFocalLengthX",
        "CalibOpticalCenterX",
        "CalibOpticalCenterY",
    ],
];

/// Whether a description with the features `has` says publishes a depth map's intrinsics.
pub fn has_intrinsics(has: impl Fn(&str) -> bool) -> bool {
    INTRINSICS_FEATURES
        .iter()
        .any(|set| set.iter().all(|f| has(f)))
}

/// Scan3d parameters needed to turn raw values into metres.
///
/// A depth map (`Coord3D_C*` in `ProjectedC`, `CalibratedC` or `RectifiedC`) becomes points
/// by SFNC's pinhole rule, with `c = raw · scale + offset` of coordinate C:
/// `x = (u − Cu) · c / f`, `y = (v − Cv) · c / (f · a)`, `z = c`, where `u`, `v` are the
/// pixel's column and row in the frame, `f` is `Scan3dFocalLength`, (`Cu`, `Cv`) is
/// `Scan3dPrincipalPointU/V` and `a` is `Scan3dAspectRatio`: the vertical focal length over
/// the horizontal one (`fy = f · a`). This is the formula of SICK's PointCloudGeneration
/// (written against SFNC's `ProjectedC`) and of Photoneo's GigE Vision notes; SFNC's own text
/// was not at hand, so the convention is theirs. Photoneo divides by `f · a` too, but its
/// `ProjectedC` takes `u`, `v` from its `CoordinateMapA/B` components, not from the pixel
/// grid: such a camera is refused in `ProjectedC` (see
/// [`check_output_mode`](super::check_output_mode)).
#[derive(Debug, Clone, PartialEq)]
pub struct Scan3d {
    /// Per coordinate A, B, C: `value_in_unit = raw * scale + offset`.
    pub scale: [f64; 3],
    /// Offsets in the distance unit.
    pub offset: [f64; 3],
    /// Metres per distance unit (0.001 for Millimeter, 0.0254 for Inch).
    pub metres_per_unit: f64,
    /// Per coordinate: the raw value marking an invalid point (Scan3dInvalidDataValue under
    /// that coordinate's selection), when flagged. A point is invalid when any coordinate
    /// equals its own marker (Basler's blaze marks only C).
    pub invalid_value: [Option<f64>; 3],
    /// Focal length in pixels (for depth maps).
    pub focal_length: f64,
    /// Principal point in pixels.
    pub principal_point: (f64, f64),
    /// Vertical over horizontal focal length (`Scan3dAspectRatio`; 1 = square pixels).
    pub aspect_ratio: f64,
}

impl Default for Scan3d {
    fn default() -> Self {
        Self {
            scale: [1.0; 3],
            offset: [0.0; 3],
            metres_per_unit: 0.001,
            invalid_value: [None; 3],
            focal_length: 0.0,
            principal_point: (0.0, 0.0),
            aspect_ratio: 1.0,
        }
    }
}

impl Scan3d {
    /// Whether `raw` of coordinate `k` marks an invalid point (NaN always does).
    pub fn is_invalid(&self, k: usize, raw: f64) -> bool {
        raw.is_nan() || self.invalid_value[k].is_some_and(|iv| raw == iv)
    }

    /// Read the camera's Scan3d features through its node map (defaults where the camera
    /// lacks a feature), for the Range component (selected when the camera has a
    /// `ComponentSelector` offering it): the output mode is checked against the pixel format;
    /// distance unit; scale, offset and invalid marker of each coordinate the pixel format
    /// carries (through `Scan3dCoordinateSelector`, only its entries); the focal length,
    /// principal point and aspect ratio a depth map needs (SFNC's `Scan3d*` features, else
    /// Lucid's `CalibFocalLengthX/Y` and `CalibOpticalCenterX/Y`).
    pub fn read(n: &mut NodeMap, p: &mut impl RegisterPort) -> Result<Self> {
        let mut s = Scan3d::default();
        let components = n.enum_entries("ComponentSelector").unwrap_or_default();
        if components.iter().any(|c| c == "Range") {
            n.set_enum(p, "ComponentSelector", "Range")?;
        }
        let format = if n.has("PixelFormat") {
            u32::try_from(n.enum_value(p, "PixelFormat")?)
                .ok()
                .and_then(range_format)
        } else {
            None
        };
        if n.has("Scan3dOutputMode") {
            let mode = n.enum_symbol(p, "Scan3dOutputMode")?;
            let offered = n.enum_entries("Scan3dOutputMode").unwrap_or_default();
            check_output_mode(&mode, format, &offered, &components)?;
        }
        s.metres_per_unit = read_unit(n, p)?;
        let mut flag_warned = false;
        if n.has("Scan3dCoordinateSelector") {
            let entries = n.enum_entries("Scan3dCoordinateSelector")?;
            let wanted = format.map_or(&[0, 1, 2][..], RangeFormat::coordinates);
            for &k in wanted {
                let sym = COORDINATE_NAMES[k];
                if !entries.iter().any(|e| e == sym) {
                    if let Some(f) = format {
                        tracing::warn!(
                            "Scan3dCoordinateSelector has no {sym} although {} carries it: \
                             scale 1 and offset 0 are used for it",
                            f.name
                        );
                    }
                    continue;
                }
                n.set_enum(p, "Scan3dCoordinateSelector", sym)?;
                if n.has("Scan3dCoordinateScale") {
                    s.scale[k] = n.number(p, "Scan3dCoordinateScale")?;
                }
                if n.has("Scan3dCoordinateOffset") {
                    s.offset[k] = n.number(p, "Scan3dCoordinateOffset")?;
                }
                s.invalid_value[k] = read_invalid(n, p, &mut flag_warned)?;
            }
        } else {
            // One set for the whole camera (Nerian, depth-only cameras).
            if n.has("Scan3dCoordinateScale") {
                s.scale = [n.number(p, "Scan3dCoordinateScale")?; 3];
            }
            if n.has("Scan3dCoordinateOffset") {
                s.offset[2] = n.number(p, "Scan3dCoordinateOffset")?;
            }
            s.invalid_value = [read_invalid(n, p, &mut flag_warned)?; 3];
        }
        read_intrinsics(n, p, &mut s)?;
        s.check()?;
        Ok(s)
    }

    /// Refuses values no camera can mean: a scale that is not positive and finite (0 puts
    /// every point at the offset), an offset beyond [`MAX_COORDINATE_M`] (1e30 mm).
    pub fn check(&self) -> Result<()> {
        for (k, name) in COORDINATE_NAMES.iter().enumerate() {
            let scale = self.scale[k];
            if !(scale.is_finite() && scale > 0.0) {
                return Err(GigeError::feature(
                    "Scan3dCoordinateScale",
                    format!("{scale} for {name}: a scale must be positive and finite; check the camera's calibration"),
                ));
            }
            let offset_m = self.offset[k] * self.metres_per_unit;
            if !(offset_m.is_finite() && offset_m.abs() <= MAX_COORDINATE_M) {
                return Err(GigeError::feature(
                    "Scan3dCoordinateOffset",
                    format!(
                        "{} for {name} ({offset_m:e} m): beyond the {MAX_COORDINATE_M} m any 3D camera measures; check the camera's calibration",
                        self.offset[k]
                    ),
                ));
            }
        }
        Ok(())
    }

    /// A point in metres as the decoders keep it: NaN (invalid) when a coordinate is not
    /// finite or beyond [`MAX_COORDINATE_M`].
    pub(crate) fn bounded(c: [f64; 3]) -> Option<[f64; 3]> {
        c.iter()
            .all(|v| v.is_finite() && v.abs() <= MAX_COORDINATE_M)
            .then_some(c)
    }
}

/// The working range: a coordinate farther than this from the camera (metres) is not a
/// measurement (the longest-range structured-light and time-of-flight cameras reach tens of
/// metres). Offsets beyond it are refused; decoded points beyond it are invalid (NaN).
pub const MAX_COORDINATE_M: f64 = 100.0;

fn read_unit(n: &mut NodeMap, p: &mut impl RegisterPort) -> Result<f64> {
    if !n.has("Scan3dDistanceUnit") {
        tracing::warn!(
            "the camera has no Scan3dDistanceUnit: its 3D values are taken as millimetres \
             (check the vendor's manual if the points come out 1000 times too small or large)"
        );
        return Ok(0.001);
    }
    let unit = n.enum_symbol(p, "Scan3dDistanceUnit")?;
    match DISTANCE_UNITS.iter().find(|(name, _)| *name == unit) {
        Some((_, m)) => Ok(*m),
        None => Err(GigeError::feature(
            "Scan3dDistanceUnit",
            format!("unknown unit `{unit}`; set it to Millimeter"),
        )),
    }
}

/// The invalid marker under the current coordinate selection: `Scan3dInvalidDataValue` when
/// `Scan3dInvalidDataFlag` is set (or absent).
fn read_invalid(
    n: &mut NodeMap,
    p: &mut impl RegisterPort,
    warned: &mut bool,
) -> Result<Option<f64>> {
    let flagged = !n.has("Scan3dInvalidDataFlag")
        || n.boolean(p, "Scan3dInvalidDataFlag").unwrap_or_else(|e| {
            // The EMVA reference producer's flag is a Boolean with a constant <Value>,
            // which this node map cannot evaluate yet.
            if !std::mem::replace(warned, true) {
                tracing::warn!("{e}; only NaN marks an invalid point");
            }
            false
        });
    if flagged && n.has("Scan3dInvalidDataValue") {
        Ok(Some(n.number(p, "Scan3dInvalidDataValue")?))
    } else {
        Ok(None)
    }
}

fn positive(feature: &str, v: f64, what: &str) -> Result<f64> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(GigeError::feature(
            feature,
            format!("{v} is not a positive {what}; check the camera's calibration"),
        ))
    }
}

/// Focal length, principal point and aspect ratio: SFNC's features, else Lucid's.
fn read_intrinsics(n: &mut NodeMap, p: &mut impl RegisterPort, s: &mut Scan3d) -> Result<()> {
    if n.has("Scan3dFocalLength") {
        s.focal_length = n.number(p, "Scan3dFocalLength")?;
        s.principal_point = (
            n.number(p, "Scan3dPrincipalPointU")?,
            n.number(p, "Scan3dPrincipalPointV")?,
        );
    } else if n.has("CalibFocalLengthX") {
        let fx = positive(
            "CalibFocalLengthX",
            n.number(p, "CalibFocalLengthX")?,
            "focal length",
        )?;
        s.focal_length = fx;
        s.principal_point = (
            n.number(p, "CalibOpticalCenterX")?,
            n.number(p, "CalibOpticalCenterY")?,
        );
        if n.has("CalibFocalLengthY") && !n.has("Scan3dAspectRatio") {
            let fy = positive(
                "CalibFocalLengthY",
                n.number(p, "CalibFocalLengthY")?,
                "focal length",
            )?;
            s.aspect_ratio = fy / fx;
        }
    }
    if n.has("Scan3dAspectRatio") {
        s.aspect_ratio = positive(
            "Scan3dAspectRatio",
            n.number(p, "Scan3dAspectRatio")?,
            "aspect ratio",
        )?;
    }
    Ok(())
}
