//! The device as the host process drives it (in the process that loaded the producer, see
//! [`crate::host`]): find and open it, configure it, capture and decode frames. Every value
//! the producer delivers is checked against the buffer, the standard and the remote device
//! (`check_parts`, `check_format`) before it is decoded.

use std::path::Path;
use std::rc::Rc;
use std::time::Duration;

use handeye_gige::decode::{decode_payload, pfnc, range_format, ChunkLayout, Scan3d};
use handeye_gige::genicam::NodeMap;
use handeye_gige::gvsp::{PartInfo, PART_CHUNK};
use handeye_gige::trigger;
use handeye_hal::{CameraInfo, PointCloud};

use crate::camera::{GentlOptions, GentlStats, InterfaceDevices};
use crate::error::{GentlError, Result};
use crate::host::watched;
use crate::producer::{Delivery, DeviceInfo, Interface, Lib, Part, RemotePort, Stream};

/// Most incomplete buffers tolerated in one capture.
const MAX_INCOMPLETE: u32 = 5;
/// Buffers announced per capture (the pool is bounded: the producer fills them in turn).
pub(crate) const POOL_BUFFERS: usize = 3;
/// Most devices believed from a producer, over all its interfaces.
pub(crate) const MAX_DEVICES: usize = 1024;

/// List a producer's interfaces and their devices (blocking: each list update may wait for the
/// producer's discovery).
pub(crate) fn list_devices(producer: &Path) -> Result<Vec<InterfaceDevices>> {
    let lib = Lib::load(producer)?;
    let system = lib.system()?;
    let mut total = 0;
    system
        .interfaces()?
        .into_iter()
        .map(|id| {
            let iface = system.open_interface(&id)?;
            let devices = iface.devices(MAX_DEVICES - total)?;
            total += devices.len();
            Ok(InterfaceDevices {
                devices,
                interface: id,
            })
        })
        .collect()
}

/// Whether `d` (at `index` in the listing) is the device `wanted` names.
pub(crate) fn matches(wanted: &str, index: usize, d: &DeviceInfo) -> bool {
    let w = wanted.trim();
    w == d.id || (!d.serial.is_empty() && w == d.serial) || w == d.model || w.parse() == Ok(index)
}

/// The open device with everything that talks to it, in drop order (stream first).
pub(crate) struct Open {
    stream: Stream,
    port: RemotePort,
    nodes: NodeMap,
    info: DeviceInfo,
    options: GentlOptions,
}

/// Find and open the device `options.device` names.
pub(crate) fn open(producer: &Path, options: GentlOptions) -> Result<Open> {
    let lib = Lib::load(producer)?;
    let system = lib.system()?;
    let mut listing = Vec::new();
    let mut chosen: Option<(Rc<Interface>, DeviceInfo)> = None;
    let mut ambiguous = Vec::new();
    for id in system.interfaces()? {
        let iface = Rc::new(system.open_interface(&id)?);
        for d in iface.devices(MAX_DEVICES - listing.len())? {
            let index = listing.len();
            let hit = options
                .device
                .as_deref()
                .is_none_or(|w| matches(w, index, &d));
            listing.push(format!(
                "{index}: {} {} (serial `{}`, id `{}`)",
                d.vendor, d.model, d.serial, d.id
            ));
            if hit {
                if chosen.is_none() {
                    chosen = Some((Rc::clone(&iface), d));
                } else if options.device.is_some() {
                    ambiguous.push(d.id.clone());
                }
            }
        }
    }
    let wanted = options
        .device
        .clone()
        .unwrap_or_else(|| "the first device".into());
    let Some((iface, info)) = chosen else {
        return Err(GentlError::NoDevice {
            wanted,
            available: if listing.is_empty() {
                "no devices".into()
            } else {
                listing.join("; ")
            },
        });
    };
    if !ambiguous.is_empty() {
        return Err(GentlError::NoDevice {
            wanted: format!("{wanted}` alone (several match: `{}`, `{}`); give the serial or id instead of `{wanted}", info.id, ambiguous.join("`, `")),
            available: listing.join("; "),
        });
    }
    let device = Rc::new(iface.open_device(&info.id)?);
    let xml = device.remote_xml(producer.parent())?;
    let nodes = NodeMap::from_xml(&xml)?;
    let port = device.remote_port();
    let stream = device.open_stream()?;
    let mut open = Open {
        stream,
        port,
        nodes,
        info,
        options,
    };
    open.select_components()?;
    Ok(open)
}

