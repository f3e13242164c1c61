//! A man-in-the-middle between a UR client and a controller (ours or a real one) that corrupts
//! what the controller reports: RTDE output fields set to NaN, infinity or any value, or
//! shifted. Dashboard, primary, secondary and real-time traffic passes through unchanged.
//!
//! It exists to prove that a client refuses what a controller (or a broken network device,
//! or a hostile one) could send: every RTDE package it forwards is a valid package, only the
//! values are wrong. Start it with [`FaultProxy::start`] in front of a controller; set faults
//! with [`FaultProxy::corrupt`] at any time (they apply to the next data package).

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex};

use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinSet;

use crate::rtde::{
    decode_values, encode_values, read_frame, ClientPackage, FieldType, Frame, PackageType,
    Protocol, ServerPackage, Value,
};
use crate::{Ports, UrError};

/// What to do to one RTDE output field's value.
#[derive(Debug, Clone, PartialEq)]
pub enum Corruption {
    /// Every number of the field becomes NaN.
    Nan,
    /// Every number of the field becomes +∞.
    Infinity,
    /// The field's numbers become these (as many as the field holds).
    Set(Vec<f64>),
    /// Number `index` of the field is shifted by `delta`.
    Add {
        /// Which number (0 for a scalar, 0..6 for a VECTOR6D).
        index: usize,
        /// How much to add.
        delta: f64,
    },
}

/// A running proxy; stops when dropped.
#[derive(Debug)]
pub struct FaultProxy {
    faults: Arc<Mutex<HashMap<String, Corruption>>>,
    tasks: JoinSet<()>,
}

impl FaultProxy {
    /// Listens on `bind` at `ports` and forwards each connection to the same port of
    /// `upstream`.
    pub async fn start(bind: IpAddr, upstream: IpAddr, ports: Ports) -> Result<Self, UrError> {
        let faults: Arc<Mutex<HashMap<String, Corruption>>> = Arc::default();
        let mut tasks = JoinSet::new();
        for (port, rtde) in [
            (ports.dashboard, false),
            (ports.primary, false),
            (ports.secondary, false),
            (ports.realtime, false),
            (ports.rtde, true),
        ] {
            let at = SocketAddr::new(bind, port);
            let listener = TcpListener::bind(at).await.map_err(|e| UrError::Io {
                peer: at.to_string(),
                source: e,
            })?;
            let to = SocketAddr::new(upstream, port);
            let faults = Arc::clone(&faults);
            tasks.spawn(async move {
                let mut conns = JoinSet::new();
                while let Ok((client, _)) = listener.accept().await {
                    let faults = Arc::clone(&faults);
                    conns.spawn(async move {
                        let Ok(server) = TcpStream::connect(to).await else {
                            return;
                        };
                        if rtde {
                            rtde_connection(client, server, faults).await;
                        } else {
                            let (mut c, mut s) = (client, server);
                            let _ = tokio::io::copy_bidirectional(&mut c, &mut s).await;
                        }
                    });
                }
            });
        }
        Ok(Self { faults, tasks })
    }

    /// From the next data package on, `field` (an RTDE output name such as
    /// `actual_TCP_pose`) arrives corrupted.
    pub fn corrupt(&self, field: &str, corruption: Corruption) {
        self.lock().insert(field.to_string(), corruption);
    }

