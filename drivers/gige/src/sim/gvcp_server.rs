//! [`SimCamera`]: the simulated camera on the network (GVCP server and GVSP streamer threads).

use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::device::{lock, SimOptions, SimStats, State};
use super::habits::xml_for;
use super::stream::stream;
use super::stream::MAX_QUEUED_RESENDS;
use super::FrameSource;
use crate::error::{GigeError, Result};
use crate::gvcp::{self, code, reg, Ack, Command, CommandKind};
use crate::gvsp;

/// A running simulated camera. Dropping it stops its threads.
#[derive(Debug)]
pub struct SimCamera {
    addr: SocketAddr,
    state: Arc<Mutex<State>>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

impl SimCamera {
    /// The GenApi XML the simulator serves.
    pub fn xml(opts: &SimOptions) -> String {
        xml_for(opts)
    }

    /// Start a camera whose GVCP server listens on `bind` (normally port 3956; port 0 picks
    /// one). Frames come from `source`.
    pub fn spawn(bind: SocketAddr, source: Box<dyn FrameSource>, opts: SimOptions) -> Result<Self> {
        let IpAddr::V4(ip) = bind.ip() else {
            return Err(GigeError::InvalidArgument(
                "GigE Vision is IPv4 only".into(),
            ));
        };
        opts.check().map_err(GigeError::InvalidArgument)?;
        let gvcp_sock = UdpSocket::bind(bind).map_err(|e| GigeError::io(bind, e))?;
        let addr = gvcp_sock.local_addr().map_err(|e| GigeError::io(bind, e))?;
        gvcp_sock
            .set_read_timeout(Some(Duration::from_millis(20)))
            .map_err(|e| GigeError::io(addr, e))?;
        let stream_sock =
            UdpSocket::bind(SocketAddr::new(bind.ip(), 0)).map_err(|e| GigeError::io(bind, e))?;
        let _ = socket2::SockRef::from(&stream_sock).set_send_buffer_size(8 << 20);
        let stream_port = stream_sock
            .local_addr()
            .map_err(|e| GigeError::io(bind, e))?
            .port();
        let sensor = source.size();
        if sensor.0 < 16 || sensor.1 < 16 {
            return Err(GigeError::InvalidArgument(format!(
                "frame source size {sensor:?} is below 16x16"
            )));
        }
        let state = Arc::new(Mutex::new(State::new(
            &opts,
            sensor,
            source.intrinsics(),
            source.aspect_ratio(),
            ip,
            stream_port,
        )));
        let stop = Arc::new(AtomicBool::new(false));
        let t1 = {
            let (state, stop) = (state.clone(), stop.clone());
            std::thread::Builder::new()
                .name("sim-gvcp".into())
                .spawn(move || serve_gvcp(gvcp_sock, state, stop))
                .map_err(|e| GigeError::io("sim thread", e))?
        };
        let t2 = {
            let (state, stop) = (state.clone(), stop.clone());
            std::thread::Builder::new()
                .name("sim-gvsp".into())
                .spawn(move || stream(stream_sock, source, state, stop, opts))
                .map_err(|e| GigeError::io("sim thread", e))?
        };
        Ok(Self {
            addr,
            state,
            stop,
            threads: vec![t1, t2],
        })
    }

    /// The GVCP address (what clients connect to).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Counters.
    pub fn stats(&self) -> SimStats {
        lock(&self.state).stats
    }

    /// Whether the simulator is streaming.
    pub fn is_acquiring(&self) -> bool {
        lock(&self.state).acquiring
    }