impl Open {
    /// Enable the Range component (and Confidence when asked) where the camera has a
    /// `ComponentSelector`; leave the selector on Range so `PixelFormat` is the range's.
    fn select_components(&mut self) -> Result<()> {
        let (n, p) = (&mut self.nodes, &mut self.port);
        if !n.has("ComponentSelector") {
            return Ok(());
        }
        let entries = n.enum_entries("ComponentSelector")?;
        let has = |c: &str| entries.iter().any(|e| e == c);
        if self.options.confidence {
            if has("Confidence") {
                n.set_enum(p, "ComponentSelector", "Confidence")?;
                n.set_boolean(p, "ComponentEnable", true)?;
            } else {
                tracing::warn!("the camera has no Confidence component; streaming without it");
            }
        }
        if has("Range") {
            n.set_enum(p, "ComponentSelector", "Range")?;
            if n.has("ComponentEnable") {
                n.set_boolean(p, "ComponentEnable", true)?;
            }
        }
        Ok(())
    }

    pub(crate) fn camera_info(&mut self) -> Result<CameraInfo> {
        // Configured settings the camera cannot take are found in preflight (issue 44).
        handeye_gige::settings::check(&self.nodes, &self.options.settings)?;
        let (n, p) = (&mut self.nodes, &mut self.port);
        let width = n.integer(p, "Width")?;
        let height = n.integer(p, "Height")?;
        Ok(CameraInfo {
            vendor: self.info.vendor.clone(),
            model: self.info.model.clone(),
            serial: self.info.serial.clone(),
            firmware: self.info.version.clone(),
            width: u32::try_from(width).unwrap_or(0),
            height: u32::try_from(height).unwrap_or(0),
            pixel_formats: n.enum_entries("PixelFormat")?,
        })
    }

    /// The features a user would set, with their value, range or entries and access.
    pub(crate) fn features(&mut self) -> Vec<handeye_gige::genicam::FeatureState> {
        handeye_gige::settings::probe(&mut self.nodes, &mut self.port)
    }

    pub(crate) fn set_exposure(&mut self, exposure: Duration) -> Result<()> {
        let (n, p) = (&mut self.nodes, &mut self.port);
        if n.has("ExposureTime") {
            n.set_float(p, "ExposureTime", exposure.as_secs_f64() * 1e6)?;
        } else {
            tracing::warn!("camera has no ExposureTime feature; exposure setting ignored");
        }
        Ok(())
    }

    /// Capture `frames` complete buffers and decode them.
    pub(crate) fn capture(
        &mut self,
        frames: u32,
        timeout: Duration,
    ) -> Result<(Vec<PointCloud>, GentlStats)> {
        // The user set and [camera.features] before anything is read: they may change the
        // format (a camera left locked is taken over first).
        self.nodes.take_over(&mut self.port)?;
        handeye_gige::settings::apply(&mut self.nodes, &mut self.port, &self.options.settings)?;
        self.select_components()?;
        let scan3d = Scan3d::read(&mut self.nodes, &mut self.port)?;
        let layout = ChunkLayout::read(&mut self.nodes, &mut self.port)?;
        // The range format the remote device says it sends (under ComponentSelector Range).
        let format = match &layout {
            Some(l) => Some(l.pixel_format),
            None if self.nodes.has("PixelFormat") => {
                u32::try_from(self.nodes.enum_value(&mut self.port, "PixelFormat")?).ok()
            }
            None => None,
        };
        let payload = match self.stream.payload_size() {
            Some(s) => s,
            None => {
                let s = self.nodes.integer(&mut self.port, "PayloadSize")?;
                u64::try_from(s).map_err(|_| GentlError::garbage("PayloadSize", format!("{s}")))?
            }
        };
        let started = self.stream.start(payload, POOL_BUFFERS);
        let result =
            started.and_then(|()| self.acquire(frames, timeout, &scan3d, layout.as_ref(), format));
        let stop = self.stop_acquisition();
        let out = result?;
        stop?;
        Ok(out)
    }

