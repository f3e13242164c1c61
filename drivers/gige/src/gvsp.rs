//! GVSP (GigE Vision Streaming Protocol): packet codec (both directions) and a frame receiver
//! with missing-packet detection, PACKETRESEND and frame timeouts.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::time::{Duration, Instant};

use crate::error::{GigeError, Result};
use crate::gvcp::{Command, CommandKind};

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
/// Multi-part data type: 2D image.
pub const PART_2D_IMAGE: u16 = 0x0001;
/// Multi-part data type: 3D image.
pub const PART_3D_IMAGE: u16 = 0x0005;
/// Multi-part data type: confidence map.
pub const PART_CONFIDENCE: u16 = 0x0009;
/// IP + UDP header bytes counted in SCPS.
pub const IP_UDP_HEADERS: usize = 28;

fn be16(b: &[u8], o: usize) -> u16 {
    u16::from_be_bytes([b[o], b[o + 1]])
}
fn be32(b: &[u8], o: usize) -> u32 {
    u32::from_be_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}
fn be64(b: &[u8], o: usize) -> u64 {
    (u64::from(be32(b, o)) << 32) | u64::from(be32(b, o + 4))
}
fn be48(b: &[u8], o: usize) -> u64 {
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
        encode_image_leader(p, block.timestamp, info);
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
    t.extend_from_slice(&(if mp { PAYLOAD_MULTIPART } else { PAYLOAD_IMAGE }).to_be_bytes());
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

/// Receiver settings.
#[derive(Debug, Clone, PartialEq)]
pub struct StreamConfig {
    /// Packet size programmed in SCPS (whole IP datagram).
    pub packet_size: usize,
    /// Whether the device was put in extended-id mode.
    pub extended: bool,
    /// Request missing packets (only if the device advertises PACKETRESEND).
    pub resend: bool,
    /// Wait this long after a gap before asking for its packets.
    pub initial_packet_timeout: Duration,
    /// Wait this long before asking again.
    pub packet_timeout: Duration,
    /// Close a frame that got no packet for this long.
    pub frame_retention: Duration,
    /// Stop asking for a frame's packets after this fraction of its packet count.
    pub request_ratio: f64,
    /// Socket receive buffer to ask for (bytes).
    pub recv_buffer: usize,
    /// Largest block accepted (bytes); bounds memory against hostile packets.
    pub max_frame_bytes: usize,
    /// Frames assembled at once; the oldest is closed when a new one would exceed this.
    pub max_frames_in_flight: usize,
}

impl Default for StreamConfig {
    fn default() -> Self {
        Self {
            packet_size: 1500,
            extended: false,
            resend: true,
            initial_packet_timeout: Duration::from_millis(2),
            packet_timeout: Duration::from_millis(20),
            frame_retention: Duration::from_millis(200),
            request_ratio: 0.25,
            recv_buffer: 64 << 20,
            max_frame_bytes: 256 << 20,
            max_frames_in_flight: 8,
        }
    }
}

/// A received block.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Block id.
    pub block_id: u64,
    /// Device timestamp (ticks).
    pub timestamp: u64,
    /// Parts with their data (one for image payloads).
    pub parts: Vec<(PartInfo, Vec<u8>)>,
    /// Every packet arrived.
    pub complete: bool,
    /// Packets that arrived as retransmissions.
    pub resent_packets: u32,
    /// Packets still missing when the frame was closed.
    pub missing_packets: u32,
    /// When the receiver closed the frame (host clock).
    pub received: Instant,
}

/// Counters over the receiver's life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct StreamStats {
    /// Frames delivered complete.
    pub complete_frames: u64,
    /// Frames delivered incomplete (timeout / lost packets).
    pub incomplete_frames: u64,
    /// Packets received.
    pub packets: u64,
    /// Packets received as retransmissions.
    pub resent_packets: u64,
    /// Packets asked for again.
    pub resend_requested: u64,
    /// Packets ignored (malformed, duplicate, late).
    pub ignored_packets: u64,
}

