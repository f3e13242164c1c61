//! [`GigeCamera`]: a GigE Vision 3D camera behind [`handeye_hal::DepthCamera`].

use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use handeye_hal::{
    CameraInfo, CameraSettings, CaptureSettings, DepthCamera, HalError, PointCloud, Trigger,
};

use crate::client::{ControlConfig, GvcpClient};
use crate::decode::{self, ChunkLayout, Scan3d};
use crate::error::{GigeError, Result};
use crate::genicam::{fetch_xml, GvcpPort, NodeMap};
use crate::gvcp::{cap, reg};
use crate::gvsp::{Frame, StreamConfig, StreamReceiver, StreamStats};
use crate::trigger;

/// Every GenICam feature the driver reads or writes (what `handeye camera xml` looks for, and
/// what the corpus test checks against the EMVA reference GenApi).
pub const DRIVER_FEATURES: &[&str] = &[
    "Width",
    "Height",
    "PixelFormat",
    "PayloadSize",
    "GevSCPSPacketSize",
    "AcquisitionMode",
    "AcquisitionStart",
    "AcquisitionStop",
    "TLParamsLocked",
    "ExposureTime",
    "ComponentSelector",
    "ComponentEnable",
    "Scan3dDistanceUnit",
    "Scan3dOutputMode",
    "Scan3dCoordinateSelector",
    "Scan3dCoordinateScale",
    "Scan3dCoordinateOffset",
    "Scan3dInvalidDataFlag",
    "Scan3dInvalidDataValue",
    "Scan3dFocalLength",
    "Scan3dPrincipalPointU",
    "Scan3dPrincipalPointV",
    "Scan3dAspectRatio",
];

/// Streaming options of a capture.
#[derive(Debug, Clone, PartialEq)]
pub struct StreamOptions {
    /// GVSP packet size to program (whole IP datagram, bytes). 1500 suits any network;
    /// jumbo frames (9000) cut the packet rate on networks that allow them.
    pub packet_size: u32,
    /// Ask for lost packets when the camera supports it.
    pub resend: bool,
    /// Also stream the confidence component (multi-part) when the camera offers it.
    pub confidence: bool,
    /// Give up after this many incomplete frames in one capture.
    pub max_incomplete: u32,
    /// How frames are started (`camera.trigger`).
    pub trigger: Trigger,
    /// The user set to load and the features to write before every capture
    /// (`camera.user_set`, `[camera.features]`).
    pub settings: CameraSettings,
    /// Receiver tuning (packet size, extended ids and resend are set from the fields above).
    pub receiver: StreamConfig,
}

impl Default for StreamOptions {
    fn default() -> Self {
        Self {
            packet_size: 1500,
            resend: true,
            confidence: false,
            max_incomplete: 5,
            trigger: Trigger::Free,
            settings: CameraSettings::default(),
            receiver: StreamConfig::default(),
        }
    }
}

/// Statistics of one capture.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct CaptureStats {
    /// Complete frames delivered.
    pub complete: u32,
    /// Incomplete frames dropped.
    pub incomplete: u32,
    /// Packets that arrived as retransmissions.
    pub resent_packets: u64,
    /// Receiver counters.
    pub stream: StreamStats,
}

#[derive(Debug)]
struct Inner {
    client: GvcpClient,
    nodes: NodeMap,
}

/// A GigE Vision camera (control + stream). Blocking methods end in `_blocking`; the
/// [`DepthCamera`] implementation runs them on tokio's blocking pool.
#[derive(Debug, Clone)]
pub struct GigeCamera {
    inner: Arc<Mutex<Inner>>,
    peer: SocketAddr,
    /// Streaming options used by [`DepthCamera::capture`].
    pub options: StreamOptions,
}

fn local_ip_towards(peer: SocketAddr) -> Result<Ipv4Addr> {
    let s = UdpSocket::bind("0.0.0.0:0").map_err(|e| GigeError::io(peer, e))?;
    s.connect(peer).map_err(|e| GigeError::io(peer, e))?;
    match s.local_addr().map_err(|e| GigeError::io(peer, e))?.ip() {
        IpAddr::V4(ip) => Ok(ip),
        IpAddr::V6(_) => Err(GigeError::InvalidArgument(
            "GigE Vision is IPv4 only".into(),
        )),
    }
}

impl GigeCamera {
    /// Connect to the camera at `addr` (GVCP port, normally 3956) and load its GenICam XML.
    pub fn connect(addr: SocketAddr, cfg: ControlConfig) -> Result<Self> {
        let client = GvcpClient::connect(addr, cfg)?;
        let xml = fetch_xml(&client)?;
        let nodes = NodeMap::from_xml(&xml)?;
        Ok(Self {
            inner: Arc::new(Mutex::new(Inner { client, nodes })),
            peer: addr,
            options: StreamOptions::default(),
        })
    }