    fn acquire(
        &mut self,
        frames: u32,
        timeout: Duration,
        scan3d: &Scan3d,
        layout: Option<&ChunkLayout>,
        format: Option<u32>,
    ) -> Result<(Vec<PointCloud>, GentlStats)> {
        let (n, p) = (&mut self.nodes, &mut self.port);
        // A camera a killed capture left locked is stopped and unlocked first (issue 46).
        n.take_over(p)?;
        // A producer may hold AcquisitionMode read-only at Continuous (viky does): only a
        // different mode is written.
        if n.has("AcquisitionMode") && n.enum_symbol(p, "AcquisitionMode")? != "Continuous" {
            n.set_enum(p, "AcquisitionMode", "Continuous")?;
        }
        let trig = self.options.trigger;
        trigger::prepare(n, p, trig)?;
        // Boolean or Integer, as the camera declares it.
        if n.has("TLParamsLocked") {
            n.set_switch(p, "TLParamsLocked", true)?;
        }
        watched("AcquisitionStart (GCWritePort)", None, || {
            n.execute(p, "AcquisitionStart")
        })?;
        let mut stats = GentlStats::default();
        let mut clouds = Vec::new();
        while clouds.len() < frames as usize {
            trigger::fire(&mut self.nodes, &mut self.port, trig)?;
            match self.stream.wait(timeout)? {
                None => {
                    return Err(GentlError::FrameTimeout {
                        timeout,
                        detail: format!("{} of {frames} frames received", clouds.len()),
                    })
                }
                Some(Delivery::Incomplete) => {
                    stats.incomplete += 1;
                    tracing::warn!("the producer delivered an incomplete buffer; dropped");
                    if stats.incomplete > MAX_INCOMPLETE {
                        return Err(GentlError::FrameTimeout {
                            timeout,
                            detail: format!("{} incomplete buffers", stats.incomplete),
                        });
                    }
                }
                Some(Delivery::Complete(parts)) => {
                    let parts = parts
                        .into_iter()
                        .map(part_info)
                        .collect::<Result<Vec<_>>>()?;
                    check_format(&parts, format)?;
                    clouds.push(decode_payload(&parts, layout, scan3d)?);
                    stats.complete += 1;
                }
            }
        }
        Ok((clouds, stats))
    }

    /// Stop the camera and the stream, whatever happened; report the first error.
    fn stop_acquisition(&mut self) -> Result<()> {
        let (n, p) = (&mut self.nodes, &mut self.port);
        let remote = watched("AcquisitionStop (GCWritePort)", None, || {
            n.execute(p, "AcquisitionStop")
        })
        .and_then(|()| {
            if n.has("TLParamsLocked") {
                n.set_switch(p, "TLParamsLocked", false)
            } else {
                Ok(())
            }
        });
        let stream = self.stream.stop();
        remote.map_err(GentlError::from)?;
        stream
    }
}

/// A range part's pixel format must be the one the remote device says it sends: a buffer
/// that calls its data another format would decode into garbage points.
fn check_format(parts: &[(PartInfo, Vec<u8>)], remote: Option<u32>) -> Result<()> {
    let Some(remote) = remote.filter(|f| range_format(*f).is_some()) else {
        return Ok(());
    };
    let has = |f: u32| parts.iter().any(|(p, _)| p.pixel_format == f);
    if has(pfnc::COORD3D_A32F) && has(pfnc::COORD3D_B32F) && has(pfnc::COORD3D_C32F) {
        // Separate A, B and C planes: an ABC format sent as three parts (viky.cti announces
        // Coord3D_ABC32f_Planar and sends them so).
        return Ok(());
    }
    let range = parts
        .iter()
        .map(|(p, _)| p.pixel_format)
        .find(|f| range_format(*f).is_some());
    match range {
        Some(f) if f != remote => Err(GentlError::garbage(
            "DSGetBufferPartInfo",
            format!(
                "a range part in {} ({f:#x}) while the camera's PixelFormat is {} ({remote:#x})",
                pfnc::name(f),
                pfnc::name(remote)
            ),
        )),
        _ => Ok(()),
    }
}