#[derive(Debug)]
struct Asm {
    leader: Option<Leader>,
    generic: Vec<u8>,
    parts: HashMap<u8, Vec<u8>>,
    received: Vec<bool>,
    count: u32,
    highest: Option<u32>,
    trailer_id: Option<u32>,
    holes: BTreeMap<u32, Instant>,
    requested: u32,
    resend_off: bool,
    resent: u32,
    last_packet: Instant,
    seq: u64,
}

impl Asm {
    fn new(now: Instant, seq: u64) -> Self {
        Self {
            leader: None,
            generic: Vec::new(),
            parts: HashMap::new(),
            received: Vec::new(),
            count: 0,
            highest: None,
            trailer_id: None,
            holes: BTreeMap::new(),
            requested: 0,
            resend_off: false,
            resent: 0,
            last_packet: now,
            seq,
        }
    }

    /// Size the buffers from the leader once, so payload packets are copied straight to their
    /// offset without growing vectors (fresh zeroed allocations are mapped lazily, so memory
    /// is only committed as packets arrive).
    fn preallocate(&mut self, data_per: usize) {
        let Some(l) = &self.leader else { return };
        let grow = |buf: &mut Vec<u8>, len: usize| {
            if buf.is_empty() {
                *buf = vec![0; len];
            } else if buf.len() < len {
                buf.resize(len, 0);
            }
        };
        if l.payload_type == PAYLOAD_MULTIPART {
            for (i, p) in l.parts.iter().enumerate() {
                grow(self.parts.entry(i as u8).or_default(), p.length as usize);
            }
        } else if let Some(p) = l.parts.first() {
            grow(&mut self.generic, p.length as usize);
        }
        if let Some(n) = self.expected(data_per) {
            if self.received.len() < n as usize {
                self.received.resize(n as usize, false);
            }
        }
    }

    /// Total packets of the block when known (trailer id + 1, or from the leader).
    fn expected(&self, data_per: usize) -> Option<u32> {
        if let Some(t) = self.trailer_id {
            return Some(t + 1);
        }
        let l = self.leader.as_ref()?;
        if l.parts.is_empty() {
            return None;
        }
        let mp = l.payload_type == PAYLOAD_MULTIPART;
        let per = if mp {
            data_per.saturating_sub(8)
        } else {
            data_per
        }
        .max(1) as u64;
        let n: u64 = l.parts.iter().map(|p| p.length.div_ceil(per)).sum();
        u32::try_from(n + 2).ok()
    }
}

/// Receives GVSP on a UDP socket and assembles frames.
#[derive(Debug)]
pub struct StreamReceiver {
    sock: UdpSocket,
    device: SocketAddr,
    cfg: StreamConfig,
    frames: HashMap<u64, Asm>,
    done: VecDeque<u64>,
    ready: VecDeque<Frame>,
    stats: StreamStats,
    req_id: u16,
    seq: u64,
    batch: RecvBatch,
    /// Pause after draining the socket, letting packets gather so one call takes many
    /// (zero with a small receive buffer: then every packet wakes the receiver).
    idle_wait: Duration,
}

impl StreamReceiver {
    /// Bind a receive socket on `local_ip` (ephemeral port). `device` is the device's GVCP
    /// address (PACKETRESEND goes there from this socket).
    pub fn bind(local_ip: Ipv4Addr, device: SocketAddr, cfg: StreamConfig) -> Result<Self> {
        let addr: SocketAddr = SocketAddrV4::new(local_ip, 0).into();
        let s = socket2::Socket::new(
            socket2::Domain::IPV4,
            socket2::Type::DGRAM,
            Some(socket2::Protocol::UDP),
        )
        .map_err(|e| GigeError::io(addr, e))?;
        set_recv_buffer(&s, cfg.recv_buffer);
        s.bind(&addr.into()).map_err(|e| GigeError::io(addr, e))?;
        let sock: UdpSocket = s.into();
        sock.set_read_timeout(Some(Duration::from_millis(2)))
            .map_err(|e| GigeError::io(addr, e))?;
        let batch = RecvBatch::new(cfg.packet_size);
        let granted = socket2::SockRef::from(&sock)
            .recv_buffer_size()
            .unwrap_or(0);
        let idle_wait = if granted >= IDLE_WAIT_MIN_BUFFER {
            IDLE_WAIT
        } else {
            Duration::ZERO
        };
        Ok(Self {
            sock,
            device,
            cfg,
            frames: HashMap::new(),
            done: VecDeque::new(),
            ready: VecDeque::new(),
            stats: StreamStats::default(),
            req_id: 0,
            seq: 0,
            batch,
            idle_wait,
        })
    }

