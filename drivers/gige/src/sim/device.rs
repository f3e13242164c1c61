//! GVCP server and GVSP streamer of the simulated camera.

use std::collections::{HashMap, VecDeque};
use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};

use super::FrameSource;
use crate::decode::pfnc;
use crate::error::{GigeError, Result};
use crate::gvcp::{self, cap, code, reg, Ack, Command, CommandKind};
use crate::gvsp::{self, Block, PartInfo};
use crate::udp_batch::{send_all, SEND_BATCH};

const XML_ADDRESS: u32 = 0x0010_0000;
const TEMPLATE: &str = include_str!("camera.xml");

// Feature registers (see camera.xml).
const WIDTH: u32 = 0xA000;
const HEIGHT: u32 = 0xA004;
const PIXEL_FORMAT: u32 = 0xA008;
const PAYLOAD_SIZE: u32 = 0xA00C;
const ACQ_MODE: u32 = 0xA010;
const ACQ_START: u32 = 0xA014;
const ACQ_STOP: u32 = 0xA018;
const TL_LOCKED: u32 = 0xA01C;
const SENSOR_WIDTH: u32 = 0xA020;
const SENSOR_HEIGHT: u32 = 0xA024;
const DISTANCE_UNIT: u32 = 0xA028;
const COORD_SYSTEM: u32 = 0xA02C;
const OUTPUT_MODE: u32 = 0xA030;
const COORD_SELECTOR: u32 = 0xA034;
const INVALID_FLAG: u32 = 0xA038;
const COMPONENT_SELECTOR: u32 = 0xA03C;
const COMPONENT_ENABLE: u32 = 0xA040;
const COMPONENT_ID: u32 = 0xA044;
const FLOAT_BASE: u32 = 0xA100; // 8-byte doubles: scale, offset, invalid, focal, pu, pv, aspect ratio, rate
/// `ComponentIDValue`s (the multi-part data purpose ids, and the chunk ids of a chunk payload).
const ID_INTENSITY: u32 = 1;
const ID_RANGE: u32 = 4;
const ID_CONFIDENCE: u32 = 6;
const C16_SCALE_MM: f64 = 0.1;

/// Simulator settings.
#[derive(Debug, Clone, PartialEq)]
pub struct SimOptions {
    /// Manufacturer name in the bootstrap registers and XML.
    pub vendor: String,
    /// Model name.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// Device version (firmware).
    pub version: String,
    /// Fraction of GVSP packets dropped on first transmission (0 = none).
    pub loss_ratio: f64,
    /// Frames per second while acquiring.
    pub frame_rate: f64,
    /// Pace packets to this many bits per second (`None` = as fast as the socket takes them).
    pub bandwidth_bps: Option<f64>,
    /// Seed of the loss injection.
    pub seed: u64,
    /// Describe and stream like a given vendor's camera does (default: by SFNC's letter).
    pub habits: VendorHabits,
}

/// Ways real cameras describe themselves and stream that differ from SFNC's letter, which the
/// simulated camera can imitate so the driver meets them on the wire.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct VendorHabits {
    /// `TLParamsLocked` is a Boolean (five Allied Vision cameras do so) instead of an Integer.
    pub tl_params_locked_boolean: bool,
    /// Offers an Intensity component (Mono16, `ComponentIDValue` 1, enabled from power-on) and
    /// sends it as the first part of a multi-part payload, before Range; without multi-part it
    /// streams the intensity image alone (Photoneo sends its other components as chunks then,
    /// which this simulator leaves out).
    pub intensity_first: bool,
    /// Streams chunk data only (GVSP payload type 0x0004): Range, and Intensity / Confidence
    /// when enabled, each a chunk whose id is its `ComponentIDValue` (Photoneo's other mode).
    pub chunk_only: bool,
    /// No `Scan3dCoordinateSelector`: one `Scan3dCoordinateScale`/`Offset` for the camera
    /// (Nerian's SceneScan/Scarlet description).
    pub no_coordinate_selector: bool,
    /// No `Scan3dDistanceUnit` (Nerian's description).
    pub no_distance_unit: bool,
    /// Publishes `Scan3dAspectRatio`, the frame source's
    /// ([`FrameSource::aspect_ratio`](super::FrameSource::aspect_ratio)).
    pub aspect_ratio: bool,
    /// `Scan3dOutputMode` is `ProjectedC`: depth values that need the camera's coordinate maps.
    pub projected_c: bool,
}

