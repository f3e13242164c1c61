//! The GVSP packet codec, both directions: headers, leaders and trailers parsed, blocks cut
//! into packets.

use crate::error::{GigeError, Result};

/// Packet format: leader.
pub const FORMAT_LEADER: u8 = 1;
/// Packet format: trailer.
pub const FORMAT_TRAILER: u8 = 2;
/// Packet format: generic payload.
pub const FORMAT_PAYLOAD: u8 = 3;
/// Packet format: all-in (not supported by the receiver).
pub const FORMAT_ALL_IN: u8 = 4;
/// Packet format: multi-part payload.
pub const FORMAT_MULTIPART: u8 = 7;
/// Payload type: image.
pub const PAYLOAD_IMAGE: u16 = 0x0001;
/// Payload type: multi-part.
pub const PAYLOAD_MULTIPART: u16 = 0x000A;
/// Payload type: chunk data only (no image; Photoneo can stream its components so).
pub const PAYLOAD_CHUNK: u16 = 0x0004;
/// Multi-part data type: 2D image.
pub const PART_2D_IMAGE: u16 = 0x0001;
/// Multi-part data type: 3D image.
pub const PART_3D_IMAGE: u16 = 0x0005;
/// Multi-part data type: confidence map.
pub const PART_CONFIDENCE: u16 = 0x0009;
/// Multi-part data type: chunk data. A chunk-only payload arrives as one part of this type
/// (split it with [`split_chunks`]).
pub const PART_CHUNK: u16 = 0x000A;
/// IP + UDP header bytes counted in SCPS.
pub const IP_UDP_HEADERS: usize = 28;

pub(crate) fn be16(b: &[u8], o: usize) -> u16 {
    u16::from_be_bytes([b[o], b[o + 1]])
}
pub(crate) fn be32(b: &[u8], o: usize) -> u32 {
    u32::from_be_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}
pub(crate) fn be64(b: &[u8], o: usize) -> u64 {
    (u64::from(be32(b, o)) << 32) | u64::from(be32(b, o + 4))
}
pub(crate) fn be48(b: &[u8], o: usize) -> u64 {
    (u64::from(be16(b, o)) << 32) | u64::from(be32(b, o + 2))
}

/// A GVSP packet header (standard or extended ids).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Status (0 normal, 0x0100 resent, 0x8xxx error packet).
    pub status: u16,
    /// Block (frame) id; 16-bit in standard mode.
    pub block_id: u64,
    /// Packet format (`FORMAT_*`).
    pub format: u8,
    /// Packet id (0 leader, 1..N payload, N+1 trailer).
    pub packet_id: u32,
    /// Extended-id (64-bit block, 32-bit packet) layout.
    pub extended: bool,
    /// Extended-mode flags (0x0001 = resent).
    pub flags: u16,
    /// Extended leader: number of parts (multi-part).
    pub parts: u8,
}

impl Header {
    /// Header length on the wire.
    pub fn len(extended: bool) -> usize {
        if extended {
            20
        } else {
            8
        }
    }

    /// Whether the device marked this packet as a retransmission.
    pub fn is_resent(&self) -> bool {
        self.status == 0x0100 || (self.extended && self.flags & 0x0001 != 0)
    }

    /// Parse; returns the header and the body after it.
    pub fn parse(b: &[u8]) -> Result<(Self, &[u8])> {
        const W: &str = "GVSP packet";
        if b.len() < 8 {
            return Err(GigeError::malformed(
                W,
                format!("{} bytes, header needs 8", b.len()),
            ));
        }
        let extended = b[4] & 0x80 != 0;
        let format = b[4] & 0x0F;
        if extended {
            if b.len() < 20 {
                return Err(GigeError::malformed(
                    W,
                    format!("{} bytes, extended header needs 20", b.len()),
                ));
            }
            Ok((
                Self {
                    status: be16(b, 0),
                    flags: be16(b, 2),
                    format,
                    parts: b[7],
                    block_id: be64(b, 8),
                    packet_id: be32(b, 16),
                    extended,
                },
                &b[20..],
            ))
        } else {
            Ok((
                Self {
                    status: be16(b, 0),
                    block_id: u64::from(be16(b, 2)),
                    format,
                    packet_id: be32(b, 4) & 0x00FF_FFFF,
                    extended,
                    flags: 0,
                    parts: 0,
                },
                &b[8..],
            ))
        }
    }

