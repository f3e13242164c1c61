//! Chunk data in a payload: a chunk-only payload carries the range image as a chunk; a
//! multi-part payload may carry a chunk-data part beside its images (Photoneo sends n
//! component parts and one chunk part, SICK its intrinsics as chunks). Shared by the GigE
//! Vision and GenTL backends.

use crate::error::{GigeError, Result};
use crate::genicam::{NodeMap, RegisterPort};
use crate::gvsp::{image_bytes, split_chunks, PartInfo, PART_3D_IMAGE, PART_CHUNK};

use super::formats::{pfnc, range_format};

/// A payload's parts: each part's geometry and its bytes.
pub type Parts = [(PartInfo, Vec<u8>)];

/// Where the range component sits in a chunk-only payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChunkLayout {
    /// `ComponentIDValue` of Range (the chunk id), when the camera has the feature.
    pub id: Option<u32>,
    /// Range's `PixelFormat`.
    pub pixel_format: u32,
    /// `Width`.
    pub width: u32,
    /// `Height`.
    pub height: u32,
}

impl ChunkLayout {
    /// What a chunk-only payload's range chunk holds (Range's pixel format, size and id),
    /// read before streaming; `None` when the camera has no Range component.
    pub fn read(n: &mut NodeMap, p: &mut impl RegisterPort) -> Result<Option<Self>> {
        let has_range = n
            .enum_entries("ComponentSelector")
            .is_ok_and(|e| e.iter().any(|c| c == "Range"));
        if !has_range {
            return Ok(None);
        }
        n.set_enum(p, "ComponentSelector", "Range")?;
        let id = if n.has("ComponentIDValue") {
            Some(n.integer(p, "ComponentIDValue")?)
        } else {
            None
        };
        let out_of_range = |f: &str| GigeError::feature(f, "out of range; check the camera");
        Ok(Some(Self {
            id: id.and_then(|i| u32::try_from(i).ok()),
            pixel_format: u32::try_from(n.enum_value(p, "PixelFormat")?)
                .map_err(|_| out_of_range("PixelFormat"))?,
            width: u32::try_from(n.integer(p, "Width")?).map_err(|_| out_of_range("Width"))?,
            height: u32::try_from(n.integer(p, "Height")?).map_err(|_| out_of_range("Height"))?,
        }))
    }
}

/// Whether one of `parts` holds a range image the decoder reads (by pixel format or the 3D
/// data type).
fn has_range_part(parts: &Parts) -> bool {
    parts.iter().any(|(p, _)| {
        p.data_type != PART_CHUNK
            && (range_format(p.pixel_format).is_some()
                || p.data_type == PART_3D_IMAGE
                || p.pixel_format == pfnc::COORD3D_A32F)
    })
}

/// The image parts of a payload, the range among them. A payload whose image parts hold the
/// range keeps them; its chunk-data parts are checked as chunks (a malformed one is logged,
/// not fatal: it holds metadata the decoder does not use). A payload without a range part
/// (chunk-only) gets it from its chunks: the chunk whose id is Range's `ComponentIDValue`,
/// else the only chunk of the range image's size.
pub fn image_parts(
    parts: &Parts,
    layout: Option<&ChunkLayout>,
) -> Result<Vec<(PartInfo, Vec<u8>)>> {
    let (chunk_parts, images): (Vec<_>, Vec<_>) =
        parts.iter().partition(|(p, _)| p.data_type == PART_CHUNK);
    if chunk_parts.is_empty() || has_range_part(parts) {
        for (_, data) in &chunk_parts {
            match split_chunks(data) {
                Ok(chunks) => tracing::trace!(chunks = chunks.len(), "chunk-data part"),
                Err(e) => tracing::debug!("chunk-data part beside the images ignored: {e}"),
            }
        }
        return Ok(images.into_iter().cloned().collect());
    }
    const W: &str = "chunk payload";
    let layout = layout.ok_or_else(|| {
        GigeError::malformed(
            W,
            "chunk data without an image from a camera without a Range component; enable \
             ComponentSelector Range with a Coord3D pixel format",
        )
    })?;
    let mut chunks = Vec::new();
    for (_, data) in &chunk_parts {
        chunks.extend(split_chunks(data)?);
    }
    let bytes = image_bytes(layout.pixel_format, layout.width, layout.height, 0);
    let by_id = layout
        .id
        .and_then(|id| chunks.iter().find(|(cid, _)| *cid == id));
    let by_size: Vec<&(u32, &[u8])> = chunks
        .iter()
        .filter(|(_, d)| d.len() as u64 == bytes)
        .collect();
    let (id, range) = match (by_id, by_size.as_slice()) {
        (Some(c), _) | (None, &[c]) => *c,
        _ => {
            return Err(GigeError::malformed(
                W,
                format!(
                    "no chunk holds the range image ({} {}x{}, {bytes} bytes{}); chunks: {}; \
                     enable ComponentSelector Range",
                    pfnc::name(layout.pixel_format),
                    layout.width,
                    layout.height,
                    layout
                        .id
                        .map_or_else(String::new, |i| format!(", ComponentIDValue {i}")),
                    chunks
                        .iter()
                        .map(|(i, d)| format!("{i:#x} ({} bytes)", d.len()))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ))
        }
    };
    let info = PartInfo {
        data_type: PART_3D_IMAGE,
        length: range.len() as u64,
        pixel_format: layout.pixel_format,
        purpose: u16::try_from(id).unwrap_or(0),
        width: layout.width,
        height: layout.height,
        padding_x: 0,
    };
    let mut out: Vec<(PartInfo, Vec<u8>)> = images.into_iter().cloned().collect();
    out.push((info, range.to_vec()));
    Ok(out)
}
