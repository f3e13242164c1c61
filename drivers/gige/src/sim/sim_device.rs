//! [`SimDevice`]: the simulated camera without a transport, as a GenTL producer serves it.

use std::net::Ipv4Addr;
use std::sync::Mutex;
use std::time::Instant;

use super::device::{lock, SimOptions, State, ACQ_MODE, XML_ADDRESS};
use super::encode::make_block;
use super::stream::StreamSettings;
use super::FrameSource;
use crate::error::{GigeError, Result};
use crate::gvsp::Block;

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

    /// Whether a frame may be delivered now: always with the trigger off; with it on, one per
    /// executed `TriggerSoftware` (used up by this call).
    pub fn take_trigger(&self) -> bool {
        lock(&self.state).take_trigger()
    }

    /// Whether the camera streams GenDC containers now (`GenDCStreamingMode` On, a
    /// [`VendorHabits::gendc`](super::VendorHabits::gendc) camera).
    pub fn gendc_streaming(&self) -> bool {
        let s = lock(&self.state);
        s.habits.gendc && s.reg(super::device::GENDC_MODE) == 1
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
    use crate::decode::pfnc;
    use crate::gvsp;
    use crate::sim::device::{
        ACQ_START, COMPONENT_ENABLE, COMPONENT_SELECTOR, PIXEL_FORMAT, WIDTH,
    };
    use crate::sim::{FrameSource, SimCamera};

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
}
