//! The simulated camera's device side: its registers (bootstrap, features, the GenApi XML)
//! and the state the GVCP server, the streamer and [`SimDevice`](super::SimDevice) share.

use std::collections::{HashMap, VecDeque};
use std::net::{Ipv4Addr, SocketAddr};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use super::habits::{xml_for, VendorHabits};
use crate::decode::pfnc;
use crate::gvcp::{cap, reg};
use crate::gvsp;

pub(super) const XML_ADDRESS: u32 = 0x0010_0000;

// Feature registers (see camera.xml).
pub(super) const WIDTH: u32 = 0xA000;
pub(super) const HEIGHT: u32 = 0xA004;
pub(super) const PIXEL_FORMAT: u32 = 0xA008;
pub(super) const PAYLOAD_SIZE: u32 = 0xA00C;
pub(super) const ACQ_MODE: u32 = 0xA010;
pub(super) const ACQ_START: u32 = 0xA014;
pub(super) const ACQ_STOP: u32 = 0xA018;
pub(super) const TL_LOCKED: u32 = 0xA01C;
pub(super) const SENSOR_WIDTH: u32 = 0xA020;
pub(super) const SENSOR_HEIGHT: u32 = 0xA024;
pub(super) const DISTANCE_UNIT: u32 = 0xA028;
pub(super) const COORD_SYSTEM: u32 = 0xA02C;
pub(super) const OUTPUT_MODE: u32 = 0xA030;
pub(super) const COORD_SELECTOR: u32 = 0xA034;
pub(super) const INVALID_FLAG: u32 = 0xA038;
pub(super) const COMPONENT_SELECTOR: u32 = 0xA03C;
pub(super) const COMPONENT_ENABLE: u32 = 0xA040;
pub(super) const COMPONENT_ID: u32 = 0xA044;
pub(super) const TRIGGER_MODE: u32 = 0xA048;
pub(super) const TRIGGER_SOURCE: u32 = 0xA04C;
pub(super) const TRIGGER_SOFTWARE: u32 = 0xA050;
pub(super) const TRIGGER_SELECTOR: u32 = 0xA054;
/// `UserSetSelector` (0 Default: the power-on pixel format; 1 UserSet1: saved with
/// Coord3D_C16) and `UserSetLoad`.
pub(super) const USER_SET_SELECTOR: u32 = 0xA058;
pub(super) const USER_SET_LOAD: u32 = 0xA05C;
/// `GenDCStreamingMode` ([`VendorHabits::gendc`]).
pub(super) const GENDC_MODE: u32 = 0xA060;
/// 8-byte doubles: scale, offset, invalid, focal, pu, pv, aspect ratio, rate, vertical focal.
pub(super) const FLOAT_BASE: u32 = 0xA100;
const FLOATS: u32 = 9;
/// `ComponentIDValue`s (the multi-part data purpose ids, and the chunk ids of a chunk payload).
pub(super) const ID_INTENSITY: u32 = 1;
pub(super) const ID_RANGE: u32 = 4;
pub(super) const ID_CONFIDENCE: u32 = 6;
/// Chunk ids of the chunk-data part ([`VendorHabits::chunk_part`]): the frame counter and
/// the intrinsics (f, cu, cv as big-endian f64), metadata the decoder does not need.
pub(super) const CHUNK_FRAME_ID: u32 = 0x4000_0001;
pub(super) const CHUNK_INTRINSICS: u32 = 0x4000_0002;
/// Bytes of the chunk-data part: a u64 frame counter and three f64, each with its 8-byte tag.
pub(super) const CHUNK_PART_BYTES: u64 = 8 + 8 + 24 + 8;
/// Most software triggers a camera holds before it has sent their frames.
const MAX_PENDING_TRIGGERS: u32 = 16;

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
pub(super) const MIN_HEARTBEAT_MS: u32 = 500;
pub(super) const MAX_HEARTBEAT_MS: u32 = 600_000;

#[derive(Debug)]
pub(super) struct State {
    pub(super) regs: HashMap<u32, u32>,
    pub(super) strings: Vec<(u32, usize, Vec<u8>)>,
    pub(super) xml: Vec<u8>,
    pub(super) sensor: (u32, u32),
    pub(super) intrinsics: (f64, f64, f64),
    pub(super) controller: Option<SocketAddr>,
    pub(super) last_heartbeat: Instant,
    pub(super) acquiring: bool,
    pub(super) confidence_enabled: bool,
    pub(super) intensity_enabled: bool,
    pub(super) habits: VendorHabits,
    pub(super) aspect_ratio: f64,
    pub(super) history: VecDeque<(u64, Arc<Vec<Vec<u8>>>)>,
    /// PACKETRESEND answers waiting for the streamer (sent within the paced bandwidth).
    pub(super) resends: VecDeque<(SocketAddr, Vec<u8>)>,
    pub(super) stats: SimStats,
    pub(super) frame_rate: f64,
    /// Served through a GenTL producer ([`SimDevice`](super::SimDevice)): the transport
    /// delivers every enabled component as a multi-part buffer, no SCCFG switch needed.
    pub(super) gentl: bool,
    /// Software triggers executed whose frames are not sent yet.
    pub(super) pending_triggers: u32,
}

impl State {
    pub(super) fn reg(&self, a: u32) -> u32 {
        self.regs.get(&a).copied().unwrap_or(0)
    }

    /// Multi-part payloads: enabled by the host (SCCFG multi-part, extended ids), unless the
    /// camera streams chunk data only.
    pub(super) fn multipart(&self) -> bool {
        !self.habits.chunk_only
            && (self.gentl
                || (self.reg(reg::SCCFG0) & 0x40 != 0
                    && self.reg(reg::GVSP_CONFIG) & 0x4000_0000 != 0))
    }