    /// Serialize.
    pub fn encode(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.status.to_be_bytes());
        if self.extended {
            out.extend_from_slice(&self.flags.to_be_bytes());
            out.extend_from_slice(&[0x80 | self.format, 0, 0, self.parts]);
            out.extend_from_slice(&self.block_id.to_be_bytes());
            out.extend_from_slice(&self.packet_id.to_be_bytes());
        } else {
            out.extend_from_slice(&(self.block_id as u16).to_be_bytes());
            out.extend_from_slice(
                &((u32::from(self.format) << 24) | (self.packet_id & 0x00FF_FFFF)).to_be_bytes(),
            );
        }
    }
}

/// One image-like part of a block (the whole payload for an image leader).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct PartInfo {
    /// Data type (`PART_*`); `PART_2D_IMAGE` for plain image payloads.
    pub data_type: u16,
    /// Part length in bytes.
    pub length: u64,
    /// PFNC pixel format.
    pub pixel_format: u32,
    /// Data purpose id (component: 1 intensity, 4 range, 6 confidence, …).
    pub purpose: u16,
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Bytes of padding after each line.
    pub padding_x: u16,
}

/// Bytes of an image of this geometry.
pub fn image_bytes(pixel_format: u32, width: u32, height: u32, padding_x: u16) -> u64 {
    let bpp = u64::from((pixel_format >> 16) & 0xFF);
    (u64::from(width) * bpp).div_ceil(8) * u64::from(height)
        + u64::from(padding_x) * u64::from(height)
}

/// A parsed leader.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Leader {
    /// Payload type.
    pub payload_type: u16,
    /// Device timestamp (ticks).
    pub timestamp: u64,
    /// Parts (one for an image payload, empty for payload types without geometry).
    pub parts: Vec<PartInfo>,
}

impl Leader {
    /// Parse a leader body (after the header).
    pub fn parse(h: &Header, b: &[u8]) -> Result<Self> {
        const W: &str = "GVSP leader";
        if b.len() < 12 {
            return Err(GigeError::malformed(
                W,
                format!("{} bytes, needs at least 12", b.len()),
            ));
        }
        let payload_type = be16(b, 2) & 0x3FFF;
        let timestamp = be64(b, 4);
        let parts = match payload_type {
            PAYLOAD_IMAGE => {
                if b.len() < 36 {
                    return Err(GigeError::malformed(
                        W,
                        format!("image leader of {} bytes, needs 36", b.len()),
                    ));
                }
                let (pf, w, hh, px) = (be32(b, 12), be32(b, 16), be32(b, 20), be16(b, 32));
                if u64::from(w) * u64::from(hh) > 1 << 30 {
                    return Err(GigeError::malformed(
                        W,
                        format!("absurd image size {w}x{hh}"),
                    ));
                }
                vec![PartInfo {
                    data_type: PART_2D_IMAGE,
                    length: image_bytes(pf, w, hh, px) + u64::from(be16(b, 34)),
                    pixel_format: pf,
                    purpose: 0,
                    width: w,
                    height: hh,
                    padding_x: px,
                }]
            }
            PAYLOAD_MULTIPART => {
                let n = usize::from(h.parts);
                if n == 0 || b.len() < 12 + 48 * n {
                    return Err(GigeError::malformed(
                        W,
                        format!("multi-part leader with {n} parts in {} bytes", b.len()),
                    ));
                }
                (0..n)
                    .map(|i| {
                        let d = &b[12 + 48 * i..12 + 48 * (i + 1)];
                        let length = be48(d, 2);
                        if length > 1 << 32 {
                            return Err(GigeError::malformed(
                                W,
                                format!("absurd part length {length}"),
                            ));
                        }
                        Ok(PartInfo {
                            data_type: be16(d, 0),
                            length,
                            pixel_format: be32(d, 8),
                            purpose: be16(d, 20),
                            width: be32(d, 24),
                            height: be32(d, 28),
                            padding_x: be16(d, 40),
                        })
                    })
                    .collect::<Result<_>>()?
            }
            _ => Vec::new(),
        };
        Ok(Self {
            payload_type,
            timestamp,
            parts,
        })
    }
}

