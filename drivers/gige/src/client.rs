//! GVCP client: discovery, register/memory access with retries, control privilege with a
//! heartbeat thread. Blocking I/O (std sockets); run it off async runtimes.

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::error::{GigeError, Result};
use crate::gvcp::{
    self, ccp, check_status, code, reg, Ack, Command, CommandKind, DiscoveryInfo,
    FLAG_ACK_REQUIRED, FLAG_BROADCAST_ACK, GVCP_PORT, MAX_MEM_BLOCK,
};

/// Hard ceiling on one command, whatever the device answers: a device may ask for more time
/// with PENDING_ACK, but one that keeps doing so (or floods us with acks for other requests)
/// gets an error after this long, not an endless wait.
pub const MAX_COMMAND_WAIT: Duration = Duration::from_secs(5);

/// Hard ceiling on one multi-block memory read (the GenICam XML: up to 16 MiB in 512-byte
/// blocks), however promptly each block is answered.
pub const MAX_BULK_READ: Duration = Duration::from_secs(60);

/// Timeouts and retries of the control channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlConfig {
    /// Time to wait for one ack.
    pub timeout: Duration,
    /// Tries per command (same req_id).
    pub tries: u32,
    /// Heartbeat timeout written to the device (0x0938); we send a heartbeat every third of it.
    pub heartbeat_timeout: Duration,
    /// Longest wait for one command, PENDING_ACK extensions included (at most
    /// [`MAX_COMMAND_WAIT`], which is also the default).
    pub max_command_wait: Duration,
}

impl Default for ControlConfig {
    fn default() -> Self {
        Self {
            timeout: Duration::from_millis(500),
            tries: 5,
            heartbeat_timeout: Duration::from_secs(3),
            max_command_wait: MAX_COMMAND_WAIT,
        }
    }
}

/// A device found by discovery.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Discovered {
    /// Where the ack came from (the device's control address).
    pub address: SocketAddr,
    /// What the device says about itself.
    pub info: DiscoveryInfo,
}