    /// Receive buffer size the kernel granted (bytes, as `SO_RCVBUF` reports it: Linux
    /// doubles the requested size to account for its bookkeeping).
    pub fn recv_buffer_size(&self) -> usize {
        socket2::SockRef::from(&self.sock)
            .recv_buffer_size()
            .unwrap_or(0)
    }

    /// Local address (program it into SCDA/SCP).
    pub fn local_addr(&self) -> Result<SocketAddr> {
        self.sock
            .local_addr()
            .map_err(|e| GigeError::io("stream socket", e))
    }

    /// Counters.
    pub fn stats(&self) -> StreamStats {
        self.stats
    }

    /// Data bytes per generic payload packet.
    fn data_per(&self) -> usize {
        self.cfg
            .packet_size
            .saturating_sub(IP_UDP_HEADERS + Header::len(self.cfg.extended))
            .max(1)
    }

    /// Wait for the next frame (complete or closed incomplete). `Err(FrameTimeout)` after `timeout`.
    pub fn next_frame(&mut self, timeout: Duration) -> Result<Frame> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(f) = self.ready.pop_front() {
                return Ok(f);
            }
            let now = Instant::now();
            if now >= deadline {
                let detail = format!(
                    "{} packets so far, {} frames in progress",
                    self.stats.packets,
                    self.frames.len()
                );
                return Err(GigeError::FrameTimeout { timeout, detail });
            }
            // Waits up to the socket timeout (2 ms) for one packet, then takes what else is
            // queued (up to a batch) in the same call.
            let mut batch = std::mem::take(&mut self.batch);
            let got = batch.recv(&self.sock);
            let now = Instant::now();
            match got {
                Ok(n) => {
                    if n < BATCH / 2 && !self.idle_wait.is_zero() {
                        // Drained: wait a moment instead of being woken for every packet.
                        std::thread::sleep(self.idle_wait);
                    }
                    for i in 0..n {
                        match batch.packet(i) {
                            Some(pkt) => self.handle(pkt, now),
                            None => self.stats.ignored_packets += 1, // truncated: too long
                        }
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock
                            | std::io::ErrorKind::TimedOut
                            | std::io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => {
                    self.batch = batch;
                    return Err(GigeError::io("stream socket", e));
                }
            }
            self.batch = batch;
            self.housekeeping(now);
        }
    }

