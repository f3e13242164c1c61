//! PFNC 3D pixel formats to [`PointCloud`]s (metres, camera frame, organized).
//!
//! Layout: [`formats`] (the one list of range formats and output modes the decoder reads,
//! which `handeye camera xml` judges by too), [`scan3d`] (the features that turn raw values
//! into metres), [`chunks`] (chunk data in a payload), `points` (range images to points);
//! intensity and confidence planes here.

pub mod chunks;
pub mod formats;
mod points;
pub mod scan3d;

use handeye_hal::PointCloud;

use crate::error::{GigeError, Result};
use crate::gvsp::{Frame, PartInfo, PART_3D_IMAGE, PART_CHUNK, PART_CONFIDENCE};

pub use chunks::{image_parts, ChunkLayout};
pub use formats::{
    check_output_mode, pfnc, range_format, Geometry, RangeFormat, CONFIDENCE_FORMATS,
    DEPTH_OUTPUT_MODES, INTENSITY_FORMATS, POINT_OUTPUT_MODES, RANGE_FORMATS,
};
pub use points::decode_range;
pub use scan3d::{Scan3d, MAX_COORDINATE_M};

pub(crate) fn f32_le(b: &[u8], i: usize) -> f32 {
    f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]])
}

pub(crate) fn u16_le(b: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([b[i], b[i + 1]])
}

fn short(p: &PartInfo, data: &[u8]) -> GigeError {
    GigeError::malformed(
        "3D frame",
        format!(
            "{} bytes for {}x{} {}",
            data.len(),
            p.width,
            p.height,
            pfnc::name(p.pixel_format)
        ),
    )
}

/// Width, height and line stride (bytes) of a part of whole bytes per pixel, checked against
/// its data.
pub(crate) fn check_len(
    p: &PartInfo,
    data: &[u8],
    bytes_per_pixel: usize,
) -> Result<(usize, usize, usize)> {
    let (w, h) = (p.width as usize, p.height as usize);
    let stride = w * bytes_per_pixel + usize::from(p.padding_x);
    if data.len() < stride * h.saturating_sub(1) + w * bytes_per_pixel {
        return Err(short(p, data));
    }
    Ok((w, h, stride))
}

/// How a scalar plane's pixels are stored.
#[derive(Debug, Clone, Copy)]
enum Sample {
    U8,
    U16,
    F32,
    /// LSB-first bit-packed, this many bits per pixel (PFNC's `…p` formats).
    Packed(usize),
}

/// Storage and full scale of an intensity or confidence format.
fn scalar_format(pf: u32) -> Option<(Sample, f32)> {
    Some(match pf {
        pfnc::CONFIDENCE8 | pfnc::MONO8 => (Sample::U8, 255.0),
        pfnc::CONFIDENCE16 | pfnc::MONO16 => (Sample::U16, 65535.0),
        pfnc::MONO10 => (Sample::U16, 1023.0),
        pfnc::MONO12 => (Sample::U16, 4095.0),
        pfnc::MONO10P => (Sample::Packed(10), 1023.0),
        pfnc::MONO12P => (Sample::Packed(12), 4095.0),
        pfnc::CONFIDENCE32F => (Sample::F32, 1.0),
        _ => return None,
    })
}

/// `bits` bits at bit offset `bit` of an LSB-first bit stream.
fn packed_at(data: &[u8], bit: usize, bits: usize) -> u16 {
    let byte = |i: usize| u32::from(data.get(i).copied().unwrap_or(0));
    let i = bit / 8;
    let word = byte(i) | byte(i + 1) << 8 | byte(i + 2) << 16;
    ((word >> (bit % 8)) & ((1 << bits) - 1)) as u16
}

