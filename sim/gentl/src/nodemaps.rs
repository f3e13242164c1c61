//! The GenTL SFNC node maps of the system, interface, device and data stream modules: each
//! module's port holds its GenApi XML (a `Local:` URL) and the registers behind it, so a
//! consumer (harvesters, Halcon, Vimba) reads `TLVendorName`, `DeviceAccessStatus`,
//! `StreamAnnouncedBufferCount` and sets `StreamBufferHandlingMode` as on a vendor's producer.
//! Values are computed when read, from the producer's state.

use super::*;

/// Which module's node map a port handle stands for.
#[derive(Debug, Clone)]
pub(crate) enum Kind {
    System,
    Interface,
    Device,
    Stream(Arc<Stream>),
}

impl Kind {
    /// The module's node map, `None` for the remote device's port (the camera's own XML) or a
    /// handle that is no port.
    pub(crate) fn of(m: &Module) -> Option<Kind> {
        match m {
            Module::System => Some(Kind::System),
            Module::Interface => Some(Kind::Interface),
            Module::Device => Some(Kind::Device),
            Module::Stream(s) => Some(Kind::Stream(Arc::clone(s))),
            _ => None,
        }
    }

    fn name(&self) -> &'static str {
        match self {
            Kind::System => "TLSystem",
            Kind::Interface => "TLInterface",
            Kind::Device => "TLDevice",
            Kind::Stream(_) => "TLDataStream",
        }
    }
}

/// Where each module keeps its XML.
const XML_ADDRESS: u64 = 0x1_0000;
/// Bytes of a string register.
const STRING_BYTES: u64 = 64;

