//! RTDE (Real-Time Data Exchange, port 30004) wire format: framing, package types, payloads of
//! protocol versions 1 and 2, and the typed field table. Shared by the client ([`crate::client`])
//! and the simulator ([`crate::sim`]). All multi-byte values are big-endian.

mod fields;
mod frame;
mod package;
mod reader;
#[cfg(test)]
pub(crate) mod tests;
mod value;

pub use frame::{read_frame, Frame, FrameReadError, PackageType};
pub use package::{ClientPackage, Protocol, ServerPackage, TextMessage};
pub use reader::Reader;
pub use value::{decode_values, encode_values, FieldType, Value};

/// Protocol name used in errors.
const P: &str = "RTDE";

/// Largest field-name list a setup request may carry (UR RTDE guide).
pub const MAX_NAMES_BYTES: usize = 2048;

/// The type of a known field, or `None` (the controller answers `NOT_FOUND`).
pub fn field_type(name: &str) -> Option<FieldType> {
    lookup(name).map(|(_, t, _)| t)
}

/// Whether a client may write this field through an input recipe.
pub fn is_input_field(name: &str) -> bool {
    lookup(name).is_some_and(|(_, _, input)| input)
}

/// Every known field and its type, sorted by name.
pub fn all_fields() -> impl Iterator<Item = (&'static str, FieldType)> {
    fields::FIELDS.iter().map(|&(n, t, _)| (n, t))
}

fn lookup(name: &str) -> Option<(&'static str, FieldType, bool)> {
    fields::FIELDS
        .binary_search_by(|(n, _, _)| (*n).cmp(name))
        .ok()
        .map(|i| fields::FIELDS[i])
}
