//! RTDE client: handshake (v2, falling back to v1), output recipe at a chosen frequency, input
//! recipes, streaming into a "latest sample" cell, and reconnection with bounded backoff that
//! repeats the whole handshake (recipes included).

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::io::{AsyncWriteExt, BufReader};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::sync::{mpsc, oneshot, watch};

use crate::rtde::{
    self, ClientPackage, FieldType, FrameReadError, PackageType, Protocol, ServerPackage, Value,
};
use crate::UrError;

/// What to set up.
#[derive(Debug, Clone)]
pub struct RtdeConfig {
    /// Controller address (port 30004 normally).
    pub addr: SocketAddr,
    /// Output frequency, Hz (≤125 CB3, ≤500 e-Series); `None` = the controller's maximum.
    pub frequency: Option<f64>,
    /// Output field names.
    pub outputs: Vec<String>,
    /// Input recipes (field names each).
    pub inputs: Vec<Vec<String>>,
    /// Limit for connecting and for each setup reply.
    pub timeout: Duration,
    /// Longest wait between reconnection attempts (backoff doubles from 100 ms up to this).
    pub max_backoff: Duration,
}

/// Longest the controller's `timestamp` may stand still while its data packages keep
/// arriving: 25 packages at 125 Hz. A controller's clock advances with every package (2 ms at
/// 500 Hz, 8 ms at 125 Hz); packages that keep coming with the same time are replays of an
/// old one (a device between the controller and this PC that buffers or repeats them), whose
/// values are not the arm's now.
pub const MAX_FROZEN_TIMESTAMP: Duration = Duration::from_millis(200);

/// How long a step back of the controller's `timestamp` (a package older than the one before
/// it) keeps the stream untrusted. TCP delivers bytes in order, so a step back means packages
/// were reordered or replayed by something between the controller and this PC: every sample
/// within this time after the last one is refused, not just the ones that arrived late.
pub const REORDERED_HOLD: Duration = Duration::from_secs(2);

/// What is wrong with the stream of data packages as a whole, judged by the controller's own
/// `timestamp` in them (seconds since the controller started).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StreamFault {
    /// Packages keep arriving but the controller's timestamp has stood at `timestamp_s` for
    /// `for_s` seconds (longer than [`MAX_FROZEN_TIMESTAMP`]).
    Frozen {
        /// The timestamp that does not advance, s.
        timestamp_s: f64,
        /// How long it has not advanced, s.
        for_s: f64,
    },
    /// A package's timestamp `to_s` was earlier than an earlier package's `from_s` (within
    /// the last [`REORDERED_HOLD`]).
    Backwards {
        /// The latest timestamp seen before, s.
        from_s: f64,
        /// The earlier one that arrived after it, s.
        to_s: f64,
    },
    /// The timestamp is not a finite number.
    NotFinite {
        /// What arrived.
        timestamp_s: f64,
    },
}

impl std::fmt::Display for StreamFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            StreamFault::Frozen { timestamp_s, for_s } => write!(
                f,
                "the controller's RTDE data stopped advancing (timestamp {timestamp_s:.3} s for \
                 {for_s:.1} s): its packages keep arriving with the same time and values, so they \
                 are not the arm's now"
            ),
            StreamFault::Backwards { from_s, to_s } => write!(
                f,
                "the controller's RTDE data arrived out of order (timestamp {to_s:.3} s after \
                 {from_s:.3} s): its packages are reordered or replayed on the way"
            ),
            StreamFault::NotFinite { timestamp_s } => write!(
                f,
                "the controller's RTDE timestamp is {timestamp_s}, not a time"
            ),
        }
    }
}

/// The controller's clock as the stream shows it: the newest `timestamp` and when it last
/// advanced, and the last step back. Pure (the time of arrival is passed in), so the rules
/// are tested without a network.
#[derive(Debug, Clone, Default)]
pub struct ControllerClock {
    /// Newest timestamp seen (s) and when it arrived.
    newest: Option<(f64, Instant)>,
    /// When the last step back arrived, and the fault it was.
    backwards: Option<(Instant, StreamFault)>,
}