impl Default for SimOptions {
    fn default() -> Self {
        Self {
            vendor: "handeye".into(),
            model: "SimCam3D".into(),
            serial: "SIM0001".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            loss_ratio: 0.0,
            frame_rate: 10.0,
            bandwidth_bps: None,
            seed: 1,
            habits: VendorHabits::default(),
        }
    }
}

impl SimOptions {
    /// Whether the numbers are usable (the streaming thread turns them into durations): a
    /// loss ratio in [0, 1), a frame rate of 0.01–1000 per second, a bandwidth of at least
    /// 1 Mbit/s and finite.
    pub fn check(&self) -> std::result::Result<(), String> {
        if !(0.0..1.0).contains(&self.loss_ratio) {
            return Err(format!("loss ratio {} is not in [0, 1)", self.loss_ratio));
        }
        if !(self.frame_rate.is_finite() && (0.01..=1000.0).contains(&self.frame_rate)) {
            return Err(format!(
                "frame rate {} is not within 0.01–1000 frames/s",
                self.frame_rate
            ));
        }
        if let Some(bps) = self.bandwidth_bps {
            if !(bps.is_finite() && bps >= 1e6) {
                return Err(format!(
                    "bandwidth {bps} bit/s is not a finite rate of at least 1 Mbit/s"
                ));
            }
        }
        Ok(())
    }
}

/// What the simulator did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct SimStats {
    /// Frames streamed.
    pub frames: u64,
    /// Packets dropped on purpose.
    pub dropped_packets: u64,
    /// Packets sent again on request.
    pub resent_packets: u64,
    /// GVCP commands handled.
    pub commands: u64,
    /// With `bandwidth_bps`: microseconds of send schedule given up because the streamer
    /// was held up past its catch-up window (a busy host), so the rate fell short by that.
    pub pacing_lag_us: u64,
    /// With `bandwidth_bps`: microseconds the link sat idle between back-to-back frames
    /// because the next frame was not rendered yet (includes the first frame of each start).
    pub render_wait_us: u64,
}

/// Shortest and longest heartbeat timeout the simulated camera accepts, ms.
const MIN_HEARTBEAT_MS: u32 = 500;
const MAX_HEARTBEAT_MS: u32 = 600_000;

#[derive(Debug)]
struct State {
    regs: HashMap<u32, u32>,
    strings: Vec<(u32, usize, Vec<u8>)>,
    xml: Vec<u8>,
    sensor: (u32, u32),
    intrinsics: (f64, f64, f64),
    controller: Option<SocketAddr>,
    last_heartbeat: Instant,
    acquiring: bool,
    confidence_enabled: bool,
    intensity_enabled: bool,
    habits: VendorHabits,
    aspect_ratio: f64,
    history: VecDeque<(u64, Arc<Vec<Vec<u8>>>)>,
    /// PACKETRESEND answers waiting for the streamer (sent within the paced bandwidth).
    resends: VecDeque<(SocketAddr, Vec<u8>)>,
    stats: SimStats,
    frame_rate: f64,
    /// Served through a GenTL producer ([`SimDevice`](super::SimDevice)): the transport
    /// delivers every enabled component as a multi-part buffer, no SCCFG switch needed.
    gentl: bool,
}

impl State {
    fn reg(&self, a: u32) -> u32 {
        self.regs.get(&a).copied().unwrap_or(0)
    }

    /// Multi-part payloads: enabled by the host (SCCFG multi-part, extended ids), unless the
    /// camera streams chunk data only.
    fn multipart(&self) -> bool {
        !self.habits.chunk_only
            && (self.gentl
                || (self.reg(reg::SCCFG0) & 0x40 != 0
                    && self.reg(reg::GVSP_CONFIG) & 0x4000_0000 != 0))
    }

    /// Streams the intensity image alone (no multi-part, no chunks).
    fn intensity_only(&self) -> bool {
        self.habits.intensity_first
            && self.intensity_enabled
            && !self.multipart()
            && !self.habits.chunk_only
    }