/// Send a DISCOVERY to `target` (a unicast device address, or a broadcast address such as
/// `255.255.255.255:3956`) and collect the answers until `wait` has passed. Malformed answers
/// are logged and skipped.
pub fn discover(target: SocketAddr, wait: Duration) -> Result<Vec<Discovered>> {
    let bind: SocketAddr = SocketAddrV4::new(Ipv4Addr::UNSPECIFIED, 0).into();
    let sock = UdpSocket::bind(bind).map_err(|e| GigeError::io(bind, e))?;
    sock.set_broadcast(true)
        .map_err(|e| GigeError::io(target, e))?;
    let cmd = Command {
        flags: FLAG_ACK_REQUIRED | FLAG_BROADCAST_ACK,
        req_id: 0xFFFF,
        kind: CommandKind::Discovery,
    };
    sock.send_to(&cmd.encode(), target)
        .map_err(|e| GigeError::io(target, e))?;
    let deadline = Instant::now() + wait;
    let mut found: Vec<Discovered> = Vec::new();
    let mut buf = [0u8; 1500];
    loop {
        let now = Instant::now();
        if now >= deadline {
            break;
        }
        sock.set_read_timeout(Some(deadline - now))
            .map_err(|e| GigeError::io(target, e))?;
        match sock.recv_from(&mut buf) {
            Ok((n, from)) => {
                let parsed = Ack::decode(&buf[..n]).and_then(|a| {
                    check_status(a.status, &cmd.kind)?;
                    if a.ack_code != code::DISCOVERY + 1 {
                        return Err(GigeError::malformed(
                            "DISCOVERY ack",
                            format!("ack code 0x{:04x}", a.ack_code),
                        ));
                    }
                    DiscoveryInfo::parse(&a.payload)
                });
                match parsed {
                    Ok(info) if !found.iter().any(|d| d.address == from) => {
                        found.push(Discovered {
                            address: from,
                            info,
                        })
                    }
                    Ok(_) => {}
                    Err(e) => tracing::warn!(%from, "ignoring discovery answer: {e}"),
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                break
            }
            Err(e) => return Err(GigeError::io(target, e)),
        }
    }
    Ok(found)
}

/// The control socket and request counter; one command in flight at a time.
#[derive(Debug)]
struct Channel {
    sock: UdpSocket,
    peer: SocketAddr,
    req_id: u16,
    cfg: ControlConfig,
}

impl Channel {
    fn next_id(&mut self) -> u16 {
        self.req_id = if self.req_id == 0xFFFF {
            1
        } else {
            self.req_id + 1
        };
        self.req_id
    }

    /// Send `kind` and wait for its ack; retries with the same req_id.
    fn transact(&mut self, kind: CommandKind) -> Result<Ack> {
        let req_id = self.next_id();
        let cmd = Command {
            flags: FLAG_ACK_REQUIRED,
            req_id,
            kind,
        };
        let bytes = cmd.encode();
        let expected = cmd.kind.code() + 1;
        let mut buf = [0u8; 1500];
        let start = Instant::now();
        let ceiling = start + self.cfg.max_command_wait.min(MAX_COMMAND_WAIT);
        let mut pending = false;
        for _ in 0..self.cfg.tries.max(1) {
            self.sock
                .send_to(&bytes, self.peer)
                .map_err(|e| GigeError::io(self.peer, e))?;
            let mut deadline = (Instant::now() + self.cfg.timeout).min(ceiling);
            loop {
                let now = Instant::now();
                if now >= ceiling && pending {
                    return Err(GigeError::Stalled {
                        peer: self.peer,
                        what: cmd.kind.describe(),
                        waited: now - start,
                    });
                }
                if now >= deadline {
                    break;
                }
                self.sock
                    .set_read_timeout(Some(deadline - now))
                    .map_err(|e| GigeError::io(self.peer, e))?;
                let (n, from) = match self.sock.recv_from(&mut buf) {
                    Ok(x) => x,
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) =>
                    {
                        break
                    }
                    // ICMP port unreachable from a previous send: the device may come up; retry.
                    Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => break,
                    Err(e) => return Err(GigeError::io(self.peer, e)),
                };
                if from.ip() != self.peer.ip() {
                    continue;
                }
                let ack = match Ack::decode(&buf[..n]) {
                    Ok(a) => a,
                    Err(e) => {
                        tracing::warn!(peer = %self.peer, "ignoring malformed ack: {e}");
                        continue;
                    }
                };
                if ack.ack_id != req_id {
                    continue; // late answer to an earlier try or command
                }
                if ack.ack_code == code::PENDING_ACK {
                    let ms = ack.pending_ms().unwrap_or(0).max(1);
                    pending = true;
                    deadline =
                        (Instant::now() + Duration::from_millis(u64::from(ms)) + self.cfg.timeout)
                            .min(ceiling);
                    continue;
                }
                check_status(ack.status, &cmd.kind)?;
                if ack.ack_code != expected {
                    return Err(GigeError::malformed(
                        "GVCP ack",
                        format!(
                            "ack code 0x{:04x} for {}, expected 0x{expected:04x}",
                            ack.ack_code,
                            cmd.kind.describe()
                        ),
                    ));
                }
                return Ok(ack);
            }
        }
        if pending {
            return Err(GigeError::Stalled {
                peer: self.peer,
                what: cmd.kind.describe(),
                waited: start.elapsed(),
            });
        }
        Err(GigeError::Timeout {
            peer: self.peer,
            what: cmd.kind.describe(),
            timeout: self.cfg.timeout,
            tries: self.cfg.tries.max(1),
        })
    }
}

/// A connection to one device's control channel. Cheap to share (`Arc` inside).
#[derive(Debug, Clone)]
pub struct GvcpClient {
    chan: Arc<Mutex<Channel>>,
    peer: SocketAddr,
}

impl GvcpClient {
    /// Open a control socket towards `device` (port normally 3956). Does not take control.
    pub fn connect(device: SocketAddr, cfg: ControlConfig) -> Result<Self> {
        let bind: SocketAddr = match device {
            SocketAddr::V4(_) => SocketAddrV4::new(Ipv4Addr::UNSPECIFIED, 0).into(),
            SocketAddr::V6(_) => {
                return Err(GigeError::InvalidArgument(
                    "GigE Vision is IPv4 only".into(),
                ))
            }
        };
        let sock = UdpSocket::bind(bind).map_err(|e| GigeError::io(bind, e))?;
        Ok(Self {
            chan: Arc::new(Mutex::new(Channel {
                sock,
                peer: device,
                req_id: 0,
                cfg,
            })),
            peer: device,
        })
    }

    /// Parse `host[:port]`; port defaults to 3956.
    pub fn parse_address(s: &str) -> Result<SocketAddr> {
        if let Ok(a) = s.parse::<SocketAddr>() {
            return Ok(a);
        }
        s.parse::<Ipv4Addr>()
            .map(|ip| SocketAddr::new(ip.into(), GVCP_PORT))
            .map_err(|_| {
                GigeError::InvalidArgument(format!(
                    "`{s}` is not an IPv4 address (optionally with :port)"
                ))
            })
    }

