//! [`GentlCamera`]: a 3D camera reached through its GenTL producer, behind
//! [`handeye_hal::DepthCamera`].
//!
//! GenTL calls block (a producer may wait seconds for a device), so one thread per camera owns
//! every producer handle and serves requests from a channel; async callers await the reply and
//! never block a runtime worker.

use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::mpsc;
use std::time::Duration;

use handeye_gige::decode::{decode_payload, ChunkLayout, Scan3d};
use handeye_gige::genicam::NodeMap;
use handeye_gige::gvsp::PartInfo;
use handeye_gige::trigger;
use handeye_hal::{CameraInfo, CaptureSettings, DepthCamera, HalError, PointCloud, Trigger};

use crate::error::{GentlError, Result};
use crate::producer::{Delivery, DeviceInfo, Interface, Lib, Part, RemotePort, Stream};

/// How to open and stream.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GentlOptions {
    /// Which device: its serial number, model name, producer id, or index in the listing
    /// ([`list_devices`]); the first device when `None`.
    pub device: Option<String>,
    /// Also enable the Confidence component when the camera offers it.
    pub confidence: bool,
    /// How frames are started (`camera.trigger`).
    pub trigger: Trigger,
    /// The user set and features written before every capture (`camera.user_set`,
    /// `[camera.features]`).
    pub settings: handeye_hal::CameraSettings,
}

/// Counters of one capture.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct GentlStats {
    /// Complete buffers decoded.
    pub complete: u32,
    /// Buffers the producer flagged incomplete (dropped).
    pub incomplete: u32,
}

/// Most incomplete buffers tolerated in one capture.
const MAX_INCOMPLETE: u32 = 5;
/// Buffers announced per capture (the pool is bounded: the producer fills them in turn).
const POOL_BUFFERS: usize = 3;

/// One interface of a producer and the devices on it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct InterfaceDevices {
    /// The producer's interface id.
    pub interface: String,
    /// Its devices.
    pub devices: Vec<DeviceInfo>,
}

/// List a producer's interfaces and their devices (blocking: each list update may wait for the
/// producer's discovery).
pub fn list_devices(producer: &Path) -> Result<Vec<InterfaceDevices>> {
    let lib = Lib::load(producer)?;
    let system = lib.system()?;
    system
        .interfaces()?
        .into_iter()
        .map(|id| {
            let iface = system.open_interface(&id)?;
            Ok(InterfaceDevices {
                devices: iface.devices()?,
                interface: id,
            })
        })
        .collect()
}

/// Whether `d` (at `index` in the listing) is the device `wanted` names.
fn matches(wanted: &str, index: usize, d: &DeviceInfo) -> bool {
    let w = wanted.trim();
    w == d.id || (!d.serial.is_empty() && w == d.serial) || w == d.model || w.parse() == Ok(index)
}

/// The open device with everything that talks to it, in drop order (stream first).
struct Open {
    stream: Stream,
    port: RemotePort,
    nodes: NodeMap,
    info: DeviceInfo,
    options: GentlOptions,
}

