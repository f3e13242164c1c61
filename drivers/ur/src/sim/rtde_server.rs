//! RTDE server (30004): handshake, recipes, NOT_FOUND / IN_USE, streaming, inputs.

use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncWriteExt, BufReader};
use tokio::net::tcp::OwnedWriteHalf;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;

use super::Shared;
use crate::rtde::{
    self, ClientPackage, FieldType, Frame, FrameReadError, Protocol, ServerPackage, TextMessage,
};
use crate::UrError;

/// Most input recipes one connection may hold (ur_rtde uses 23).
const MAX_INPUT_RECIPES: usize = 255;

pub(crate) async fn serve(listener: TcpListener, shared: Arc<Shared>) {
    super::accept_loop(listener, shared, "RTDE", |sock, shared| async move {
        let id = {
            let mut s = shared.lock();
            s.next_conn += 1;
            s.next_conn
        };
        let _release = ReleaseInputs {
            shared: shared.clone(),
            id,
        };
        connection(sock, &shared, id).await
    })
    .await;
}

/// Releases every input a connection owned when the connection ends, however it ends
/// (closed by the peer, an error, or dropped by fault injection).
struct ReleaseInputs {
    shared: Arc<Shared>,
    id: u64,
}

impl Drop for ReleaseInputs {
    fn drop(&mut self) {
        self.shared
            .lock()
            .owners
            .retain(|_, owner| *owner != self.id);
    }
}

struct Conn {
    proto: Protocol,
    outputs: Vec<(String, FieldType)>,
    period: Duration,
    inputs: Vec<(Vec<String>, Vec<FieldType>)>,
    streaming: bool,
}

async fn send(
    w: &mut OwnedWriteHalf,
    shared: &Shared,
    proto: Protocol,
    p: ServerPackage,
    delay: bool,
) -> Result<(), UrError> {
    if delay {
        let latency = shared.lock().latency;
        if !latency.is_zero() {
            tokio::time::sleep(latency).await;
        }
    }
    let bytes = p.encode(proto)?;
    w.write_all(&bytes).await.map_err(|source| UrError::Io {
        peer: "RTDE client".into(),
        source,
    })
}

