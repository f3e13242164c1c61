//! The simulated camera's streamer: frames rendered one ahead, cut into GVSP packets, paced,
//! and resent on request.

use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};

use super::device::{lock, SimOptions, State, ACQ_MODE, HEIGHT, PIXEL_FORMAT, WIDTH};
use super::encode::make_block;
use super::habits::Coding;
use super::FrameSource;
use crate::gvcp::reg;
use crate::gvsp;
use crate::udp_batch::{send_all, SEND_BATCH};

/// What the streamer needs to know about the device settings; a frame prepared under other
/// settings is dropped.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct StreamSettings {
    pub(super) scps: usize,
    pub(super) ext: bool,
    pub(super) mp: bool,
    /// Chunk-only payload.
    pub(super) chunks: bool,
    /// Components sent beside Range (in multi-part or chunk payloads).
    pub(super) confidence: bool,
    pub(super) intensity: bool,
    /// The intensity image alone.
    pub(super) intensity_only: bool,
    pub(super) w: u32,
    pub(super) h: u32,
    pub(super) pf: u32,
    /// How the pixel format's coordinates are coded.
    pub(super) coding: Coding,
    /// A chunk-data part after the components ([`VendorHabits::chunk_part`](crate::sim::VendorHabits::chunk_part)).
    pub(super) chunk_part: bool,
    /// Focal length and principal point (px) the chunk part carries.
    pub(super) intrinsics: [f64; 3],
}

impl StreamSettings {
    pub(super) fn read(s: &State) -> Self {
        Self {
            scps: s.reg(reg::SCPS0) as usize,
            ext: s.reg(reg::GVSP_CONFIG) & 0x4000_0000 != 0,
            mp: s.multipart(),
            chunks: s.habits.chunk_only,
            confidence: s.confidence_enabled && (s.multipart() || s.habits.chunk_only),
            intensity: s.intensity_enabled
                && (s.multipart() || s.habits.chunk_only || s.intensity_only()),
            intensity_only: s.intensity_only(),
            w: s.reg(WIDTH),
            h: s.reg(HEIGHT),
            pf: s.reg(PIXEL_FORMAT),
            coding: s.habits.coding(s.reg(PIXEL_FORMAT)),
            chunk_part: s.habits.chunk_part && s.multipart(),
            intrinsics: [s.intrinsics.0, s.intrinsics.1, s.intrinsics.2],
        }
    }
}

/// A frame rendered and cut into packets, waiting to be sent (block id filled in on send).
struct Prepared {
    settings: StreamSettings,
    packets: Vec<Vec<u8>>,
}

/// Logs the first failure of a repeating error, then a summary with the count every
/// `every` (a frame source that keeps failing would otherwise log at the frame rate).
#[derive(Debug)]
pub(crate) struct RateLimitedWarning {
    every: Duration,
    last_log: Option<Instant>,
    suppressed: u64,
}

impl RateLimitedWarning {
    pub(crate) fn new(every: Duration) -> Self {
        Self {
            every,
            last_log: None,
            suppressed: 0,
        }
    }

    /// Record one failure; returns the message to log now, if any.
    pub(crate) fn failure(&mut self, now: Instant, what: &str) -> Option<String> {
        match self.last_log {
            None => {
                self.last_log = Some(now);
                Some(what.to_string())
            }
            Some(t) if now.duration_since(t) >= self.every => {
                let n = self.suppressed + 1;
                self.last_log = Some(now);
                self.suppressed = 0;
                Some(format!(
                    "{n} failures in the last {:.0} s, latest: {what}",
                    now.duration_since(t).as_secs_f64()
                ))
            }
            Some(_) => {
                self.suppressed += 1;
                None
            }
        }
    }

    /// Record a success; returns a closing message when failures were being suppressed.
    pub(crate) fn success(&mut self) -> Option<String> {
        let n = self.suppressed;
        let was_failing = self.last_log.take().is_some();
        self.suppressed = 0;
        (was_failing && n > 0).then(|| format!("recovered after {n} more failures"))
    }
}