    fn payload_size(&self) -> u32 {
        let (w, h) = (self.reg(WIDTH), self.reg(HEIGHT));
        let plane = u64::from(w) * u64::from(h) * 2;
        if self.intensity_only() {
            return u32::try_from(plane).unwrap_or(u32::MAX);
        }
        let main = gvsp::image_bytes(self.reg(PIXEL_FORMAT), w, h, 0);
        let components = self.multipart() || self.habits.chunk_only;
        let extra = [self.confidence_enabled, self.intensity_enabled]
            .iter()
            .filter(|&&on| on && components)
            .count() as u64;
        let chunks = if self.habits.chunk_only {
            8 * (1 + extra)
        } else {
            0
        };
        u32::try_from(main + extra * plane + chunks).unwrap_or(u32::MAX)
    }

    fn float(&self, a: u32) -> Option<f64> {
        if !(FLOAT_BASE..FLOAT_BASE + 0x40).contains(&a) {
            return None;
        }
        let c16 = self.reg(PIXEL_FORMAT) == pfnc::COORD3D_C16;
        // Without a selector the one scale/offset pair is the depth's.
        let coord = if self.habits.no_coordinate_selector {
            2
        } else {
            self.reg(COORD_SELECTOR)
        };
        let (f, pu, pv) = self.intrinsics;
        let (w, h) = (self.reg(WIDTH), self.reg(HEIGHT));
        // The ROI is centred in the sensor: shift the principal point.
        let ox = f64::from((self.sensor.0 - w) / 2);
        let oy = f64::from((self.sensor.1 - h) / 2);
        Some(match (a - FLOAT_BASE) / 8 {
            0 => {
                if c16 && coord == 2 {
                    C16_SCALE_MM
                } else {
                    1.0
                }
            }
            1 => 0.0,
            2 => {
                if c16 {
                    0.0
                } else {
                    f64::NAN
                }
            }
            3 => f,
            4 => pu - ox,
            5 => pv - oy,
            6 => self.aspect_ratio,
            7 => self.frame_rate,
            _ => 0.0,
        })
    }

    /// Read one big-endian 32-bit word.
    fn read_word(&self, a: u32) -> Option<u32> {
        if !a.is_multiple_of(4) {
            return None;
        }
        for (base, len, bytes) in &self.strings {
            if (*base..*base + *len as u32).contains(&a) {
                let o = (a - base) as usize;
                let b = |i: usize| bytes.get(o + i).copied().unwrap_or(0);
                return Some(u32::from_be_bytes([b(0), b(1), b(2), b(3)]));
            }
        }
        if (XML_ADDRESS..XML_ADDRESS + self.xml.len() as u32 + 4).contains(&a) {
            let o = (a - XML_ADDRESS) as usize;
            let b = |i: usize| self.xml.get(o + i).copied().unwrap_or(0);
            return Some(u32::from_be_bytes([b(0), b(1), b(2), b(3)]));
        }
        if let Some(x) = self.float(a & !7) {
            let bits = x.to_bits();
            return Some(if a.is_multiple_of(8) {
                (bits >> 32) as u32
            } else {
                bits as u32
            });
        }
        match a {
            PAYLOAD_SIZE => Some(self.payload_size()),
            OUTPUT_MODE if self.habits.projected_c => Some(2),
            OUTPUT_MODE => Some(u32::from(self.reg(PIXEL_FORMAT) == pfnc::COORD3D_C16)),
            COMPONENT_ENABLE => Some(match self.reg(COMPONENT_SELECTOR) {
                0 => 1,
                1 => u32::from(self.confidence_enabled),
                _ => u32::from(self.intensity_enabled),
            }),
            COMPONENT_ID => Some(match self.reg(COMPONENT_SELECTOR) {
                0 => ID_RANGE,
                1 => ID_CONFIDENCE,
                _ => ID_INTENSITY,
            }),
            _ => self.regs.get(&a).copied(),
        }
    }

