//! Where a device's GenICam XML is and how it is read: the URL register's text (`Local:`,
//! `File:` as RFC 8089 reads it, `http:` refused), unzipping, and the bounds on both.

use std::io::Read;

use crate::client::GvcpClient;
use crate::error::{GigeError, Result};
use crate::gvcp::reg;

/// Where a device keeps its XML.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum XmlUrl {
    /// In device memory.
    Local {
        /// File name (ends in `.zip` when compressed).
        file: String,
        /// Start address.
        address: u32,
        /// Length in bytes.
        length: u32,
    },
    /// A file on the host: its path, percent-decoded (RFC 8089: `File:///abs/x.xml` and
    /// `File:/abs/x.xml` are absolute, `File:x.xml` is relative to the producer's directory).
    File(String),
    /// A web address (not fetched by this driver).
    Http(String),
}

impl XmlUrl {
    /// Parse the URL register text (`Local:name.xml;10000;3e67`, `local:///name;0x10000;3e67`,
    /// optional `?SchemaVersion=…`).
    pub fn parse(s: &str) -> Result<Self> {
        const W: &str = "XML URL";
        let s = s.trim_matches(|c: char| c == '\0' || c.is_whitespace());
        let s = s.split('?').next().unwrap_or(s);
        let (scheme, rest) = s
            .split_once(':')
            .ok_or_else(|| GigeError::malformed(W, format!("`{s}` has no scheme")))?;
        match scheme.to_ascii_lowercase().as_str() {
            "local" => {
                let rest = rest.trim_start_matches('/');
                let parts: Vec<&str> = rest.split(';').collect();
                if parts.len() != 3 {
                    return Err(GigeError::malformed(
                        W,
                        format!("`{s}`: expected Local:name;address;length"),
                    ));
                }
                let hex = |t: &str| {
                    let t = t.trim();
                    let t = t
                        .strip_prefix("0x")
                        .or_else(|| t.strip_prefix("0X"))
                        .unwrap_or(t);
                    u64::from_str_radix(t, 16)
                        .ok()
                        .and_then(|v| u32::try_from(v).ok())
                        .ok_or_else(|| {
                            GigeError::malformed(
                                W,
                                format!("`{s}`: `{t}` is not a 32-bit hex number"),
                            )
                        })
                };
                let (address, length) = (hex(parts[1])?, hex(parts[2])?);
                if length == 0 || length as usize > MAX_XML_BYTES {
                    return Err(GigeError::malformed(
                        W,
                        format!("`{s}`: absurd XML length {length}"),
                    ));
                }
                Ok(Self::Local {
                    file: parts[0].trim().to_owned(),
                    address,
                    length,
                })
            }
            "file" => file_path(rest)
                .map(Self::File)
                .map_err(|e| GigeError::malformed(W, format!("`{s}`: {e}"))),
            "http" | "https" => Ok(Self::Http(s.to_owned())),
            other => Err(GigeError::malformed(
                W,
                format!("`{s}`: unknown scheme `{other}`"),
            )),
        }
    }
}

/// The path of a `file:` URL after its scheme (RFC 8089): `//host/path` with an empty host or
/// `localhost`, or a path (absolute with a leading `/`, else relative); percent-decoded.
fn file_path(rest: &str) -> std::result::Result<String, String> {
    let path = match rest.strip_prefix("//") {
        Some(after) => {
            let (host, path) = after.split_at(after.find('/').unwrap_or(after.len()));
            if !(host.is_empty() || host.eq_ignore_ascii_case("localhost")) {
                return Err(format!("a file on another host (`{host}`) cannot be read"));
            }
            path
        }
        None => rest,
    };
    let b = path.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = b
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| format!("a bad percent escape at byte {i}"))?;
            out.push(hex);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    let path = String::from_utf8(out).map_err(|_| "a path that is not UTF-8".to_owned())?;
    if path.is_empty() || path.contains('\0') {
        return Err("no file name".into());
    }
    Ok(path)
}

/// Largest unzipped GenICam XML, bytes.
const MAX_UNZIPPED_XML_BYTES: u64 = 32 << 20;