/// Per-pixel scalar (confidence or intensity), normalized to [0, 1] for integer formats.
fn scalar_plane(p: &PartInfo, data: &[u8]) -> Result<Vec<f32>> {
    let Some((sample, max)) = scalar_format(p.pixel_format) else {
        return Err(GigeError::UnsupportedFormat {
            format: p.pixel_format,
            name: pfnc::name(p.pixel_format),
        });
    };
    let (w, h) = (p.width as usize, p.height as usize);
    let mut out = Vec::with_capacity(w * h);
    if let Sample::Packed(bits) = sample {
        // Without line padding the lines run on in one bit stream.
        let line_bits = if p.padding_x == 0 {
            w * bits
        } else {
            ((w * bits).div_ceil(8) + usize::from(p.padding_x)) * 8
        };
        let last_bit = line_bits * h.saturating_sub(1) + w * bits;
        if data.len() * 8 < last_bit {
            return Err(short(p, data));
        }
        for v in 0..h {
            for u in 0..w {
                out.push(f32::from(packed_at(data, v * line_bits + u * bits, bits)) / max);
            }
        }
        return Ok(out);
    }
    let bpp = match sample {
        Sample::U8 => 1,
        Sample::U16 => 2,
        _ => 4,
    };
    let (_, _, stride) = check_len(p, data, bpp)?;
    for v in 0..h {
        for u in 0..w {
            let i = v * stride + u * bpp;
            out.push(match sample {
                Sample::U8 => f32::from(data[i]) / max,
                Sample::U16 => f32::from(u16_le(data, i)) / max,
                _ => f32_le(data, i),
            });
        }
    }
    Ok(out)
}

/// Decode a frame's parts (see [`decode_parts`]).
pub fn decode(frame: &Frame, s: &Scan3d) -> Result<PointCloud> {
    decode_parts(&frame.parts, s)
}

/// Decode a payload that may carry chunk data: the image parts (with the range taken from a
/// chunk when no image part holds it, see [`image_parts`]), then [`decode_parts`].
pub fn decode_payload(
    parts: &[(PartInfo, Vec<u8>)],
    layout: Option<&ChunkLayout>,
    s: &Scan3d,
) -> Result<PointCloud> {
    if parts.iter().any(|(p, _)| p.data_type == PART_CHUNK) {
        decode_parts(&image_parts(parts, layout)?, s)
    } else {
        decode_parts(parts, s)
    }
}