    /// Write one register; Err(status) on refusal.
    fn write_word(&mut self, a: u32, v: u32) -> std::result::Result<(), u16> {
        let locked = self.reg(TL_LOCKED) != 0 || self.acquiring;
        match a {
            WIDTH | HEIGHT => {
                let max = if a == WIDTH {
                    self.sensor.0
                } else {
                    self.sensor.1
                };
                if locked {
                    return Err(0x8004);
                }
                if !(16..=max).contains(&v) {
                    return Err(0x8002);
                }
            }
            PIXEL_FORMAT => {
                if locked {
                    return Err(0x8004);
                }
                if v != pfnc::COORD3D_ABC32F && v != pfnc::COORD3D_C16 {
                    return Err(0x8002);
                }
            }
            ACQ_MODE if v > 1 => return Err(0x8002),
            ACQ_START => {
                if self.reg(reg::SCP0) & 0xFFFF == 0 {
                    tracing::warn!("AcquisitionStart without a stream channel");
                }
                self.acquiring = true;
                return Ok(());
            }
            ACQ_STOP => {
                self.acquiring = false;
                return Ok(());
            }
            COORD_SELECTOR if v > 2 => return Err(0x8002),
            COMPONENT_SELECTOR if v > 2 || (v == 2 && !self.habits.intensity_first) => {
                return Err(0x8002)
            }
            COMPONENT_ENABLE => {
                match self.reg(COMPONENT_SELECTOR) {
                    0 => return if v == 1 { Ok(()) } else { Err(0x8002) },
                    1 => self.confidence_enabled = v != 0,
                    _ => self.intensity_enabled = v != 0,
                }
                return Ok(());
            }
            TL_LOCKED | ACQ_MODE | COORD_SELECTOR | COMPONENT_SELECTOR => {}
            // The standard allows any 32-bit value (49.7 days): a client that dies would hold
            // the camera that long. Like cameras that bound it, 0.5 s to 10 min.
            reg::HEARTBEAT_TIMEOUT if !(MIN_HEARTBEAT_MS..=MAX_HEARTBEAT_MS).contains(&v) => {
                return Err(0x8002)
            }
            reg::SCPS0 => {
                let size = v & 0xFFFF;
                if !(576..=16_000).contains(&size) {
                    return Err(0x8002);
                }
                self.regs.insert(a, size);
                return Ok(());
            }
            reg::SCP0 => {
                self.regs.insert(a, v & 0xFFFF);
                if v & 0xFFFF == 0 {
                    self.acquiring = false;
                }
                return Ok(());
            }
            reg::SCCFG0 => {
                self.regs.insert(a, v & 0x40);
                return Ok(());
            }
            reg::GVSP_CONFIG => {
                self.regs.insert(a, v & 0x4000_0000);
                return Ok(());
            }
            reg::TIMESTAMP_CONTROL => return Ok(()),
            reg::HEARTBEAT_TIMEOUT | reg::SCPD0 | reg::SCDA0 | reg::GVCP_CONFIG => {}
            _ if self.read_word(a).is_some() => return Err(0x8004),
            _ => return Err(0x8003),
        }
        self.regs.insert(a, v);
        Ok(())
    }
}