/// Bits per pixel of a PFNC code (bits 16–23 of the code, the standard's "effective size").
fn pfnc_bits(format: u32) -> u64 {
    u64::from((format >> 16) & 0xff)
}

/// A delivered part as the PFNC decoders take it; sizes that do not fit are the producer's
/// garbage: an image part's width and height are at least 1, and its data is its lines
/// (width × the format's bits per pixel, plus the line padding) to within one line.
pub(crate) fn part_info(p: Part) -> Result<(PartInfo, Vec<u8>)> {
    let bad = |what: &str, v: u64| {
        GentlError::garbage(
            "DSGetBufferPartInfo",
            format!("{what} = {v} is out of range"),
        )
    };
    // Far above any sensor; keeps the decoders' size arithmetic small.
    const MAX_SIDE: u64 = 1 << 20;
    if p.width > MAX_SIDE || p.height > MAX_SIDE {
        return Err(GentlError::garbage(
            "DSGetBufferPartInfo",
            format!("a {} x {} image", p.width, p.height),
        ));
    }
    let info = PartInfo {
        data_type: u16::try_from(p.data_type).map_err(|_| bad("data type", p.data_type))?,
        length: p.data.len() as u64,
        pixel_format: u32::try_from(p.pixel_format)
            .map_err(|_| bad("pixel format", p.pixel_format))?,
        purpose: u16::try_from(p.purpose).unwrap_or(0),
        width: u32::try_from(p.width).map_err(|_| bad("width", p.width))?,
        height: u32::try_from(p.height).map_err(|_| bad("height", p.height))?,
        padding_x: u16::try_from(p.padding_x).map_err(|_| bad("x padding", p.padding_x))?,
    };
    if info.data_type != PART_CHUNK {
        if info.width == 0 || info.height == 0 {
            return Err(GentlError::garbage(
                "DSGetBufferPartInfo",
                format!("an empty {} x {} image", info.width, info.height),
            ));
        }
        let bits = pfnc_bits(info.pixel_format);
        if bits > 0 {
            let stride = (p.width * bits).div_ceil(8) + p.padding_x;
            let needed = stride * (p.height - 1) + (p.width * bits).div_ceil(8);
            let len = info.length;
            if len < needed || len > needed + stride {
                return Err(GentlError::garbage(
                    "DSGetBufferPartInfo",
                    format!(
                        "{len} bytes for a {} x {} {} image ({needed} expected: {bits} bits a \
                         pixel, {} bytes of padding a line)",
                        p.width,
                        p.height,
                        pfnc::name(info.pixel_format),
                        p.padding_x
                    ),
                ));
            }
        }
    }
    Ok((info, p.data))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dev(id: &str, model: &str, serial: &str) -> DeviceInfo {
        DeviceInfo {
            id: id.into(),
            model: model.into(),
            serial: serial.into(),
            ..DeviceInfo::default()
        }
    }

    #[test]
    fn devices_are_chosen_by_id_serial_model_or_index() {
        let d = dev("VikyTL_DEV_red", "Viky", "0");
        assert!(matches("VikyTL_DEV_red", 5, &d));
        assert!(matches("Viky", 5, &d));
        assert!(matches("0", 5, &d), "serial");
        assert!(matches("5", 5, &d), "index");
        assert!(!matches("Other", 5, &d));
        assert!(!matches("6", 5, &d));
        let no_serial = dev("a", "m", "");
        assert!(!matches("", 1, &no_serial));
    }

    fn part(width: u64, height: u64, pixel_format: u64, bytes: usize) -> Part {
        Part {
            data_type: 7,
            pixel_format,
            width,
            height,
            padding_x: 0,
            purpose: 4,
            data: vec![0; bytes],
        }
    }

    /// A producer's part sizes that cannot be an image are its garbage, not a decoder's
    /// overflow.
    #[test]
    fn absurd_part_geometry_is_refused() {
        let (info, data) = part_info(part(3, 1, 0x012000BD, 12)).expect("a 3 x 1 plane");
        assert_eq!(
            (info.width, info.height, info.data_type, info.length),
            (3, 1, 7, 12)
        );
        assert_eq!(data.len(), 12);
        for bad in [
            part(1 << 21, 1, 0x012000BD, 12),
            part(1, u64::MAX, 0x012000BD, 12),
            part(1, 1, 1 << 40, 12),
        ] {
            let e = part_info(bad).expect_err("garbage").to_string();
            assert!(
                e.contains("returned garbage from DSGetBufferPartInfo"),
                "{e}"
            );
        }
    }

    /// Issue 46: a part of width or height 0, or whose size is not its width × height × the
    /// format's bits (Coord3D_C16 over Coord3D_ABC32f data: 6 times too many bytes), is
    /// refused; a size within one line of the image's passes.
    #[test]
    fn issue_46_part_sizes_must_match_width_height_and_format() {
        let c16 = u64::from(pfnc::COORD3D_C16);
        let abc = u64::from(pfnc::COORD3D_ABC32F);
        assert!(part_info(part(32, 32, abc, 32 * 32 * 12)).is_ok());
        assert!(
            part_info(part(32, 32, c16, 32 * 32 * 2 + 64)).is_ok(),
            "one line more"
        );
        for (bad, why) in [
            (
                part(32, 32, c16, 32 * 32 * 12),
                "12288 bytes for a 32 x 32 Coord3D_C16",
            ),
            (part(32, 32, abc, 100), "100 bytes for a 32 x 32"),
            (part(0, 32, abc, 0), "an empty 0 x 32 image"),
            (part(32, 0, abc, 0), "an empty 32 x 0 image"),
        ] {
            let e = part_info(bad).expect_err(why).to_string();
            assert!(e.contains(why), "{e}");
        }
    }

    /// Issue 46: the buffer's range format must be the remote device's `PixelFormat`.
    #[test]
    fn issue_46_a_range_format_other_than_the_cameras_is_refused() {
        let p = |pf| {
            (
                PartInfo {
                    data_type: 5,
                    length: 0,
                    pixel_format: pf,
                    purpose: 0,
                    width: 1,
                    height: 1,
                    padding_x: 0,
                },
                Vec::new(),
            )
        };
        let abc = pfnc::COORD3D_ABC32F;
        assert!(check_format(&[p(abc)], Some(abc)).is_ok());
        assert!(check_format(&[p(abc)], None).is_ok());
        let planes = [
            p(pfnc::COORD3D_A32F),
            p(pfnc::COORD3D_B32F),
            p(pfnc::COORD3D_C32F),
        ];
        assert!(check_format(&planes, Some(pfnc::COORD3D_ABC32F_PLANAR)).is_ok());
        let e = check_format(&[p(pfnc::COORD3D_C16)], Some(abc))
            .expect_err("lies")
            .to_string();
        assert!(
            e.contains("a range part in Coord3D_C16 (0x11000b8) while the camera's PixelFormat is Coord3D_ABC32f"),
            "{e}"
        );
    }

    #[test]
    fn a_file_that_is_not_a_producer_is_a_clear_error() {
        let e = list_devices(Path::new("/nonexistent/x.cti"))
            .expect_err("missing")
            .to_string();
        assert!(e.contains("cannot load the GenTL producer"), "{e}");
        // A real shared library without the GenTL functions.
        let libm = [
            "/lib/x86_64-linux-gnu/libm.so.6",
            "/usr/lib/x86_64-linux-gnu/libm.so.6",
        ]
        .into_iter()
        .find(|p| Path::new(p).exists());
        if let Some(libm) = libm {
            let e = list_devices(Path::new(libm))
                .expect_err("not gentl")
                .to_string();
            assert!(
                e.contains("not a GenTL producer: no `GCGetLastError`"),
                "{e}"
            );
        }
    }
}
