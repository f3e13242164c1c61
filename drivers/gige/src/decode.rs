//! PFNC 3D pixel formats to [`PointCloud`]s (metres, camera frame, organized).

use handeye_hal::nalgebra::Point3;
use handeye_hal::PointCloud;

use crate::error::{GigeError, Result};
use crate::genicam::{NodeMap, RegisterPort};
use crate::gvsp::{Frame, PartInfo, PART_3D_IMAGE, PART_CONFIDENCE};

/// PFNC codes this module knows.
pub mod pfnc {
    /// Coord3D_ABC32f (X, Y, Z float32 per pixel).
    pub const COORD3D_ABC32F: u32 = 0x026000C0;
    /// Coord3D_ABC32f_Planar (all X, then all Y, then all Z, float32).
    pub const COORD3D_ABC32F_PLANAR: u32 = 0x026000C1;
    /// Coord3D_ABC16 (X, Y, Z uint16 per pixel; scale and offset make them distances).
    pub const COORD3D_ABC16: u32 = 0x023000B9;
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
    /// Mono16.
    pub const MONO16: u32 = 0x01100007;
    /// Mono12 (unpacked, 16 bits).
    pub const MONO12: u32 = 0x01100005;

    /// Name of a known format.
    pub fn name(code: u32) -> &'static str {
        match code {
            COORD3D_ABC32F => "Coord3D_ABC32f",
            COORD3D_C16 => "Coord3D_C16",
            COORD3D_C32F => "Coord3D_C32f",
            CONFIDENCE8 => "Confidence8",
            CONFIDENCE16 => "Confidence16",
            CONFIDENCE32F => "Confidence32f",
            MONO8 => "Mono8",
            MONO16 => "Mono16",
            MONO12 => "Mono12",
            COORD3D_ABC32F_PLANAR => "Coord3D_ABC32f_Planar",
            COORD3D_A32F => "Coord3D_A32f",
            COORD3D_B32F => "Coord3D_B32f",
            COORD3D_ABC16 => "Coord3D_ABC16",
            _ => "unknown",
        }
    }
}

/// Scan3d parameters needed to turn raw values into metres.
#[derive(Debug, Clone, PartialEq)]
pub struct Scan3d {
    /// Per coordinate A, B, C: `value_in_unit = raw * scale + offset`.
    pub scale: [f64; 3],
    /// Offsets in the distance unit.
    pub offset: [f64; 3],
    /// Metres per distance unit (0.001 for Millimeter, 0.0254 for Inch).
    pub metres_per_unit: f64,
    /// Raw value marking an invalid point (Scan3dInvalidDataValue), when flagged.
    pub invalid_value: Option<f64>,
    /// Focal length in pixels (for depth maps).
    pub focal_length: f64,
    /// Principal point in pixels.
    pub principal_point: (f64, f64),
    /// Scan3dAspectRatio: a pixel's height over its width (depth maps: y scales by it).
    pub aspect_ratio: f64,
}

impl Default for Scan3d {
    fn default() -> Self {
        Self {
            scale: [1.0; 3],
            offset: [0.0; 3],
            metres_per_unit: 0.001,
            invalid_value: None,
            focal_length: 0.0,
            principal_point: (0.0, 0.0),
            aspect_ratio: 1.0,
        }
    }
}