impl ControllerClock {
    /// Takes the timestamp of a package that arrived at `now`; returns what is wrong with the
    /// stream as of this package, if anything.
    pub fn observe(&mut self, timestamp_s: f64, now: Instant) -> Option<StreamFault> {
        if !timestamp_s.is_finite() {
            return Some(StreamFault::NotFinite { timestamp_s });
        }
        match self.newest {
            Some((newest, _)) if timestamp_s < newest => {
                let fault = StreamFault::Backwards {
                    from_s: newest,
                    to_s: timestamp_s,
                };
                self.backwards = Some((now, fault));
            }
            Some((newest, _)) if timestamp_s == newest => {}
            _ => self.newest = Some((timestamp_s, now)),
        }
        if let Some((at, fault)) = self.backwards {
            if now.saturating_duration_since(at) < REORDERED_HOLD {
                return Some(fault);
            }
            self.backwards = None;
        }
        match self.newest {
            Some((newest, since))
                if timestamp_s == newest
                    && now.saturating_duration_since(since) > MAX_FROZEN_TIMESTAMP =>
            {
                Some(StreamFault::Frozen {
                    timestamp_s,
                    for_s: now.saturating_duration_since(since).as_secs_f64(),
                })
            }
            _ => None,
        }
    }
}

/// One output data package, decoded.
#[derive(Debug, Clone)]
pub struct Sample {
    names: Arc<Vec<String>>,
    values: Vec<Value>,
    /// When it arrived.
    pub received: Instant,
    /// What the controller's `timestamp` says about the stream at this package (when the
    /// output recipe holds `timestamp`): a faulty sample's values are not the arm's now.
    pub fault: Option<StreamFault>,
}

impl Sample {
    /// A field's value.
    pub fn get(&self, name: &str) -> Option<Value> {
        self.names
            .iter()
            .position(|n| n == name)
            .map(|i| self.values[i])
    }

    /// A scalar field as f64.
    pub fn f64(&self, name: &str) -> Option<f64> {
        self.get(name).and_then(|v| v.as_f64())
    }

    /// A VECTOR6D field.
    pub fn vec6(&self, name: &str) -> Option<[f64; 6]> {
        self.get(name).and_then(|v| v.as_vec6())
    }

    /// This sample, unless the stream it came in is faulty ([`Sample::fault`]).
    pub fn trusted(self: Arc<Self>) -> Result<Arc<Self>, UrError> {
        match self.fault {
            Some(fault) => Err(UrError::Stream(fault)),
            None => Ok(self),
        }
    }
}

/// Controller version reported by `v`.
pub type ControllerVersion = [u32; 4];

enum Cmd {
    Write {
        recipe: usize,
        values: Vec<Value>,
        done: oneshot::Sender<Result<(), UrError>>,
    },
}

/// A running RTDE client. Dropping it closes the connection.
#[derive(Debug)]
pub struct RtdeClient {
    latest: watch::Receiver<Option<Arc<Sample>>>,
    cmd: mpsc::Sender<Cmd>,
    reconnects: Arc<AtomicU64>,
    version: ControllerVersion,
    protocol: Protocol,
    input_types: Vec<Vec<FieldType>>,
    task: tokio::task::JoinHandle<()>,
}

impl std::fmt::Debug for Cmd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Cmd")
    }
}

impl Drop for RtdeClient {
    fn drop(&mut self) {
        self.task.abort();
    }
}

struct Link {
    reader: OwnedReadHalf,
    w: OwnedWriteHalf,
    proto: Protocol,
    version: ControllerVersion,
    output_types: Vec<FieldType>,
    input_ids: Vec<u8>,
}

async fn send(
    w: &mut OwnedWriteHalf,
    p: &ClientPackage,
    proto: Protocol,
    peer: SocketAddr,
) -> Result<(), UrError> {
    let b = p.encode(proto)?;
    w.write_all(&b).await.map_err(|source| UrError::Io {
        peer: peer.to_string(),
        source,
    })
}

/// Wait for the reply of type `kind`, skipping text messages and stray data packages.
async fn reply(
    r: &mut BufReader<OwnedReadHalf>,
    kind: PackageType,
    proto: Protocol,
    cfg: &RtdeConfig,
) -> Result<ServerPackage, UrError> {
    let deadline = Instant::now() + cfg.timeout;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let f = tokio::time::timeout(left, rtde::read_frame(r))
            .await
            .map_err(|_| UrError::Timeout {
                what: format!("RTDE reply to {kind:?}"),
                after: cfg.timeout,
            })?
            .map_err(|e| match e {
                FrameReadError::Io(source) => UrError::Io {
                    peer: cfg.addr.to_string(),
                    source,
                },
                FrameReadError::Protocol(e) => e,
            })?
            .ok_or_else(|| UrError::Io {
                peer: cfg.addr.to_string(),
                source: std::io::Error::new(
                    std::io::ErrorKind::UnexpectedEof,
                    "controller closed the RTDE connection",
                ),
            })?;
        if f.kind == kind {
            return ServerPackage::decode(&f, proto);
        }
        match f.kind {
            PackageType::TextMessage => {
                if let Ok(ServerPackage::Text(t)) = ServerPackage::decode(&f, proto) {
                    tracing::warn!(level = t.level, "RTDE controller message: {}", t.message);
                }
            }
            PackageType::DataPackage if kind == PackageType::Start => {
                // URCL: a data package arriving before the start reply means started.
                return Ok(ServerPackage::Start(true));
            }
            PackageType::DataPackage => {}
            other => {
                return Err(UrError::malformed(
                    "RTDE",
                    format!("expected a {kind:?} reply, got {other:?}"),
                ))
            }
        }
    }
}

