//! The client and controller packages of protocol versions 1 and 2 (version requests, recipes,
//! start/pause, data, text) and their payload encoding.

use super::frame::{Frame, PackageType};
use super::reader::Reader;
use super::value::FieldType;
use super::{MAX_NAMES_BYTES, P};
use crate::UrError;

/// Protocol version in use on a connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    /// Version 1 (no recipe ids, no output frequency).
    V1,
    /// Version 2.
    V2,
}

/// A package a client sends.
#[derive(Debug, Clone, PartialEq)]
pub enum ClientPackage {
    /// `V`: ask for a protocol version.
    RequestProtocolVersion(u16),
    /// `v`
    GetUrcontrolVersion,
    /// `O`: output recipe (frequency only in v2).
    SetupOutputs {
        /// Hz; `None` in v1.
        frequency: Option<f64>,
        /// Field names, empties dropped.
        names: Vec<String>,
    },
    /// `I`: input recipe.
    SetupInputs {
        /// Field names, empties dropped.
        names: Vec<String>,
    },
    /// `S`
    Start,
    /// `P`
    Pause,
    /// `U` from the client: input values.
    Data {
        /// Input recipe id (v2).
        recipe_id: Option<u8>,
        /// Packed values.
        body: Vec<u8>,
    },
    /// `M` from the client.
    Text(TextMessage),
}

/// A package the controller sends.
#[derive(Debug, Clone, PartialEq)]
pub enum ServerPackage {
    /// `V` reply.
    ProtocolVersionAccepted(bool),
    /// `v` reply.
    UrcontrolVersion {
        /// Major (3 CB3, 5 e-Series).
        major: u32,
        /// Minor.
        minor: u32,
        /// Bugfix.
        bugfix: u32,
        /// Build.
        build: u32,
    },
    /// `O` reply: recipe id (0 = invalid; `None` in v1) and one type name per field.
    SetupOutputs {
        /// Output recipe id.
        recipe_id: Option<u8>,
        /// Type names (`NOT_FOUND` for unknown).
        types: Vec<String>,
    },
    /// `I` reply.
    SetupInputs {
        /// Input recipe id (0 = invalid).
        recipe_id: Option<u8>,
        /// Type names (`NOT_FOUND`, `IN_USE`).
        types: Vec<String>,
    },
    /// `S` reply.
    Start(bool),
    /// `P` reply.
    Pause(bool),
    /// `U` output data.
    Data {
        /// Output recipe id (v2).
        recipe_id: Option<u8>,
        /// Packed values.
        body: Vec<u8>,
    },
    /// `M`
    Text(TextMessage),
}

/// `M` package contents.
#[derive(Debug, Clone, PartialEq)]
pub struct TextMessage {
    /// Text.
    pub message: String,
    /// Source (v2 only).
    pub source: String,
    /// 0 EXCEPTION, 1 ERROR, 2 WARNING, 3 INFO.
    pub level: u8,
}

fn split_names(bytes: &[u8]) -> Result<Vec<String>, UrError> {
    if bytes.len() > MAX_NAMES_BYTES {
        return Err(UrError::malformed(
            P,
            format!(
                "field-name list of {} bytes exceeds the {MAX_NAMES_BYTES}-byte limit",
                bytes.len()
            ),
        ));
    }
    let s = std::str::from_utf8(bytes)
        .map_err(|_| UrError::malformed(P, "field names are not ASCII"))?;
    if !s.is_ascii() {
        return Err(UrError::malformed(P, "field names are not ASCII"));
    }
    Ok(s.split(',')
        .map(str::trim)
        .filter(|n| !n.is_empty())
        .map(String::from)
        .collect())
}

fn join(names: &[String]) -> Vec<u8> {
    names.join(",").into_bytes()
}

/// The comma-joined list, refused (before it goes on the wire and the controller drops the
/// connection) if it is longer than a setup request may be.
fn names_within_limit(names: &[String]) -> Result<Vec<u8>, UrError> {
    let b = join(names);
    if b.len() > MAX_NAMES_BYTES {
        return Err(UrError::InvalidArgument(format!(
            "RTDE recipe of {} fields is {} bytes of names; a setup request allows \
             {MAX_NAMES_BYTES}: use fewer fields (e.g. a narrower register range)",
            names.len(),
            b.len()
        )));
    }
    Ok(b)
}

fn one_byte(p: &[u8], what: &str) -> Result<u8, UrError> {
    match p {
        [b] => Ok(*b),
        _ => Err(UrError::malformed(
            P,
            format!("{what} reply must be 1 byte, got {}", p.len()),
        )),
    }
}

fn expect_empty(p: &[u8], what: &str) -> Result<(), UrError> {
    if p.is_empty() {
        Ok(())
    } else {
        Err(UrError::malformed(
            P,
            format!("{what} request must be empty, got {} bytes", p.len()),
        ))
    }
}