impl Scan3d {
    /// Read the camera's Scan3d features through its node map (defaults where the camera lacks
    /// a feature): distance unit, per-coordinate scale and offset, the invalid-data marker, and
    /// the focal length and principal point a depth map needs.
    pub fn read(n: &mut NodeMap, p: &mut impl RegisterPort) -> Result<Self> {
        let mut s = Scan3d::default();
        if n.has("Scan3dOutputMode") {
            let mode = n.enum_symbol(p, "Scan3dOutputMode")?;
            crate::camera::check_output_mode(&mode)?;
        }
        if !n.has("Scan3dDistanceUnit") {
            tracing::warn!(
                "the camera has no Scan3dDistanceUnit: its 3D values are taken as \
                 millimetres (check the vendor's manual if the points come out 1000 times \
                 too small or large)"
            );
        } else {
            s.metres_per_unit = match n.enum_symbol(p, "Scan3dDistanceUnit")?.as_str() {
                "Millimeter" => 0.001,
                "Inch" => 0.0254,
                "Meter" => 1.0,
                other => {
                    return Err(GigeError::feature(
                        "Scan3dDistanceUnit",
                        format!("unknown unit `{other}`"),
                    ))
                }
            };
        }
        if n.has("Scan3dCoordinateSelector") {
            for (k, sym) in ["CoordinateA", "CoordinateB", "CoordinateC"]
                .iter()
                .enumerate()
            {
                n.set_enum(p, "Scan3dCoordinateSelector", sym)?;
                if n.has("Scan3dCoordinateScale") {
                    s.scale[k] = n.number(p, "Scan3dCoordinateScale")?;
                }
                if n.has("Scan3dCoordinateOffset") {
                    s.offset[k] = n.number(p, "Scan3dCoordinateOffset")?;
                }
            }
        } else {
            // One pair for the whole camera (Nerian, depth-only cameras).
            if n.has("Scan3dCoordinateScale") {
                s.scale = [n.number(p, "Scan3dCoordinateScale")?; 3];
            }
            if n.has("Scan3dCoordinateOffset") {
                s.offset[2] = n.number(p, "Scan3dCoordinateOffset")?;
            }
        }
        if n.has("Scan3dAspectRatio") {
            let a = n.number(p, "Scan3dAspectRatio")?;
            if !(a.is_finite() && a > 0.0) {
                return Err(GigeError::feature(
                    "Scan3dAspectRatio",
                    format!("{a} is not a positive pixel aspect ratio"),
                ));
            }
            s.aspect_ratio = a;
        }
        let flagged = !n.has("Scan3dInvalidDataFlag")
            || n.boolean(p, "Scan3dInvalidDataFlag").unwrap_or_else(|e| {
                // The EMVA reference producer's flag is a Boolean with a constant <Value>,
                // which this node map cannot evaluate yet.
                tracing::warn!("{e}; only NaN marks an invalid point");
                false
            });
        if flagged && n.has("Scan3dInvalidDataValue") {
            s.invalid_value = Some(n.number(p, "Scan3dInvalidDataValue")?);
        }
        if n.has("Scan3dFocalLength") {
            s.focal_length = n.number(p, "Scan3dFocalLength")?;
            s.principal_point = (
                n.number(p, "Scan3dPrincipalPointU")?,
                n.number(p, "Scan3dPrincipalPointV")?,
            );
        }
        Ok(s)
    }
}

fn f32_le(b: &[u8], i: usize) -> f32 {
    f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]])
}

fn u16_le(b: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([b[i], b[i + 1]])
}

fn check_len(p: &PartInfo, data: &[u8], bytes_per_pixel: usize) -> Result<(usize, usize, usize)> {
    let (w, h) = (p.width as usize, p.height as usize);
    let stride = w * bytes_per_pixel + usize::from(p.padding_x);
    if data.len() < stride * h.saturating_sub(1) + w * bytes_per_pixel {
        return Err(GigeError::malformed(
            "3D frame",
            format!(
                "{} bytes for {w}x{h} {}",
                data.len(),
                pfnc::name(p.pixel_format)
            ),
        ));
    }
    Ok((w, h, stride))
}

/// Per-pixel scalar (confidence or intensity), normalized to [0, 1] for integer formats.
fn scalar_plane(p: &PartInfo, data: &[u8]) -> Result<Vec<f32>> {
    let bpp = match p.pixel_format {
        pfnc::CONFIDENCE8 | pfnc::MONO8 => 1,
        pfnc::CONFIDENCE16 | pfnc::MONO16 | pfnc::MONO12 => 2,
        pfnc::CONFIDENCE32F => 4,
        f => {
            return Err(GigeError::UnsupportedFormat {
                format: f,
                name: pfnc::name(f),
            })
        }
    };
    let (w, h, stride) = check_len(p, data, bpp)?;
    let max = match p.pixel_format {
        pfnc::MONO12 => 4095.0,
        _ => ((1u64 << (8 * bpp.min(2))) - 1) as f32,
    };
    let mut out = Vec::with_capacity(w * h);
    for v in 0..h {
        for u in 0..w {
            let i = v * stride + u * bpp;
            out.push(match bpp {
                1 => f32::from(data[i]) / max,
                2 => f32::from(u16_le(data, i)) / max,
                _ => f32_le(data, i),
            });
        }
    }
    Ok(out)
}

/// Decode the range part of a frame (plus confidence/intensity parts when present). The range
/// part is the one in a 3D pixel format, else the one of the 3D data type, else the only part
/// (cameras send intensity first: a multi-part frame's first part need not be the range).
pub fn decode(frame: &Frame, s: &Scan3d) -> Result<PointCloud> {
    decode_parts(&frame.parts, s)
}