/// Encode an image leader body.
pub fn encode_image_leader(out: &mut Vec<u8>, timestamp: u64, p: &PartInfo) {
    out.extend_from_slice(&[0, 0]);
    out.extend_from_slice(&PAYLOAD_IMAGE.to_be_bytes());
    out.extend_from_slice(&timestamp.to_be_bytes());
    for v in [p.pixel_format, p.width, p.height, 0, 0] {
        out.extend_from_slice(&v.to_be_bytes());
    }
    out.extend_from_slice(&p.padding_x.to_be_bytes());
    out.extend_from_slice(&[0, 0]);
}

/// Encode a multi-part leader body.
pub fn encode_multipart_leader(out: &mut Vec<u8>, timestamp: u64, parts: &[PartInfo]) {
    out.extend_from_slice(&[0, 0]);
    out.extend_from_slice(&PAYLOAD_MULTIPART.to_be_bytes());
    out.extend_from_slice(&timestamp.to_be_bytes());
    for p in parts {
        out.extend_from_slice(&p.data_type.to_be_bytes());
        out.extend_from_slice(&((p.length >> 32) as u16).to_be_bytes());
        out.extend_from_slice(&(p.length as u32).to_be_bytes());
        out.extend_from_slice(&p.pixel_format.to_be_bytes());
        out.extend_from_slice(&[0; 8]); // reserved, source id, zones, zone directions
        out.extend_from_slice(&p.purpose.to_be_bytes());
        out.extend_from_slice(&[0, 0]); // region id
        for v in [p.width, p.height, 0, 0] {
            out.extend_from_slice(&v.to_be_bytes());
        }
        out.extend_from_slice(&p.padding_x.to_be_bytes());
        out.extend_from_slice(&[0; 6]);
    }
}

/// Encode a chunk-data leader body (payload type [`PAYLOAD_CHUNK`]: no geometry).
pub fn encode_chunk_leader(out: &mut Vec<u8>, timestamp: u64) {
    out.extend_from_slice(&[0, 0]);
    out.extend_from_slice(&PAYLOAD_CHUNK.to_be_bytes());
    out.extend_from_slice(&timestamp.to_be_bytes());
}

/// Most chunks in one payload (each takes at least its 8-byte tag, so a payload cannot hold
/// more than a frame's bytes / 8; this bounds the list a hostile payload makes).
pub const MAX_CHUNKS: usize = 1024;

/// Split GenICam chunk data into `(chunk id, data)`, in payload order. Chunk data is a series
/// of `[data][id: u32 BE][length: u32 BE]`, read from the end backwards.
pub fn split_chunks(data: &[u8]) -> Result<Vec<(u32, &[u8])>> {
    const W: &str = "chunk data";
    let mut out = Vec::new();
    let mut end = data.len();
    while end > 0 {
        if end < 8 {
            return Err(GigeError::malformed(
                W,
                format!("{end} bytes left before a chunk, its tag needs 8"),
            ));
        }
        if out.len() == MAX_CHUNKS {
            return Err(GigeError::malformed(
                W,
                format!("more than {MAX_CHUNKS} chunks"),
            ));
        }
        let id = be32(data, end - 8);
        let len = be32(data, end - 4) as usize;
        let start = (end - 8).checked_sub(len).ok_or_else(|| {
            GigeError::malformed(
                W,
                format!(
                    "chunk {id:#x} says {len} bytes but only {} precede its tag",
                    end - 8
                ),
            )
        })?;
        out.push((id, &data[start..end - 8]));
        end = start;
    }
    out.reverse();
    Ok(out)
}

/// Append one chunk (`data`, then its id and length) to a chunk payload.
pub fn push_chunk(out: &mut Vec<u8>, id: u32, data: &[u8]) {
    out.extend_from_slice(data);
    out.extend_from_slice(&id.to_be_bytes());
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
}