fn check_types(
    names: &[String],
    types: &[String],
    outputs: bool,
) -> Result<Vec<FieldType>, UrError> {
    if types.len() != names.len() {
        return Err(UrError::malformed(
            "RTDE",
            format!(
                "setup reply has {} types for {} fields",
                types.len(),
                names.len()
            ),
        ));
    }
    names
        .iter()
        .zip(types)
        .map(|(n, t)| match t.as_str() {
            "NOT_FOUND" => Err(UrError::FieldNotFound { name: n.clone() }),
            "IN_USE" if !outputs => Err(UrError::in_use(n)),
            t => FieldType::from_wire_name(t)
                .ok_or_else(|| UrError::malformed("RTDE", format!("unknown type `{t}` for `{n}`"))),
        })
        .collect()
}

async fn handshake(cfg: &RtdeConfig) -> Result<Link, UrError> {
    let sock = crate::connect_within(cfg.addr, cfg.timeout, || {
        format!("RTDE connect to {}", cfg.addr)
    })
    .await?;
    let _ = sock.set_nodelay(true);
    let (r, mut w) = sock.into_split();
    let mut r = BufReader::new(r);
    let peer = cfg.addr;
    let mut proto = Protocol::V2;
    for v in [2u16, 1] {
        send(
            &mut w,
            &ClientPackage::RequestProtocolVersion(v),
            Protocol::V2,
            peer,
        )
        .await?;
        match reply(
            &mut r,
            PackageType::RequestProtocolVersion,
            Protocol::V2,
            cfg,
        )
        .await?
        {
            ServerPackage::ProtocolVersionAccepted(true) => {
                proto = if v == 2 { Protocol::V2 } else { Protocol::V1 };
                break;
            }
            _ if v == 1 => {
                return Err(UrError::Refused {
                    device: "RTDE",
                    request: "protocol version 2 or 1".into(),
                    reason: "refused both".into(),
                })
            }
            _ => tracing::info!("controller refused RTDE protocol 2; trying 1"),
        }
    }
    send(&mut w, &ClientPackage::GetUrcontrolVersion, proto, peer).await?;
    let version = match reply(&mut r, PackageType::GetUrcontrolVersion, proto, cfg).await? {
        ServerPackage::UrcontrolVersion {
            major,
            minor,
            bugfix,
            build,
        } => [major, minor, bugfix, build],
        other => return Err(UrError::malformed("RTDE", format!("unexpected {other:?}"))),
    };
    let max_hz = if version[0] < 5 { 125.0 } else { 500.0 };
    let hz = cfg.frequency.unwrap_or(max_hz);
    if !(hz > 0.0 && hz <= max_hz) {
        return Err(UrError::InvalidArgument(format!(
            "RTDE frequency {hz} Hz is outside 0–{max_hz} Hz for controller {version:?}"
        )));
    }
    send(
        &mut w,
        &ClientPackage::SetupOutputs {
            frequency: Some(hz),
            names: cfg.outputs.clone(),
        },
        proto,
        peer,
    )
    .await?;
    let output_types = match reply(&mut r, PackageType::SetupOutputs, proto, cfg).await? {
        ServerPackage::SetupOutputs { recipe_id, types } => {
            let t = check_types(&cfg.outputs, &types, true)?;
            if recipe_id == Some(0) {
                return Err(UrError::Refused {
                    device: "RTDE",
                    request: "output recipe".into(),
                    reason: "recipe id 0 (invalid)".into(),
                });
            }
            t
        }
        other => return Err(UrError::malformed("RTDE", format!("unexpected {other:?}"))),
    };
    let mut input_ids = Vec::new();
    for names in &cfg.inputs {
        send(
            &mut w,
            &ClientPackage::SetupInputs {
                names: names.clone(),
            },
            proto,
            peer,
        )
        .await?;
        match reply(&mut r, PackageType::SetupInputs, proto, cfg).await? {
            ServerPackage::SetupInputs { recipe_id, types } => {
                check_types(names, &types, false)?;
                let id = recipe_id.unwrap_or(1);
                if id == 0 {
                    return Err(UrError::Refused {
                        device: "RTDE",
                        request: format!("input recipe {names:?}"),
                        reason: "recipe id 0 (invalid)".into(),
                    });
                }
                input_ids.push(id);
            }
            other => return Err(UrError::malformed("RTDE", format!("unexpected {other:?}"))),
        }
    }
    send(&mut w, &ClientPackage::Start, proto, peer).await?;
    match reply(&mut r, PackageType::Start, proto, cfg).await? {
        ServerPackage::Start(true) => {}
        _ => {
            return Err(UrError::Refused {
                device: "RTDE",
                request: "start".into(),
                reason: "start refused".into(),
            })
        }
    }
    Ok(Link {
        reader: r.into_inner(),
        w,
        proto,
        version,
        output_types,
        input_ids,
    })
}