/// A feature of a module's node map and the register behind it.
#[derive(Debug, Clone, Copy)]
enum Feature {
    /// A read-only string.
    Text(&'static str, u64),
    /// A read-only integer (8 bytes).
    Int(&'static str, u64),
    /// An enumeration over an 8-byte register: entries (name, value), writable or not.
    Enum(&'static str, u64, &'static [(&'static str, i64)], bool),
}

const TL_TYPE_ENTRIES: &[(&str, i64)] = &[("Custom", 0)];
/// `DEVICE_ACCESS_STATUS_*` values, as SFNC's `DeviceAccessStatus` entries.
const ACCESS_ENTRIES: &[(&str, i64)] = &[
    ("Unknown", 0),
    ("ReadWrite", 1),
    ("ReadOnly", 2),
    ("NoAccess", 3),
    ("Busy", 4),
    ("OpenReadWrite", 5),
    ("OpenReadOnly", 6),
];
/// The one buffer handling this producer does: filled buffers are delivered in order, a
/// frame with no free buffer is dropped (SFNC's OldestFirst).
const HANDLING_ENTRIES: &[(&str, i64)] = &[("OldestFirst", 1)];

fn features(kind: &Kind) -> &'static [Feature] {
    use Feature::*;
    match kind {
        Kind::System => &[
            Text("TLID", 0x100),
            Text("TLVendorName", 0x140),
            Text("TLModelName", 0x180),
            Text("TLVersion", 0x1C0),
            Text("TLPath", 0x200),
            Enum("TLType", 0x400, TL_TYPE_ENTRIES, false),
            Int("GenTLVersionMajor", 0x408),
            Int("GenTLVersionMinor", 0x410),
            Int("InterfaceSelector", 0x418),
            Text("InterfaceID", 0x240),
        ],
        Kind::Interface => &[
            Text("InterfaceID", 0x100),
            Enum("InterfaceType", 0x400, TL_TYPE_ENTRIES, false),
            Int("DeviceSelector", 0x408),
            Text("DeviceID", 0x140),
            Text("DeviceVendorName", 0x180),
            Text("DeviceModelName", 0x1C0),
            Enum("DeviceAccessStatus", 0x410, ACCESS_ENTRIES, false),
        ],
        Kind::Device => &[
            Text("DeviceID", 0x100),
            Text("DeviceVendorName", 0x140),
            Text("DeviceModelName", 0x180),
            Text("DeviceSerialNumber", 0x1C0),
            Text("DeviceVersion", 0x200),
            Enum("DeviceType", 0x400, TL_TYPE_ENTRIES, false),
            Enum("DeviceAccessStatus", 0x408, ACCESS_ENTRIES, false),
        ],
        Kind::Stream(_) => &[
            Text("StreamID", 0x100),
            Enum("StreamType", 0x400, TL_TYPE_ENTRIES, false),
            Enum("StreamBufferHandlingMode", 0x408, HANDLING_ENTRIES, true),
            Int("StreamAnnouncedBufferCount", 0x410),
            Int("StreamAnnounceBufferMinimum", 0x418),
            Int("StreamDeliveredFrameCount", 0x420),
        ],
    }
}

/// The module's GenApi XML.
fn xml(kind: &Kind) -> String {
    let list = features(kind);
    let mut body = String::new();
    let reg = |name: &str, address: u64, len: u64, mode: &str, tag: &str| {
        // A StringReg has neither sign nor byte order.
        format!(
            "  <{tag} Name=\"{name}\">\n    <Address>{address:#x}</Address>\n    \
             <Length>{len}</Length>\n    <AccessMode>{mode}</AccessMode>\n    \
             <pPort>TLPort</pPort>\n{}  </{tag}>\n",
            if tag == "IntReg" {
                "    <Sign>Unsigned</Sign>\n    <Endianess>LittleEndian</Endianess>\n"
            } else {
                ""
            }
        )
    };
    for f in list {
        match *f {
            Feature::Text(name, a) => body += &reg(name, a, STRING_BYTES, "RO", "StringReg"),
            Feature::Int(name, a) => body += &reg(name, a, 8, "RO", "IntReg"),
            Feature::Enum(name, a, entries, writable) => {
                body += &format!("  <Enumeration Name=\"{name}\" NameSpace=\"Standard\">\n");
                for (entry, v) in entries {
                    body += &format!(
                        "    <EnumEntry Name=\"{entry}\" NameSpace=\"Standard\">\n      \
                         <Value>{v}</Value>\n    </EnumEntry>\n"
                    );
                }
                body += &format!("    <pValue>{name}Reg</pValue>\n  </Enumeration>\n");
                let mode = if writable { "RW" } else { "RO" };
                body += &reg(&format!("{name}Reg"), a, 8, mode, "IntReg");
            }
        }
    }
    let names: String = list
        .iter()
        .map(|f| {
            let (Feature::Text(n, _) | Feature::Int(n, _) | Feature::Enum(n, ..)) = *f;
            format!("    <pFeature>{n}</pFeature>\n")
        })
        .collect();
    format!(
        "<?xml version=\"1.0\" encoding=\"utf-8\"?>\n<RegisterDescription ModelName=\"{model}\" \
         VendorName=\"handeye\" ToolTip=\"handeye simulated producer: {model}\" \
         StandardNameSpace=\"None\" SchemaMajorVersion=\"1\" SchemaMinorVersion=\"1\" \
         SchemaSubMinorVersion=\"0\" MajorVersion=\"1\" MinorVersion=\"0\" SubMinorVersion=\"0\" \
         ProductGuid=\"5f1c3a52-9d1e-4d57-9a3e-3c5b2a0e0d{n:02x}\" \
         VersionGuid=\"5f1c3a52-9d1e-4d57-9a3e-3c5b2a0e1d{n:02x}\" \
         xmlns=\"http://www.genicam.org/GenApi/Version_1_1\" \
         xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" \
         xsi:schemaLocation=\"http://www.genicam.org/GenApi/Version_1_1 \
         http://www.genicam.org/GenApi/GenApiSchema_Version_1_1.xsd\">\n  \
         <Category Name=\"Root\" NameSpace=\"Standard\">\n{names}  </Category>\n{body}  \
         <Port Name=\"TLPort\" NameSpace=\"Standard\"/>\n</RegisterDescription>\n",
        model = kind.name(),
        n = list.len(),
    )
}

/// The module port's one URL: `Local:NAME.xml;ADDRESS;LENGTH` (hex).
pub(crate) fn url(kind: &Kind) -> String {
    format!(
        "Local:{}.xml;{XML_ADDRESS:x};{:x}",
        kind.name(),
        xml(kind).len()
    )
}

/// The current value of a feature register, as its bytes (strings NUL-padded).
fn value(p: &Producer, kind: &Kind, address: u64) -> Option<Vec<u8>> {
    let o = &p.options;
    let f = features(kind).iter().find(|f| match **f {
        Feature::Text(_, a) | Feature::Int(_, a) | Feature::Enum(_, a, ..) => a == address,
    })?;
    let text = |s: &str| {
        let mut b = s.as_bytes().to_vec();
        b.resize(STRING_BYTES as usize, 0);
        Some(b)
    };
    let int = |v: i64| Some(v.to_le_bytes().to_vec());
    let access = i64::from(if p.device.is_some() {
        abi::ACCESS_STATUS_OPEN_READWRITE
    } else {
        abi::ACCESS_STATUS_READWRITE
    });
    match (*f, kind) {
        (Feature::Text("TLID", _), _) => text(TL_ID),
        (Feature::Text("TLVendorName", _), _) => text(&SimOptions::default().vendor),
        (Feature::Text("TLModelName", _), _) => text("handeye simulated 3D camera producer"),
        (Feature::Text("TLVersion", _), _) => text(env!("CARGO_PKG_VERSION")),
        (Feature::Text("TLPath", _), _) => text(&own_path()),
        (Feature::Text("InterfaceID", _), _) => text(IF_ID),
        (Feature::Text("DeviceID", _), _) => text(p.device_id()),
        (Feature::Text("DeviceVendorName", _), _) => text(&o.vendor),
        (Feature::Text("DeviceModelName", _), _) => text(&o.model),
        (Feature::Text("DeviceSerialNumber", _), _) => text(&o.serial),
        (Feature::Text("DeviceVersion", _), _) => text(&o.version),
        (Feature::Text("StreamID", _), _) => text(STREAM_ID),
        (Feature::Int("GenTLVersionMajor", _), _) => int(1),
        (Feature::Int("GenTLVersionMinor", _), _) => int(5),
        (Feature::Int("StreamAnnounceBufferMinimum", _), _) => int(1),
        (Feature::Int("StreamAnnouncedBufferCount", _), Kind::Stream(s)) => {
            int(lock(&s.state).buffers.len() as i64)
        }
        (Feature::Int("StreamDeliveredFrameCount", _), Kind::Stream(s)) => {
            let st = lock(&s.state);
            int(st.buffers.values().filter(|b| b.filled.is_some()).count() as i64)
        }
        (Feature::Enum("DeviceAccessStatus", ..), _) => int(access),
        (Feature::Enum("StreamBufferHandlingMode", ..), _) => int(HANDLING_ENTRIES[0].1),
        (Feature::Enum(..), _) | (Feature::Int(..), _) => int(0),
        (Feature::Text(..), _) => text(""),
    }
}

/// Read `dst.len()` bytes at `address` of the module's port: its XML or a feature register
/// (a read that starts inside a register must cover it whole).
pub(crate) fn read(p: &Producer, kind: &Kind, address: u64, dst: &mut [u8]) -> Res {
    let doc = xml(kind);
    let end = address.checked_add(dst.len() as u64);
    if address >= XML_ADDRESS && end.is_some_and(|e| e <= XML_ADDRESS + doc.len() as u64) {
        let o = (address - XML_ADDRESS) as usize;
        dst.copy_from_slice(&doc.as_bytes()[o..o + dst.len()]);
        return Ok(());
    }
    match value(p, kind, address) {
        Some(v) if dst.len() <= v.len() => {
            dst.copy_from_slice(&v[..dst.len()]);
            Ok(())
        }
        _ => Err(Fail::new(
            err::INVALID_ADDRESS,
            format!(
                "{}: no register of {} bytes at 0x{address:x}",
                kind.name(),
                dst.len()
            ),
        )),
    }
}

/// Write at `address` of the module's port: only `StreamBufferHandlingMode` is writable, and
/// only to a mode this producer does.
pub(crate) fn write(kind: &Kind, address: u64, src: &[u8]) -> Res {
    let handling = features(kind).iter().find_map(|f| match *f {
        Feature::Enum("StreamBufferHandlingMode", a, ..) => Some(a),
        _ => None,
    });
    if handling != Some(address) {
        return Err(Fail::new(
            err::ACCESS_DENIED,
            format!("{}: register 0x{address:x} is read-only", kind.name()),
        ));
    }
    let mut raw = [0u8; 8];
    let n = src.len().min(8);
    raw[..n].copy_from_slice(&src[..n]);
    let v = i64::from_le_bytes(raw);
    if HANDLING_ENTRIES.iter().any(|(_, e)| *e == v) {
        Ok(())
    } else {
        Err(Fail::new(
            err::INVALID_VALUE,
            format!("StreamBufferHandlingMode {v}: this producer does OldestFirst (1) only"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every module's XML loads in our GenApi and names its port TLPort; the URL's length is
    /// the XML's.
    #[test]
    fn module_xml_loads() {
        for kind in [Kind::System, Kind::Interface, Kind::Device] {
            let doc = xml(&kind);
            let nm = handeye_gige::genicam::NodeMap::from_xml(&doc)
                .unwrap_or_else(|e| panic!("{}: {e}", kind.name()));
            assert!(nm.has("TLPort"));
            assert!(url(&kind).ends_with(&format!(";{:x}", doc.len())));
        }
    }
}