/// One block as a device sends it.
#[derive(Debug, Clone)]
pub struct Block {
    /// Block id.
    pub block_id: u64,
    /// Timestamp (ticks).
    pub timestamp: u64,
    /// Parts and their bytes.
    pub parts: Vec<(PartInfo, Vec<u8>)>,
    /// Send as multi-part (needs extended ids).
    pub multipart: bool,
}

/// Cut a block into GVSP packets for a packet size `scps` (whole IP datagram).
pub fn packetize(block: &Block, scps: usize, extended: bool) -> Result<Vec<Vec<u8>>> {
    let mut packets = Vec::new();
    packetize_into(block, scps, extended, &mut packets)?;
    Ok(packets)
}

/// [`packetize`] into `packets`, reusing its buffers (a streamer recycles the packets of an
/// old frame instead of allocating tens of thousands per frame).
pub fn packetize_into(
    block: &Block,
    scps: usize,
    extended: bool,
    packets: &mut Vec<Vec<u8>>,
) -> Result<()> {
    let hl = Header::len(extended);
    let mp = block.multipart;
    if mp && !extended {
        return Err(GigeError::InvalidArgument(
            "multi-part needs extended ids".into(),
        ));
    }
    let data_per = scps.saturating_sub(IP_UDP_HEADERS + hl + if mp { 8 } else { 0 });
    if data_per < 16 {
        return Err(GigeError::InvalidArgument(format!(
            "packet size {scps} too small"
        )));
    }
    let mut used = 0;
    let header = |format, packet_id, parts| Header {
        status: 0,
        block_id: block.block_id,
        format,
        packet_id,
        extended,
        flags: 0,
        parts,
    };
    let infos: Vec<PartInfo> = block.parts.iter().map(|(i, _)| i.clone()).collect();
    let p = next_packet(packets, &mut used, hl + 12 + 48 * block.parts.len());
    if mp {
        header(FORMAT_LEADER, 0, infos.len() as u8).encode(p);
        encode_multipart_leader(p, block.timestamp, &infos);
    } else {
        header(FORMAT_LEADER, 0, 0).encode(p);
        let info = infos
            .first()
            .ok_or_else(|| GigeError::InvalidArgument("block without parts".into()))?;
        if info.data_type == PART_CHUNK {
            encode_chunk_leader(p, block.timestamp);
        } else {
            encode_image_leader(p, block.timestamp, info);
        }
    }
    let mut pid = 1u32;
    for (idx, (_, data)) in block.parts.iter().enumerate() {
        if !mp && idx > 0 {
            return Err(GigeError::InvalidArgument(
                "several parts need multi-part".into(),
            ));
        }
        for (i, chunk) in data.chunks(data_per).enumerate() {
            let p = next_packet(packets, &mut used, hl + 8 + data_per);
            if mp {
                header(FORMAT_MULTIPART, pid, 0).encode(p);
                p.push(idx as u8);
                p.push(0);
                let off = (i * data_per) as u64;
                p.extend_from_slice(&((off >> 32) as u16).to_be_bytes());
                p.extend_from_slice(&(off as u32).to_be_bytes());
            } else {
                header(FORMAT_PAYLOAD, pid, 0).encode(p);
            }
            p.extend_from_slice(chunk);
            pid += 1;
        }
    }
    let t = next_packet(packets, &mut used, hl + 8);
    header(FORMAT_TRAILER, pid, 0).encode(t);
    t.extend_from_slice(&[0, 0]);
    let payload_type = match infos.first() {
        _ if mp => PAYLOAD_MULTIPART,
        Some(i) if i.data_type == PART_CHUNK => PAYLOAD_CHUNK,
        _ => PAYLOAD_IMAGE,
    };
    t.extend_from_slice(&payload_type.to_be_bytes());
    t.extend_from_slice(&infos.first().map_or(0, |i| i.height).to_be_bytes());
    packets.truncate(used);
    Ok(())
}

/// The next packet buffer of [`packetize_into`]: a recycled one, emptied, or a new one.
fn next_packet<'a>(packets: &'a mut Vec<Vec<u8>>, used: &mut usize, cap: usize) -> &'a mut Vec<u8> {
    if *used == packets.len() {
        packets.push(Vec::with_capacity(cap));
    }
    let p = &mut packets[*used];
    p.clear();
    *used += 1;
    p
}