    /// Handle one packet (public for tests that feed packets directly).
    pub fn handle(&mut self, pkt: &[u8], now: Instant) {
        let (h, body) = match Header::parse(pkt) {
            Ok(x) => x,
            Err(e) => {
                tracing::debug!("ignoring GVSP packet: {e}");
                self.stats.ignored_packets += 1;
                return;
            }
        };
        if h.block_id == 0 && !h.extended {
            self.stats.ignored_packets += 1; // test packet
            return;
        }
        let data_per = self.data_per();
        if !self.frames.contains_key(&h.block_id) {
            if self.done.contains(&h.block_id) {
                self.stats.ignored_packets += 1;
                return;
            }
            self.stats.packets += 1;
            if h.status & 0x8000 != 0 {
                return;
            }
            self.seq += 1;
            // With resend off, a newer frame closes older ones.
            if !self.cfg.resend {
                let old: Vec<u64> = self.frames.keys().copied().collect();
                for b in old {
                    self.close(b, data_per);
                }
            }
            if self.frames.len() >= self.cfg.max_frames_in_flight.max(1) {
                if let Some((&oldest, _)) = self.frames.iter().min_by_key(|(_, f)| f.seq) {
                    self.close(oldest, data_per);
                }
            }
            self.frames.insert(h.block_id, Asm::new(now, self.seq));
        } else {
            self.stats.packets += 1;
        }
        let Some(f) = self.frames.get_mut(&h.block_id) else {
            return;
        };
        if h.status & 0x8000 != 0 {
            // PACKET_UNAVAILABLE / REMOVED: the device cannot resend; stop asking.
            if matches!(h.status, 0x800C | 0x8011 | 0x8012) {
                f.resend_off = true;
            }
            return;
        }
        let pid = h.packet_id;
        let max_bytes = self.cfg.max_frame_bytes;
        if pid as usize > max_bytes / data_per.saturating_sub(8).max(1) + 2 {
            self.stats.ignored_packets += 1;
            return;
        }
        let k = pid as usize;
        if f.received.len() <= k {
            f.received.resize(k + 1, false);
        }
        if f.received[k] {
            self.stats.ignored_packets += 1;
            return;
        }
        let ok = match h.format {
            FORMAT_LEADER => match Leader::parse(&h, body) {
                Ok(l) if l.parts.iter().map(|p| p.length).sum::<u64>() <= max_bytes as u64 => {
                    f.leader = Some(l);
                    f.preallocate(data_per);
                    true
                }
                Ok(_) => false,
                Err(e) => {
                    tracing::debug!("{e}");
                    false
                }
            },
            FORMAT_TRAILER => {
                f.trailer_id = Some(pid);
                true
            }
            FORMAT_PAYLOAD if pid >= 1 => {
                let off = (k - 1) * data_per;
                if off + body.len() > max_bytes {
                    false
                } else {
                    if f.generic.len() < off + body.len() {
                        f.generic.resize(off + body.len(), 0);
                    }
                    f.generic[off..off + body.len()].copy_from_slice(body);
                    true
                }
            }
            FORMAT_MULTIPART if body.len() >= 8 => {
                let part = body[0];
                let off = be48(body, 2);
                let d = &body[8..];
                if off + d.len() as u64 > max_bytes as u64 {
                    false
                } else {
                    let off = off as usize;
                    let buf = f.parts.entry(part).or_default();
                    if buf.len() < off + d.len() {
                        buf.resize(off + d.len(), 0);
                    }
                    buf[off..off + d.len()].copy_from_slice(d);
                    true
                }
            }
            _ => false,
        };
        if !ok {
            self.stats.ignored_packets += 1;
            return;
        }
        f.received[k] = true;
        f.count += 1;
        f.last_packet = now;
        if h.is_resent() {
            f.resent += 1;
            self.stats.resent_packets += 1;
        }
        f.holes.remove(&pid);
        let next = f.highest.map_or(0, |x| x + 1);
        if pid > next && self.cfg.resend {
            for p in next..pid {
                if !f.received.get(p as usize).copied().unwrap_or(false) {
                    f.holes.insert(p, now + self.cfg.initial_packet_timeout);
                }
            }
        }
        f.highest = Some(f.highest.map_or(pid, |x| x.max(pid)));
        if let Some(n) = f.expected(data_per) {
            if f.count >= n && f.received.iter().take(n as usize).all(|&r| r) {
                self.close(h.block_id, data_per);
            }
        }
    }