    /// The camera's control address.
    pub fn peer(&self) -> SocketAddr {
        self.peer
    }

    /// Run `f` with the node map and a port to the device (feature access).
    pub fn with_features<T>(
        &self,
        f: impl FnOnce(&mut NodeMap, &mut GvcpPort) -> Result<T>,
    ) -> Result<T> {
        let mut g = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        let mut port = GvcpPort(g.client.clone());
        f(&mut g.nodes, &mut port)
    }

    /// The control client (register access).
    pub fn client(&self) -> GvcpClient {
        self.inner
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .client
            .clone()
    }

    /// Identify the camera (bootstrap strings, size, pixel formats); an error when the
    /// configured settings do not fit its description ([`crate::settings::check`]).
    pub fn info_blocking(&self) -> Result<CameraInfo> {
        let c = self.client();
        let vendor = c.read_string(reg::MANUFACTURER, 32)?;
        let model = c.read_string(reg::MODEL, 32)?;
        let firmware = c.read_string(reg::DEVICE_VERSION, 32)?;
        let serial = c.read_string(reg::SERIAL, 16)?;
        self.with_features(|n, p| {
            // A configured setting the camera cannot take is found here, in preflight, before
            // the arm moves.
            crate::settings::check(n, &self.options.settings)?;
            let width = n.integer(p, "Width")?;
            let height = n.integer(p, "Height")?;
            let pixel_formats = n.enum_entries("PixelFormat")?;
            Ok(CameraInfo {
                vendor,
                model,
                serial,
                firmware,
                width: u32::try_from(width).unwrap_or(0),
                height: u32::try_from(height).unwrap_or(0),
                pixel_formats,
            })
        })
    }

    /// The features a user would set ([`crate::settings::USER_FEATURES`]) the camera has, with
    /// their value, range or entries and access now (`handeye camera probe`).
    pub fn user_features_blocking(&self) -> Result<Vec<crate::genicam::FeatureState>> {
        self.with_features(|n, p| Ok(crate::settings::probe(n, p)))
    }

    /// Read the Scan3d conversion parameters (defaults where the camera lacks a feature):
    /// without `Scan3dDistanceUnit` values are millimetres (a warning says so); without
    /// `Scan3dCoordinateSelector` the one `Scan3dCoordinateScale` applies to every coordinate and
    /// `Scan3dCoordinateOffset` to the depth (C). An output mode that needs the camera's
    /// coordinate maps (`ProjectedC`, `UncalibratedC`, …) is an error.
    pub fn scan3d_blocking(&self) -> Result<Scan3d> {
        self.with_features(Scan3d::read)
    }

    /// Take control, stream until `frames` complete frames arrived (incomplete ones are
    /// counted and dropped), stop and release. Fails on a frame timeout, on too many
    /// incomplete frames or when control is lost.
    pub fn capture_raw_blocking(
        &self,
        frames: u32,
        frame_timeout: Duration,
    ) -> Result<(Vec<Frame>, CaptureStats)> {
        self.capture_configured(frames, frame_timeout, |_, _| Ok(()))
            .map(|(f, s, ())| (f, s))
    }

