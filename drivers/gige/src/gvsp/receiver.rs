//! The GVSP frame receiver: reassembly with missing-packet detection, PACKETRESEND and frame
//! timeouts.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::time::{Duration, Instant};

use super::codec::*;
use crate::error::{GigeError, Result};
use crate::gvcp::{Command, CommandKind};
use crate::udp_batch::{RecvBatch, BATCH};

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
    /// Frames assembled at once; the oldest is closed when a new one would exceed this. Also
    /// how many finished frames wait to be read (the oldest is dropped beyond it).
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
    /// Finished frames dropped unread, oldest first, because more than `max_frames_in_flight`
    /// were waiting to be read (a device sending faster than frames are taken).
    pub dropped_frames: u64,
}

#[derive(Debug)]
pub(super) struct Asm {
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

/// Zero-extends `buf` to `len` bytes, `len` within the frame budget `max`. Capacity grows by
/// doubling, as `Vec` does, but never past `max`: a frame assembled from out-of-order packets
/// holds at most its budget, where `Vec`'s own doubling could reserve up to twice it (found by
/// the `gvsp` fuzz target).
fn grow_to(buf: &mut Vec<u8>, len: usize, max: usize) {
    if buf.len() >= len {
        return;
    }
    if buf.capacity() < len {
        let target = buf.capacity().saturating_mul(2).clamp(len, max.max(len));
        buf.reserve_exact(target - buf.len());
    }
    buf.resize(len, 0);
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
    fn preallocate(&mut self, data_per: usize, max: usize) {
        let Some(l) = &self.leader else { return };
        // The leader's lengths were checked against the frame budget.
        if l.payload_type == PAYLOAD_MULTIPART {
            for (i, p) in l.parts.iter().enumerate() {
                grow_to(
                    self.parts.entry(i as u8).or_default(),
                    p.length as usize,
                    max,
                );
            }
        } else if let Some(p) = l.parts.first() {
            grow_to(&mut self.generic, p.length as usize, max);
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
    pub(super) cfg: StreamConfig,
    pub(super) frames: HashMap<u64, Asm>,
    done: VecDeque<u64>,
    pub(super) ready: VecDeque<Frame>,
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
                    f.preallocate(data_per, max_bytes);
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
                    grow_to(&mut f.generic, off + body.len(), max_bytes);
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
                    grow_to(buf, off + d.len(), max_bytes);
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
            Some(l) if l.payload_type == PAYLOAD_CHUNK => {
                // Chunk data only: one part holding the chunks, as long as what arrived.
                let d = std::mem::take(&mut f.generic);
                let info = PartInfo {
                    data_type: PART_CHUNK,
                    length: d.len() as u64,
                    ..PartInfo::default()
                };
                (l.timestamp, vec![(info, d)])
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
        // Finished frames wait for `next_frame`; one call handles a whole batch of packets,
        // so a device sending many small frames could otherwise queue them without end.
        while self.ready.len() > self.cfg.max_frames_in_flight.max(1) {
            self.ready.pop_front();
            self.stats.dropped_frames += 1;
        }
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

/// Pause of the receiver after it drained the socket (see [`StreamReceiver::next_frame`]).
const IDLE_WAIT: Duration = Duration::from_micros(500);
/// Receive buffer (as `SO_RCVBUF` reports it) from which the receiver pauses when drained.
/// The kernel charges a packet's whole buffer (several KiB on loopback), so a 4 MiB
/// `rmem_max` holds only ~10 ms at 1 Gbit/s and a pause that oversleeps on a busy host lost
/// packets (measured); 32 MiB and more leave ample margin.
const IDLE_WAIT_MIN_BUFFER: usize = 32 << 20;