    /// Resend requests and frame timeouts.
    pub fn housekeeping(&mut self, now: Instant) {
        let data_per = self.data_per();
        let mut to_close = Vec::new();
        let mut requests: Vec<(u64, u32, u32)> = Vec::new();
        for (&b, f) in self.frames.iter_mut() {
            if now.duration_since(f.last_packet) > self.cfg.frame_retention {
                to_close.push(b);
                continue;
            }
            if !self.cfg.resend || f.resend_off {
                continue;
            }
            // A lost tail (or trailer): ask once the stream went quiet for a while.
            if let (Some(n), Some(hi)) = (f.expected(data_per), f.highest) {
                if hi + 1 < n && now.duration_since(f.last_packet) > self.cfg.packet_timeout {
                    for p in hi + 1..n {
                        f.holes.entry(p).or_insert(now);
                    }
                }
            }
            let due: Vec<u32> = f
                .holes
                .iter()
                .filter(|(_, &d)| d <= now)
                .map(|(&p, _)| p)
                .collect();
            if due.is_empty() {
                continue;
            }
            let cap = (f.expected(data_per).unwrap_or(f.highest.unwrap_or(0) + 2) as f64
                * self.cfg.request_ratio)
                .ceil() as u32;
            let mut start = due[0];
            let mut prev = due[0];
            for &p in due.iter().skip(1).chain(std::iter::once(&u32::MAX)) {
                if p != prev + 1 || p == u32::MAX {
                    let n = prev - start + 1;
                    if f.requested + n > cap.max(1) {
                        f.resend_off = true;
                        break;
                    }
                    f.requested += n;
                    requests.push((b, start, prev));
                    start = p;
                }
                prev = p;
            }
            for p in due {
                if let Some(d) = f.holes.get_mut(&p) {
                    *d = now + self.cfg.packet_timeout;
                }
            }
        }
        for (b, first, last) in requests {
            self.request_resend(b, first, last);
        }
        for b in to_close {
            self.close(b, data_per);
        }
    }

    fn request_resend(&mut self, block_id: u64, first: u32, last: u32) {
        self.req_id = if self.req_id == 0xFFFF {
            1
        } else {
            self.req_id + 1
        };
        let cmd = Command {
            flags: 0,
            req_id: self.req_id,
            kind: CommandKind::PacketResend {
                channel: 0,
                block_id,
                first,
                last,
                extended: self.cfg.extended,
            },
        };
        self.stats.resend_requested += u64::from(last - first + 1);
        if let Err(e) = self.sock.send_to(&cmd.encode(), self.device) {
            tracing::warn!("PACKETRESEND to {} failed: {e}", self.device);
        }
    }

    fn close(&mut self, block_id: u64, data_per: usize) {
        let Some(mut f) = self.frames.remove(&block_id) else {
            return;
        };
        self.done.push_back(block_id);
        if self.done.len() > 256 {
            self.done.pop_front();
        }
        let expected = f.expected(data_per);
        let complete = expected.is_some_and(|n| {
            f.received.iter().take(n as usize).filter(|&&r| r).count() as u32 == n
        });
        let missing = expected.map_or(1, |n| n.saturating_sub(f.count));
        let (timestamp, parts) = match f.leader.take() {
            Some(l) if l.payload_type == PAYLOAD_MULTIPART => {
                let parts = l
                    .parts
                    .into_iter()
                    .enumerate()
                    .map(|(i, p)| {
                        let mut d = f.parts.remove(&(i as u8)).unwrap_or_default();
                        d.resize(p.length as usize, 0);
                        (p, d)
                    })
                    .collect();
                (l.timestamp, parts)
            }
            Some(l) => {
                let mut d = std::mem::take(&mut f.generic);
                let parts = l
                    .parts
                    .into_iter()
                    .map(|p| {
                        d.resize(p.length as usize, 0);
                        (p, std::mem::take(&mut d))
                    })
                    .collect();
                (l.timestamp, parts)
            }
            None => (0, Vec::new()),
        };
        let complete = complete && !parts.is_empty();
        if complete {
            self.stats.complete_frames += 1;
        } else {
            self.stats.incomplete_frames += 1;
        }
        let _ = f.seq;
        self.ready.push_back(Frame {
            block_id,
            timestamp,
            parts,
            complete,
            resent_packets: f.resent,
            missing_packets: missing,
            received: Instant::now(),
        });
    }
}