    /// Block until `stop` is set (for the CLI).
    pub fn wait(&self, stop: &AtomicBool) {
        while !stop.load(Ordering::Relaxed) && !self.stop.load(Ordering::Relaxed) {
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for SimCamera {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

fn serve_gvcp(sock: UdpSocket, state: Arc<Mutex<State>>, stop: Arc<AtomicBool>) {
    let mut buf = [0u8; 2048];
    while !stop.load(Ordering::Relaxed) {
        {
            let mut s = lock(&state);
            let hb = Duration::from_millis(u64::from(s.reg(reg::HEARTBEAT_TIMEOUT).max(500)));
            if s.controller.is_some() && s.last_heartbeat.elapsed() > hb {
                tracing::info!("sim camera: heartbeat timeout, releasing control");
                s.controller = None;
                s.regs.insert(reg::CCP, 0);
                s.acquiring = false;
                s.regs.insert(reg::SCP0, 0);
            }
        }
        let (n, from) = match sock.recv_from(&mut buf) {
            Ok(x) => x,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue
            }
            Err(e) => {
                tracing::warn!("sim camera GVCP socket: {e}");
                std::thread::sleep(Duration::from_millis(20));
                continue;
            }
        };
        let cmd = match Command::decode(&buf[..n]) {
            Ok(c) => c,
            Err(e) => {
                tracing::debug!("sim camera: ignoring bad command from {from}: {e}");
                continue;
            }
        };
        let reply = handle(&cmd, from, &state);
        if let Some(ack) = reply {
            if cmd.flags & gvcp::FLAG_ACK_REQUIRED != 0 {
                let _ = sock.send_to(&ack.encode(), from);
            }
        }
    }
}

fn handle(cmd: &Command, from: SocketAddr, state: &Mutex<State>) -> Option<Ack> {
    let mut s = lock(state);
    s.stats.commands += 1;
    if s.controller == Some(from) {
        s.last_heartbeat = Instant::now();
    }
    let ack = |status: u16, payload: Vec<u8>| Ack {
        status,
        ack_code: cmd.kind.code() + 1,
        ack_id: cmd.req_id,
        payload,
    };
    let may_write = s.controller.is_none() || s.controller == Some(from);
    Some(match &cmd.kind {
        CommandKind::Discovery => {
            let mut p = Vec::with_capacity(0xF8);
            for a in (0..0xF8).step_by(4) {
                p.extend_from_slice(&s.read_word(a).unwrap_or(0).to_be_bytes());
            }
            ack(0, p)
        }
        CommandKind::ReadReg(addrs) => {
            let mut p = Vec::new();
            for &a in addrs {
                match s.read_word(a) {
                    Some(v) => p.extend_from_slice(&v.to_be_bytes()),
                    None => return Some(ack(if a % 4 != 0 { 0x8005 } else { 0x8003 }, p)),
                }
            }
            ack(0, p)
        }
        CommandKind::WriteReg(pairs) => {
            for (i, &(a, v)) in pairs.iter().enumerate() {
                let idx = (i as u32).to_be_bytes().to_vec();
                if a == reg::CCP {
                    if !may_write {
                        return Some(ack(0x8006, idx));
                    }
                    if v & (gvcp::ccp::CONTROL | gvcp::ccp::EXCLUSIVE) != 0 {
                        s.controller = Some(from);
                        s.last_heartbeat = Instant::now();
                    } else {
                        s.controller = None;
                    }
                    s.regs.insert(reg::CCP, v & 0x3);
                    continue;
                }
                if !may_write {
                    return Some(ack(0x8006, idx));
                }
                if a % 4 != 0 {
                    return Some(ack(0x8005, idx));
                }
                if let Err(st) = s.write_word(a, v) {
                    return Some(ack(st, idx));
                }
            }
            ack(0, (pairs.len() as u32).to_be_bytes().to_vec())
        }
        CommandKind::ReadMem { address, count } => {
            let count = usize::from(*count);
            if address % 4 != 0 || count % 4 != 0 {
                return Some(ack(0x8005, Vec::new()));
            }
            if count == 0 || count > gvcp::MAX_MEM_BLOCK {
                return Some(ack(0x8002, Vec::new()));
            }
            let mut p = address.to_be_bytes().to_vec();
            for i in (0..count as u32).step_by(4) {
                match address.checked_add(i).and_then(|a| s.read_word(a)) {
                    Some(v) => p.extend_from_slice(&v.to_be_bytes()),
                    None => return Some(ack(0x8003, Vec::new())),
                }
            }
            ack(0, p)
        }
        CommandKind::WriteMem { address, data } => {
            if !may_write {
                return Some(ack(0x8006, vec![0; 4]));
            }
            if !address.is_multiple_of(4) || !data.len().is_multiple_of(4) || data.is_empty() {
                return Some(ack(0x8005, vec![0; 4]));
            }
            for (i, c) in data.chunks_exact(4).enumerate() {
                let a = address.wrapping_add(4 * i as u32);
                if let Err(st) = s.write_word(a, u32::from_be_bytes([c[0], c[1], c[2], c[3]])) {
                    return Some(ack(st, (4 * i as u32).to_be_bytes().to_vec()));
                }
            }
            ack(0, (data.len() as u32).to_be_bytes().to_vec())
        }
        CommandKind::PacketResend {
            block_id,
            first,
            last,
            extended,
            ..
        } => {
            let dest = SocketAddr::new(
                IpAddr::V4(Ipv4Addr::from(s.reg(reg::SCDA0))),
                s.reg(reg::SCP0) as u16,
            );
            let packets = s
                .history
                .iter()
                .find(|(b, _)| b == block_id)
                .map(|(_, p)| p.clone());
            let mut sent = 0;
            match packets {
                Some(pk) => {
                    for pid in *first..=(*last).min(pk.len().saturating_sub(1) as u32) {
                        if let Some(p) = pk.get(pid as usize) {
                            let mut p = p.clone();
                            if *extended {
                                p[2] |= 0; // flags high byte
                                p[3] |= 0x01; // resent flag
                            } else {
                                p[0] = 0x01;
                                p[1] = 0x00;
                            }
                            if s.resends.len() < MAX_QUEUED_RESENDS {
                                s.resends.push_back((dest, p));
                                sent += 1;
                            }
                        }
                    }
                }
                None => {
                    // PACKET_UNAVAILABLE error packet for the block.
                    let mut p = Vec::new();
                    gvsp::Header {
                        status: 0x800C,
                        block_id: *block_id,
                        format: gvsp::FORMAT_PAYLOAD,
                        packet_id: *first,
                        extended: *extended,
                        flags: 0,
                        parts: 0,
                    }
                    .encode(&mut p);
                    s.resends.push_back((dest, p));
                }
            }
            s.stats.resent_packets += sent;
            return None;
        }
        CommandKind::Other { code: c, .. } => {
            let status = if *c == code::FORCEIP { 0x8006 } else { 0x8001 };
            ack(status, Vec::new())
        }
    })
}