async fn connection(sock: TcpStream, shared: &Shared, id: u64) -> Result<(), UrError> {
    let _ = sock.set_nodelay(true);
    let (r, mut w) = sock.into_split();
    // A reader task turns bytes into frames, so the stream loop below stays cancel-safe.
    let (tx, mut rx) = mpsc::channel::<Result<Frame, UrError>>(8);
    let reader = tokio::spawn(async move {
        let mut r = BufReader::new(r);
        loop {
            let res = match rtde::read_frame(&mut r).await {
                Ok(Some(f)) => Ok(f),
                Ok(None) => break,
                Err(FrameReadError::Io(_)) => break,
                Err(FrameReadError::Protocol(e)) => Err(e),
            };
            let stop = res.is_err();
            if tx.send(res).await.is_err() || stop {
                break;
            }
        }
    });
    let _reader_guard = AbortOnDrop(reader);
    let max_hz = if shared.config.model.is_cb3() {
        125.0
    } else {
        500.0
    };
    let mut c = Conn {
        proto: Protocol::V2,
        outputs: Vec::new(),
        period: Duration::from_millis(8),
        inputs: Vec::new(),
        streaming: false,
    };
    let mut tick = tokio::time::interval(c.period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut body = Vec::new();
    loop {
        tokio::select! {
            f = rx.recv() => {
                let Some(f) = f else { return Ok(()) };
                let f = match f {
                    Ok(f) => f,
                    Err(e) => {
                        // Tell the client why, then close.
                        let msg = TextMessage { message: e.to_string(), source: "RTDE".into(), level: 1 };
                        let _ = send(&mut w, shared, c.proto, ServerPackage::Text(msg), false).await;
                        return Err(e);
                    }
                };
                let pkg = match ClientPackage::decode(&f, c.proto) {
                    Ok(p) => p,
                    Err(e) => {
                        let msg = TextMessage { message: e.to_string(), source: "RTDE".into(), level: 1 };
                        let _ = send(&mut w, shared, c.proto, ServerPackage::Text(msg), false).await;
                        return Err(e);
                    }
                };
                let reply = handle(&mut c, shared, id, pkg, max_hz)?;
                if let Some(reply) = reply {
                    send(&mut w, shared, c.proto, reply, true).await?;
                }
                if tick.period() != c.period {
                    tick = tokio::time::interval(c.period);
                    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
                }
            }
            _ = tick.tick(), if c.streaming => {
                body.clear();
                {
                    let s = shared.lock();
                    for (name, t) in &c.outputs {
                        s.output(name, *t).encode(&mut body);
                    }
                }
                let pkg = ServerPackage::Data { recipe_id: Some(1), body: std::mem::take(&mut body) };
                send(&mut w, shared, c.proto, pkg, false).await?;
            }
        }
    }
}

struct AbortOnDrop(tokio::task::JoinHandle<()>);
impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

fn handle(
    c: &mut Conn,
    shared: &Shared,
    id: u64,
    pkg: ClientPackage,
    max_hz: f64,
) -> Result<Option<ServerPackage>, UrError> {
    Ok(Some(match pkg {
        ClientPackage::RequestProtocolVersion(v) => {
            let ok = v == 1 || (v == 2 && shared.config.rtde_v2);
            if ok {
                c.proto = if v == 2 { Protocol::V2 } else { Protocol::V1 };
            }
            ServerPackage::ProtocolVersionAccepted(ok)
        }
        ClientPackage::GetUrcontrolVersion => {
            let (major, minor, bugfix, build) = shared.version();
            ServerPackage::UrcontrolVersion {
                major,
                minor,
                bugfix,
                build,
            }
        }
        ClientPackage::SetupOutputs { frequency, names } => {
            let hz = frequency.unwrap_or(max_hz).clamp(1.0, max_hz);
            let mut types = Vec::with_capacity(names.len());
            let mut valid = !names.is_empty();
            let mut outputs = Vec::with_capacity(names.len());
            for n in names {
                match rtde::field_type(&n) {
                    Some(t) => {
                        types.push(t.wire_name().to_string());
                        outputs.push((n, t));
                    }
                    None => {
                        types.push("NOT_FOUND".into());
                        valid = false;
                    }
                }
            }
            if valid {
                c.outputs = outputs;
                c.period = Duration::from_secs_f64(1.0 / hz);
            }
            ServerPackage::SetupOutputs {
                recipe_id: Some(u8::from(valid)),
                types,
            }
        }
        ClientPackage::SetupInputs { names } => {
            let mut s = shared.lock();
            let mut types = Vec::with_capacity(names.len());
            let mut valid = !names.is_empty() && c.inputs.len() < MAX_INPUT_RECIPES;
            let mut ftypes = Vec::with_capacity(names.len());
            for n in &names {
                match rtde::field_type(n) {
                    Some(t) if rtde::is_input_field(n) => {
                        let held = shared.fieldbus.contains(n)
                            || s.owners.get(n).is_some_and(|o| *o != id);
                        if held {
                            types.push("IN_USE".into());
                            valid = false;
                        } else {
                            types.push(t.wire_name().to_string());
                        }
                        ftypes.push(t);
                    }
                    _ => {
                        types.push("NOT_FOUND".into());
                        valid = false;
                    }
                }
            }
            let recipe_id = if valid {
                for n in &names {
                    s.owners.insert(n.clone(), id);
                }
                c.inputs.push((names, ftypes));
                c.inputs.len() as u8
            } else {
                0
            };
            ServerPackage::SetupInputs {
                recipe_id: Some(recipe_id),
                types,
            }
        }
        ClientPackage::Start => {
            c.streaming = !c.outputs.is_empty();
            ServerPackage::Start(c.streaming)
        }
        ClientPackage::Pause => {
            c.streaming = false;
            ServerPackage::Pause(true)
        }
        ClientPackage::Data { recipe_id, body } => {
            let idx = match recipe_id {
                Some(0) => {
                    return Err(UrError::malformed(
                        "RTDE",
                        "data package for recipe 0 (an invalid recipe)",
                    ))
                }
                Some(i) => usize::from(i) - 1,
                None => c.inputs.len().saturating_sub(1),
            };
            let (names, types) = c.inputs.get(idx).ok_or_else(|| {
                UrError::malformed(
                    "RTDE",
                    format!("data package for unknown input recipe {}", idx + 1),
                )
            })?;
            let values = rtde::decode_values(types, &body)?;
            shared.lock().apply_inputs(names, &values);
            return Ok(None);
        }
        ClientPackage::Text(t) => {
            shared
                .lock()
                .push_log(format!("RTDE client says: {}", t.message));
            return Ok(None);
        }
    }))
}