/// Ask for a `bytes` receive buffer: `SO_RCVBUFFORCE` first (allowed with CAP_NET_ADMIN, e.g.
/// as root; ignores `net.core.rmem_max`), else `SO_RCVBUF` (capped at `net.core.rmem_max`).
/// Logs the size the kernel granted.
fn set_recv_buffer(s: &socket2::Socket, bytes: usize) {
    #[cfg(target_os = "linux")]
    let forced = {
        use std::os::fd::AsRawFd;
        let v = libc::c_int::try_from(bytes).unwrap_or(libc::c_int::MAX);
        // SAFETY: setsockopt on an open socket with a pointer to a live c_int and its size.
        let rc = unsafe {
            libc::setsockopt(
                s.as_raw_fd(),
                libc::SOL_SOCKET,
                libc::SO_RCVBUFFORCE,
                (&v as *const libc::c_int).cast(),
                std::mem::size_of::<libc::c_int>() as libc::socklen_t,
            )
        };
        rc == 0
    };
    #[cfg(not(target_os = "linux"))]
    let forced = false;
    if !forced {
        if let Err(e) = s.set_recv_buffer_size(bytes) {
            tracing::warn!("cannot set a {bytes} byte receive buffer: {e}");
        }
    }
    let granted = s.recv_buffer_size().unwrap_or(0);
    if granted < bytes {
        tracing::warn!(
            "stream receive buffer is {granted} bytes, {bytes} asked for: frames may lose packets \
             at high rates; raise net.core.rmem_max (sysctl) or run with CAP_NET_ADMIN"
        );
    } else {
        tracing::debug!(
            "stream receive buffer: {granted} bytes{}",
            if forced { " (SO_RCVBUFFORCE)" } else { "" }
        );
    }
}

/// Datagrams taken per receive call.
const BATCH: usize = 64;
/// Pause of the receiver after it drained the socket (see [`StreamReceiver::next_frame`]).
const IDLE_WAIT: Duration = Duration::from_micros(500);
/// Receive buffer (as `SO_RCVBUF` reports it) from which the receiver pauses when drained.
/// The kernel charges a packet's whole buffer (several KiB on loopback), so a 4 MiB
/// `rmem_max` holds only ~10 ms at 1 Gbit/s and a pause that oversleeps on a busy host lost
/// packets (measured); 32 MiB and more leave ample margin.
const IDLE_WAIT_MIN_BUFFER: usize = 32 << 20;

/// Preallocated buffers for a batch of datagrams (one `recvmmsg` call on Linux): no
/// allocation and one system call for up to [`BATCH`] packets.
#[derive(Debug, Default)]
struct RecvBatch {
    slot: usize,
    data: Vec<u8>,
    /// Datagram lengths; longer than `slot` means truncated.
    lens: Vec<usize>,
}

impl RecvBatch {
    fn new(packet_size: usize) -> Self {
        // A datagram of the negotiated packet size is `packet_size - 28` bytes; leave slack
        // and treat anything longer than a slot as malformed (truncated).
        let slot = (packet_size.clamp(576, 65_536) + 256).min(65_536);
        Self {
            slot,
            data: vec![0; slot * BATCH],
            lens: Vec::with_capacity(BATCH),
        }
    }

    /// Datagram `i` of the last receive; `None` when it was truncated.
    fn packet(&self, i: usize) -> Option<&[u8]> {
        let n = *self.lens.get(i)?;
        (n <= self.slot).then(|| &self.data[i * self.slot..i * self.slot + n])
    }

    /// Wait (up to the socket's read timeout) for one datagram, then take what else is
    /// queued, up to a batch. Returns the number received.
    #[cfg(target_os = "linux")]
    fn recv(&mut self, sock: &UdpSocket) -> std::io::Result<usize> {
        use std::os::fd::AsRawFd;
        self.lens.clear();
        let slot = self.slot;
        let base = self.data.as_mut_ptr();
        // SAFETY: all-zero bytes are valid iovec/mmsghdr values (null pointers, zero lengths).
        let mut iovs: [libc::iovec; BATCH] = unsafe { std::mem::zeroed() };
        let mut msgs: [libc::mmsghdr; BATCH] = unsafe { std::mem::zeroed() };
        for (i, (iov, m)) in iovs.iter_mut().zip(msgs.iter_mut()).enumerate() {
            // SAFETY: `i * slot` is within `data` (BATCH slots of `slot` bytes).
            iov.iov_base = unsafe { base.add(i * slot) }.cast();
            iov.iov_len = slot;
            m.msg_hdr.msg_iov = iov;
            m.msg_hdr.msg_iovlen = 1;
        }
        // SAFETY: every mmsghdr points at one iovec covering its own slot of `data`, which
        // outlives the call; the kernel writes at most `slot` bytes per slot and the lengths.
        let n = unsafe {
            libc::recvmmsg(
                sock.as_raw_fd(),
                msgs.as_mut_ptr(),
                BATCH as libc::c_uint,
                libc::MSG_WAITFORONE,
                std::ptr::null_mut(),
            )
        };
        if n < 0 {
            return Err(std::io::Error::last_os_error());
        }
        let n = n as usize;
        for m in &msgs[..n] {
            let truncated = m.msg_hdr.msg_flags & libc::MSG_TRUNC != 0;
            self.lens.push(if truncated {
                usize::MAX
            } else {
                m.msg_len as usize
            });
        }
        Ok(n)
    }

