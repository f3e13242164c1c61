//! A man-in-the-middle between a UR client and a controller (ours or a real one) that corrupts
//! what the controller reports:
//!
//! - RTDE output fields set to NaN, infinity or any value, or shifted ([`FaultProxy::corrupt`]),
//!   in every data package or only while a program plays, e.g. during a move
//!   ([`FaultProxy::corrupt_while_playing`]);
//! - the RTDE data stream as a whole frozen (the same package again and again, the
//!   controller's timestamp standing still) or reordered (packages swapped in pairs, the
//!   timestamp going back) ([`FaultProxy::stream`]);
//! - the kinematics info the controller publishes in its robot state on the primary and
//!   secondary interfaces (DH values, calibration status, checksums)
//!   ([`FaultProxy::corrupt_kinematics`]).
//!
//! Dashboard and real-time traffic, what the client sends, and every other primary package
//! pass through unchanged.
//!
//! It exists to prove that a client refuses what a controller (or a broken network device,
//! or a hostile one) could send: every package it forwards is a valid package, re-encoded with
//! the right lengths; only the values are wrong. Start it with [`FaultProxy::start`] in front
//! of a controller; set faults at any time (they apply to the next package).

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex};

use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinSet;

use handeye_hal::ur_dh::DhParams;
use tokio::io::AsyncReadExt;

use crate::primary::{self, KinematicsInfo};
use crate::rtde::{
    decode_values, encode_values, read_frame, ClientPackage, FieldType, Frame, PackageType,
    Protocol, Reader, ServerPackage, Value,
};
use crate::sim::state::RUNTIME_PLAYING;
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

/// What happens to the RTDE data stream as a whole.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StreamMode {
    /// Every data package passes (with its field corruptions).
    #[default]
    Live,
    /// Each connection's data packages are replaced by the last one it forwarded before the
    /// mode was set (or, on a connection opened afterwards, its first): packages keep
    /// arriving at the controller's rate, the controller's `timestamp` and every value in them
    /// stand still.
    Frozen,
    /// Data packages are delivered swapped in pairs (the second before the first): the
    /// controller's `timestamp` goes back every other package.
    Reordered,
}

/// What to do to the kinematics info (robot-state sub-package 5) the controller publishes on
/// the primary and secondary interfaces.
#[derive(Debug, Clone, PartialEq)]
pub enum KinematicsCorruption {
    /// Every DH value becomes NaN.
    Nan,
    /// The DH set is replaced by this one (e.g. another UR model's nominal DH).
    Dh(DhParams),
    /// `calibration_status` becomes this.
    CalibrationStatus(u32),
    /// The per-joint checksums become these.
    Checksum([u32; 6]),
}

impl KinematicsCorruption {
    fn apply(&self, k: &mut KinematicsInfo) {
        match self {
            KinematicsCorruption::Nan => {
                let dh = &mut k.dh;
                for v in
                    dh.a.iter_mut()
                        .chain(&mut dh.d)
                        .chain(&mut dh.alpha)
                        .chain(&mut dh.theta)
                {
                    *v = f64::NAN;
                }
            }
            KinematicsCorruption::Dh(dh) => k.dh = *dh,
            KinematicsCorruption::CalibrationStatus(s) => k.calibration_status = *s,
            KinematicsCorruption::Checksum(c) => k.checksum = *c,
        }
    }
}

/// Every fault set on a proxy.
#[derive(Debug, Default)]
struct Faults {
    fields: HashMap<String, Corruption>,
    /// Applied only to data packages whose `runtime_state` says a program plays.
    while_playing: HashMap<String, Corruption>,
    stream: StreamMode,
    kinematics: Option<KinematicsCorruption>,
}

type SharedFaults = Arc<Mutex<Faults>>;

/// A running proxy; stops when dropped.
#[derive(Debug)]
pub struct FaultProxy {
    faults: SharedFaults,
    tasks: JoinSet<()>,
}

/// Which of the proxied ports a connection came in on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Link {
    /// Passed through byte for byte.
    Plain,
    /// Primary or secondary: robot states rewritten.
    Primary,
    /// RTDE: data packages rewritten.
    Rtde,
}