    /// The device's control address.
    pub fn peer(&self) -> SocketAddr {
        self.peer
    }

    /// Local address of the control socket.
    pub fn local_addr(&self) -> Result<SocketAddr> {
        let c = self.lock();
        c.sock.local_addr().map_err(|e| GigeError::io(c.peer, e))
    }

    fn lock(&self) -> MutexGuard<'_, Channel> {
        // A panic while holding the lock cannot leave the channel inconsistent.
        self.chan.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Read several 32-bit registers (one per command, so no concatenation capability needed).
    pub fn read_reg(&self, address: u32) -> Result<u32> {
        let ack = self.lock().transact(CommandKind::ReadReg(vec![address]))?;
        Ok(ack.readreg_values(1)?[0])
    }

    /// Write one 32-bit register.
    pub fn write_reg(&self, address: u32, value: u32) -> Result<()> {
        self.lock()
            .transact(CommandKind::WriteReg(vec![(address, value)]))?;
        Ok(())
    }

    /// Read `len` bytes of device memory starting at `address` (any length; split in blocks,
    /// rounded up to multiples of 4 on the wire and trimmed).
    pub fn read_mem(&self, address: u32, len: usize) -> Result<Vec<u8>> {
        let mut out = Vec::with_capacity(len);
        let mut chan = self.lock();
        let start = Instant::now();
        while out.len() < len {
            if start.elapsed() > MAX_BULK_READ {
                return Err(GigeError::Stalled {
                    peer: chan.peer,
                    what: format!(
                        "READMEM of {len} bytes at 0x{address:08x} ({} read)",
                        out.len()
                    ),
                    waited: start.elapsed(),
                });
            }
            let a = address.checked_add(out.len() as u32).ok_or_else(|| {
                GigeError::InvalidArgument(format!(
                    "read of {len} bytes at 0x{address:08x} wraps the address space"
                ))
            })?;
            let want = (len - out.len()).min(512);
            let count = want.div_ceil(4) * 4;
            let ack = chan.transact(CommandKind::ReadMem {
                address: a,
                count: count as u16,
            })?;
            let data = ack.readmem_data(a, count)?;
            out.extend_from_slice(&data[..want]);
        }
        Ok(out)
    }

    /// Write device memory (multiple of 4 bytes; split in blocks of at most 536 bytes).
    pub fn write_mem(&self, address: u32, data: &[u8]) -> Result<()> {
        if !data.len().is_multiple_of(4) {
            return Err(GigeError::InvalidArgument(format!(
                "WRITEMEM of {} bytes: must be a multiple of 4",
                data.len()
            )));
        }
        let mut chan = self.lock();
        for (i, chunk) in data.chunks(MAX_MEM_BLOCK - MAX_MEM_BLOCK % 4).enumerate() {
            let a = address + (i * (MAX_MEM_BLOCK - MAX_MEM_BLOCK % 4)) as u32;
            chan.transact(CommandKind::WriteMem {
                address: a,
                data: chunk.to_vec(),
            })?;
        }
        Ok(())
    }

    /// Read a NUL-terminated string register block.
    pub fn read_string(&self, address: u32, len: usize) -> Result<String> {
        Ok(gvcp::c_string(&self.read_mem(address, len)?))
    }

    /// Take control (CCP = control access), set the heartbeat timeout, and keep control alive
    /// with a heartbeat thread until the returned guard is dropped (which releases control).
    pub fn take_control(&self) -> Result<ControlGuard> {
        self.write_reg(reg::CCP, ccp::CONTROL)
            .map_err(|e| match e {
                GigeError::DeviceStatus { status: 0x8006, .. } => GigeError::ControlLost {
                    peer: self.peer,
                    detail: "another application has control (ACCESS_DENIED)".into(),
                },
                e => e,
            })?;
        let hb = self.lock().cfg.heartbeat_timeout;
        let ms = hb.as_millis().clamp(500, u128::from(u32::MAX)) as u32;
        if let Err(e) = self.write_reg(reg::HEARTBEAT_TIMEOUT, ms) {
            tracing::warn!("could not set the heartbeat timeout, keeping the device's: {e}");
        }
        let period = Duration::from_millis(u64::from(ms) / 3);
        let stop = Arc::new(AtomicBool::new(false));
        let lost = Arc::new(Mutex::new(None));
        let client = self.clone();
        let (stop2, lost2) = (stop.clone(), lost.clone());
        let thread = std::thread::Builder::new()
            .name("gvcp-heartbeat".into())
            .spawn(move || heartbeat(client, period, stop2, lost2))
            .map_err(|e| GigeError::io("heartbeat thread", e))?;
        Ok(ControlGuard {
            client: self.clone(),
            stop,
            lost,
            thread: Some(thread),
        })
    }
}

