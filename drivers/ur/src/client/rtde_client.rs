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

/// One output data package, decoded.
#[derive(Debug, Clone)]
pub struct Sample {
    names: Arc<Vec<String>>,
    values: Vec<Value>,
    /// When it arrived.
    pub received: Instant,
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

    /// Wait for a sample that arrived after `after` (at most `timeout`).
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
                        return Ok(s);
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
                    latest.send_replace(Some(Arc::new(Sample {
                        names: names.clone(),
                        values,
                        received: Instant::now(),
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