/// Decode the parts of one payload: the range part (`Coord3D_ABC32f` packed or planar,
/// `Coord3D_C16/C32f`, or three `Coord3D_A32f`/`B32f`/`C32f` parts of a multipart payload),
/// plus confidence and intensity parts of the same size when present. The range part is the
/// one in a 3D pixel format, else the one of the 3D data type, else the only part (cameras
/// send intensity first: a multi-part frame's first part need not be the range).
pub fn decode_parts(parts: &[(PartInfo, Vec<u8>)], s: &Scan3d) -> Result<PointCloud> {
    let find = |pf: u32| parts.iter().find(|(p, _)| p.pixel_format == pf);
    let range = parts
        .iter()
        .find(|(p, _)| {
            matches!(
                p.pixel_format,
                pfnc::COORD3D_ABC32F
                    | pfnc::COORD3D_ABC32F_PLANAR
                    | pfnc::COORD3D_ABC16
                    | pfnc::COORD3D_C16
                    | pfnc::COORD3D_C32F
            )
        })
        .or_else(|| parts.iter().find(|(p, _)| p.data_type == PART_3D_IMAGE))
        .or(match parts {
            [only] => Some(only),
            _ => None,
        });
    // Separate A, B and C planes come first: the C plane alone would pass for a depth map.
    let mut cloud = match (
        find(pfnc::COORD3D_A32F),
        find(pfnc::COORD3D_B32F),
        find(pfnc::COORD3D_C32F),
        range,
    ) {
        (Some(a), Some(b), Some(c), _) => decode_abc_parts([a, b, c], s)?,
        (.., Some((p, d))) => decode_range(p, d, s)?,
        _ => {
            let names: Vec<String> = parts
                .iter()
                .map(|(p, _)| {
                    format!(
                        "{} (data type {:#x})",
                        pfnc::name(p.pixel_format),
                        p.data_type
                    )
                })
                .collect();
            return Err(GigeError::malformed(
                "3D frame",
                if names.is_empty() {
                    "frame without data".to_owned()
                } else {
                    format!(
                        "no range part among {}; enable ComponentSelector Range with a \
                         Coord3D pixel format",
                        names.join(", ")
                    )
                },
            ));
        }
    };
    for (p, d) in parts {
        let is_conf = p.data_type == PART_CONFIDENCE
            || matches!(
                p.pixel_format,
                pfnc::CONFIDENCE8 | pfnc::CONFIDENCE16 | pfnc::CONFIDENCE32F
            );
        let is_int = matches!(p.pixel_format, pfnc::MONO8 | pfnc::MONO16 | pfnc::MONO12);
        if (is_conf || is_int) && p.width == cloud.width && p.height == cloud.height {
            let plane = scalar_plane(p, d)?;
            if is_conf {
                cloud.confidence = Some(plane);
            } else {
                cloud.intensity = Some(plane);
            }
        }
    }
    Ok(cloud)
}

/// Organized points from raw A, B, C values per pixel (`raw(u, v)`, row-major): scale, offset
/// and unit applied in f64, rounded once to f32; a NaN or flagged-invalid coordinate makes the
/// point NaN.
fn abc_points(
    w: usize,
    h: usize,
    s: &Scan3d,
    raw: impl Fn(usize, usize) -> [f32; 3],
) -> Vec<Point3<f32>> {
    let m = s.metres_per_unit;
    let invalid = |r: f64| r.is_nan() || s.invalid_value.is_some_and(|iv| r == iv);
    let mut points = Vec::with_capacity(w * h);
    for v in 0..h {
        for u in 0..w {
            let r = raw(u, v).map(f64::from);
            if r.iter().any(|&x| invalid(x)) {
                points.push(Point3::new(f32::NAN, f32::NAN, f32::NAN));
                continue;
            }
            let c: [f64; 3] = std::array::from_fn(|k| (r[k] * s.scale[k] + s.offset[k]) * m);
            points.push(Point3::new(c[0] as f32, c[1] as f32, c[2] as f32));
        }
    }
    points
}

