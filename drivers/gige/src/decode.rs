//! PFNC 3D pixel formats to [`PointCloud`]s (metres, camera frame, organized).

use handeye_hal::nalgebra::Point3;
use handeye_hal::PointCloud;

use crate::error::{GigeError, Result};
use crate::gvsp::{Frame, PartInfo, PART_3D_IMAGE, PART_CONFIDENCE};

/// PFNC codes this module knows.
pub mod pfnc {
    /// Coord3D_ABC32f (X, Y, Z float32 per pixel).
    pub const COORD3D_ABC32F: u32 = 0x026000C0;
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
            0x0260_00C1 => "Coord3D_ABC32f_Planar",
            0x0230_00B9 => "Coord3D_ABC16",
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
    let range = frame
        .parts
        .iter()
        .find(|(p, _)| {
            matches!(
                p.pixel_format,
                pfnc::COORD3D_ABC32F | pfnc::COORD3D_C16 | pfnc::COORD3D_C32F
            )
        })
        .or_else(|| {
            frame
                .parts
                .iter()
                .find(|(p, _)| p.data_type == PART_3D_IMAGE)
        })
        .or(match frame.parts.as_slice() {
            [only] => Some(only),
            _ => None,
        })
        .ok_or_else(|| {
            let parts: Vec<String> = frame
                .parts
                .iter()
                .map(|(p, _)| {
                    format!(
                        "{} (data type {:#x})",
                        pfnc::name(p.pixel_format),
                        p.data_type
                    )
                })
                .collect();
            GigeError::malformed(
                "3D frame",
                if parts.is_empty() {
                    "frame without data".to_owned()
                } else {
                    format!(
                        "no range part among {}; enable ComponentSelector Range with a \
                         Coord3D pixel format",
                        parts.join(", ")
                    )
                },
            )
        })?;
    let mut cloud = decode_range(&range.0, &range.1, s)?;
    for (p, d) in &frame.parts {
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
            points.reserve(wu * hu);
            for v in 0..hu {
                for u in 0..wu {
                    let i = v * stride + u * 12;
                    let raw =
                        [f32_le(data, i), f32_le(data, i + 4), f32_le(data, i + 8)].map(f64::from);
                    if raw.iter().any(|&r| invalid(r)) {
                        points.push(nan);
                        continue;
                    }
                    let c: [f64; 3] =
                        std::array::from_fn(|k| (raw[k] * s.scale[k] + s.offset[k]) * m);
                    points.push(Point3::new(c[0] as f32, c[1] as f32, c[2] as f32));
                }
            }
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