impl RtdeClient {
    /// Connect and perform the handshake; errors (NOT_FOUND, IN_USE, refusals) are returned
    /// here. Afterwards a background task keeps the connection alive and reconnects.
    pub async fn connect(cfg: RtdeConfig) -> Result<Self, UrError> {
        let link = handshake(&cfg).await?;
        let (latest_tx, latest) = watch::channel(None);
        let (cmd, cmd_rx) = mpsc::channel(16);
        let reconnects = Arc::new(AtomicU64::new(0));
        let version = link.version;
        let protocol = link.proto;
        let input_types = cfg
            .inputs
            .iter()
            .map(|names| {
                names
                    .iter()
                    .map(|n| rtde::field_type(n).unwrap_or(FieldType::Double))
                    .collect()
            })
            .collect();
        let task = tokio::spawn(run(cfg, link, latest_tx, cmd_rx, reconnects.clone()));
        Ok(Self {
            latest,
            cmd,
            reconnects,
            version,
            protocol,
            input_types,
            task,
        })
    }

    /// Controller version from the first handshake.
    pub fn version(&self) -> ControllerVersion {
        self.version
    }

    /// Protocol version negotiated at the first handshake.
    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    /// How many times the link was re-established.
    pub fn reconnects(&self) -> u64 {
        self.reconnects.load(Ordering::Relaxed)
    }

    /// The newest sample, if any.
    pub fn latest(&self) -> Option<Arc<Sample>> {
        self.latest.borrow().clone()
    }

    /// Wait for a sample that arrived after `after` (at most `timeout`); a sample whose
    /// stream is faulty ([`Sample::fault`]: the controller's timestamp stands still or went
    /// back) is an error, [`UrError::Stream`].
    pub async fn next_sample(
        &self,
        after: Instant,
        timeout: Duration,
    ) -> Result<Arc<Sample>, UrError> {
        let mut rx = self.latest.clone();
        let fut = async {
            loop {
                if let Some(s) = rx.borrow_and_update().clone() {
                    if s.received > after {
                        return s.trusted();
                    }
                }
                if rx.changed().await.is_err() {
                    return Err(UrError::Io {
                        peer: "RTDE".into(),
                        source: std::io::Error::new(
                            std::io::ErrorKind::BrokenPipe,
                            "RTDE client stopped",
                        ),
                    });
                }
            }
        };
        tokio::time::timeout(timeout, fut)
            .await
            .map_err(|_| UrError::Timeout {
                what: "RTDE data".into(),
                after: timeout,
            })?
    }

    /// Send values for input recipe `recipe` (index into [`RtdeConfig::inputs`]).
    pub async fn write(&self, recipe: usize, values: Vec<Value>) -> Result<(), UrError> {
        let types = self
            .input_types
            .get(recipe)
            .ok_or_else(|| UrError::InvalidArgument(format!("no input recipe {recipe}")))?;
        if types.len() != values.len()
            || types.iter().zip(&values).any(|(t, v)| *t != v.field_type())
        {
            return Err(UrError::InvalidArgument(format!(
                "values do not match input recipe {recipe} ({types:?})"
            )));
        }
        if self.protocol == Protocol::V1 && self.input_types.len() > 1 {
            return Err(UrError::InvalidArgument(
                "this controller speaks RTDE protocol 1 only, whose data packages cannot say which of several input recipes they fill; update PolyScope (3.3+) to write registers".into(),
            ));
        }
        let (done, rx) = oneshot::channel();
        let gone = || UrError::Io {
            peer: "RTDE".into(),
            source: std::io::Error::new(std::io::ErrorKind::BrokenPipe, "RTDE client stopped"),
        };
        self.cmd
            .send(Cmd::Write {
                recipe,
                values,
                done,
            })
            .await
            .map_err(|_| gone())?;
        rx.await.map_err(|_| gone())?
    }
}