/// Three single-coordinate parts (`Coord3D_A32f`, `B32f`, `C32f`, in that order) of one size.
fn decode_abc_parts(planes: [&(PartInfo, Vec<u8>); 3], s: &Scan3d) -> Result<PointCloud> {
    let (p0, _) = planes[0];
    if planes
        .iter()
        .any(|(p, _)| (p.width, p.height) != (p0.width, p0.height))
    {
        return Err(GigeError::malformed(
            "3D frame",
            format!(
                "the A, B and C parts differ in size: {}",
                planes
                    .iter()
                    .map(|(p, _)| format!("{}x{}", p.width, p.height))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ));
    }
    let mut strides = [0; 3];
    for (k, (p, d)) in planes.iter().enumerate() {
        strides[k] = check_len(p, d, 4)?.2;
    }
    let (w, h) = (p0.width as usize, p0.height as usize);
    let points = abc_points(w, h, s, |u, v| {
        std::array::from_fn(|k| f32_le(&planes[k].1, v * strides[k] + u * 4))
    });
    Ok(PointCloud {
        width: p0.width,
        height: p0.height,
        points,
        intensity: None,
        confidence: None,
    })
}

/// Decode one range image.
pub fn decode_range(p: &PartInfo, data: &[u8], s: &Scan3d) -> Result<PointCloud> {
    let nan = Point3::new(f32::NAN, f32::NAN, f32::NAN);
    let m = s.metres_per_unit;
    let invalid = |raw: f64| raw.is_nan() || s.invalid_value.is_some_and(|iv| raw == iv);
    let mut points = Vec::new();
    let (w, h) = (p.width, p.height);
    match p.pixel_format {
        pfnc::COORD3D_ABC32F => {
            let (wu, hu, stride) = check_len(p, data, 12)?;
            points = abc_points(wu, hu, s, |u, v| {
                let i = v * stride + u * 12;
                [f32_le(data, i), f32_le(data, i + 4), f32_le(data, i + 8)]
            });
        }
        pfnc::COORD3D_ABC16 => {
            let (wu, hu, stride) = check_len(p, data, 6)?;
            points = abc_points(wu, hu, s, |u, v| {
                let i = v * stride + u * 6;
                [u16_le(data, i), u16_le(data, i + 2), u16_le(data, i + 4)].map(f32::from)
            });
        }
        pfnc::COORD3D_ABC32F_PLANAR => {
            // Three planes of one line layout each: all A, then all B, then all C.
            let (wu, hu, stride) = check_len(p, data, 4)?;
            let plane = stride * hu;
            if data.len() < 3 * plane {
                return Err(GigeError::malformed(
                    "3D frame",
                    format!(
                        "{} bytes for {wu}x{hu} Coord3D_ABC32f_Planar (3 planes of {plane})",
                        data.len()
                    ),
                ));
            }
            points = abc_points(wu, hu, s, |u, v| {
                std::array::from_fn(|k| f32_le(data, k * plane + v * stride + u * 4))
            });
        }
        pfnc::COORD3D_C16 | pfnc::COORD3D_C32F => {
            if s.focal_length <= 0.0 || !s.focal_length.is_finite() {
                return Err(GigeError::feature(
                    "Scan3dFocalLength",
                    "a depth map needs a positive focal length to make points",
                ));
            }
            let bpp = if p.pixel_format == pfnc::COORD3D_C16 {
                2
            } else {
                4
            };
            let (wu, hu, stride) = check_len(p, data, bpp)?;
            points.reserve(wu * hu);
            let (cu, cv) = s.principal_point;
            for v in 0..hu {
                for u in 0..wu {
                    let i = v * stride + u * bpp;
                    let raw = if bpp == 2 {
                        f64::from(u16_le(data, i))
                    } else {
                        f64::from(f32_le(data, i))
                    };
                    if invalid(raw) {
                        points.push(nan);
                        continue;
                    }
                    let z = (raw * s.scale[2] + s.offset[2]) * m;
                    let x = (u as f64 - cu) * z / s.focal_length;
                    let y = (v as f64 - cv) * z * s.aspect_ratio / s.focal_length;
                    points.push(Point3::new(x as f32, y as f32, z as f32));
                }
            }
        }
        f => {
            return Err(GigeError::UnsupportedFormat {
                format: f,
                name: pfnc::name(f),
            })
        }
    }
    Ok(PointCloud {
        width: w,
        height: h,
        points,
        intensity: None,
        confidence: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn part(pf: u32, w: u32, h: u32) -> PartInfo {
        PartInfo {
            data_type: 5,
            length: 0,
            pixel_format: pf,
            purpose: 4,
            width: w,
            height: h,
            padding_x: 0,
        }
    }

    #[test]
    fn abc32f_in_mm_becomes_metres_and_invalid_is_nan() {
        let mut d = Vec::new();
        for v in [100.0f32, -50.0, 1000.0, 0.0, 0.0, 0.0] {
            d.extend_from_slice(&v.to_le_bytes());
        }
        let s = Scan3d {
            invalid_value: Some(0.0),
            ..Scan3d::default()
        };
        let c = decode_range(&part(pfnc::COORD3D_ABC32F, 2, 1), &d, &s).expect("decode");
        assert!((c.points[0].x - 0.1).abs() < 1e-6 && (c.points[0].z - 1.0).abs() < 1e-6);
        assert!(c.points[1].x.is_nan());
        assert_eq!(c.valid_count(), 1);
    }

    #[test]
    fn c16_uses_scale_offset_and_intrinsics() {
        // 3x1 depth map, 0.1 mm per unit, 5 mm offset; f = 100 px, principal point (1, 0).
        let mut d = Vec::new();
        for v in [10_000u16, 0, 20_000] {
            d.extend_from_slice(&v.to_le_bytes());
        }
        let s = Scan3d {
            scale: [1.0, 1.0, 0.1],
            offset: [0.0, 0.0, 5.0],
            invalid_value: Some(0.0),
            focal_length: 100.0,
            principal_point: (1.0, 0.0),
            ..Scan3d::default()
        };
        let c = decode_range(&part(pfnc::COORD3D_C16, 3, 1), &d, &s).expect("decode");
        assert!((c.points[0].z - 1.005).abs() < 1e-6);
        assert!((c.points[0].x + 1.005 / 100.0).abs() < 1e-6);
        assert!(c.points[1].z.is_nan());
        assert!(
            (c.points[2].z - 2.005).abs() < 1e-6 && (c.points[2].x - 2.005 / 100.0).abs() < 1e-6
        );
        assert!(decode_range(&part(pfnc::COORD3D_C16, 3, 1), &d, &Scan3d::default()).is_err());
    }

    fn f32s(v: &[f32]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    /// Planar ABC32f (one part) and separate A/B/C parts (a multipart payload, as the EMVA
    /// reference producer sends) give the packed format's points; the C part alone is not
    /// taken for a depth map.
    #[test]
    fn planar_and_separate_abc_planes_decode_like_packed() {
        let (a, b, c) = ([1.0f32, 2.0], [3.0f32, 4.0], [500.0f32, f32::NAN]);
        let s = Scan3d::default();
        let packed = decode_range(
            &part(pfnc::COORD3D_ABC32F, 2, 1),
            &f32s(&[a[0], b[0], c[0], a[1], b[1], c[1]]),
            &s,
        )
        .expect("packed");
        let planar = decode_range(
            &part(pfnc::COORD3D_ABC32F_PLANAR, 2, 1),
            &f32s(&[a[0], a[1], b[0], b[1], c[0], c[1]]),
            &s,
        )
        .expect("planar");
        let parts = vec![
            (part(pfnc::MONO8, 2, 1), vec![0, 255]),
            (part(pfnc::COORD3D_A32F, 2, 1), f32s(&a)),
            (part(pfnc::COORD3D_B32F, 2, 1), f32s(&b)),
            (part(pfnc::COORD3D_C32F, 2, 1), f32s(&c)),
        ];
        let separate = decode_parts(&parts, &s).expect("parts");
        assert_eq!(packed.points[0], Point3::new(0.001, 0.003, 0.5));
        assert!(packed.points[1].x.is_nan());
        for cloud in [&planar, &separate] {
            assert_eq!(cloud.points[0], packed.points[0]);
            assert!(cloud.points[1].x.is_nan());
            assert_eq!((cloud.width, cloud.height), (2, 1));
        }
        assert_eq!(separate.intensity, Some(vec![0.0, 1.0]));
        // Coord3D_ABC16 with per-coordinate scale and offset (a ToF camera's 0.25 mm steps
        // around a centred origin); raw 0 flagged invalid.
        let abc16: Vec<u8> = [4000u16, 8000, 4000, 0, 0, 0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let scaled = Scan3d {
            scale: [0.25; 3],
            offset: [-1000.0, -1000.0, 0.0],
            invalid_value: Some(0.0),
            ..Scan3d::default()
        };
        let c = decode_range(&part(pfnc::COORD3D_ABC16, 2, 1), &abc16, &scaled).expect("abc16");
        assert_eq!(c.points[0], Point3::new(0.0, 1.0, 1.0));
        assert!(c.points[1].x.is_nan());
        // Short planes and parts of different sizes are errors.
        assert!(decode_range(
            &part(pfnc::COORD3D_ABC32F_PLANAR, 2, 1),
            &f32s(&[1.0; 5]),
            &s
        )
        .is_err());
        let mut uneven = parts.clone();
        uneven[2].0.width = 1;
        assert!(decode_parts(&uneven, &s).is_err());
    }

    #[test]
    fn short_data_and_unknown_formats_are_errors() {
        assert!(decode_range(
            &part(pfnc::COORD3D_ABC32F, 4, 4),
            &[0; 10],
            &Scan3d::default()
        )
        .is_err());
        assert!(decode_range(&part(0x01080001, 1, 1), &[0; 10], &Scan3d::default()).is_err());
    }
}