/// Decode the parts of one payload: the range part (a format of [`RANGE_FORMATS`], or three
/// `Coord3D_A32f`/`B32f`/`C32f` parts of a multipart payload), plus confidence and intensity
/// parts of the same size when present (`Coord3D_ABCY16` carries its intensity itself). The
/// range part is the one in a 3D pixel format, else the one of the 3D data type, else the
/// only part (cameras send intensity first: a multi-part frame's first part need not be the
/// range).
pub fn decode_parts(parts: &[(PartInfo, Vec<u8>)], s: &Scan3d) -> Result<PointCloud> {
    let find = |pf: u32| parts.iter().find(|(p, _)| p.pixel_format == pf);
    let range = parts
        .iter()
        .find(|(p, _)| range_format(p.pixel_format).is_some())
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
        (Some(a), Some(b), Some(c), _) => points::decode_abc_parts([a, b, c], s)?,
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
        let is_conf =
            p.data_type == PART_CONFIDENCE || CONFIDENCE_FORMATS.contains(&p.pixel_format);
        let is_int = INTENSITY_FORMATS.contains(&p.pixel_format);
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

#[cfg(test)]
mod tests {
    use super::*;
    use handeye_hal::nalgebra::Point3;

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
            invalid_value: [Some(0.0); 3],
            ..Scan3d::default()
        };
        let c = decode_range(&part(pfnc::COORD3D_ABC32F, 2, 1), &d, &s).expect("decode");
        assert!((c.points[0].x - 0.1).abs() < 1e-6 && (c.points[0].z - 1.0).abs() < 1e-6);
        assert!(c.points[1].x.is_nan());
        assert_eq!(c.valid_count(), 1);
    }

    /// Issue 46: a scale of 0 (every point at the origin) or an offset of 1e30 mm is refused;
    /// a decoded coordinate beyond the working range (or infinite) is an invalid point, not
    /// a valid one.
    #[test]
    fn issue_46_scale_offset_and_coordinates_are_bounded() {
        let e = Scan3d {
            scale: [1.0, 1.0, 0.0],
            ..Scan3d::default()
        }
        .check()
        .expect_err("scale 0")
        .to_string();
        assert!(
            e.contains("Scan3dCoordinateScale") && e.contains("0 for C"),
            "{e}"
        );
        let e = Scan3d {
            offset: [1e30, 0.0, 0.0],
            ..Scan3d::default()
        }
        .check()
        .expect_err("offset")
        .to_string();
        assert!(
            e.contains("Scan3dCoordinateOffset") && e.contains("beyond the 100 m"),
            "{e}"
        );
        assert!(Scan3d::default().check().is_ok());
        let mut d = Vec::new();
        for v in [
            1e30f32,
            0.0,
            1000.0,
            f32::INFINITY,
            0.0,
            1.0,
            0.0,
            0.0,
            99_000.0,
        ] {
            d.extend_from_slice(&v.to_le_bytes());
        }
        let c = decode_range(&part(pfnc::COORD3D_ABC32F, 3, 1), &d, &Scan3d::default())
            .expect("decode");
        assert!(
            c.points[0].x.is_nan() && c.points[1].x.is_nan(),
            "{:?}",
            c.points
        );
        assert_eq!(c.valid_count(), 1);
        assert!((c.points[2].z - 99.0).abs() < 1e-4);
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
            invalid_value: [Some(0.0); 3],
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
            invalid_value: [Some(0.0); 3],
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

    /// LSB-first bit packing (PFNC's `…p` formats).
    fn pack(values: &[u16], bits: usize) -> Vec<u8> {
        let mut out = vec![0u8; (values.len() * bits).div_ceil(8)];
        for (i, &v) in values.iter().enumerate() {
            for b in 0..bits {
                if v >> b & 1 == 1 {
                    let bit = i * bits + b;
                    out[bit / 8] |= 1 << (bit % 8);
                }
            }
        }
        out
    }

    /// Issue 44: Photoneo's intensity is Mono10 or Mono12 (packed on some firmware): it was
    /// silently left out of the cloud. Unpacked, normalized by the bit depth.
    #[test]
    fn issue_44_intensity_in_mono10_mono10p_mono12p_is_unpacked() {
        let range = (part(pfnc::COORD3D_ABC32F, 4, 2), f32s(&[1.0; 24]));
        let values = [0u16, 1023, 512, 1, 7, 1000, 3, 300];
        for (pf, bits, data) in [
            (
                pfnc::MONO10,
                10,
                values.iter().flat_map(|v| v.to_le_bytes()).collect(),
            ),
            (pfnc::MONO10P, 10, pack(&values, 10)),
            (pfnc::MONO12P, 12, pack(&values.map(|v| v * 4), 12)),
        ] {
            let mut intensity = part(pf, 4, 2);
            intensity.data_type = 1;
            let c = decode_parts(&[range.clone(), (intensity, data)], &Scan3d::default())
                .unwrap_or_else(|e| panic!("{}: {e}", pfnc::name(pf)));
            let got = c.intensity.expect("intensity");
            let max = ((1u32 << bits) - 1) as f32;
            let scale = if bits == 12 { 4.0 } else { 1.0 };
            for (g, v) in got.iter().zip(values) {
                assert!((g - f32::from(v) * scale / max).abs() < 1e-6, "{got:?}");
            }
        }
        // A packed plane too short for its size is an error, not a panic.
        let short = (part(pfnc::MONO10P, 4, 2), vec![0u8; 9]);
        assert!(decode_parts(&[range, short], &Scan3d::default()).is_err());
    }

    /// Issue 44: Lucid's Coord3D_ABCY16 (invalid = 65535 per coordinate) was "not a supported
    /// 3D format"; its fourth value is the intensity.
    #[test]
    fn issue_44_abcy16_decodes_points_and_intensity() {
        let raw: Vec<u8> = [40000u16, 32768, 4000, 65535, 65535, 65535, 65535, 0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let s = Scan3d {
            scale: [0.25; 3],
            offset: [-8192.0, -8192.0, 0.0],
            invalid_value: [Some(65535.0); 3],
            ..Scan3d::default()
        };
        let c = decode_range(&part(pfnc::COORD3D_ABCY16, 2, 1), &raw, &s).expect("ABCY16");
        assert_eq!(c.points[0], Point3::new(1.808, 0.0, 1.0));
        assert!(c.points[1].x.is_nan());
        assert_eq!(c.intensity, Some(vec![1.0, 0.0]));
    }
}