impl FaultProxy {
    /// Listens on `bind` at `ports` and forwards each connection to the same port of
    /// `upstream`.
    pub async fn start(bind: IpAddr, upstream: IpAddr, ports: Ports) -> Result<Self, UrError> {
        let faults: SharedFaults = Arc::default();
        let mut tasks = JoinSet::new();
        for (port, link) in [
            (ports.dashboard, Link::Plain),
            (ports.primary, Link::Primary),
            (ports.secondary, Link::Primary),
            (ports.realtime, Link::Plain),
            (ports.rtde, Link::Rtde),
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
                        match link {
                            Link::Rtde => rtde_connection(client, server, faults).await,
                            Link::Primary => primary_connection(client, server, faults).await,
                            Link::Plain => {
                                let (mut c, mut s) = (client, server);
                                let _ = tokio::io::copy_bidirectional(&mut c, &mut s).await;
                            }
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
        self.lock().fields.insert(field.to_string(), corruption);
    }

    /// From the next data package on, `field` arrives corrupted in the packages whose
    /// `runtime_state` is 2 (a program plays: the arm follows a move, or a stop), as the
    /// controller's state changing mid-move. The client's recipe must hold `runtime_state`.
    pub fn corrupt_while_playing(&self, field: &str, corruption: Corruption) {
        self.lock()
            .while_playing
            .insert(field.to_string(), corruption);
    }

    /// Stops corrupting `field` (always or while playing).
    pub fn heal(&self, field: &str) {
        let mut faults = self.lock();
        faults.fields.remove(field);
        faults.while_playing.remove(field);
    }

    /// From the next data package on, the RTDE stream is delivered as `mode` says
    /// ([`StreamMode::Live`] heals it).
    pub fn stream(&self, mode: StreamMode) {
        self.lock().stream = mode;
    }

    /// From the next robot state on, its kinematics info arrives corrupted by `corruption`
    /// (`None` heals it), on the primary and the secondary interface.
    pub fn corrupt_kinematics(&self, corruption: Option<KinematicsCorruption>) {
        self.lock().kinematics = corruption;
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Faults> {
        lock(&self.faults)
    }
}

fn lock(faults: &SharedFaults) -> std::sync::MutexGuard<'_, Faults> {
    faults.lock().unwrap_or_else(|e| e.into_inner())
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

async fn rtde_connection(client: TcpStream, server: TcpStream, faults: SharedFaults) {
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
        let mut stream = StreamState::default();
        while let Ok(Some(frame)) = read_frame(&mut s_read).await {
            let is_data = frame.kind == PackageType::DataPackage;
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
                        let (always, playing) = {
                            let f = lock(&faults);
                            (f.fields.clone(), f.while_playing.clone())
                        };
                        match r.outputs.get(&recipe_id.unwrap_or(0)) {
                            Some(fields) if !always.is_empty() || !playing.is_empty() => {
                                corrupted(fields, recipe_id, &body, &always, &playing)
                                    .map_or_else(|_| frame.encode(), Ok)
                            }
                            _ => frame.encode(),
                        }
                    }
                    _ => frame.encode(),
                }
            };
            let Ok(bytes) = bytes else { break };
            let out = if is_data {
                let mode = lock(&faults).stream;
                stream.deliver(mode, bytes)
            } else {
                vec![bytes]
            };
            for bytes in out {
                if c_write.write_all(&bytes).await.is_err() {
                    return;
                }
            }
        }
    };
    tokio::join!(up, down);
}

/// One RTDE connection's data packages as [`StreamMode`] delivers them.
#[derive(Debug, Default)]
struct StreamState {
    /// The last data package forwarded (as sent).
    last: Option<Vec<u8>>,
    /// While frozen: the package sent instead of every new one.
    frozen: Option<Vec<u8>>,
    /// While reordered: the package held back until the next one has been sent.
    held: Option<Vec<u8>>,
}