/// Render frames at the frame rate while acquiring, one frame ahead of the sender (a real
/// camera exposes the next frame while the link carries the previous one).
fn generate(
    mut source: Box<dyn FrameSource>,
    state: Arc<Mutex<State>>,
    stop: Arc<AtomicBool>,
    frame_rate: f64,
    tx: std::sync::mpsc::SyncSender<Prepared>,
    recycled: std::sync::mpsc::Receiver<Vec<Vec<u8>>>,
) {
    // Buffers reused from frame to frame: tens of MB per frame would otherwise be mapped,
    // faulted in and unmapped again each time.
    let mut data_buf = Vec::new();
    let mut conf_buf = Vec::new();
    let t0 = Instant::now();
    let period = Duration::from_secs_f64(1.0 / frame_rate.max(0.01));
    let mut next = Instant::now();
    let mut source_warn = RateLimitedWarning::new(Duration::from_secs(10));
    while !stop.load(Ordering::Relaxed) {
        let (active, settings) = {
            let s = lock(&state);
            (
                s.acquiring && s.reg(reg::SCP0) & 0xFFFF != 0,
                StreamSettings::read(&s),
            )
        };
        if !active {
            std::thread::sleep(Duration::from_millis(5));
            next = Instant::now();
            continue;
        }
        let now = Instant::now();
        if now < next {
            std::thread::sleep((next - now).min(Duration::from_millis(20)));
            continue;
        }
        // With the trigger on, a frame per software trigger.
        if !lock(&state).take_trigger() {
            std::thread::sleep(Duration::from_millis(2));
            continue;
        }
        // Never fall further behind than one period (no bursts of stale frames).
        next = (next + period).max(now);
        let cloud = match source.next_frame() {
            Ok(c) => {
                if let Some(m) = source_warn.success() {
                    tracing::info!("sim camera: frame source {m}");
                }
                c
            }
            Err(e) => {
                if let Some(m) = source_warn.failure(Instant::now(), &e.to_string()) {
                    tracing::warn!("sim camera: frame source failed: {m}");
                }
                continue;
            }
        };
        let (scps, ext) = (settings.scps, settings.ext);
        let ts = t0.elapsed().as_nanos() as u64;
        let bufs = (std::mem::take(&mut data_buf), std::mem::take(&mut conf_buf));
        let block = make_block(&cloud, ts, &settings, bufs);
        drop(cloud);
        let mut packets = recycled.try_recv().unwrap_or_default();
        let cut = gvsp::packetize_into(&block, scps, ext, &mut packets);
        let mut parts = block.parts.into_iter().map(|(_, d)| d);
        data_buf = parts.next().unwrap_or_default();
        conf_buf = parts.next().unwrap_or_default();
        if let Err(e) = cut {
            tracing::warn!("sim camera: {e}");
            continue;
        }
        if tx.send(Prepared { settings, packets }).is_err() {
            return;
        }
    }
}

/// Write `block_id` into a GVSP packet header.
fn set_block_id(p: &mut [u8], block_id: u64, ext: bool) {
    if ext {
        if let Some(b) = p.get_mut(8..16) {
            b.copy_from_slice(&block_id.to_be_bytes());
        }
    } else if let Some(b) = p.get_mut(2..4) {
        b.copy_from_slice(&(block_id as u16).to_be_bytes());
    }
}