fn decode_text(p: &[u8], proto: Protocol) -> Result<TextMessage, UrError> {
    let mut r = Reader::new(p);
    match proto {
        Protocol::V2 => {
            let n = usize::from(r.u8()?);
            let message = String::from_utf8_lossy(r.take(n)?).into_owned();
            let n = usize::from(r.u8()?);
            let source = String::from_utf8_lossy(r.take(n)?).into_owned();
            let level = r.u8()?;
            if r.remaining() != 0 {
                return Err(UrError::malformed(P, "trailing bytes after a text message"));
            }
            Ok(TextMessage {
                message,
                source,
                level,
            })
        }
        Protocol::V1 => {
            let level = r.u8()?;
            Ok(TextMessage {
                message: String::from_utf8_lossy(r.rest()).into_owned(),
                source: String::new(),
                level,
            })
        }
    }
}

fn encode_text(t: &TextMessage, proto: Protocol) -> Vec<u8> {
    let mut out = Vec::new();
    match proto {
        Protocol::V2 => {
            let m = &t.message.as_bytes()[..t.message.len().min(255)];
            out.push(m.len() as u8);
            out.extend_from_slice(m);
            let s = &t.source.as_bytes()[..t.source.len().min(255)];
            out.push(s.len() as u8);
            out.extend_from_slice(s);
            out.push(t.level);
        }
        Protocol::V1 => {
            out.push(t.level);
            out.extend_from_slice(t.message.as_bytes());
        }
    }
    out
}

impl ClientPackage {
    /// Decode a client package. `V` is decoded the same in both versions.
    pub fn decode(f: &Frame, proto: Protocol) -> Result<Self, UrError> {
        let p = &f.payload[..];
        Ok(match f.kind {
            PackageType::RequestProtocolVersion => {
                let mut r = Reader::new(p);
                let v = r.u16()?;
                if r.remaining() != 0 {
                    return Err(UrError::malformed(
                        P,
                        "protocol-version request must be 2 bytes",
                    ));
                }
                ClientPackage::RequestProtocolVersion(v)
            }
            PackageType::GetUrcontrolVersion => {
                expect_empty(p, "URControl-version")?;
                ClientPackage::GetUrcontrolVersion
            }
            PackageType::SetupOutputs => match proto {
                Protocol::V2 => {
                    let mut r = Reader::new(p);
                    let frequency = r.f64()?;
                    if !frequency.is_finite() || frequency <= 0.0 {
                        return Err(UrError::malformed(
                            P,
                            format!("output frequency {frequency} Hz is not positive"),
                        ));
                    }
                    ClientPackage::SetupOutputs {
                        frequency: Some(frequency),
                        names: split_names(r.rest())?,
                    }
                }
                Protocol::V1 => ClientPackage::SetupOutputs {
                    frequency: None,
                    names: split_names(p)?,
                },
            },
            PackageType::SetupInputs => ClientPackage::SetupInputs {
                names: split_names(p)?,
            },
            PackageType::Start => {
                expect_empty(p, "start")?;
                ClientPackage::Start
            }
            PackageType::Pause => {
                expect_empty(p, "pause")?;
                ClientPackage::Pause
            }
            PackageType::DataPackage => match proto {
                Protocol::V2 => {
                    let mut r = Reader::new(p);
                    let id = r.u8()?;
                    ClientPackage::Data {
                        recipe_id: Some(id),
                        body: r.rest().to_vec(),
                    }
                }
                Protocol::V1 => ClientPackage::Data {
                    recipe_id: None,
                    body: p.to_vec(),
                },
            },
            PackageType::TextMessage => ClientPackage::Text(decode_text(p, proto)?),
        })
    }

    /// Encode as a frame.
    pub fn encode(&self, proto: Protocol) -> Result<Vec<u8>, UrError> {
        let (kind, payload) = match self {
            ClientPackage::RequestProtocolVersion(v) => (
                PackageType::RequestProtocolVersion,
                v.to_be_bytes().to_vec(),
            ),
            ClientPackage::GetUrcontrolVersion => (PackageType::GetUrcontrolVersion, vec![]),
            ClientPackage::SetupOutputs { frequency, names } => {
                let mut p = Vec::new();
                if proto == Protocol::V2 {
                    p.extend_from_slice(&frequency.unwrap_or(125.0).to_be_bytes());
                }
                p.extend_from_slice(&names_within_limit(names)?);
                (PackageType::SetupOutputs, p)
            }
            ClientPackage::SetupInputs { names } => {
                (PackageType::SetupInputs, names_within_limit(names)?)
            }
            ClientPackage::Start => (PackageType::Start, vec![]),
            ClientPackage::Pause => (PackageType::Pause, vec![]),
            ClientPackage::Data { recipe_id, body } => {
                let mut p = Vec::with_capacity(body.len() + 1);
                if proto == Protocol::V2 {
                    p.push(recipe_id.unwrap_or(1));
                }
                p.extend_from_slice(body);
                (PackageType::DataPackage, p)
            }
            ClientPackage::Text(t) => (PackageType::TextMessage, encode_text(t, proto)),
        };
        Frame::new(kind, payload).encode()
    }
}

