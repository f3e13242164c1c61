//! Point-cloud files (PLY, PCD) and cloud utilities. The cloud type itself is
//! [`handeye_hal::PointCloud`].
//!
//! - [`read_cloud`] memory-maps a file and detects PLY or PCD from its first bytes;
//!   [`read_ply`] and [`read_pcd`] parse bytes already in memory.
//! - [`write_ply`] (binary little-endian `float32` by default, see [`PlyEncoding`]) and
//!   [`write_pcd`] keep the organization (width × height), intensity and confidence.
//! - [`voxel_downsample`] reduces a point set to one centroid per voxel.
//!
//! Coordinates are metres. Files we write say so (`comment unit m`); a file carrying
//! `comment unit mm` (PLY) or `# unit mm` (PCD) is scaled to metres on reading (also `cm`,
//! `um`); a file without a unit line is taken as metres. Zivid Studio exports millimetres
//! without saying so: add `comment unit mm` to the header, or scale after reading.
//!
//! Organized PLY files carry the pixel grid as `obj_info width W` / `obj_info height H`
//! (PCL's `obj_info num_cols` / `num_rows` are read too). PCD has `WIDTH`/`HEIGHT`.
//! Invalid pixels are NaN, preserved bit-for-bit by the binary encodings.
//!
//! Every malformed file gives a [`CloudError`] that says what is wrong, where (line or byte
//! offset, element and property) and what to do. Counts in headers are checked against the
//! file size before anything is allocated.

mod image;
mod pcd;
mod ply;
mod scalar;
mod voxel;

use std::fmt;
use std::path::{Path, PathBuf};

use handeye_hal::nalgebra::Point3;
use handeye_hal::PointCloud;

pub use image::{read_png, write_png, ColorImage};
pub use pcd::{read_pcd, write_pcd};
pub use ply::{read_ply, write_ply, PlyEncoding};
pub use voxel::voxel_downsample;

/// The two point-cloud file formats we read and write.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CloudFormat {
    /// Stanford PLY (`ply` magic).
    Ply,
    /// PCL's Point Cloud Data format (version .7).
    Pcd,
}

impl fmt::Display for CloudFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            CloudFormat::Ply => "PLY",
            CloudFormat::Pcd => "PCD",
        })
    }
}

/// Re-export advice appended to messages about files we cannot use.
const REEXPORT: &str =
    "re-export the cloud as binary_little_endian PLY with float x,y,z vertex properties (or PCD with FIELDS x y z)";

/// Everything that can go wrong reading or writing a point-cloud file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CloudError {
    /// The file could not be opened, mapped, created or written.
    #[error("cannot {action} {path}: {source}; check the path and its permissions")]
    Io {
        /// What we were doing (`open`, `map`, `create`, `write`).
        action: &'static str,
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// The bytes do not start like a PLY or PCD file.
    #[error(
        "not a point-cloud file: expected `ply` (PLY) or a `# .PCD`/`VERSION`/`FIELDS` header \
         (PCD) at byte 0, found {found:?}; {REEXPORT}"
    )]
    NoMagic {
        /// The first bytes of the file, lossily decoded.
        found: String,
    },
    /// The header names an encoding we do not know.
    #[error("{format} header line {line}: unknown data encoding `{found}`; expected {expected}")]
    UnknownEncoding {
        /// File format.
        format: CloudFormat,
        /// 1-based header line.
        line: usize,
        /// What the file says.
        found: String,
        /// What we accept.
        expected: &'static str,
    },
    /// A header line is malformed or inconsistent with the others.
    #[error("{format} header line {line}: {reason}; {REEXPORT}")]
    BadHeader {
        /// File format.
        format: CloudFormat,
        /// 1-based header line (0 when the problem is the header as a whole).
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// A property/field has a type we cannot read.
    #[error("{format} header line {line}: unsupported type `{found}` for `{field}`; {REEXPORT}")]
    UnsupportedType {
        /// File format.
        format: CloudFormat,
        /// 1-based header line.
        line: usize,
        /// Property or field name.
        field: String,
        /// The type as written in the file.
        found: String,
    },
    /// A required element or property (the vertex element, `x`, `y` or `z`) is absent.
    #[error("{format} file has no {what}; {REEXPORT}")]
    Missing {
        /// File format.
        format: CloudFormat,
        /// What is missing, e.g. "vertex property `z`".
        what: String,
    },
    /// The data section is shorter than the header promises.
    #[error(
        "{format} data truncated: {what} needs {expected_bytes} bytes from byte offset \
         {offset}, the file has only {available}; the file was cut short (incomplete copy or \
         export): copy or export it again"
    )]
    Truncated {
        /// File format.
        format: CloudFormat,
        /// Which data, e.g. "12 vertices of 20 bytes (element `vertex`)".
        what: String,
        /// Bytes needed.
        expected_bytes: u64,
        /// Byte offset where that data starts.
        offset: u64,
        /// Bytes available from there.
        available: u64,
    },
    /// A count in the header cannot possibly fit in the file (checked before allocating).
    #[error(
        "{format} header declares {count} {what}, but only {available} bytes of data follow \
         the header: the header is corrupt; {REEXPORT}"
    )]
    AbsurdCount {
        /// File format.
        format: CloudFormat,
        /// What is counted, e.g. "`vertex` elements".
        what: String,
        /// The declared count.
        count: u64,
        /// Bytes of data in the file.
        available: u64,
    },
    /// A value in the data section is unreadable (ASCII number, list length, missing token).
    #[error("{format} data {location}: {reason}; {REEXPORT}")]
    BadData {
        /// File format.
        format: CloudFormat,
        /// Where: "line 17, element `vertex` #3, property `y`" or "byte offset 1234 ...".
        location: String,
        /// What is wrong.
        reason: String,
    },
    /// A feature of the format that we do not implement.
    #[error("{format}: {feature} is not supported; {advice}")]
    Unsupported {
        /// File format.
        format: CloudFormat,
        /// The feature.
        feature: String,
        /// What to do instead.
        advice: &'static str,
    },
    /// An image file (the colour registered to a scan) cannot be used.
    #[error("image {path}: {reason}")]
    Image {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A cloud given to a writer is inconsistent (grid size, attribute lengths).
    #[error("cannot write the cloud: {reason}; fix the cloud's width/height or attribute vectors")]
    InconsistentCloud {
        /// What is inconsistent.
        reason: String,
    },
}