impl StreamState {
    /// What to send for the data package `bytes` in `mode`, in order.
    fn deliver(&mut self, mode: StreamMode, bytes: Vec<u8>) -> Vec<Vec<u8>> {
        if mode != StreamMode::Frozen {
            self.frozen = None;
        }
        let mut out: Vec<Vec<u8>> = Vec::with_capacity(2);
        if mode != StreamMode::Reordered {
            out.extend(self.held.take());
        }
        match mode {
            StreamMode::Live => out.push(bytes),
            StreamMode::Frozen => {
                let frozen = self
                    .frozen
                    .get_or_insert_with(|| self.last.clone().unwrap_or(bytes));
                out.push(frozen.clone());
            }
            StreamMode::Reordered => match self.held.take() {
                None => self.held = Some(bytes),
                Some(earlier) => {
                    out.push(bytes);
                    out.push(earlier);
                }
            },
        }
        if let Some(l) = out.last() {
            self.last = Some(l.clone());
        }
        out
    }
}

/// A primary or secondary connection: what the client sends passes unchanged; the
/// controller's packages are cut at their lengths and robot states get the kinematics fault.
/// A stream that cannot be cut (a length no package has) is passed on as it is from there.
async fn primary_connection(client: TcpStream, server: TcpStream, faults: SharedFaults) {
    let (mut c_read, mut c_write) = client.into_split();
    let (mut s_read, mut s_write) = server.into_split();
    let up = async move {
        let _ = tokio::io::copy(&mut c_read, &mut s_write).await;
        let _ = s_write.shutdown().await;
    };
    let down = async move {
        let mut buf: Vec<u8> = Vec::new();
        let mut chunk = vec![0u8; 1 << 16];
        let mut raw = false;
        loop {
            let n = match s_read.read(&mut chunk).await {
                Ok(0) | Err(_) => return,
                Ok(n) => n,
            };
            buf.extend_from_slice(&chunk[..n]);
            let mut out = Vec::new();
            if raw {
                out.append(&mut buf);
            }
            while !raw && buf.len() >= 5 {
                let len = i32::from_be_bytes([buf[0], buf[1], buf[2], buf[3]]);
                if len < 5 || len as usize > primary::MAX_PACKAGE {
                    raw = true;
                    out.append(&mut buf);
                    break;
                }
                let len = len as usize;
                if buf.len() < len {
                    break;
                }
                let package: Vec<u8> = buf.drain(..len).collect();
                let fault = lock(&faults).kinematics.clone();
                match fault.and_then(|c| corrupted_robot_state(&package, &c)) {
                    Some(changed) => out.extend_from_slice(&changed),
                    None => out.extend_from_slice(&package),
                }
            }
            if c_write.write_all(&out).await.is_err() {
                return;
            }
        }
    };
    tokio::join!(up, down);
}

/// `package` (a whole primary package) with `c` applied to the kinematics info of a robot
/// state, every sub-package length and the package length re-encoded; `None` when it is no
/// robot state, holds no kinematics info, or cannot be cut into sub-packages.
fn corrupted_robot_state(package: &[u8], c: &KinematicsCorruption) -> Option<Vec<u8>> {
    if package.get(4) != Some(&primary::ROBOT_STATE) {
        return None;
    }
    let mut rest = &package[5..];
    let mut body = Vec::with_capacity(rest.len());
    let mut changed = false;
    while !rest.is_empty() {
        let len = u32::from_be_bytes(rest.get(..4)?.try_into().ok()?) as usize;
        if len < 5 || len > rest.len() {
            return None;
        }
        let (sub, tail) = rest.split_at(len);
        rest = tail;
        if sub[4] != primary::KINEMATICS_INFO {
            body.extend_from_slice(sub);
            continue;
        }
        let mut r = Reader::for_protocol(&sub[5..], "primary");
        let mut k = KinematicsInfo::decode(&mut r).ok()?;
        c.apply(&mut k);
        let mut payload = Vec::with_capacity(len - 5);
        k.encode(&mut payload);
        // A newer firmware's longer sub-package keeps what follows.
        payload.extend_from_slice(r.rest());
        body.extend_from_slice(&((payload.len() + 5) as u32).to_be_bytes());
        body.push(primary::KINEMATICS_INFO);
        body.extend_from_slice(&payload);
        changed = true;
    }
    changed.then(|| primary::frame(primary::ROBOT_STATE, &body))
}

