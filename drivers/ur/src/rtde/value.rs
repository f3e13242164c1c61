//! The wire types of RTDE fields and typed values of them, with their big-endian encoding and
//! the packing of data-package bodies.

use super::reader::Reader;
use super::P;
use crate::UrError;

/// Wire type of an RTDE field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[allow(missing_docs)]
pub enum FieldType {
    Bool,
    Uint8,
    Uint32,
    Uint64,
    Int32,
    Double,
    Vector3d,
    Vector6d,
    Vector6Int32,
    Vector6Uint32,
}

impl FieldType {
    /// Encoded size in bytes.
    pub fn size(self) -> usize {
        match self {
            FieldType::Bool | FieldType::Uint8 => 1,
            FieldType::Uint32 | FieldType::Int32 => 4,
            FieldType::Uint64 | FieldType::Double => 8,
            FieldType::Vector3d | FieldType::Vector6Int32 | FieldType::Vector6Uint32 => 24,
            FieldType::Vector6d => 48,
        }
    }

    /// The name the controller uses in setup replies.
    pub fn wire_name(self) -> &'static str {
        match self {
            FieldType::Bool => "BOOL",
            FieldType::Uint8 => "UINT8",
            FieldType::Uint32 => "UINT32",
            FieldType::Uint64 => "UINT64",
            FieldType::Int32 => "INT32",
            FieldType::Double => "DOUBLE",
            FieldType::Vector3d => "VECTOR3D",
            FieldType::Vector6d => "VECTOR6D",
            FieldType::Vector6Int32 => "VECTOR6INT32",
            FieldType::Vector6Uint32 => "VECTOR6UINT32",
        }
    }

    /// Parse a setup-reply type name (`NOT_FOUND`/`IN_USE` are not types: `None`).
    pub fn from_wire_name(s: &str) -> Option<Self> {
        Some(match s {
            "BOOL" => FieldType::Bool,
            "UINT8" => FieldType::Uint8,
            "UINT32" => FieldType::Uint32,
            "UINT64" => FieldType::Uint64,
            "INT32" => FieldType::Int32,
            "DOUBLE" => FieldType::Double,
            "VECTOR3D" => FieldType::Vector3d,
            "VECTOR6D" => FieldType::Vector6d,
            "VECTOR6INT32" => FieldType::Vector6Int32,
            "VECTOR6UINT32" => FieldType::Vector6Uint32,
            _ => return None,
        })
    }
}

/// A typed RTDE value.
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(missing_docs)]
pub enum Value {
    Bool(bool),
    Uint8(u8),
    Uint32(u32),
    Uint64(u64),
    Int32(i32),
    Double(f64),
    Vector3d([f64; 3]),
    Vector6d([f64; 6]),
    Vector6Int32([i32; 6]),
    Vector6Uint32([u32; 6]),
}

impl Value {
    /// The wire type of this value.
    pub fn field_type(&self) -> FieldType {
        match self {
            Value::Bool(_) => FieldType::Bool,
            Value::Uint8(_) => FieldType::Uint8,
            Value::Uint32(_) => FieldType::Uint32,
            Value::Uint64(_) => FieldType::Uint64,
            Value::Int32(_) => FieldType::Int32,
            Value::Double(_) => FieldType::Double,
            Value::Vector3d(_) => FieldType::Vector3d,
            Value::Vector6d(_) => FieldType::Vector6d,
            Value::Vector6Int32(_) => FieldType::Vector6Int32,
            Value::Vector6Uint32(_) => FieldType::Vector6Uint32,
        }
    }

    /// The all-zero value of a type.
    pub fn zero(t: FieldType) -> Self {
        match t {
            FieldType::Bool => Value::Bool(false),
            FieldType::Uint8 => Value::Uint8(0),
            FieldType::Uint32 => Value::Uint32(0),
            FieldType::Uint64 => Value::Uint64(0),
            FieldType::Int32 => Value::Int32(0),
            FieldType::Double => Value::Double(0.0),
            FieldType::Vector3d => Value::Vector3d([0.0; 3]),
            FieldType::Vector6d => Value::Vector6d([0.0; 6]),
            FieldType::Vector6Int32 => Value::Vector6Int32([0; 6]),
            FieldType::Vector6Uint32 => Value::Vector6Uint32([0; 6]),
        }
    }

    /// Append the big-endian encoding.
    pub fn encode(&self, out: &mut Vec<u8>) {
        match self {
            Value::Bool(b) => out.push(u8::from(*b)),
            Value::Uint8(v) => out.push(*v),
            Value::Uint32(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Uint64(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Int32(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Double(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Vector3d(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6d(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6Int32(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6Uint32(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
        }
    }

    /// Decode one value of type `t` from the front of `r`.
    pub fn decode(t: FieldType, r: &mut Reader<'_>) -> Result<Self, UrError> {
        Ok(match t {
            FieldType::Bool => Value::Bool(r.u8()? != 0),
            FieldType::Uint8 => Value::Uint8(r.u8()?),
            FieldType::Uint32 => Value::Uint32(r.u32()?),
            FieldType::Uint64 => Value::Uint64(r.u64()?),
            FieldType::Int32 => Value::Int32(r.i32()?),
            FieldType::Double => Value::Double(r.f64()?),
            FieldType::Vector3d => Value::Vector3d([r.f64()?, r.f64()?, r.f64()?]),
            FieldType::Vector6d => {
                let mut v = [0.0; 6];
                for x in &mut v {
                    *x = r.f64()?;
                }
                Value::Vector6d(v)
            }
            FieldType::Vector6Int32 => {
                let mut v = [0; 6];
                for x in &mut v {
                    *x = r.i32()?;
                }
                Value::Vector6Int32(v)
            }
            FieldType::Vector6Uint32 => {
                let mut v = [0; 6];
                for x in &mut v {
                    *x = r.u32()?;
                }
                Value::Vector6Uint32(v)
            }
        })
    }

    /// As a double, if scalar numeric.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Value::Bool(b) => Some(f64::from(u8::from(b))),
            Value::Uint8(v) => Some(f64::from(v)),
            Value::Uint32(v) => Some(f64::from(v)),
            Value::Uint64(v) => Some(v as f64),
            Value::Int32(v) => Some(f64::from(v)),
            Value::Double(v) => Some(v),
            _ => None,
        }
    }

    /// As a 6-vector of doubles.
    pub fn as_vec6(&self) -> Option<[f64; 6]> {
        match *self {
            Value::Vector6d(v) => Some(v),
            _ => None,
        }
    }
}

/// Encode values back to back (a data-package body).
pub fn encode_values(values: &[Value], out: &mut Vec<u8>) {
    values.iter().for_each(|v| v.encode(out));
}

/// Decode a data-package body that must hold exactly `types`.
pub fn decode_values(types: &[FieldType], body: &[u8]) -> Result<Vec<Value>, UrError> {
    let expected: usize = types.iter().map(|t| t.size()).sum();
    if body.len() != expected {
        return Err(UrError::malformed(
            P,
            format!(
                "data package holds {} bytes but its recipe needs {expected}",
                body.len()
            ),
        ));
    }
    let mut r = Reader::new(body);
    types.iter().map(|&t| Value::decode(t, &mut r)).collect()
}