impl CloudError {
    fn io(action: &'static str, path: &Path, source: std::io::Error) -> Self {
        CloudError::Io {
            action,
            path: path.to_path_buf(),
            source,
        }
    }
}

/// Appends one decoded ASCII row — `[x, y, z, intensity, confidence]` in file units — to the
/// point, intensity and confidence columns, scaling coordinates to metres.
pub(crate) fn push_row(
    vals: &[f32; 5],
    scale: f32,
    points: &mut Vec<Point3<f32>>,
    intensity: &mut Option<Vec<f32>>,
    confidence: &mut Option<Vec<f32>>,
) {
    points.push(Point3::new(
        vals[0] * scale,
        vals[1] * scale,
        vals[2] * scale,
    ));
    if let Some(v) = intensity.as_mut() {
        v.push(vals[3]);
    }
    if let Some(v) = confidence.as_mut() {
        v.push(vals[4]);
    }
}

/// Longest word of a (non-comment) header line, bytes.
const MAX_HEADER_WORD: usize = 256;

/// The next non-empty header line of a text header, as `(keyword, other words)`, starting at
/// `*pos` and leaving `*pos` after it; `*line_no` counts lines (1-based after the call).
/// `Ok(None)` when the input ends or `max_bytes` of header have been read. `format` names the
/// file format in the error for a line that is not UTF-8.
pub(crate) fn next_header_line<'a>(
    bytes: &'a [u8],
    pos: &mut usize,
    line_no: &mut usize,
    max_bytes: usize,
    format: CloudFormat,
) -> Result<Option<(&'a str, Vec<&'a str>)>, CloudError> {
    loop {
        if *pos >= bytes.len() || *pos > max_bytes {
            return Ok(None);
        }
        let rest = &bytes[*pos..];
        let (raw, next) = match rest.iter().position(|&b| b == b'\n') {
            Some(i) => (&rest[..i], *pos + i + 1),
            None => (rest, bytes.len()),
        };
        *pos = next;
        *line_no += 1;
        let text = std::str::from_utf8(raw).map_err(|_| CloudError::BadHeader {
            format,
            line: *line_no,
            reason: "header line is not UTF-8 text".into(),
        })?;
        let mut words = text.split_ascii_whitespace();
        if let Some(keyword) = words.next() {
            let words: Vec<&str> = words.collect();
            // Header words are echoed in errors: none may carry control characters (terminal
            // escapes) or be longer than any real keyword, type or number. Comments may.
            let is_comment = keyword == "comment" || keyword.starts_with('#');
            let bad = |w: &&str| w.len() > MAX_HEADER_WORD || w.chars().any(char::is_control);
            if !is_comment && (bad(&keyword) || words.iter().any(bad)) {
                return Err(CloudError::BadHeader {
                    format,
                    line: *line_no,
                    reason: format!(
                        "a word longer than {MAX_HEADER_WORD} bytes or with control characters (starts `{}`)",
                        handeye_hal::limits::Quoted(&text[..text.len().min(40)])
                    ),
                });
            }
            return Ok(Some((keyword, words)));
        }
    }
}

/// Largest point-cloud file read (a 2448×2048 scan with intensity and confidence is ~100 MB).
pub const MAX_CLOUD_FILE_BYTES: u64 = 8 << 30;