/// A data package with `always` applied to its fields, and `while_playing` too when its
/// `runtime_state` says a program plays.
fn corrupted(
    fields: &[(String, FieldType)],
    recipe_id: Option<u8>,
    body: &[u8],
    always: &HashMap<String, Corruption>,
    while_playing: &HashMap<String, Corruption>,
) -> Result<Vec<u8>, UrError> {
    let types: Vec<FieldType> = fields.iter().map(|(_, t)| *t).collect();
    let mut values = decode_values(&types, body)?;
    let playing = fields
        .iter()
        .zip(&values)
        .any(|((name, _), v)| name == "runtime_state" && *v == Value::Uint32(RUNTIME_PLAYING));
    for ((name, _), value) in fields.iter().zip(&mut values) {
        let fault = always
            .get(name)
            .or_else(|| playing.then(|| while_playing.get(name)).flatten());
        if let Some(c) = fault {
            *value = apply(value, c);
        }
    }
    let mut payload = Vec::new();
    payload.extend(recipe_id);
    encode_values(&values, &mut payload);
    Frame::new(PackageType::DataPackage, payload).encode()
}

/// `value` corrupted by `c` (doubles, vectors of doubles, 32-bit integers; other types pass
/// unchanged).
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
        // Integers (`safety_mode`, `runtime_state`) take the number cut to the type (NaN 0).
        Value::Int32(v) => Value::Int32(change(&[f64::from(*v)])[0] as i32),
        Value::Uint32(v) => Value::Uint32(change(&[f64::from(*v)])[0] as u32),
        other => *other,
    }
}

#[cfg(test)]
mod tests {
    use handeye_hal::ur_dh::UrModel;

    use super::*;
    use crate::primary::tests::state;
    use crate::primary::{
        encode_robot_state, split, PrimaryPackage, RobotModeData, CALIBRATION_LINEARISED,
    };

    fn robot_state() -> (Vec<u8>, KinematicsInfo) {
        let kin = KinematicsInfo::for_arm(UrModel::Ur5e.dh(), CALIBRATION_LINEARISED);
        let mode = RobotModeData {
            timestamp_us: 7,
            robot_mode: 7,
            ..Default::default()
        };
        (encode_robot_state(&state(mode, [0.1; 6], kin)), kin)
    }

    fn decoded(package: &[u8]) -> PrimaryPackage {
        let (p, n) = split(package).expect("well-formed").expect("whole");
        assert_eq!(n, package.len());
        p
    }

