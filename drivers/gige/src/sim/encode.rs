//! Frames of the source encoded as the camera's settings ask (ROI, pixel format, components,
//! chunks).

use super::device::{CHUNK_FRAME_ID, CHUNK_INTRINSICS, ID_CONFIDENCE, ID_INTENSITY, ID_RANGE};
use super::stream::StreamSettings;
use crate::decode::pfnc;
use crate::gvsp::{self, Block, PartInfo};

/// Crop the source cloud to the centred `w × h` ROI and encode it in `pf` (mm on the wire).
/// The block id is filled in when the frame is sent; `data`/`conf` are reused buffers.
pub(super) fn make_block(
    cloud: &handeye_hal::PointCloud,
    timestamp: u64,
    settings: &StreamSettings,
    (mut data, mut conf): (Vec<u8>, Vec<u8>),
) -> Block {
    let StreamSettings {
        w,
        h,
        pf,
        mp,
        chunks,
        confidence,
        intensity,
        intensity_only,
        coding,
        ..
    } = *settings;
    let (cw, ch) = (cloud.width as usize, cloud.height as usize);
    let ox = cw.saturating_sub(w as usize) / 2;
    let oy = ch.saturating_sub(h as usize) / 2;
    let n = (w * h) as usize;
    let bpp = (((pf >> 16) & 0xFF) / 8) as usize;
    data.clear();
    data.reserve(n * bpp);
    conf.clear();
    conf.reserve(if confidence { n * 2 } else { 0 });
    let mut gray = Vec::with_capacity(if intensity { n * 2 } else { 0 });
    // A 16-bit coordinate: its raw value (never the invalid marker), or the marker.
    let raw16 = |mm: Option<f64>, k: usize| -> u16 {
        let marker = coding.invalid[k].unwrap_or(0.0);
        let Some(mm) = mm else {
            return marker as u16;
        };
        let r = ((mm - coding.offset[k]) / coding.scale[k])
            .round()
            .clamp(0.0, 65535.0);
        (if r == marker && r > 0.0 {
            r - 1.0
        } else if r == marker {
            r + 1.0
        } else {
            r
        }) as u16
    };
    for v in 0..h as usize {
        for u in 0..w as usize {
            let i = (oy + v) * cw + ox + u;
            let p = cloud.points.get(i).copied();
            let valid = p.is_some_and(|p| p.coords.iter().all(|c| c.is_finite()) && i < cw * ch);
            let p = p.filter(|_| valid);
            let mm = p.map(|p| [p.x, p.y, p.z].map(|c| f64::from(c) * 1000.0));
            // A grey level falling with distance (what a structured-light camera's intensity
            // image roughly shows); 0 where nothing was measured.
            let g = p.map_or(0, |p| (65535.0 / (1.0 + f64::from(p.z))).round() as u16);
            match pf {
                pfnc::COORD3D_C16 => {
                    data.extend_from_slice(&raw16(mm.map(|m| m[2]), 2).to_le_bytes())
                }
                pfnc::COORD3D_ABC16 | pfnc::COORD3D_ABCY16 => {
                    for k in 0..3 {
                        data.extend_from_slice(&raw16(mm.map(|m| m[k]), k).to_le_bytes());
                    }
                    if pf == pfnc::COORD3D_ABCY16 {
                        data.extend_from_slice(&g.to_le_bytes());
                    }
                }
                _ => {
                    for k in 0..3 {
                        let c = match mm {
                            Some(m) => ((m[k] - coding.offset[k]) / coding.scale[k]) as f32,
                            None => coding.invalid[k].unwrap_or(0.0) as f32,
                        };
                        data.extend_from_slice(&c.to_le_bytes());
                    }
                }
            }
            if intensity {
                gray.extend_from_slice(&g.to_le_bytes());
            }
            if confidence {
                let c = cloud
                    .confidence
                    .as_ref()
                    .and_then(|c| c.get(i).copied())
                    .unwrap_or(if valid { 1.0 } else { 0.0 });
                conf.extend_from_slice(
                    &((c.clamp(0.0, 1.0) * 65535.0).round() as u16).to_le_bytes(),
                );
            }
        }
    }
    let part = |data_type, pixel_format, purpose: u32, data: Vec<u8>| {
        (
            PartInfo {
                data_type,
                length: data.len() as u64,
                pixel_format,
                purpose: purpose as u16,
                width: w,
                height: h,
                padding_x: 0,
            },
            data,
        )
    };
    if chunks {
        // Range, then the other enabled components, each a chunk tagged with its id.
        let mut payload = Vec::with_capacity(data.len() + conf.len() + gray.len() + 24);
        gvsp::push_chunk(&mut payload, ID_RANGE, &data);
        if intensity {
            gvsp::push_chunk(&mut payload, ID_INTENSITY, &gray);
        }
        if confidence {
            gvsp::push_chunk(&mut payload, ID_CONFIDENCE, &conf);
        }
        return Block {
            block_id: 1,
            timestamp,
            parts: vec![(
                PartInfo {
                    data_type: gvsp::PART_CHUNK,
                    length: payload.len() as u64,
                    ..PartInfo::default()
                },
                payload,
            )],
            multipart: false,
        };
    }
    if intensity_only {
        return Block {
            block_id: 1,
            timestamp,
            parts: vec![part(gvsp::PART_2D_IMAGE, pfnc::MONO16, ID_INTENSITY, gray)],
            multipart: false,
        };
    }
    let mut parts = Vec::new();
    if intensity {
        parts.push(part(gvsp::PART_2D_IMAGE, pfnc::MONO16, ID_INTENSITY, gray));
    }
    parts.push(part(gvsp::PART_3D_IMAGE, pf, ID_RANGE, data));
    if confidence {
        parts.push(part(
            gvsp::PART_CONFIDENCE,
            pfnc::CONFIDENCE16,
            ID_CONFIDENCE,
            conf,
        ));
    }
    if settings.chunk_part {
        // Metadata as chunks after the components (Photoneo's n + 1st part, SICK's
        // intrinsics): the decoder does not need them.
        let mut meta = Vec::with_capacity(48);
        gvsp::push_chunk(&mut meta, CHUNK_FRAME_ID, &timestamp.to_be_bytes());
        let lens: Vec<u8> = settings
            .intrinsics
            .iter()
            .flat_map(|x| x.to_be_bytes())
            .collect();
        gvsp::push_chunk(&mut meta, CHUNK_INTRINSICS, &lens);
        parts.push((
            PartInfo {
                data_type: gvsp::PART_CHUNK,
                length: meta.len() as u64,
                ..PartInfo::default()
            },
            meta,
        ));
    }
    Block {
        block_id: 1,
        timestamp,
        parts,
        multipart: mp,
    }
}