async fn read_loop(
    reader: OwnedReadHalf,
    proto: Protocol,
    names: Arc<Vec<String>>,
    types: Vec<FieldType>,
    latest: watch::Sender<Option<Arc<Sample>>>,
    silence: Duration,
) -> UrError {
    let mut r = BufReader::new(reader);
    let timestamp = names.iter().position(|n| n == "timestamp");
    let mut clock = ControllerClock::default();
    loop {
        let Ok(read) = tokio::time::timeout(silence, rtde::read_frame(&mut r)).await else {
            return UrError::Timeout {
                what: "RTDE data stream".into(),
                after: silence,
            };
        };
        let f = match read {
            Ok(Some(f)) => f,
            Ok(None) => {
                return UrError::Io {
                    peer: "RTDE".into(),
                    source: std::io::Error::new(
                        std::io::ErrorKind::UnexpectedEof,
                        "controller closed the connection",
                    ),
                }
            }
            Err(FrameReadError::Io(source)) => {
                return UrError::Io {
                    peer: "RTDE".into(),
                    source,
                }
            }
            Err(FrameReadError::Protocol(e)) => return e,
        };
        match ServerPackage::decode(&f, proto) {
            Ok(ServerPackage::Data { body, .. }) => match rtde::decode_values(&types, &body) {
                Ok(values) => {
                    let received = Instant::now();
                    let fault = timestamp
                        .and_then(|i| values.get(i)?.as_f64())
                        .and_then(|t| clock.observe(t, received));
                    latest.send_replace(Some(Arc::new(Sample {
                        names: names.clone(),
                        values,
                        received,
                        fault,
                    })));
                }
                Err(e) => return e,
            },
            Ok(ServerPackage::Text(t)) => {
                tracing::warn!(level = t.level, "RTDE controller message: {}", t.message)
            }
            Ok(_) => {}
            Err(e) => return e,
        }
    }
}