pub(super) fn stream(
    sock: UdpSocket,
    source: Box<dyn FrameSource>,
    state: Arc<Mutex<State>>,
    stop: Arc<AtomicBool>,
    opts: SimOptions,
) {
    let (tx, rx) = std::sync::mpsc::sync_channel::<Prepared>(1);
    let (recycle, recycled) = std::sync::mpsc::channel::<Vec<Vec<u8>>>();
    let generator = {
        let (state, stop, rate) = (state.clone(), stop.clone(), opts.frame_rate);
        match std::thread::Builder::new()
            .name("sim-render".into())
            .spawn(move || generate(source, state, stop, rate, tx, recycled))
        {
            Ok(t) => t,
            Err(e) => {
                tracing::error!("sim camera: cannot start the render thread: {e}");
                return;
            }
        }
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(opts.seed);
    let mut block_id: u64 = 0;
    // Pacing clock: when the next packet may leave. It runs across frames so back-to-back
    // frames keep the configured rate; after an idle gap it restarts from now (no burst).
    let mut clock = Instant::now();
    let bps = opts.bandwidth_bps;
    while !stop.load(Ordering::Relaxed) {
        send_resends(&sock, &state, usize::MAX, bps, &mut clock);
        let frame = match rx.recv_timeout(Duration::from_millis(2)) {
            Ok(f) => f,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => continue,
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
        };
        let (active, dest, settings, single) = {
            let s = lock(&state);
            let port = s.reg(reg::SCP0) as u16;
            let ip = Ipv4Addr::from(s.reg(reg::SCDA0));
            (
                s.acquiring && port != 0 && !ip.is_unspecified(),
                SocketAddr::new(IpAddr::V4(ip), port),
                StreamSettings::read(&s),
                s.reg(ACQ_MODE) == 1,
            )
        };
        if !active || settings != frame.settings {
            // Stale: acquisition stopped or settings changed meanwhile.
            let _ = recycle.send(frame.packets);
            continue;
        }
        let ext = settings.ext;
        block_id = if ext {
            block_id + 1
        } else if block_id >= 0xFFFF {
            1
        } else {
            block_id + 1
        };
        let mut packets = frame.packets;
        for p in &mut packets {
            set_block_id(p, block_id, ext);
        }
        let packets = Arc::new(packets);
        let evicted = {
            let mut s = lock(&state);
            s.history.push_back((block_id, packets.clone()));
            (s.history.len() > 4)
                .then(|| s.history.pop_front())
                .flatten()
        };
        // Hand an old frame's buffers back to the renderer (unless a resend holds them).
        if let Some(Ok(old)) = evicted.map(|(_, p)| Arc::try_unwrap(p)) {
            let _ = recycle.send(old);
        }
        let now = Instant::now();
        let mut render_wait = Duration::ZERO;
        let mut lag = Duration::ZERO;
        if now > clock + MAX_CATCH_UP {
            render_wait = now - clock;
            clock = now;
        }
        let mut dropped = 0;
        let mut out: Vec<&[u8]> = Vec::with_capacity(SEND_BATCH);
        for p in packets.iter() {
            if opts.loss_ratio > 0.0 && rng.random::<f64>() < opts.loss_ratio {
                dropped += 1;
                continue;
            }
            if let Some(bps) = opts.bandwidth_bps {
                let mut now = Instant::now();
                if clock > now + PACING_SLACK {
                    send_all(&sock, dest, &mut out);
                    // Answer resend requests in the gaps of the stream.
                    send_resends(
                        &sock,
                        &state,
                        SEND_BATCH / 2,
                        opts.bandwidth_bps,
                        &mut clock,
                    );
                    std::thread::sleep(clock.saturating_duration_since(Instant::now()));
                    now = Instant::now();
                }
                if now > clock + MAX_CATCH_UP {
                    lag += now - clock - MAX_CATCH_UP;
                    clock = now - MAX_CATCH_UP;
                }
                clock +=
                    Duration::from_secs_f64((p.len() + gvsp::IP_UDP_HEADERS) as f64 * 8.0 / bps);
            }
            out.push(p);
            if out.len() == SEND_BATCH {
                send_all(&sock, dest, &mut out);
                send_resends(&sock, &state, SEND_BATCH / 2, bps, &mut clock);
            }
        }
        send_all(&sock, dest, &mut out);
        let mut s = lock(&state);
        s.stats.frames += 1;
        s.stats.dropped_packets += dropped;
        if opts.bandwidth_bps.is_some() {
            s.stats.pacing_lag_us += lag.as_micros() as u64;
            s.stats.render_wait_us += render_wait.as_micros() as u64;
        }
        if single {
            s.acquiring = false;
        }
    }
    drop(rx);
    let _ = generator.join();
}

/// Sleeping overshoots (timer slack, a busy host): the streamer catches up by sending faster
/// for at most this long a backlog, so the average rate holds without long line-rate bursts.
const MAX_CATCH_UP: Duration = Duration::from_millis(20);
/// Packets due this soon go out in the current batch.
const PACING_SLACK: Duration = Duration::from_micros(200);
/// Bound of the resend queue (packets); requests beyond it are not served.
pub(super) const MAX_QUEUED_RESENDS: usize = 1 << 16;

/// Send up to `max` queued PACKETRESEND answers, paced on the stream's clock (a camera
/// resends within its bandwidth; a burst would overrun the host again).
fn send_resends(
    sock: &UdpSocket,
    state: &Mutex<State>,
    max: usize,
    bps: Option<f64>,
    clock: &mut Instant,
) {
    let batch: Vec<(SocketAddr, Vec<u8>)> = {
        let mut s = lock(state);
        let n = s.resends.len().min(max);
        s.resends.drain(..n).collect()
    };
    for (dest, p) in batch {
        if let Some(bps) = bps {
            let now = Instant::now();
            if *clock > now + PACING_SLACK {
                std::thread::sleep(*clock - now);
            } else if now > *clock + MAX_CATCH_UP {
                *clock = now - MAX_CATCH_UP;
            }
            *clock += Duration::from_secs_f64((p.len() + gvsp::IP_UDP_HEADERS) as f64 * 8.0 / bps);
        }
        if let Err(e) = sock.send_to(&p, dest) {
            tracing::debug!("sim camera: resend failed: {e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repeated_source_failures_log_first_then_a_summary_per_interval() {
        let mut w = RateLimitedWarning::new(Duration::from_secs(10));
        let t0 = Instant::now();
        assert_eq!(
            w.failure(t0, "robot unreachable").as_deref(),
            Some("robot unreachable")
        );
        // 10 frames per second for 9.9 s: silent.
        for i in 1..100 {
            assert_eq!(
                w.failure(t0 + Duration::from_millis(100 * i), "robot unreachable"),
                None
            );
        }
        let m = w
            .failure(t0 + Duration::from_secs(10), "robot unreachable")
            .expect("summary after the interval");
        assert!(m.starts_with("100 failures in the last 10 s"), "{m}");
        assert_eq!(w.failure(t0 + Duration::from_millis(10_100), "x"), None);
        assert_eq!(
            w.success().as_deref(),
            Some("recovered after 1 more failures")
        );
        // After recovery the next failure is logged at once again.
        assert!(w.failure(t0 + Duration::from_secs(11), "again").is_some());
        assert_eq!(w.success(), None);
    }
}