/// Reads a PLY or PCD file (a regular file, at most [`MAX_CLOUD_FILE_BYTES`]), memory-mapped, detecting the format from its first bytes.
///
/// Blocks on file I/O (run it off async runtime workers). Errors do not repeat the path;
/// callers add it as context.
pub fn read_cloud(path: &Path) -> Result<PointCloud, CloudError> {
    // Before opening: opening a FIFO blocks until a writer comes, reading a device never ends.
    handeye_hal::limits::check_regular_file(path, MAX_CLOUD_FILE_BYTES)
        .map_err(|e| CloudError::io("open", path, e))?;
    let file = std::fs::File::open(path).map_err(|e| CloudError::io("open", path, e))?;
    let len = file
        .metadata()
        .map_err(|e| CloudError::io("open", path, e))?
        .len();
    if len == 0 {
        return read_cloud_bytes(&[]);
    }
    // SAFETY: the map is read-only and lives only for this call. If another process
    // truncates the file meanwhile, reads of the vanished pages raise SIGBUS; that is the
    // documented limitation of memory-mapped reading, accepted for the 10× speed-up on
    // multi-hundred-megabyte scans. The parser itself never trusts the contents.
    let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| CloudError::io("map", path, e))?;
    read_cloud_bytes(&map)
}

/// Parses PLY or PCD bytes, detecting the format from the first bytes.
pub fn read_cloud_bytes(bytes: &[u8]) -> Result<PointCloud, CloudError> {
    match detect(bytes) {
        Some(CloudFormat::Ply) => read_ply(bytes),
        Some(CloudFormat::Pcd) => read_pcd(bytes),
        None => Err(no_magic(bytes)),
    }
}

/// The format the bytes start with, if any.
pub fn detect(bytes: &[u8]) -> Option<CloudFormat> {
    if ply::has_magic(bytes) {
        Some(CloudFormat::Ply)
    } else if pcd::has_magic(bytes) {
        Some(CloudFormat::Pcd)
    } else {
        None
    }
}

fn no_magic(bytes: &[u8]) -> CloudError {
    let head = &bytes[..bytes.len().min(16)];
    CloudError::NoMagic {
        found: String::from_utf8_lossy(head).into_owned(),
    }
}

/// Checks a cloud before writing: grid size and attribute lengths agree with `points`.
fn check_cloud(cloud: &PointCloud) -> Result<(), CloudError> {
    let n = cloud.points.len();
    let grid = u64::from(cloud.width) * u64::from(cloud.height);
    if grid != n as u64 {
        return Err(CloudError::InconsistentCloud {
            reason: format!(
                "width {} × height {} = {grid}, but the cloud has {n} points",
                cloud.width, cloud.height
            ),
        });
    }
    for (name, attr) in [
        ("intensity", &cloud.intensity),
        ("confidence", &cloud.confidence),
    ] {
        if let Some(v) = attr {
            if v.len() != n {
                return Err(CloudError::InconsistentCloud {
                    reason: format!("{name} has {} values for {n} points", v.len()),
                });
            }
        }
    }
    Ok(())
}

/// File unit → metres factor from a unit name in a header comment.
fn unit_scale(unit: &str) -> Option<f32> {
    match unit.to_ascii_lowercase().as_str() {
        "m" | "meter" | "meters" | "metre" | "metres" => Some(1.0),
        "cm" => Some(0.01),
        "mm" | "millimeter" | "millimeters" | "millimetre" | "millimetres" => Some(0.001),
        "um" | "µm" | "micrometer" | "micrometre" => Some(1e-6),
        _ => None,
    }
}

/// Whether a property/field name is the per-point intensity.
fn is_intensity(name: &str) -> bool {
    let n = name.to_ascii_lowercase();
    matches!(
        n.strip_prefix("scalar_").unwrap_or(&n),
        "intensity" | "grey" | "gray"
    )
}

/// Whether a property/field name is the per-point confidence.
fn is_confidence(name: &str) -> bool {
    let n = name.to_ascii_lowercase();
    matches!(n.strip_prefix("scalar_").unwrap_or(&n), "confidence")
}

/// Appends one ASCII data line: the values separated by single spaces, then a newline.
fn ascii_row(out: &mut Vec<u8>, values: impl Iterator<Item = f32>) {
    for (i, v) in values.enumerate() {
        if i > 0 {
            out.push(b' ');
        }
        ascii_f32(out, v);
    }
    out.push(b'\n');
}

/// Formats a float for ASCII files: shortest round-trip form, `nan` for NaN (what PCL and C
/// readers expect).
fn ascii_f32(out: &mut Vec<u8>, v: f32) {
    use std::io::Write as _;
    if v.is_nan() {
        out.extend_from_slice(b"nan");
    } else {
        // Writing to a Vec cannot fail.
        let _ = write!(out, "{v}");
    }
}

#[cfg(test)]
mod tests;