impl State {
    /// The registers, strings and XML of a camera with a `sensor`-sized frame source of
    /// `intrinsics` and `aspect_ratio`, at `ip` streaming from `stream_port`.
    fn new(
        opts: &SimOptions,
        sensor: (u32, u32),
        intrinsics: (f64, f64, f64),
        aspect_ratio: f64,
        ip: Ipv4Addr,
        stream_port: u16,
    ) -> Self {
        let xml = xml_for(opts).into_bytes();
        let mut regs = HashMap::new();
        let mac = [
            0x02,
            0x00,
            ip.octets()[0],
            ip.octets()[1],
            ip.octets()[2],
            ip.octets()[3],
        ];
        let url = format!("Local:handeye-sim.xml;{XML_ADDRESS:x};{:x}", xml.len());
        for (a, v) in [
            (reg::VERSION, 0x0002_0001),
            (reg::DEVICE_MODE, 0x8000_0001),
            (
                reg::MAC_HIGH,
                u32::from(u16::from_be_bytes([mac[0], mac[1]])),
            ),
            (
                reg::MAC_LOW,
                u32::from_be_bytes([mac[2], mac[3], mac[4], mac[5]]),
            ),
            (reg::SUPPORTED_IP_CONFIG, 0x7),
            (reg::CURRENT_IP_CONFIG, 0x1),
            (reg::CURRENT_IP, u32::from(ip)),
            (reg::SUBNET_MASK, 0xFF00_0000),
            (reg::GATEWAY, 0),
            (reg::NUM_INTERFACES, 1),
            (reg::LINK_SPEED, 1000),
            (reg::NUM_MESSAGE_CHANNELS, 0),
            (reg::NUM_STREAM_CHANNELS, 1),
            (reg::GVSP_CAPABILITY, 0xC000_0000),
            (
                reg::GVCP_CAPABILITY,
                cap::USER_NAME
                    | cap::SERIAL_NUMBER
                    | cap::PACKET_RESEND
                    | cap::WRITEMEM
                    | cap::CONCATENATION,
            ),
            (reg::HEARTBEAT_TIMEOUT, 3000),
            (reg::TICK_FREQ_HIGH, 0),
            (reg::TICK_FREQ_LOW, 1_000_000_000),
            (reg::TIMESTAMP_CONTROL, 0),
            (reg::TIMESTAMP_HIGH, 0),
            (reg::TIMESTAMP_LOW, 0),
            (reg::GVCP_CONFIG, 0),
            (reg::GVSP_CONFIG, 0),
            (reg::CCP, 0),
            (reg::SCP0, 0),
            (reg::SCPS0, 1500),
            (reg::SCPD0, 0),
            (reg::SCDA0, 0),
            (reg::SCSP0, u32::from(stream_port)),
            (reg::SCC0, 0x40),
            (reg::SCCFG0, 0),
            (WIDTH, sensor.0),
            (HEIGHT, sensor.1),
            (PIXEL_FORMAT, pfnc::COORD3D_ABC32F),
            (ACQ_MODE, 0),
            (ACQ_START, 0),
            (ACQ_STOP, 0),
            (TL_LOCKED, 0),
            (SENSOR_WIDTH, sensor.0),
            (SENSOR_HEIGHT, sensor.1),
            (DISTANCE_UNIT, 0),
            (COORD_SYSTEM, 0),
            (COORD_SELECTOR, 2),
            (INVALID_FLAG, 1),
            (COMPONENT_SELECTOR, 0),
        ] {
            regs.insert(a, v);
        }
        let s = |t: &str| t.as_bytes().to_vec();
        let mut url_bytes = s(&url);
        url_bytes.push(0);
        let strings = vec![
            (reg::MANUFACTURER, 32, s(&opts.vendor)),
            (reg::MODEL, 32, s(&opts.model)),
            (reg::DEVICE_VERSION, 32, s(&opts.version)),
            (
                reg::MANUFACTURER_INFO,
                48,
                s("simulated GigE Vision 3D camera"),
            ),
            (reg::SERIAL, 16, s(&opts.serial)),
            (reg::USER_NAME, 16, s("")),
            (reg::FIRST_URL, 512, url_bytes.clone()),
            (reg::SECOND_URL, 512, url_bytes),
        ];
        State {
            regs,
            strings,
            xml,
            sensor,
            intrinsics,
            controller: None,
            last_heartbeat: Instant::now(),
            acquiring: false,
            confidence_enabled: false,
            intensity_enabled: opts.habits.intensity_first,
            habits: opts.habits.clone(),
            aspect_ratio,
            history: VecDeque::new(),
            resends: VecDeque::new(),
            stats: SimStats::default(),
            frame_rate: opts.frame_rate,
            gentl: false,
        }
    }
}

/// A running simulated camera. Dropping it stops its threads.
#[derive(Debug)]
pub struct SimCamera {
    addr: SocketAddr,
    state: Arc<Mutex<State>>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

fn lock(s: &Mutex<State>) -> MutexGuard<'_, State> {
    s.lock().unwrap_or_else(|p| p.into_inner())
}