    /// Streams the intensity image alone (no multi-part, no chunks).
    pub(super) fn intensity_only(&self) -> bool {
        self.habits.intensity_first
            && self.intensity_enabled
            && !self.multipart()
            && !self.habits.chunk_only
    }

    pub(super) fn payload_size(&self) -> u32 {
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
        } else if self.habits.chunk_part && self.multipart() {
            CHUNK_PART_BYTES
        } else {
            0
        };
        u32::try_from(main + extra * plane + chunks).unwrap_or(u32::MAX)
    }

    /// The coordinate `Scan3dCoordinateSelector` selects (C without a selector).
    fn coordinate(&self) -> usize {
        if self.habits.no_coordinate_selector {
            2
        } else {
            (self.reg(COORD_SELECTOR) as usize).min(2)
        }
    }

    /// The `index`-th double of the float block at `a`.
    pub(super) fn float(&self, a: u32) -> Option<f64> {
        if !(FLOAT_BASE..FLOAT_BASE + 8 * FLOATS).contains(&a) {
            return None;
        }
        let coding = self.habits.coding(self.reg(PIXEL_FORMAT));
        let k = self.coordinate();
        let (f, pu, pv) = self.intrinsics;
        let (w, h) = (self.reg(WIDTH), self.reg(HEIGHT));
        // The ROI is centred in the sensor: shift the principal point.
        let ox = f64::from((self.sensor.0 - w) / 2);
        let oy = f64::from((self.sensor.1 - h) / 2);
        Some(match (a - FLOAT_BASE) / 8 {
            0 => coding.scale[k],
            1 => coding.offset[k],
            2 => coding.invalid[k].unwrap_or(0.0),
            3 => f,
            4 => pu - ox,
            5 => pv - oy,
            6 => self.aspect_ratio,
            7 => self.frame_rate,
            8 => f * self.aspect_ratio,
            _ => 0.0,
        })
    }

    /// Whether a frame may be sent now: always with the trigger off; with it on, one per
    /// executed `TriggerSoftware` (the trigger is used up).
    pub(super) fn take_trigger(&mut self) -> bool {
        if self.reg(TRIGGER_MODE) == 0 {
            return true;
        }
        if self.reg(TRIGGER_SOURCE) == 0 && self.pending_triggers > 0 {
            self.pending_triggers -= 1;
            return true;
        }
        false
    }

    /// Read one big-endian 32-bit word.
    pub(super) fn read_word(&self, a: u32) -> Option<u32> {
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
            INVALID_FLAG => Some(u32::from(
                self.habits.coding(self.reg(PIXEL_FORMAT)).invalid[self.coordinate()].is_some(),
            )),
            TRIGGER_MODE | TRIGGER_SOURCE | TRIGGER_SOFTWARE | TRIGGER_SELECTOR
                if !self.habits.software_trigger =>
            {
                None
            }
            GENDC_MODE if !self.habits.gendc => None,
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
    pub(super) fn write_word(&mut self, a: u32, v: u32) -> std::result::Result<(), u16> {
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
                if !self.habits.pixel_formats().contains(&v) {
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
                self.pending_triggers = 0;
                return Ok(());
            }
            COORD_SELECTOR if v > 2 || (self.habits.only_coordinate_c && v != 2) => {
                return Err(0x8002)
            }
            TRIGGER_MODE | TRIGGER_SOURCE if !self.habits.software_trigger => return Err(0x8003),
            TRIGGER_MODE | TRIGGER_SOURCE if v > 1 => return Err(0x8002),
            TRIGGER_SELECTOR if !self.habits.software_trigger => return Err(0x8003),
            TRIGGER_SELECTOR if v != 0 => return Err(0x8002),
            TRIGGER_SOFTWARE => {
                if !self.habits.software_trigger {
                    return Err(0x8003);
                }
                // Taken only while acquiring with the software trigger on, as a camera does.
                if self.acquiring && self.reg(TRIGGER_MODE) == 1 && self.reg(TRIGGER_SOURCE) == 0 {
                    self.pending_triggers = (self.pending_triggers + 1).min(MAX_PENDING_TRIGGERS);
                }
                return Ok(());
            }
            TRIGGER_MODE | TRIGGER_SOURCE | TRIGGER_SELECTOR => {}
            GENDC_MODE if !self.habits.gendc => return Err(0x8003),
            GENDC_MODE if locked => return Err(0x8004),
            GENDC_MODE if v > 1 => return Err(0x8002),
            GENDC_MODE => {}
            USER_SET_SELECTOR if v > 1 => return Err(0x8002),
            USER_SET_LOAD => {
                if locked {
                    return Err(0x8004);
                }
                let format = match self.reg(USER_SET_SELECTOR) {
                    0 => self.habits.pixel_formats()[0],
                    _ => pfnc::COORD3D_C16,
                };
                if self.habits.pixel_formats().contains(&format) {
                    self.regs.insert(PIXEL_FORMAT, format);
                }
                return Ok(());
            }
            USER_SET_SELECTOR => {}
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
    pub(super) fn new(
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
            (PIXEL_FORMAT, opts.habits.pixel_formats()[0]),
            (TRIGGER_MODE, u32::from(opts.habits.software_trigger)),
            (TRIGGER_SOURCE, 0),
            (TRIGGER_SELECTOR, 0),
            (USER_SET_SELECTOR, 0),
            (GENDC_MODE, u32::from(opts.habits.gendc)),
            (USER_SET_LOAD, 0),
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
            pending_triggers: 0,
        }
    }
}

pub(super) fn lock(s: &Mutex<State>) -> MutexGuard<'_, State> {
    s.lock().unwrap_or_else(|p| p.into_inner())
}