fn heartbeat(
    client: GvcpClient,
    period: Duration,
    stop: Arc<AtomicBool>,
    lost: Arc<Mutex<Option<String>>>,
) {
    let step = Duration::from_millis(20);
    let mut last = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(step);
        if last.elapsed() < period {
            continue;
        }
        last = Instant::now();
        let problem = match client.read_reg(reg::CCP) {
            Ok(v) if v & (ccp::CONTROL | ccp::EXCLUSIVE) != 0 => None,
            Ok(v) => Some(format!("CCP register reads 0x{v:08x} (no control bit)")),
            Err(e) => Some(format!("heartbeat failed: {e}")),
        };
        if let Some(p) = problem {
            tracing::warn!(peer = %client.peer, "{p}");
            *lost.lock().unwrap_or_else(|p| p.into_inner()) = Some(p);
            return;
        }
    }
}

/// Holds control of the device; dropping it stops the heartbeat and releases control.
#[derive(Debug)]
pub struct ControlGuard {
    client: GvcpClient,
    stop: Arc<AtomicBool>,
    lost: Arc<Mutex<Option<String>>>,
    thread: Option<JoinHandle<()>>,
}

impl ControlGuard {
    /// `Err(ControlLost)` when the heartbeat found that control is gone.
    pub fn check(&self) -> Result<()> {
        match &*self.lost.lock().unwrap_or_else(|p| p.into_inner()) {
            Some(detail) => Err(GigeError::ControlLost {
                peer: self.client.peer,
                detail: detail.clone(),
            }),
            None => Ok(()),
        }
    }
}

impl Drop for ControlGuard {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        if self.lost.lock().map(|l| l.is_none()).unwrap_or(false) {
            if let Err(e) = self.client.write_reg(reg::CCP, 0) {
                tracing::warn!("releasing control failed: {e}");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 16: a device that answers every request with PENDING_ACK (asking for more time,
    /// forever) gets an error after the command's hard ceiling, not an endless wait; so does
    /// one that floods acks for other requests.
    #[test]
    fn issue_16_a_device_that_always_pends_is_cut_off() {
        for flood in [false, true] {
            let dev = UdpSocket::bind("127.0.0.170:0").expect("bind the stalling device");
            let addr = dev.local_addr().expect("addr");
            dev.set_read_timeout(Some(Duration::from_millis(50)))
                .expect("timeout");
            let stop = Arc::new(AtomicBool::new(false));
            let stop2 = Arc::clone(&stop);
            let device = std::thread::spawn(move || {
                let mut buf = [0u8; 1500];
                let mut last: Option<(u16, SocketAddr)> = None;
                while !stop2.load(Ordering::Relaxed) {
                    if let Ok((n, from)) = dev.recv_from(&mut buf) {
                        if n >= 8 {
                            last = Some((u16::from_be_bytes([buf[6], buf[7]]), from));
                        }
                    }
                    if let Some((req_id, from)) = last {
                        let ack = Ack {
                            status: 0,
                            ack_code: if flood { 0x0081 } else { code::PENDING_ACK },
                            ack_id: if flood {
                                req_id.wrapping_add(7)
                            } else {
                                req_id
                            },
                            // PENDING_ACK: reserved(2) + time to completion (ms, 2).
                            payload: vec![0, 0, 0xFF, 0xFF],
                        };
                        let _ = dev.send_to(&ack.encode(), from);
                    }
                }
            });
            let cfg = ControlConfig {
                timeout: Duration::from_millis(100),
                tries: 3,
                max_command_wait: Duration::from_millis(1500),
                ..ControlConfig::default()
            };
            let client = GvcpClient::connect(addr, cfg).expect("socket");
            let t = Instant::now();
            let e = client
                .read_reg(reg::GVCP_CAPABILITY)
                .expect_err("never answered");
            let took = t.elapsed();
            stop.store(true, Ordering::Relaxed);
            device.join().expect("device thread");
            assert!(took < Duration::from_secs(3), "waited {took:?}");
            if flood {
                assert!(matches!(e, GigeError::Timeout { .. }), "{e}");
            } else {
                assert!(matches!(e, GigeError::Stalled { .. }), "{e}");
                assert!(e.to_string().contains("PENDING_ACK"), "{e}");
            }
        }
    }
}