fn xml_for(opts: &SimOptions) -> String {
    let esc = |s: &str| {
        s.replace('&', "&amp;")
            .replace('<', "&lt;")
            .replace('"', "&quot;")
    };
    let mut xml = TEMPLATE
        .replace("@MODEL@", &esc(&opts.model))
        .replace("@VENDOR@", &esc(&opts.vendor));
    let h = &opts.habits;
    if h.intensity_first {
        xml = xml.replace(
            "<pValue>ComponentSelectorReg</pValue>",
            r#"<EnumEntry Name="Intensity" NameSpace="Standard">
      <Value>2</Value>
    </EnumEntry>
    <pValue>ComponentSelectorReg</pValue>"#,
        );
    }
    if h.projected_c {
        xml = xml.replace(
            "<pValue>Scan3dOutputModeReg</pValue>",
            r#"<EnumEntry Name="ProjectedC" NameSpace="Standard">
      <Value>2</Value>
    </EnumEntry>
    <pValue>Scan3dOutputModeReg</pValue>"#,
        );
    }
    if h.no_distance_unit {
        xml = remove_feature(&xml, "Enumeration", "Scan3dDistanceUnit");
    }
    if h.no_coordinate_selector {
        xml = remove_feature(&xml, "Enumeration", "Scan3dCoordinateSelector");
    }
    if h.aspect_ratio {
        xml = xml
            .replace(
                "<pFeature>Scan3dPrincipalPointV</pFeature>",
                "<pFeature>Scan3dPrincipalPointV</pFeature>\n    <pFeature>Scan3dAspectRatio</pFeature>",
            )
            .replace(
                "</RegisterDescription>",
                r#"  <FloatReg Name="Scan3dAspectRatio" NameSpace="Standard">
    <Address>0xA130</Address>
    <Length>8</Length>
    <AccessMode>RO</AccessMode>
    <pPort>Device</pPort>
    <Endianess>BigEndian</Endianess>
  </FloatReg>
</RegisterDescription>"#,
            );
    }
    if h.tl_params_locked_boolean {
        xml = xml.replace(
            TL_LOCKED_INTEGER,
            r#"<Boolean Name="TLParamsLocked" NameSpace="Standard">
    <Visibility>Invisible</Visibility>
    <pValue>TLParamsLockedReg</pValue>
    <OnValue>1</OnValue>
    <OffValue>0</OffValue>
  </Boolean>"#,
        );
    }
    xml
}

/// `xml` without the `kind` node `name` and the references to it.
fn remove_feature(xml: &str, kind: &str, name: &str) -> String {
    let open = format!("<{kind} Name=\"{name}\"");
    let close = format!("</{kind}>");
    let mut out = xml.replace(&format!("<pFeature>{name}</pFeature>"), "");
    if let Some(start) = out.find(&open) {
        if let Some(len) = out[start..].find(&close) {
            out.replace_range(start..start + len + close.len(), "");
        }
    }
    out
}

/// SFNC's `TLParamsLocked` in the template (replaced by a vendor's habit).
const TL_LOCKED_INTEGER: &str = r#"<Integer Name="TLParamsLocked" NameSpace="Standard">
    <Visibility>Invisible</Visibility>
    <pValue>TLParamsLockedReg</pValue>
    <Min>0</Min>
    <Max>1</Max>
  </Integer>"#;

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

/// What the streamer needs to know about the device settings; a frame prepared under other
/// settings is dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct StreamSettings {
    scps: usize,
    ext: bool,
    mp: bool,
    /// Chunk-only payload.
    chunks: bool,
    /// Components sent beside Range (in multi-part or chunk payloads).
    confidence: bool,
    intensity: bool,
    /// The intensity image alone.
    intensity_only: bool,
    w: u32,
    h: u32,
    pf: u32,
}