async fn run(
    cfg: RtdeConfig,
    first: Link,
    latest: watch::Sender<Option<Arc<Sample>>>,
    mut cmd: mpsc::Receiver<Cmd>,
    reconnects: Arc<AtomicU64>,
) {
    let names = Arc::new(cfg.outputs.clone());
    let mut link = Some(first);
    let mut backoff = Duration::from_millis(100);
    loop {
        let l = match link.take() {
            Some(l) => l,
            None => match handshake(&cfg).await {
                Ok(l) => {
                    reconnects.fetch_add(1, Ordering::Relaxed);
                    backoff = Duration::from_millis(100);
                    tracing::info!("RTDE reconnected to {}", cfg.addr);
                    l
                }
                Err(e) => {
                    tracing::warn!(
                        "RTDE reconnect to {} failed: {e}; retrying in {backoff:?}",
                        cfg.addr
                    );
                    // Fail writes while disconnected rather than queueing them.
                    let sleep = tokio::time::sleep(backoff);
                    tokio::pin!(sleep);
                    loop {
                        tokio::select! {
                            _ = &mut sleep => break,
                            c = cmd.recv() => match c {
                                Some(Cmd::Write { done, .. }) => {
                                    let _ = done.send(Err(UrError::Io {
                                        peer: cfg.addr.to_string(),
                                        source: std::io::Error::new(std::io::ErrorKind::NotConnected, "RTDE is reconnecting"),
                                    }));
                                }
                                None => return,
                            }
                        }
                    }
                    backoff = (backoff * 2).min(cfg.max_backoff);
                    continue;
                }
            },
        };
        let Link {
            reader,
            mut w,
            proto,
            output_types,
            input_ids,
            ..
        } = l;
        let mut reader_task = tokio::spawn(read_loop(
            reader,
            proto,
            names.clone(),
            output_types,
            latest.clone(),
            cfg.timeout.max(Duration::from_secs(1)),
        ));
        let err = loop {
            tokio::select! {
                e = &mut reader_task => break e.unwrap_or_else(|j| UrError::malformed("RTDE", format!("reader task failed: {j}"))),
                c = cmd.recv() => match c {
                    Some(Cmd::Write { recipe, values, done }) => {
                        let mut body = Vec::new();
                        rtde::encode_values(&values, &mut body);
                        let pkg = ClientPackage::Data { recipe_id: input_ids.get(recipe).copied(), body };
                        let r = send(&mut w, &pkg, proto, cfg.addr).await;
                        let failed = r.is_err();
                        let _ = done.send(r);
                        if failed {
                            reader_task.abort();
                            break UrError::malformed("RTDE", "write failed");
                        }
                    }
                    None => {
                        reader_task.abort();
                        let _ = send(&mut w, &ClientPackage::Pause, proto, cfg.addr).await;
                        return;
                    }
                }
            }
        };
        tracing::warn!("RTDE link to {} lost: {err}; reconnecting", cfg.addr);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    /// A controller's clock at 125 Hz: every package 8 ms later than the one before.
    #[test]
    fn an_advancing_clock_is_no_fault() {
        let t0 = Instant::now();
        let mut clock = ControllerClock::default();
        for i in 0..1000u32 {
            let ts = 12.0 + f64::from(i) * 0.008;
            assert_eq!(clock.observe(ts, t0 + 8 * MS * i), None, "package {i}");
        }
    }

    #[test]
    fn a_timestamp_standing_still_longer_than_the_bound_is_frozen() {
        let t0 = Instant::now();
        let mut clock = ControllerClock::default();
        assert_eq!(clock.observe(5.0, t0), None);
        // The same package again within the bound: a repeat is tolerated that long.
        assert_eq!(clock.observe(5.0, t0 + MAX_FROZEN_TIMESTAMP), None);
        let late = t0 + MAX_FROZEN_TIMESTAMP + 100 * MS;
        let fault = clock.observe(5.0, late).expect("frozen");
        let StreamFault::Frozen { timestamp_s, for_s } = fault else {
            panic!("{fault:?}")
        };
        assert_eq!(timestamp_s, 5.0);
        assert!((for_s - 0.3).abs() < 1e-6, "{for_s}");
        let text = fault.to_string();
        assert!(
            text.contains("stopped advancing (timestamp 5.000 s for 0.3 s)"),
            "{text}"
        );
        // Once the clock moves again, the stream is trusted again.
        assert_eq!(clock.observe(5.008, late + 8 * MS), None);
    }

    #[test]
    fn a_timestamp_going_back_taints_the_stream_for_the_hold() {
        let t0 = Instant::now();
        let mut clock = ControllerClock::default();
        assert_eq!(clock.observe(1.008, t0), None);
        let back = clock.observe(1.000, t0 + 8 * MS).expect("backwards");
        assert_eq!(
            back,
            StreamFault::Backwards {
                from_s: 1.008,
                to_s: 1.0
            }
        );
        assert!(
            back.to_string()
                .contains("out of order (timestamp 1.000 s after 1.008 s)"),
            "{back}"
        );
        // The packages after it advance, but the stream stays untrusted for the hold.
        assert_eq!(clock.observe(1.016, t0 + 16 * MS), Some(back));
        assert_eq!(
            clock.observe(1.5, t0 + 8 * MS + REORDERED_HOLD - MS),
            Some(back)
        );
        assert_eq!(clock.observe(1.6, t0 + 8 * MS + REORDERED_HOLD), None);
    }

    /// Pairs swapped (what the fault proxy's `Reordered` does): every other package goes
    /// back, so every sample from the first swap on is refused.
    #[test]
    fn pairs_swapped_are_refused_throughout() {
        let t0 = Instant::now();
        let mut clock = ControllerClock::default();
        let mut faults = 0;
        for pair in 0..100u32 {
            for k in [1, 0] {
                let i = 2 * pair + k;
                let at = t0 + 8 * MS * (2 * pair + 1 - k);
                faults += usize::from(clock.observe(f64::from(i) * 0.008, at).is_some());
            }
        }
        // Only the very first package (1 before 0) is taken.
        assert_eq!(faults, 199);
    }

    #[test]
    fn a_timestamp_that_is_no_number_is_a_fault() {
        let mut clock = ControllerClock::default();
        let f = clock.observe(f64::NAN, Instant::now()).expect("NaN");
        assert!(matches!(f, StreamFault::NotFinite { .. }), "{f:?}");
        assert!(clock.observe(f64::INFINITY, Instant::now()).is_some());
    }
}