    /// The proxy's robot state is a valid package (lengths re-encoded) whose kinematics info
    /// carries the fault and whose other sub-packages are the controller's.
    #[test]
    fn kinematics_faults_are_re_encoded_robot_states() {
        let (package, kin) = robot_state();
        let PrimaryPackage::RobotState {
            mode,
            joints,
            cartesian,
            configuration,
            ..
        } = decoded(&package)
        else {
            panic!("robot state")
        };
        let ur10e = UrModel::Ur10e.dh();
        for (c, check) in [
            (
                KinematicsCorruption::Nan,
                Box::new(|k: &KinematicsInfo| k.dh.d.iter().all(|v| v.is_nan()))
                    as Box<dyn Fn(&KinematicsInfo) -> bool>,
            ),
            (
                KinematicsCorruption::Dh(ur10e),
                Box::new(move |k: &KinematicsInfo| k.dh == ur10e && k.checksum == kin.checksum),
            ),
            (
                KinematicsCorruption::CalibrationStatus(9),
                Box::new(move |k: &KinematicsInfo| k.calibration_status == 9 && k.dh == kin.dh),
            ),
            (
                KinematicsCorruption::Checksum([1; 6]),
                Box::new(|k: &KinematicsInfo| k.checksum == [1; 6]),
            ),
        ] {
            let out = corrupted_robot_state(&package, &c).expect("a robot state");
            assert_eq!(out.len(), package.len(), "{c:?}");
            let PrimaryPackage::RobotState {
                mode: m,
                joints: j,
                cartesian: ca,
                kinematics: Some(k),
                configuration: co,
            } = decoded(&out)
            else {
                panic!("{c:?}: no kinematics")
            };
            assert!(check(&k), "{c:?}: {k:?}");
            assert_eq!((m, j, ca, co), (mode, joints, cartesian, configuration));
        }
        // A newer firmware's longer kinematics info keeps its tail; other packages pass.
        let mut sub = Vec::new();
        kin.encode(&mut sub);
        sub.extend_from_slice(&[0xab; 7]);
        let mut body = ((sub.len() + 5) as u32).to_be_bytes().to_vec();
        body.push(primary::KINEMATICS_INFO);
        body.extend_from_slice(&sub);
        let longer = primary::frame(primary::ROBOT_STATE, &body);
        let out = corrupted_robot_state(&longer, &KinematicsCorruption::CalibrationStatus(0))
            .expect("changed");
        assert_eq!(&out[out.len() - 7..], &[0xab; 7]);
        assert_eq!(out.len(), longer.len());
        let text = primary::encode_text(1, "hello");
        assert_eq!(
            corrupted_robot_state(&text, &KinematicsCorruption::Nan),
            None
        );
        // A sub-package length past the package: not cut, passed on as it is.
        let mut broken = package.clone();
        broken[5..9].copy_from_slice(&u32::MAX.to_be_bytes());
        assert_eq!(
            corrupted_robot_state(&broken, &KinematicsCorruption::Nan),
            None
        );
    }

    /// Fuzz target `fault_proxy_primary`: mutated robot states are rewritten or left alone
    /// (the "refused" count), never a panic; a rewritten one carries its own length and cuts
    /// into whole sub-packages.
    #[test]
    fn fuzz_fault_proxy_primary() {
        let (state, _) = robot_state();
        let seeds = vec![state];
        handeye_hal::fuzz::Target::new("fault_proxy_primary", seeds)
            .allocation_cap(16, 1 << 16)
            .run(|b| {
                for c in [
                    KinematicsCorruption::Nan,
                    KinematicsCorruption::CalibrationStatus(9),
                ] {
                    let Some(out) = corrupted_robot_state(b, &c) else {
                        return Err("no robot state with a kinematics info: passed on as it is");
                    };
                    let len = u32::from_be_bytes([out[0], out[1], out[2], out[3]]) as usize;
                    assert_eq!(len, out.len());
                    let mut rest = &out[5..];
                    while !rest.is_empty() {
                        let n = u32::from_be_bytes([rest[0], rest[1], rest[2], rest[3]]);
                        rest = &rest[n as usize..];
                    }
                }
                Ok(())
            });
    }

    #[test]
    fn stream_modes_freeze_and_swap_data_packages() {
        let mut s = StreamState::default();
        let p = |i: u8| vec![i];
        assert_eq!(s.deliver(StreamMode::Live, p(1)), [p(1)]);
        // Frozen: the last package forwarded, again and again.
        for i in 2..6 {
            assert_eq!(s.deliver(StreamMode::Frozen, p(i)), [p(1)]);
        }
        assert_eq!(s.deliver(StreamMode::Live, p(6)), [p(6)]);
        // Reordered: swapped in pairs.
        assert!(s.deliver(StreamMode::Reordered, p(7)).is_empty());
        assert_eq!(s.deliver(StreamMode::Reordered, p(8)), [p(8), p(7)]);
        assert!(s.deliver(StreamMode::Reordered, p(9)).is_empty());
        // Healed: the held package goes first.
        assert_eq!(s.deliver(StreamMode::Live, p(10)), [p(9), p(10)]);
        // Frozen on a connection that forwarded nothing yet: its first package.
        let mut fresh = StreamState::default();
        assert_eq!(fresh.deliver(StreamMode::Frozen, p(3)), [p(3)]);
        assert_eq!(fresh.deliver(StreamMode::Frozen, p(4)), [p(3)]);
    }
}