/// Find and open the device `options.device` names.
fn open(producer: &Path, options: GentlOptions) -> Result<Open> {
    let lib = Lib::load(producer)?;
    let system = lib.system()?;
    let mut listing = Vec::new();
    let mut chosen: Option<(Rc<Interface>, DeviceInfo)> = None;
    let mut ambiguous = Vec::new();
    for id in system.interfaces()? {
        let iface = Rc::new(system.open_interface(&id)?);
        for d in iface.devices()? {
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
    let xml = device.remote_xml()?;
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

    fn camera_info(&mut self) -> Result<CameraInfo> {
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

    fn set_exposure(&mut self, exposure: Duration) -> Result<()> {
        let (n, p) = (&mut self.nodes, &mut self.port);
        if n.has("ExposureTime") {
            n.set_float(p, "ExposureTime", exposure.as_secs_f64() * 1e6)?;
        } else {
            tracing::warn!("camera has no ExposureTime feature; exposure setting ignored");
        }
        Ok(())
    }

    /// Capture `frames` complete buffers and decode them.
    fn capture(&mut self, frames: u32, timeout: Duration) -> Result<(Vec<PointCloud>, GentlStats)> {
        // The user set and [camera.features] before anything is read: they may change the
        // format (a camera left locked is taken over first).
        self.nodes.take_over(&mut self.port)?;
        handeye_gige::settings::apply(&mut self.nodes, &mut self.port, &self.options.settings)?;
        self.select_components()?;
        let scan3d = Scan3d::read(&mut self.nodes, &mut self.port)?;
        let layout = ChunkLayout::read(&mut self.nodes, &mut self.port)?;
        let payload = match self.stream.payload_size() {
            Some(s) => s,
            None => {
                let s = self.nodes.integer(&mut self.port, "PayloadSize")?;
                u64::try_from(s).map_err(|_| GentlError::garbage("PayloadSize", format!("{s}")))?
            }
        };
        let started = self.stream.start(payload, POOL_BUFFERS);
        let result = started.and_then(|()| self.acquire(frames, timeout, &scan3d, layout.as_ref()));
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
        n.execute(p, "AcquisitionStart")?;
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
        let remote = n.execute(p, "AcquisitionStop").and_then(|()| {
            if n.has("TLParamsLocked") {
                n.set_switch(p, "TLParamsLocked", false)
            } else {
                Ok(())
            }
        });
        let stream = self.stream.stop();
        remote?;
        stream
    }
}

/// A delivered part as the PFNC decoders take it; sizes that do not fit are the producer's
/// garbage.
fn part_info(p: Part) -> Result<(PartInfo, Vec<u8>)> {
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
    Ok((info, p.data))
}

/// A request to the camera thread.
enum Request {
    Info(tokio::sync::oneshot::Sender<Result<CameraInfo>>),
    Capture {
        settings: CaptureSettings,
        reply: tokio::sync::oneshot::Sender<Result<(Vec<PointCloud>, GentlStats)>>,
    },
}

/// A camera behind a GenTL producer. Cloning shares the one thread that owns the producer's
/// handles; the device is closed (stream, device, interface, system, library in that order)
/// when the last clone is dropped and the current request is done.
#[derive(Debug, Clone)]
pub struct GentlCamera {
    requests: mpsc::Sender<Request>,
    producer: PathBuf,
}

impl GentlCamera {
    /// Load `producer`, open the device `options.device` names (the first one when `None`),
    /// read its GenICam XML and open its data stream. Blocks until the device is open.
    pub fn connect(producer: &Path, options: GentlOptions) -> Result<Self> {
        let (requests, rx) = mpsc::channel::<Request>();
        let (ready_tx, ready_rx) = mpsc::channel::<Result<()>>();
        let path = producer.to_owned();
        std::thread::Builder::new()
            .name("gentl-camera".into())
            .spawn(move || match open(&path, options) {
                Ok(mut cam) => {
                    // The caller waits for this; if it went away there is nobody to serve.
                    if ready_tx.send(Ok(())).is_err() {
                        return;
                    }
                    serve(&mut cam, &rx);
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            })
            .map_err(|e| GentlError::Closed(format!("cannot start the camera thread: {e}")))?;
        ready_rx
            .recv()
            .map_err(|_| GentlError::Closed("the camera thread panicked while opening".into()))??;
        Ok(Self {
            requests,
            producer: producer.to_owned(),
        })
    }

    /// The producer this camera was opened through.
    pub fn producer(&self) -> &Path {
        &self.producer
    }

    async fn ask<T>(
        &self,
        make: impl FnOnce(tokio::sync::oneshot::Sender<Result<T>>) -> Request,
    ) -> Result<T> {
        let (tx, rx) = tokio::sync::oneshot::channel();
        self.requests
            .send(make(tx))
            .map_err(|_| GentlError::Closed("it ended".into()))?;
        rx.await
            .map_err(|_| GentlError::Closed("it dropped the request (panic?)".into()))?
    }

    /// Capture `settings.frames` frames, with the capture's counters.
    pub async fn capture_with_stats(
        &self,
        settings: &CaptureSettings,
    ) -> Result<(Vec<PointCloud>, GentlStats)> {
        let settings = settings.clone();
        self.ask(|reply| Request::Capture { settings, reply }).await
    }
}

/// The camera thread: serve requests until every [`GentlCamera`] clone is gone.
fn serve(cam: &mut Open, rx: &mpsc::Receiver<Request>) {
    while let Ok(req) = rx.recv() {
        match req {
            Request::Info(reply) => {
                let _ = reply.send(cam.camera_info());
            }
            Request::Capture { settings, reply } => {
                let r = settings
                    .exposure
                    .map_or(Ok(()), |e| cam.set_exposure(e))
                    .and_then(|()| cam.capture(settings.frames, settings.frame_timeout));
                let _ = reply.send(r);
            }
        }
    }
}

impl DepthCamera for GentlCamera {
    async fn info(&self) -> Result<CameraInfo, HalError> {
        Ok(self.ask(Request::Info).await?)
    }

    async fn capture(&self, settings: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
        Ok(self.capture_with_stats(settings).await?.0)
    }
}

/// The producers the GenTL standard's search finds: every `*.cti` in the directories of
/// `GENICAM_GENTL64_PATH` (`:`-separated; `;` on Windows), in order, each directory's files
/// sorted by name.
pub fn producers_on_path() -> Vec<PathBuf> {
    let Some(var) = std::env::var_os("GENICAM_GENTL64_PATH") else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for dir in std::env::split_paths(&var) {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut ctis: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("cti")) && p.is_file())
            .collect();
        ctis.sort();
        out.extend(ctis);
    }
    out
}

/// The producer to use: `given`, else the only one (or the first one) on
/// `GENICAM_GENTL64_PATH`.
pub fn resolve_producer(given: Option<&Path>) -> Result<PathBuf> {
    if let Some(p) = given {
        return Ok(p.to_owned());
    }
    let found = producers_on_path();
    match found.as_slice() {
        [] => Err(GentlError::NoProducer(
            "GENICAM_GENTL64_PATH names no directory with a .cti; install the vendor's GenTL producer or give its path (camera.producer, --gentl)".into(),
        )),
        [one] => Ok(one.clone()),
        [first, rest @ ..] => {
            tracing::warn!(
                "GENICAM_GENTL64_PATH has {} producers; using {} (set camera.producer to choose)",
                rest.len() + 1,
                first.display()
            );
            Ok(first.clone())
        }
    }
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

    /// A producer's part sizes that cannot be an image are its garbage, not a decoder's
    /// overflow.
    #[test]
    fn absurd_part_geometry_is_refused() {
        let part = |width, height, pixel_format| Part {
            data_type: 7,
            pixel_format,
            width,
            height,
            padding_x: 0,
            purpose: 4,
            data: vec![0; 12],
        };
        let (info, data) = part_info(part(3, 1, 0x012000BD)).expect("a 3 x 1 plane");
        assert_eq!(
            (info.width, info.height, info.data_type, info.length),
            (3, 1, 7, 12)
        );
        assert_eq!(data.len(), 12);
        for bad in [
            part(1 << 21, 1, 0x012000BD),
            part(1, u64::MAX, 0x012000BD),
            part(1, 1, 1 << 40),
        ] {
            let e = part_info(bad).expect_err("garbage").to_string();
            assert!(
                e.contains("returned garbage from DSGetBufferPartInfo"),
                "{e}"
            );
        }
    }

    #[test]
    fn producers_are_searched_on_the_standard_variable() {
        let dir = std::env::temp_dir().join(format!("handeye-gentl-path-{}", std::process::id()));
        let (a, b) = (dir.join("a"), dir.join("b"));
        std::fs::create_dir_all(&a).expect("dir");
        std::fs::create_dir_all(&b).expect("dir");
        for f in [
            a.join("z.cti"),
            a.join("y.CTI"),
            a.join("x.so"),
            b.join("w.cti"),
        ] {
            std::fs::write(&f, b"").expect("file");
        }
        let var = std::env::join_paths([&a, &dir.join("missing"), &b]).expect("join");
        // No other test of this crate reads or writes this variable.
        std::env::set_var("GENICAM_GENTL64_PATH", &var);
        assert_eq!(
            producers_on_path(),
            vec![a.join("y.CTI"), a.join("z.cti"), b.join("w.cti")]
        );
        assert_eq!(resolve_producer(None).expect("first"), a.join("y.CTI"));
        assert_eq!(
            resolve_producer(Some(Path::new("/x.cti"))).expect("given"),
            Path::new("/x.cti")
        );
        std::env::set_var("GENICAM_GENTL64_PATH", dir.join("missing"));
        let e = resolve_producer(None).expect_err("none").to_string();
        assert!(e.contains("GENICAM_GENTL64_PATH"), "{e}");
        std::env::remove_var("GENICAM_GENTL64_PATH");
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }

    #[test]
    fn a_file_that_is_not_a_producer_is_a_clear_error() {
        let e = list_devices(Path::new("/nonexistent/x.cti"))
            .expect_err("missing")
            .to_string();
        assert!(e.contains("cannot load the GenTL producer"), "{e}");
        // A real shared library without the GenTL functions.
        let libc = [
            "/lib/x86_64-linux-gnu/libm.so.6",
            "/usr/lib/x86_64-linux-gnu/libm.so.6",
        ]
        .into_iter()
        .find(|p| Path::new(p).exists());
        if let Some(libm) = libc {
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