    /// Portable fallback: one datagram per call.
    #[cfg(not(target_os = "linux"))]
    fn recv(&mut self, sock: &UdpSocket) -> std::io::Result<usize> {
        self.lens.clear();
        let (n, _) = sock.recv_from(&mut self.data[..self.slot])?;
        self.lens.push(n);
        Ok(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn block(id: u64, multipart: bool) -> Block {
        let w = 40;
        let h = 30;
        let pf = 0x026000C0;
        let data: Vec<u8> = (0..w * h * 12).map(|i| (i % 251) as u8).collect();
        let info = PartInfo {
            data_type: PART_3D_IMAGE,
            length: data.len() as u64,
            pixel_format: pf,
            purpose: 4,
            width: w,
            height: h,
            padding_x: 0,
        };
        let mut parts = vec![(info, data)];
        if multipart {
            let c: Vec<u8> = (0..w * h * 2).map(|i| (i % 7) as u8).collect();
            parts.push((
                PartInfo {
                    data_type: PART_CONFIDENCE,
                    length: c.len() as u64,
                    pixel_format: 0x011000C7,
                    purpose: 6,
                    width: w,
                    height: h,
                    padding_x: 0,
                },
                c,
            ));
        }
        Block {
            block_id: id,
            timestamp: 99,
            parts,
            multipart,
        }
    }

    fn receiver(extended: bool, resend: bool) -> StreamReceiver {
        let cfg = StreamConfig {
            packet_size: 400,
            extended,
            resend,
            max_frame_bytes: 1 << 20,
            ..StreamConfig::default()
        };
        StreamReceiver::bind(
            Ipv4Addr::LOCALHOST,
            "127.0.0.1:9".parse().expect("addr"),
            cfg,
        )
        .expect("bind")
    }

    #[test]
    fn frames_reassemble_standard_and_multipart_with_wraparound() {
        for (ext, mp) in [(false, false), (true, false), (true, true)] {
            let mut r = receiver(ext, true);
            let now = Instant::now();
            let ids: &[u64] = if ext {
                &[1 << 40, (1 << 40) + 1]
            } else {
                &[65534, 65535, 1, 2]
            };
            for &id in ids {
                let b = block(id, mp);
                let mut pk = packetize(&b, 400, ext).expect("packetize");
                pk.swap(2, 5); // reordering
                for p in &pk {
                    r.handle(p, now);
                }
                let f = r.ready.pop_front().expect("frame");
                assert!(f.complete, "{ext} {mp} {id}");
                assert_eq!(f.block_id, id);
                assert_eq!(f.parts.len(), b.parts.len());
                for ((pi, pd), (bi, bd)) in f.parts.iter().zip(&b.parts) {
                    assert_eq!(pd, bd);
                    assert_eq!(pi.pixel_format, bi.pixel_format);
                    assert_eq!((pi.width, pi.height), (bi.width, bi.height));
                }
            }
        }
    }

    #[test]
    fn packetize_into_recycled_buffers_matches_fresh_packets() {
        // Recycled from a bigger multi-part frame with other contents and packet size.
        let mut reused = packetize(&block(9, true), 300, true).expect("p");
        let n_old = reused.len();
        for (ext, mp) in [(false, false), (true, true)] {
            let b = block(4, mp);
            packetize_into(&b, 400, ext, &mut reused).expect("packetize_into");
            assert_eq!(reused, packetize(&b, 400, ext).expect("packetize"));
        }
        assert!(reused.len() < n_old);
    }

    #[test]
    fn socket_path_reads_batches_and_ignores_oversized_datagrams() {
        let mut r = receiver(false, true);
        let to = r.local_addr().expect("addr");
        let tx = UdpSocket::bind("127.0.0.1:0").expect("bind");
        // Longer than a receive slot for 400-byte packets: truncated, so ignored.
        tx.send_to(&[0x55; 5000], to).expect("send");
        let pk = packetize(&block(7, false), 400, false).expect("packetize");
        for p in &pk {
            tx.send_to(p, to).expect("send");
        }
        let f = r.next_frame(Duration::from_secs(2)).expect("frame");
        assert!(f.complete);
        assert_eq!(f.block_id, 7);
        assert_eq!(f.parts[0].1, block(7, false).parts[0].1);
        assert_eq!(r.stats().ignored_packets, 1);
        assert_eq!(r.stats().packets, pk.len() as u64);
    }

    #[test]
    fn lost_packets_are_detected_and_frame_closes_incomplete() {
        let mut r = receiver(false, false);
        let now = Instant::now();
        let pk = packetize(&block(5, false), 400, false).expect("packetize");
        for (i, p) in pk.iter().enumerate() {
            if i != 3 {
                r.handle(p, now);
            }
        }
        assert!(r.ready.is_empty());
        r.housekeeping(now + Duration::from_secs(1));
        let f = r.ready.pop_front().expect("closed");
        assert!(!f.complete);
        assert_eq!(f.missing_packets, 1);
    }

    #[test]
    fn fuzz_gvsp_parsers_never_panic() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(0x65e5);
        let mut seeds = packetize(&block(3, false), 400, false).expect("p");
        seeds.extend(packetize(&block(4, true), 400, true).expect("p"));
        let mut r = receiver(true, true);
        let now = Instant::now();
        for i in 0..30_000 {
            let mut b = seeds[i % seeds.len()].clone();
            match rng.random_range(0..3) {
                0 => b.truncate(rng.random_range(0..=b.len())),
                1 => {
                    for _ in 0..rng.random_range(1..8) {
                        let j = rng.random_range(0..b.len().clamp(1, 80));
                        if let Some(x) = b.get_mut(j) {
                            *x = rng.random();
                        }
                    }
                }
                _ => {}
            }
            if let Ok((h, body)) = Header::parse(&b) {
                let _ = Leader::parse(&h, body);
            }
            r.handle(&b, now);
        }
        r.housekeeping(now + Duration::from_secs(5));
        assert!(r.frames.is_empty());
    }

    /// Issue 16: structure-aware huge counts — every 16- and 32-bit field of a leader, data
    /// and trailer packet set in turn to the largest values (sizes, part counts, packet and
    /// block ids, offsets); the receiver stays within its frame budget and never panics.
    #[test]
    fn issue_16_huge_fields_in_every_packet_position() {
        let t0 = Instant::now();
        for (mp, ext) in [(false, false), (true, true)] {
            let packets = packetize(&block(5, mp), 400, ext).expect("p");
            let mut r = receiver(ext, true);
            let now = Instant::now();
            let picks = [0, 1, packets.len() - 1];
            for &k in &picks {
                let seed = &packets[k];
                for off in 0..seed.len().min(96) {
                    for value in [u32::MAX, 0x7FFF_FFFF, 0x8000_0000, 0x0001_0000] {
                        let mut b = seed.clone();
                        for (i, byte) in value.to_be_bytes().iter().enumerate() {
                            if let Some(x) = b.get_mut(off + i) {
                                *x = *byte;
                            }
                        }
                        if let Ok((h, body)) = Header::parse(&b) {
                            let _ = Leader::parse(&h, body);
                        }
                        r.handle(&b, now);
                        assert!(r.frames.len() <= r.cfg.max_frames_in_flight.max(1));
                    }
                }
            }
            r.housekeeping(now + Duration::from_secs(5));
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "{:?}", t0.elapsed());
    }
}