impl StreamSettings {
    fn read(s: &State) -> Self {
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

fn stream(
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
const MAX_QUEUED_RESENDS: usize = 1 << 16;

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

/// Crop the source cloud to the centred `w × h` ROI and encode it in `pf` (mm on the wire).
/// The block id is filled in when the frame is sent; `data`/`conf` are reused buffers.
fn make_block(
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
        ..
    } = *settings;
    let (cw, ch) = (cloud.width as usize, cloud.height as usize);
    let ox = cw.saturating_sub(w as usize) / 2;
    let oy = ch.saturating_sub(h as usize) / 2;
    let c16 = pf == pfnc::COORD3D_C16;
    let n = (w * h) as usize;
    data.clear();
    data.reserve(n * if c16 { 2 } else { 12 });
    conf.clear();
    conf.reserve(if confidence { n * 2 } else { 0 });
    let mut gray = Vec::with_capacity(if intensity { n * 2 } else { 0 });
    for v in 0..h as usize {
        for u in 0..w as usize {
            let i = (oy + v) * cw + ox + u;
            let p = cloud.points.get(i).copied();
            let valid = p.is_some_and(|p| p.coords.iter().all(|c| c.is_finite()) && i < cw * ch);
            if c16 {
                let raw = match p.filter(|_| valid) {
                    Some(p) => (f64::from(p.z) * 1000.0 / C16_SCALE_MM)
                        .round()
                        .clamp(1.0, 65535.0) as u16,
                    None => 0,
                };
                data.extend_from_slice(&raw.to_le_bytes());
            } else {
                let mm = match p.filter(|_| valid) {
                    Some(p) => [p.x * 1000.0, p.y * 1000.0, p.z * 1000.0],
                    None => [f32::NAN; 3],
                };
                for c in mm {
                    data.extend_from_slice(&c.to_le_bytes());
                }
            }
            if intensity {
                // A grey level falling with distance (what a structured-light camera's
                // intensity image roughly shows); 0 where nothing was measured.
                let g = p
                    .filter(|_| valid)
                    .map_or(0, |p| (65535.0 / (1.0 + f64::from(p.z))).round() as u16);
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
    Block {
        block_id: 1,
        timestamp,
        parts,
        multipart: mp,
    }
}

/// The simulated camera's device side without a transport: the registers and GenApi XML
/// [`SimCamera`] serves over GVCP, read and written as a GenTL producer's remote-device port
/// reads and writes them, and frames encoded as the parts of a multi-part buffer (Range, then
/// Confidence when `ComponentEnable[Confidence]` is set; Intensity first with
/// [`VendorHabits::intensity_first`]). The GigE Vision bootstrap registers stay readable; no
/// transport uses them.
#[derive(Debug)]
pub struct SimDevice {
    state: Mutex<State>,
    t0: Instant,
}

/// Why the simulated device refused a register access.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PortError {
    /// No register at the address, or an access not aligned to 4 bytes.
    #[error("no register at that address (or not a 4-byte aligned access)")]
    InvalidAddress,
    /// A read-only register, or one locked while acquiring / `TLParamsLocked`.
    #[error("the register is read-only, or locked while acquiring")]
    AccessDenied,
    /// A value the register does not take.
    #[error("the register does not take that value")]
    InvalidValue,
}

impl SimDevice {
    /// The device for frames of `source`'s size and lens (at least 16×16 pixels).
    pub fn new(source: &dyn FrameSource, opts: &SimOptions) -> Result<Self> {
        opts.check().map_err(GigeError::InvalidArgument)?;
        let sensor = source.size();
        if sensor.0 < 16 || sensor.1 < 16 {
            return Err(GigeError::InvalidArgument(format!(
                "frame source size {sensor:?} is below 16x16"
            )));
        }
        let mut state = State::new(
            opts,
            sensor,
            source.intrinsics(),
            source.aspect_ratio(),
            Ipv4Addr::LOCALHOST,
            0,
        );
        state.gentl = true;
        Ok(Self {
            state: Mutex::new(state),
            t0: Instant::now(),
        })
    }

    /// Where the GenApi XML is: `Local:handeye-sim.xml;ADDRESS;LENGTH` (hex), readable with
    /// [`read`](Self::read).
    pub fn xml_url(&self) -> String {
        let s = lock(&self.state);
        format!("Local:handeye-sim.xml;{XML_ADDRESS:x};{:x}", s.xml.len())
    }

    /// Read `buf.len()` bytes from `address` (registers are big-endian 32-bit words; any
    /// alignment and length inside them).
    pub fn read(&self, address: u64, buf: &mut [u8]) -> std::result::Result<(), PortError> {
        let end = address
            .checked_add(buf.len() as u64)
            .filter(|&e| e <= u64::from(u32::MAX))
            .ok_or(PortError::InvalidAddress)?;
        let s = lock(&self.state);
        let mut word_at = address & !3;
        while word_at < end {
            let w = s
                .read_word(word_at as u32)
                .ok_or(PortError::InvalidAddress)?
                .to_be_bytes();
            for (k, b) in w.iter().enumerate() {
                let a = word_at + k as u64;
                if (address..end).contains(&a) {
                    buf[(a - address) as usize] = *b;
                }
            }
            word_at += 4;
        }
        Ok(())
    }

    /// Write `data` (whole big-endian 32-bit words) at `address`, word by word as GVCP
    /// WRITEREG does; stops at the first refused word.
    pub fn write(&self, address: u64, data: &[u8]) -> std::result::Result<(), PortError> {
        if !address.is_multiple_of(4) || !data.len().is_multiple_of(4) || data.is_empty() {
            return Err(PortError::InvalidAddress);
        }
        let mut s = lock(&self.state);
        for (i, c) in data.chunks_exact(4).enumerate() {
            let a = address
                .checked_add(4 * i as u64)
                .and_then(|a| u32::try_from(a).ok())
                .ok_or(PortError::InvalidAddress)?;
            s.write_word(a, u32::from_be_bytes([c[0], c[1], c[2], c[3]]))
                .map_err(|status| match status {
                    0x8004 => PortError::AccessDenied,
                    0x8002 => PortError::InvalidValue,
                    _ => PortError::InvalidAddress,
                })?;
        }
        Ok(())
    }

    /// Bytes of one frame's parts under the current settings (the `PayloadSize` register).
    pub fn payload_size(&self) -> u64 {
        u64::from(lock(&self.state).payload_size())
    }

    /// Whether `AcquisitionStart` was executed (and neither `AcquisitionStop` nor a single
    /// frame's delivery ended it).
    pub fn is_acquiring(&self) -> bool {
        lock(&self.state).acquiring
    }

    /// Frames per second while acquiring (`AcquisitionFrameRate`).
    pub fn frame_rate(&self) -> f64 {
        lock(&self.state).frame_rate
    }

    /// Encode `cloud` (the frame source's, metres) as the current settings ask (ROI, pixel
    /// format, enabled components), timestamped in ns since the device was made, and count it
    /// delivered: in `SingleFrame` mode acquisition ends with it.
    pub fn encode(&self, cloud: &handeye_hal::PointCloud) -> Block {
        let settings = StreamSettings::read(&lock(&self.state));
        let ts = self.t0.elapsed().as_nanos() as u64;
        let block = make_block(cloud, ts, &settings, (Vec::new(), Vec::new()));
        let mut s = lock(&self.state);
        s.stats.frames += 1;
        if s.reg(ACQ_MODE) == 1 {
            s.acquiring = false;
        }
        block
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The transport-free device a GenTL producer serves: the XML at its URL, registers at
    /// any alignment, refusals as errors, and multi-part frames without any SCCFG switch.
    #[test]
    fn sim_device_serves_registers_and_multipart_frames_without_a_transport() {
        let mut source = super::super::SceneSource::new(64, 48);
        let dev = SimDevice::new(&source, &SimOptions::default()).expect("device");
        let url = dev.xml_url();
        let fields: Vec<&str> = url.split(';').collect();
        let (addr, len) = (
            u64::from_str_radix(fields[1], 16).expect("hex address"),
            usize::from_str_radix(fields[2], 16).expect("hex length"),
        );
        let mut xml = vec![0u8; len];
        dev.read(addr, &mut xml).expect("xml");
        assert_eq!(xml, SimCamera::xml(&SimOptions::default()).into_bytes());
        let mut b = [0u8; 2];
        dev.read(u64::from(WIDTH) + 2, &mut b).expect("unaligned");
        assert_eq!(b, [0, 64]);
        assert_eq!(
            dev.write(0xDEAD_0000, &[0; 4]),
            Err(PortError::InvalidAddress)
        );
        // Addresses at the end of the 64-bit space are refused, not wrapped.
        assert_eq!(
            dev.write(u64::MAX - 3, &[0; 8]),
            Err(PortError::InvalidAddress)
        );
        assert_eq!(
            dev.read(u64::MAX - 1, &mut [0; 4]),
            Err(PortError::InvalidAddress)
        );
        assert_eq!(
            dev.write(u64::from(PIXEL_FORMAT), &7u32.to_be_bytes()),
            Err(PortError::InvalidValue)
        );
        dev.write(u64::from(COMPONENT_SELECTOR), &1u32.to_be_bytes())
            .expect("select Confidence");
        dev.write(u64::from(COMPONENT_ENABLE), &1u32.to_be_bytes())
            .expect("enable it");
        assert_eq!(dev.payload_size(), 64 * 48 * (12 + 2));
        dev.write(u64::from(ACQ_START), &1u32.to_be_bytes())
            .expect("start");
        assert!(dev.is_acquiring());
        assert_eq!(
            dev.write(u64::from(WIDTH), &32u32.to_be_bytes()),
            Err(PortError::AccessDenied)
        );
        let block = dev.encode(&source.next_frame().expect("frame"));
        let kinds: Vec<(u16, u32, u16, usize)> = block
            .parts
            .iter()
            .map(|(i, d)| (i.data_type, i.pixel_format, i.purpose, d.len()))
            .collect();
        assert_eq!(
            kinds,
            [
                (gvsp::PART_3D_IMAGE, pfnc::COORD3D_ABC32F, 4, 64 * 48 * 12),
                (gvsp::PART_CONFIDENCE, pfnc::CONFIDENCE16, 6, 64 * 48 * 2),
            ]
        );
    }

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