impl ServerPackage {
    /// Decode a controller package.
    pub fn decode(f: &Frame, proto: Protocol) -> Result<Self, UrError> {
        let p = &f.payload[..];
        let types = |b: &[u8]| -> Result<Vec<String>, UrError> {
            let s = std::str::from_utf8(b)
                .map_err(|_| UrError::malformed(P, "type list is not ASCII"))?;
            let v: Vec<String> = s
                .split(',')
                .filter(|t| !t.is_empty())
                .map(String::from)
                .collect();
            for t in &v {
                if FieldType::from_wire_name(t).is_none() && t != "NOT_FOUND" && t != "IN_USE" {
                    return Err(UrError::malformed(
                        P,
                        format!("unknown field type `{t}` in setup reply"),
                    ));
                }
            }
            Ok(v)
        };
        Ok(match f.kind {
            PackageType::RequestProtocolVersion => {
                ServerPackage::ProtocolVersionAccepted(one_byte(p, "protocol-version")? != 0)
            }
            PackageType::GetUrcontrolVersion => {
                let mut r = Reader::new(p);
                let v = ServerPackage::UrcontrolVersion {
                    major: r.u32()?,
                    minor: r.u32()?,
                    bugfix: r.u32()?,
                    build: r.u32()?,
                };
                if r.remaining() != 0 {
                    return Err(UrError::malformed(
                        P,
                        "URControl-version reply must be 16 bytes",
                    ));
                }
                v
            }
            PackageType::SetupOutputs | PackageType::SetupInputs => {
                let (recipe_id, rest) = match proto {
                    Protocol::V2 => {
                        let (id, rest) = p.split_first().ok_or_else(|| {
                            UrError::malformed(P, "setup reply without a recipe id")
                        })?;
                        (Some(*id), rest)
                    }
                    Protocol::V1 => (None, p),
                };
                let types = types(rest)?;
                if f.kind == PackageType::SetupOutputs {
                    ServerPackage::SetupOutputs { recipe_id, types }
                } else {
                    ServerPackage::SetupInputs { recipe_id, types }
                }
            }
            PackageType::Start => ServerPackage::Start(one_byte(p, "start")? != 0),
            PackageType::Pause => ServerPackage::Pause(one_byte(p, "pause")? != 0),
            PackageType::DataPackage => match proto {
                Protocol::V2 => {
                    let (id, rest) = p
                        .split_first()
                        .ok_or_else(|| UrError::malformed(P, "data package without a recipe id"))?;
                    ServerPackage::Data {
                        recipe_id: Some(*id),
                        body: rest.to_vec(),
                    }
                }
                Protocol::V1 => ServerPackage::Data {
                    recipe_id: None,
                    body: p.to_vec(),
                },
            },
            PackageType::TextMessage => ServerPackage::Text(decode_text(p, proto)?),
        })
    }

    /// Encode as a frame.
    pub fn encode(&self, proto: Protocol) -> Result<Vec<u8>, UrError> {
        let (kind, payload) = match self {
            ServerPackage::ProtocolVersionAccepted(a) => {
                (PackageType::RequestProtocolVersion, vec![u8::from(*a)])
            }
            ServerPackage::UrcontrolVersion {
                major,
                minor,
                bugfix,
                build,
            } => {
                let mut p = Vec::with_capacity(16);
                for v in [major, minor, bugfix, build] {
                    p.extend_from_slice(&v.to_be_bytes());
                }
                (PackageType::GetUrcontrolVersion, p)
            }
            ServerPackage::SetupOutputs { recipe_id, types }
            | ServerPackage::SetupInputs { recipe_id, types } => {
                let mut p = Vec::new();
                if proto == Protocol::V2 {
                    p.push(recipe_id.unwrap_or(0));
                }
                p.extend_from_slice(&join(types));
                let kind = if matches!(self, ServerPackage::SetupOutputs { .. }) {
                    PackageType::SetupOutputs
                } else {
                    PackageType::SetupInputs
                };
                (kind, p)
            }
            ServerPackage::Start(a) => (PackageType::Start, vec![u8::from(*a)]),
            ServerPackage::Pause(a) => (PackageType::Pause, vec![u8::from(*a)]),
            ServerPackage::Data { recipe_id, body } => {
                let mut p = Vec::with_capacity(body.len() + 1);
                if proto == Protocol::V2 {
                    p.push(recipe_id.unwrap_or(1));
                }
                p.extend_from_slice(body);
                (PackageType::DataPackage, p)
            }
            ServerPackage::Text(t) => (PackageType::TextMessage, encode_text(t, proto)),
        };
        Frame::new(kind, payload).encode()
    }
}