/// Unzip `bytes` when they are a ZIP archive (first entry), else return them; then UTF-8.
pub fn xml_text(bytes: &[u8]) -> Result<String> {
    const W: &str = "GenICam XML";
    let data = if bytes.starts_with(b"PK\x03\x04") {
        let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes))
            .map_err(|e| GigeError::malformed(W, format!("bad ZIP archive: {e}")))?;
        let mut entry = zip
            .by_index(0)
            .map_err(|e| GigeError::malformed(W, format!("ZIP archive without a file: {e}")))?;
        let mut out = Vec::new();
        entry
            .by_ref()
            .take(MAX_UNZIPPED_XML_BYTES + 1)
            .read_to_end(&mut out)
            .map_err(|e| GigeError::malformed(W, format!("cannot unzip: {e}")))?;
        if out.len() as u64 > MAX_UNZIPPED_XML_BYTES {
            return Err(GigeError::malformed(
                W,
                format!("the ZIP archive unzips to more than {MAX_UNZIPPED_XML_BYTES} bytes"),
            ));
        }
        out
    } else {
        bytes.to_vec()
    };
    let end = data.iter().rposition(|&c| c != 0).map_or(0, |i| i + 1);
    String::from_utf8(data[..end].to_vec())
        .map_err(|e| GigeError::malformed(W, format!("not UTF-8: {e}")))
}

/// Largest GenICam XML (or ZIP of it) read from a device or file, bytes; real ones are a few
/// hundred kB (ZIP: tens of kB), and each 536 bytes of device memory is one GVCP round trip.
pub const MAX_XML_BYTES: usize = 16 << 20;

/// Read the XML a URL names: `Local:` through `read_mem(address, length)` (the device's
/// memory), `File:` from this host (a relative path from `base`, the GenTL producer's
/// directory; refused without one); unzipped when zipped. `http:` is refused with what to do.
pub fn load_xml(
    url: XmlUrl,
    base: Option<&std::path::Path>,
    read_mem: impl FnOnce(u32, usize) -> Result<Vec<u8>>,
) -> Result<String> {
    match url {
        XmlUrl::Local {
            address, length, ..
        } => xml_text(&read_mem(address, length as usize)?),
        XmlUrl::File(path) => {
            let given = std::path::Path::new(&path);
            let file = match base {
                _ if given.is_absolute() => given.to_owned(),
                Some(dir) => dir.join(given),
                None => {
                    return Err(GigeError::malformed(
                        "XML URL",
                        format!("`File:{path}` is relative, and this device has no directory to read it from; give the file's absolute path"),
                    ))
                }
            };
            // The device names the file: never a FIFO or device, never unbounded.
            handeye_hal::limits::check_regular_file(&file, MAX_XML_BYTES as u64)
                .and_then(|_| std::fs::read(&file))
                .map_err(|e| {
                    GigeError::malformed(
                        "XML URL",
                        format!("cannot read the device's XML file {}: {e}", file.display()),
                    )
                })
                .and_then(|bytes| xml_text(&bytes))
        }
        XmlUrl::Http(u) => Err(GigeError::malformed(
            "XML URL",
            format!("`{u}`: downloading the XML is not supported; save it and use a File: URL"),
        )),
    }
}

/// Read the XML of a device: first URL register, then the second one as fallback.
pub fn fetch_xml(client: &GvcpClient) -> Result<String> {
    let mut last_err = None;
    for url_reg in [reg::FIRST_URL, reg::SECOND_URL] {
        let fetched = client
            .read_string(url_reg, 512)
            .and_then(|u| XmlUrl::parse(&u))
            .and_then(|url| {
                load_xml(url, None, |address, length| {
                    client.read_mem(address, length)
                })
            });
        match fetched {
            Ok(x) => return Ok(x),
            // A device that does not answer (or stalls) will not answer the second URL either.
            Err(e @ (GigeError::Timeout { .. } | GigeError::Stalled { .. })) => return Err(e),
            Err(e) => last_err = Some(e),
        }
    }
    Err(last_err.unwrap_or_else(|| GigeError::malformed("XML URL", "no URL register")))
}