    /// Stops corrupting `field`.
    pub fn heal(&self, field: &str) {
        self.lock().remove(field);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, Corruption>> {
        self.faults.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl Drop for FaultProxy {
    fn drop(&mut self) {
        self.tasks.abort_all();
    }
}

/// What the proxy knows of one RTDE connection: the protocol version agreed and each output
/// recipe's fields.
#[derive(Debug, Default)]
struct Recipes {
    proto: Option<Protocol>,
    /// Version the client asked for, until the controller answers.
    asked: Option<u16>,
    /// Output setups sent and not yet answered, in order.
    pending: std::collections::VecDeque<Vec<String>>,
    /// Output recipe id (0 in v1) → fields (name, type).
    outputs: HashMap<u8, Vec<(String, FieldType)>>,
}

impl Recipes {
    fn proto(&self) -> Protocol {
        self.proto.unwrap_or(Protocol::V1)
    }
}

async fn rtde_connection(
    client: TcpStream,
    server: TcpStream,
    faults: Arc<Mutex<HashMap<String, Corruption>>>,
) {
    let recipes = Arc::new(Mutex::new(Recipes::default()));
    let (mut c_read, mut c_write) = client.into_split();
    let (mut s_read, mut s_write) = server.into_split();
    let up = {
        let recipes = Arc::clone(&recipes);
        async move {
            while let Ok(Some(frame)) = read_frame(&mut c_read).await {
                {
                    let mut r = recipes.lock().unwrap_or_else(|e| e.into_inner());
                    match ClientPackage::decode(&frame, r.proto()) {
                        Ok(ClientPackage::RequestProtocolVersion(v)) => r.asked = Some(v),
                        Ok(ClientPackage::SetupOutputs { names, .. }) => r.pending.push_back(names),
                        _ => {}
                    }
                }
                let Ok(bytes) = frame.encode() else { break };
                if s_write.write_all(&bytes).await.is_err() {
                    break;
                }
            }
        }
    };
    let down = async move {
        while let Ok(Some(frame)) = read_frame(&mut s_read).await {
            let bytes = {
                let mut r = recipes.lock().unwrap_or_else(|e| e.into_inner());
                let proto = r.proto();
                match ServerPackage::decode(&frame, proto) {
                    Ok(ServerPackage::ProtocolVersionAccepted(true)) => {
                        r.proto = Some(match r.asked {
                            Some(2..) => Protocol::V2,
                            _ => Protocol::V1,
                        });
                        frame.encode()
                    }
                    Ok(ServerPackage::SetupOutputs { recipe_id, types }) => {
                        if let Some(names) = r.pending.pop_front() {
                            let fields = names
                                .into_iter()
                                .zip(&types)
                                .filter_map(|(n, t)| Some((n, FieldType::from_wire_name(t)?)))
                                .collect();
                            r.outputs.insert(recipe_id.unwrap_or(0), fields);
                        }
                        frame.encode()
                    }
                    Ok(ServerPackage::Data { recipe_id, body }) => {
                        let faults = faults.lock().unwrap_or_else(|e| e.into_inner()).clone();
                        match r.outputs.get(&recipe_id.unwrap_or(0)) {
                            Some(fields) if !faults.is_empty() => {
                                corrupted(fields, recipe_id, &body, &faults)
                                    .map_or_else(|_| frame.encode(), Ok)
                            }
                            _ => frame.encode(),
                        }
                    }
                    _ => frame.encode(),
                }
            };
            let Ok(bytes) = bytes else { break };
            if c_write.write_all(&bytes).await.is_err() {
                break;
            }
        }
    };
    tokio::join!(up, down);
}

/// A data package with `faults` applied to its fields.
fn corrupted(
    fields: &[(String, FieldType)],
    recipe_id: Option<u8>,
    body: &[u8],
    faults: &HashMap<String, Corruption>,
) -> Result<Vec<u8>, UrError> {
    let types: Vec<FieldType> = fields.iter().map(|(_, t)| *t).collect();
    let mut values = decode_values(&types, body)?;
    for ((name, _), value) in fields.iter().zip(&mut values) {
        if let Some(c) = faults.get(name) {
            *value = apply(value, c);
        }
    }
    let mut payload = Vec::new();
    payload.extend(recipe_id);
    encode_values(&values, &mut payload);
    Frame::new(PackageType::DataPackage, payload).encode()
}

/// `value` corrupted by `c` (numbers only; other types pass unchanged).
fn apply(value: &Value, c: &Corruption) -> Value {
    let change = |old: &[f64]| -> Vec<f64> {
        match c {
            Corruption::Nan => vec![f64::NAN; old.len()],
            Corruption::Infinity => vec![f64::INFINITY; old.len()],
            Corruption::Set(v) => old
                .iter()
                .enumerate()
                .map(|(i, o)| v.get(i).copied().unwrap_or(*o))
                .collect(),
            Corruption::Add { index, delta } => old
                .iter()
                .enumerate()
                .map(|(i, o)| if i == *index { o + delta } else { *o })
                .collect(),
        }
    };
    match value {
        Value::Double(v) => Value::Double(change(&[*v])[0]),
        Value::Vector6d(v) => {
            let n = change(v);
            Value::Vector6d([n[0], n[1], n[2], n[3], n[4], n[5]])
        }
        Value::Vector3d(v) => {
            let n = change(v);
            Value::Vector3d([n[0], n[1], n[2]])
        }
        other => *other,
    }
}
