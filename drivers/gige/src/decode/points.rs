//! Range images to organized points (metres).

use handeye_hal::nalgebra::Point3;
use handeye_hal::PointCloud;

use crate::error::{GigeError, Result};
use crate::gvsp::PartInfo;

use super::{check_len, f32_le, pfnc, u16_le, Scan3d};

const NAN: Point3<f32> = Point3::new(f32::NAN, f32::NAN, f32::NAN);

/// Organized points from raw A, B, C values per pixel (`raw(u, v)`, row-major): scale, offset
/// and unit applied in f64, rounded once to f32; a NaN coordinate, or one equal to its own
/// invalid marker, makes the point NaN.
fn abc_points(
    w: usize,
    h: usize,
    s: &Scan3d,
    raw: impl Fn(usize, usize) -> [f32; 3],
) -> Vec<Point3<f32>> {
    let m = s.metres_per_unit;
    let mut points = Vec::with_capacity(w * h);
    for v in 0..h {
        for u in 0..w {
            let r = raw(u, v).map(f64::from);
            if (0..3).any(|k| s.is_invalid(k, r[k])) {
                points.push(NAN);
                continue;
            }
            let c: [f64; 3] = std::array::from_fn(|k| (r[k] * s.scale[k] + s.offset[k]) * m);
            points.push(match Scan3d::bounded(c) {
                Some(c) => Point3::new(c[0] as f32, c[1] as f32, c[2] as f32),
                None => NAN,
            });
        }
    }
    points
}

fn cloud(w: u32, h: u32, points: Vec<Point3<f32>>) -> PointCloud {
    PointCloud {
        width: w,
        height: h,
        points,
        intensity: None,
        confidence: None,
    }
}

/// Three single-coordinate parts (`Coord3D_A32f`, `B32f`, `C32f`, in that order) of one size.
pub(super) fn decode_abc_parts(
    planes: [&(PartInfo, Vec<u8>); 3],
    s: &Scan3d,
) -> Result<PointCloud> {
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
    Ok(cloud(p0.width, p0.height, points))
}

/// A depth map to points by the pinhole rule documented on [`Scan3d`].
fn depth_points(
    (w, h, stride): (usize, usize, usize),
    bpp: usize,
    data: &[u8],
    s: &Scan3d,
) -> Result<Vec<Point3<f32>>> {
    if s.focal_length <= 0.0 || !s.focal_length.is_finite() {
        return Err(GigeError::feature(
            "Scan3dFocalLength",
            "a depth map needs a positive focal length to make points; choose a Coord3D_ABC \
             pixel format, or check that the camera publishes Scan3dFocalLength (or \
             CalibFocalLengthX)",
        ));
    }
    let (cu, cv) = s.principal_point;
    let (fx, fy) = (s.focal_length, s.focal_length * s.aspect_ratio);
    let m = s.metres_per_unit;
    let mut points = Vec::with_capacity(w * h);
    for v in 0..h {
        for u in 0..w {
            let i = v * stride + u * bpp;
            let raw = if bpp == 2 {
                f64::from(u16_le(data, i))
            } else {
                f64::from(f32_le(data, i))
            };
            if s.is_invalid(2, raw) {
                points.push(NAN);
                continue;
            }
            let z = (raw * s.scale[2] + s.offset[2]) * m;
            let x = (u as f64 - cu) * z / fx;
            let y = (v as f64 - cv) * z / fy;
            points.push(match Scan3d::bounded([x, y, z]) {
                Some(_) => Point3::new(x as f32, y as f32, z as f32),
                None => NAN,
            });
        }
    }
    Ok(points)
}

/// Decode one range image (a format of [`super::RANGE_FORMATS`]). `Coord3D_ABCY16`'s fourth
/// value becomes the cloud's intensity (normalized to [0, 1]).
pub fn decode_range(p: &PartInfo, data: &[u8], s: &Scan3d) -> Result<PointCloud> {
    let (w, h) = (p.width, p.height);
    let mut intensity = None;
    let points = match p.pixel_format {
        pfnc::COORD3D_ABC32F => {
            let (wu, hu, stride) = check_len(p, data, 12)?;
            abc_points(wu, hu, s, |u, v| {
                let i = v * stride + u * 12;
                [f32_le(data, i), f32_le(data, i + 4), f32_le(data, i + 8)]
            })
        }
        pfnc::COORD3D_ABC16 | pfnc::COORD3D_ABCY16 => {
            let bpp = if p.pixel_format == pfnc::COORD3D_ABC16 {
                6
            } else {
                8
            };
            let (wu, hu, stride) = check_len(p, data, bpp)?;
            if bpp == 8 {
                let mut y = Vec::with_capacity(wu * hu);
                for v in 0..hu {
                    for u in 0..wu {
                        y.push(f32::from(u16_le(data, v * stride + u * 8 + 6)) / 65535.0);
                    }
                }
                intensity = Some(y);
            }
            abc_points(wu, hu, s, |u, v| {
                let i = v * stride + u * bpp;
                [u16_le(data, i), u16_le(data, i + 2), u16_le(data, i + 4)].map(f32::from)
            })
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
            abc_points(wu, hu, s, |u, v| {
                std::array::from_fn(|k| f32_le(data, k * plane + v * stride + u * 4))
            })
        }
        pfnc::COORD3D_C16 => depth_points(check_len(p, data, 2)?, 2, data, s)?,
        pfnc::COORD3D_C32F => depth_points(check_len(p, data, 4)?, 4, data, s)?,
        f => {
            return Err(GigeError::UnsupportedFormat {
                format: f,
                name: pfnc::name(f),
            })
        }
    };
    Ok(PointCloud {
        intensity,
        ..cloud(w, h, points)
    })
}