    /// [`Self::capture_raw_blocking`], running `configured` once the camera is configured
    /// (settings applied, components enabled) and before it streams: what it reads is what the
    /// frames are made with.
    fn capture_configured<T>(
        &self,
        frames: u32,
        frame_timeout: Duration,
        configured: impl FnOnce(&mut NodeMap, &mut GvcpPort) -> Result<T>,
    ) -> Result<(Vec<Frame>, CaptureStats, T)> {
        let o = &self.options;
        let client = self.client();
        let control = client.take_control()?;
        self.with_features(|n, p| {
            n.take_over(p)?;
            crate::settings::apply(n, p, &o.settings)
        })?;
        let caps = client.read_reg(reg::GVCP_CAPABILITY)?;
        client.write_reg(reg::SCPS0, o.packet_size & 0xFFFF)?;
        let packet_size = (client.read_reg(reg::SCPS0)? & 0xFFFF) as usize;
        let mut extended = false;
        let offers_range = self.with_features(|n, _| {
            Ok(n.enum_entries("ComponentSelector")
                .is_ok_and(|e| e.iter().any(|c| c == "Range")))
        })?;
        if offers_range {
            match self.enable_components(&client, o.confidence) {
                Ok(()) => extended = true,
                Err(e) => tracing::warn!(
                    "multi-part not available, streaming the camera's single image: {e}"
                ),
            }
        }
        let before = self.with_features(configured)?;
        let local_ip = local_ip_towards(self.peer)?;
        let rcfg = StreamConfig {
            packet_size,
            extended,
            resend: o.resend && caps & cap::PACKET_RESEND != 0,
            ..o.receiver.clone()
        };
        let mut rx = StreamReceiver::bind(local_ip, self.peer, rcfg)?;
        let port = rx.local_addr()?.port();
        client.write_reg(reg::SCDA0, u32::from(local_ip))?;
        client.write_reg(reg::SCP0, u32::from(port))?;
        self.with_features(|n, p| {
            if n.has("AcquisitionMode") {
                n.set_enum(p, "AcquisitionMode", "Continuous")?;
            }
            trigger::prepare(n, p, o.trigger)?;
            if n.has("TLParamsLocked") {
                n.set_switch(p, "TLParamsLocked", true)?;
            }
            n.execute(p, "AcquisitionStart")
        })?;
        let mut out = Vec::new();
        let mut stats = CaptureStats::default();
        let result = (|| {
            while out.len() < frames as usize {
                control.check()?;
                self.with_features(|n, p| trigger::fire(n, p, o.trigger))?;
                let f = rx.next_frame(frame_timeout)?;
                stats.resent_packets += u64::from(f.resent_packets);
                if f.complete {
                    stats.complete += 1;
                    out.push(f);
                } else {
                    stats.incomplete += 1;
                    tracing::warn!(
                        block_id = f.block_id,
                        missing = f.missing_packets,
                        "incomplete frame dropped"
                    );
                    if stats.incomplete > o.max_incomplete {
                        return Err(GigeError::FrameTimeout {
                            timeout: frame_timeout,
                            detail: format!("{} incomplete frames (packets lost); lower the frame rate or packet size, or raise the receive buffer", stats.incomplete),
                        });
                    }
                }
            }
            Ok(())
        })();
        stats.stream = rx.stats();
        // Stop even after an error; report the first error.
        let stop = self.with_features(|n, p| {
            n.execute(p, "AcquisitionStop")?;
            if n.has("TLParamsLocked") {
                n.set_switch(p, "TLParamsLocked", false)?;
            }
            Ok(())
        });
        let close = client.write_reg(reg::SCP0, 0);
        drop(control);
        result?;
        stop?;
        close?;
        Ok((out, stats, before))
    }

    /// Enable the Range component (and Confidence when asked and offered) and ask for a
    /// multi-part payload: cameras that offer components send them so (Photoneo sends its
    /// intensity first and the rest as chunks otherwise).
    fn enable_components(&self, client: &GvcpClient, confidence: bool) -> Result<()> {
        self.with_features(|n, p| {
            if confidence {
                let on = n
                    .set_enum(p, "ComponentSelector", "Confidence")
                    .and_then(|()| {
                        if n.has("ComponentEnable") {
                            n.set_boolean(p, "ComponentEnable", true)
                        } else {
                            Ok(())
                        }
                    });
                if let Err(e) = on {
                    tracing::warn!("confidence not available, streaming the range only: {e}");
                }
            }
            n.set_enum(p, "ComponentSelector", "Range")?;
            if n.has("ComponentEnable") {
                n.set_boolean(p, "ComponentEnable", true)?;
            }
            Ok(())
        })?;
        client.write_reg(reg::GVSP_CONFIG, 0x4000_0000)?;
        client.write_reg(reg::SCCFG0, 0x40)
    }

    /// Capture and decode `frames` point clouds (metres, camera frame).
    pub fn capture_blocking(
        &self,
        frames: u32,
        frame_timeout: Duration,
    ) -> Result<(Vec<PointCloud>, CaptureStats)> {
        let (raw, stats, (scan3d, layout)) =
            self.capture_configured(frames, frame_timeout, |n, p| {
                Ok((Scan3d::read(n, p)?, ChunkLayout::read(n, p)?))
            })?;
        let clouds = raw
            .iter()
            .map(|f| decode::decode_payload(&f.parts, layout.as_ref(), &scan3d))
            .collect::<Result<Vec<_>>>()?;
        Ok((clouds, stats))
    }
}

async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T> + Send + 'static,
) -> Result<T, HalError> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| HalError::Protocol {
            peer: "GigE Vision camera".into(),
            detail: format!("capture thread failed: {e}"),
        })?
        .map_err(HalError::from)
}

impl DepthCamera for GigeCamera {
    async fn info(&self) -> Result<CameraInfo, HalError> {
        let cam = self.clone();
        blocking(move || cam.info_blocking()).await
    }

    async fn capture(&self, settings: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
        let cam = self.clone();
        let (n, t, exposure) = (settings.frames, settings.frame_timeout, settings.exposure);
        blocking(move || {
            if let Some(e) = exposure {
                cam.with_features(|nm, p| {
                    if nm.has("ExposureTime") {
                        nm.set_float(p, "ExposureTime", e.as_secs_f64() * 1e6)
                    } else {
                        tracing::warn!(
                            "camera has no ExposureTime feature; exposure setting ignored"
                        );
                        Ok(())
                    }
                })?;
            }
            cam.capture_blocking(n, t).map(|(c, _)| c)
        })
        .await
    }
}
