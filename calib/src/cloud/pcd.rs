//! PCD (PCL Point Cloud Data, v0.7) reading and writing: `DATA ascii`, `binary` and
//! `binary_compressed` (LZF, read only).
use std::io::Write as _;
use std::path::Path;

use handeye_hal::PointCloud;
use nalgebra::Point3;

use super::scalar::{nonblank_lines, read_column, read_points, tokens, Column, Scalar};
use super::CloudFormat::Pcd as FMT;
use super::{ascii_row, check_cloud, is_confidence, is_intensity, unit_scale, CloudError};

/// Headers longer than this are refused (real ones are a few hundred bytes).
const MAX_HEADER_BYTES: usize = 1 << 16;

/// LZF expands at most ~88× (a 3-byte back-reference yields 264 bytes); a declared
/// uncompressed size beyond this ratio is corrupt and is refused before allocating.
const LZF_MAX_RATIO: u64 = 100;

pub(super) fn has_magic(bytes: &[u8]) -> bool {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    let b = &bytes[start..];
    b.starts_with(b"# .PCD") || b.starts_with(b"VERSION") || b.starts_with(b"FIELDS")
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Data {
    Ascii,
    Binary,
    Compressed,
}

#[derive(Debug)]
struct Field {
    name: String,
    size: usize,
    ty: Scalar,
    count: usize,
    /// Byte offset inside one point record.
    offset: usize,
}

#[derive(Debug)]
struct Header {
    fields: Vec<Field>,
    width: u32,
    height: u32,
    points: u64,
    data: Data,
    scale: f32,
    data_offset: usize,
    lines: usize,
}

fn bad_header(line: usize, reason: impl Into<String>) -> CloudError {
    CloudError::BadHeader {
        format: FMT,
        line,
        reason: reason.into(),
    }
}

fn parse_header(bytes: &[u8]) -> Result<Header, CloudError> {
    if !has_magic(bytes) {
        return Err(super::no_magic(bytes));
    }
    let mut names: Option<(usize, Vec<String>)> = None;
    let mut sizes: Option<(usize, Vec<usize>)> = None;
    let mut types: Option<(usize, Vec<String>)> = None;
    let mut counts: Option<(usize, Vec<usize>)> = None;
    let (mut width, mut height, mut points) = (None, None, None);
    let mut scale = 1.0;
    let mut pos = 0usize;
    let mut line_no = 0usize;
    let data = loop {
        let Some((keyword, words)) =
            super::next_header_line(bytes, &mut pos, &mut line_no, MAX_HEADER_BYTES, FMT)?
        else {
            return Err(bad_header(line_no, "no `DATA` line ends the header"));
        };
        let num = |w: &str, what: &str| {
            w.parse::<u64>()
                .map_err(|_| bad_header(line_no, format!("{what} `{w}` is not a whole number")))
        };
        let nums = |what: &str| -> Result<Vec<usize>, CloudError> {
            words
                .iter()
                .map(|w| num(w, what).map(|v| v as usize))
                .collect()
        };
        match keyword {
            k if k.starts_with('#') => {
                if let ["unit" | "units", u] = words.as_slice() {
                    scale = unit_scale(u).ok_or_else(|| {
                        bad_header(
                            line_no,
                            format!(
                                "unknown unit `{}` (expected m, cm, mm or um)",
                                handeye_hal::limits::Quoted(u)
                            ),
                        )
                    })?;
                }
            }
            "VERSION" | "VIEWPOINT" => {}
            "FIELDS" => names = Some((line_no, words.iter().map(|s| (*s).to_owned()).collect())),
            "SIZE" => sizes = Some((line_no, nums("SIZE")?)),
            "TYPE" => types = Some((line_no, words.iter().map(|s| (*s).to_owned()).collect())),
            "COUNT" => counts = Some((line_no, nums("COUNT")?)),
            "WIDTH" | "HEIGHT" | "POINTS" => {
                let [w] = words.as_slice() else {
                    return Err(bad_header(
                        line_no,
                        format!("expected `{keyword} <number>`"),
                    ));
                };
                let v = num(w, keyword)?;
                match keyword {
                    "WIDTH" => width = Some(v),
                    "HEIGHT" => height = Some(v),
                    _ => points = Some(v),
                }
            }
            "DATA" => {
                break match words.first().copied().unwrap_or("") {
                    "ascii" => Data::Ascii,
                    "binary" => Data::Binary,
                    "binary_compressed" => Data::Compressed,
                    other => {
                        return Err(CloudError::UnknownEncoding {
                            format: FMT,
                            line: line_no,
                            found: other.to_owned(),
                            expected: "ascii, binary or binary_compressed",
                        })
                    }
                };
            }
            other => {
                return Err(bad_header(
                    line_no,
                    format!(
                        "unknown header keyword `{}`",
                        handeye_hal::limits::Quoted(other)
                    ),
                ))
            }
        }
    };
    let (_, names) = names.ok_or_else(|| bad_header(line_no, "no `FIELDS` line"))?;
    let (sl, sizes) = sizes.ok_or_else(|| bad_header(line_no, "no `SIZE` line"))?;
    let (tl, types) = types.ok_or_else(|| bad_header(line_no, "no `TYPE` line"))?;
    let (cl, counts) = counts.unwrap_or((0, vec![1; names.len()]));
    for (l, what, len) in [
        (sl, "SIZE", sizes.len()),
        (tl, "TYPE", types.len()),
        (cl, "COUNT", counts.len()),
    ] {
        if len != names.len() {
            return Err(bad_header(
                l,
                format!("{what} has {len} entries for {} FIELDS", names.len()),
            ));
        }
    }
    let mut fields = Vec::with_capacity(names.len());
    let mut offset = 0usize;
    for (((name, &size), ty), &count) in names.iter().zip(&sizes).zip(&types).zip(&counts) {
        let scalar = match (ty.as_str(), size) {
            ("F", 4) => Scalar::F32,
            ("F", 8) => Scalar::F64,
            ("I", 1) => Scalar::I8,
            ("I", 2) => Scalar::I16,
            ("I", 4) => Scalar::I32,
            ("I", 8) => Scalar::I64,
            ("U", 1) => Scalar::U8,
            ("U", 2) => Scalar::U16,
            ("U", 4) => Scalar::U32,
            ("U", 8) => Scalar::U64,
            _ => {
                return Err(CloudError::UnsupportedType {
                    format: FMT,
                    line: tl,
                    field: name.clone(),
                    found: format!("TYPE {ty} SIZE {size}"),
                })
            }
        };
        if count == 0 || count > 1 << 20 {
            return Err(bad_header(
                cl,
                format!("COUNT {count} of field `{name}` is out of range"),
            ));
        }
        fields.push(Field {
            name: name.clone(),
            size,
            ty: scalar,
            count,
            offset,
        });
        offset += size * count;
    }
    let width = width.ok_or_else(|| bad_header(line_no, "no `WIDTH` line"))?;
    let height = height.unwrap_or(1);
    let grid = width.saturating_mul(height);
    let points = points.unwrap_or(grid);
    if points != grid {
        return Err(bad_header(
            line_no,
            format!("POINTS {points} differs from WIDTH {width} × HEIGHT {height}"),
        ));
    }
    let (Ok(width), Ok(height)) = (u32::try_from(width), u32::try_from(height)) else {
        return Err(bad_header(line_no, "WIDTH or HEIGHT exceeds 4294967295"));
    };
    Ok(Header {
        fields,
        width,
        height,
        points,
        data,
        scale,
        data_offset: pos,
        lines: line_no,
    })
}

/// Parses PCD bytes (ascii, binary or binary_compressed) into a cloud in metres.
pub fn read_pcd(bytes: &[u8]) -> Result<PointCloud, CloudError> {
    let h = parse_header(bytes)?;
    let field = |name: &str| h.fields.iter().position(|f| f.name == name);
    let axis = |name: &str| {
        field(name).ok_or_else(|| CloudError::Missing {
            format: FMT,
            what: format!("field `{name}`"),
        })
    };
    let xyz = [axis("x")?, axis("y")?, axis("z")?];
    let intensity = h.fields.iter().position(|f| is_intensity(&f.name));
    let confidence = h.fields.iter().position(|f| is_confidence(&f.name));
    let data = &bytes[h.data_offset..];
    let available = data.len() as u64;
    if h.points > available || h.points > u64::from(u32::MAX) {
        return Err(CloudError::AbsurdCount {
            format: FMT,
            what: "points".to_owned(),
            count: h.points,
            available,
        });
    }
    let n = h.points as usize;
    let stride: usize = h.fields.iter().map(|f| f.size * f.count).sum();
    let (points, intensity, confidence) = match h.data {
        Data::Ascii => read_ascii(&h, data, xyz, intensity, confidence)?,
        Data::Binary => {
            let need = (n as u64).saturating_mul(stride as u64);
            if need > available {
                return Err(CloudError::Truncated {
                    format: FMT,
                    what: format!("{n} points of {stride} bytes"),
                    expected_bytes: need,
                    offset: h.data_offset as u64,
                    available,
                });
            }
            let col = |i: usize| Column {
                base: h.fields[i].offset,
                stride,
                ty: h.fields[i].ty,
                big_endian: false,
            };
            let block = &data[..need as usize];
            (
                read_points(block, n, xyz.map(col), h.scale),
                intensity.map(|i| read_column(block, n, col(i))),
                confidence.map(|i| read_column(block, n, col(i))),
            )
        }
        Data::Compressed => {
            let block = decompress(&h, data, n, stride)?;
            // Column layout: all values of field 0, then all of field 1, …
            let col = |i: usize| Column {
                base: n * h.fields[i].offset,
                stride: h.fields[i].size * h.fields[i].count,
                ty: h.fields[i].ty,
                big_endian: false,
            };
            (
                read_points(&block, n, xyz.map(col), h.scale),
                intensity.map(|i| read_column(&block, n, col(i))),
                confidence.map(|i| read_column(&block, n, col(i))),
            )
        }
    };
    Ok(PointCloud {
        width: h.width,
        height: h.height,
        points,
        intensity,
        confidence,
    })
}

fn decompress(h: &Header, data: &[u8], n: usize, stride: usize) -> Result<Vec<u8>, CloudError> {
    let word = |i: usize| {
        data.get(i..i + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let (Some(compressed), Some(raw)) = (word(0), word(4)) else {
        return Err(CloudError::Truncated {
            format: FMT,
            what: "the binary_compressed size words".to_owned(),
            expected_bytes: 8,
            offset: h.data_offset as u64,
            available: data.len() as u64,
        });
    };
    let (compressed, raw) = (u64::from(compressed), u64::from(raw));
    let available = data.len() as u64 - 8;
    if compressed > available {
        return Err(CloudError::Truncated {
            format: FMT,
            what: "the LZF-compressed block".to_owned(),
            expected_bytes: compressed,
            offset: h.data_offset as u64 + 8,
            available,
        });
    }
    let need = (n as u64).saturating_mul(stride as u64);
    let location = || format!("byte offset {}, binary_compressed block", h.data_offset);
    if raw != need {
        return Err(CloudError::BadData {
            format: FMT,
            location: location(),
            reason: format!(
                "uncompressed size {raw} differs from {n} points × {stride} bytes = {need}"
            ),
        });
    }
    if raw > compressed.saturating_mul(LZF_MAX_RATIO) + 1024 {
        return Err(CloudError::AbsurdCount {
            format: FMT,
            what: format!("uncompressed bytes in a {compressed}-byte LZF block"),
            count: raw,
            available: compressed,
        });
    }
    lzf_decompress(&data[8..8 + compressed as usize], raw as usize).map_err(|reason| {
        CloudError::BadData {
            format: FMT,
            location: location(),
            reason: format!("corrupt LZF data: {reason}"),
        }
    })
}

/// Decompresses LZF (liblzf's format, as PCL writes it) into exactly `out_len` bytes.
pub(super) fn lzf_decompress(input: &[u8], out_len: usize) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(out_len);
    let mut i = 0;
    let byte = |i: usize| {
        input
            .get(i)
            .copied()
            .ok_or_else(|| format!("input ends at byte {i}"))
    };
    while i < input.len() {
        let ctrl = usize::from(input[i]);
        i += 1;
        if ctrl < 32 {
            let len = ctrl + 1;
            let lit = input
                .get(i..i + len)
                .ok_or_else(|| format!("literal run at byte {i} ends past the input"))?;
            if out.len() + len > out_len {
                return Err(format!("output exceeds the declared {out_len} bytes"));
            }
            out.extend_from_slice(lit);
            i += len;
        } else {
            let mut len = ctrl >> 5;
            if len == 7 {
                len += usize::from(byte(i)?);
                i += 1;
            }
            len += 2;
            let back = ((ctrl & 0x1f) << 8) + usize::from(byte(i)?) + 1;
            i += 1;
            if back > out.len() {
                return Err(format!(
                    "back-reference at byte {} reaches before the start",
                    i - 2
                ));
            }
            if out.len() + len > out_len {
                return Err(format!("output exceeds the declared {out_len} bytes"));
            }
            let start = out.len() - back;
            for k in start..start + len {
                out.push(out[k]);
            }
        }
    }
    if out.len() != out_len {
        return Err(format!(
            "decompressed to {} bytes, the header declares {out_len}",
            out.len()
        ));
    }
    Ok(out)
}

type Columns = (Vec<Point3<f32>>, Option<Vec<f32>>, Option<Vec<f32>>);

fn read_ascii(
    h: &Header,
    data: &[u8],
    xyz: [usize; 3],
    intensity: Option<usize>,
    confidence: Option<usize>,
) -> Result<Columns, CloudError> {
    let values_per_point: usize = h.fields.iter().map(|f| f.count).sum();
    // Each value takes at least two bytes ("0 "): bounds the allocation by the file size.
    if h.points.saturating_mul(2 * values_per_point as u64) > data.len() as u64 + 1 {
        return Err(CloudError::AbsurdCount {
            format: FMT,
            what: format!("points of {values_per_point} ASCII values"),
            count: h.points,
            available: data.len() as u64,
        });
    }
    // Token index of each wanted field's first value.
    let first: Vec<usize> = h
        .fields
        .iter()
        .scan(0, |acc, f| {
            let s = *acc;
            *acc += f.count;
            Some(s)
        })
        .collect();
    let slots = [
        Some(xyz[0]),
        Some(xyz[1]),
        Some(xyz[2]),
        intensity,
        confidence,
    ];
    let n = h.points as usize;
    let mut points = Vec::with_capacity(n);
    let mut inten = intensity.map(|_| Vec::with_capacity(n));
    let mut conf = confidence.map(|_| Vec::with_capacity(n));
    let mut lines = nonblank_lines(data, h.lines + 1);
    for k in 0..n {
        let Some((line, text)) = lines.next() else {
            return Err(CloudError::BadData {
                format: FMT,
                location: format!("end of file, point #{k}"),
                reason: format!("the header declares {n} points, the file ends after {k}"),
            });
        };
        let mut vals = [f32::NAN; 5];
        let mut seen = 0;
        for (t, tok) in tokens(text).enumerate() {
            seen = t + 1;
            for (slot, v) in slots.iter().zip(vals.iter_mut()) {
                if let Some(fi) = *slot {
                    if first[fi] == t {
                        let f = &h.fields[fi];
                        *v = f.ty.parse_f32(tok).ok_or_else(|| CloudError::BadData {
                            format: FMT,
                            location: format!("line {line}, point #{k}, field `{}`", f.name),
                            reason: format!(
                                "`{}` is not a valid {:?} number",
                                handeye_hal::limits::Quoted(&String::from_utf8_lossy(tok)),
                                f.ty
                            ),
                        })?;
                    }
                }
            }
        }
        if seen != values_per_point {
            return Err(CloudError::BadData {
                format: FMT,
                location: format!("line {line}, point #{k}"),
                reason: format!(
                    "the line has {seen} values, the header declares {values_per_point}"
                ),
            });
        }
        super::push_row(&vals, h.scale, &mut points, &mut inten, &mut conf);
    }
    Ok((points, inten, conf))
}

/// Writes a cloud as PCD v0.7 (`DATA binary` or `DATA ascii`) in one buffered pass:
/// `F 4` fields x, y, z, then `intensity` and `confidence` when present; `WIDTH`/`HEIGHT`
/// keep the grid.
///
/// Blocks on file I/O. Overwrites `path`.
pub fn write_pcd(path: &Path, cloud: &PointCloud, binary: bool) -> Result<(), CloudError> {
    check_cloud(cloud)?;
    let file = std::fs::File::create(path).map_err(|e| CloudError::io("create", path, e))?;
    let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
    let wr = |e| CloudError::io("write", path, e);
    let attrs: Vec<&[f32]> = [&cloud.intensity, &cloud.confidence]
        .iter()
        .filter_map(|a| a.as_deref())
        .collect();
    let mut names = String::from("x y z");
    if cloud.intensity.is_some() {
        names.push_str(" intensity");
    }
    if cloud.confidence.is_some() {
        names.push_str(" confidence");
    }
    let nf = 3 + attrs.len();
    let rep = |s: &str| vec![s; nf].join(" ");
    let header = format!(
        "# .PCD v0.7 - Point Cloud Data file format\n# unit m\nVERSION 0.7\nFIELDS {names}\nSIZE {}\nTYPE {}\nCOUNT {}\nWIDTH {}\nHEIGHT {}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {}\nDATA {}\n",
        rep("4"),
        rep("F"),
        rep("1"),
        cloud.width,
        cloud.height,
        cloud.points.len(),
        if binary { "binary" } else { "ascii" }
    );
    out.write_all(header.as_bytes()).map_err(wr)?;
    const CHUNK: usize = 1 << 15;
    let mut buf: Vec<u8> = Vec::with_capacity(CHUNK * 20 * 4);
    for (c, pts) in cloud.points.chunks(CHUNK).enumerate() {
        buf.clear();
        let base = c * CHUNK;
        for (j, p) in pts.iter().enumerate() {
            let vals = [p.x, p.y, p.z]
                .into_iter()
                .chain(attrs.iter().map(|a| a[base + j]));
            if binary {
                for v in vals {
                    buf.extend_from_slice(&v.to_le_bytes());
                }
            } else {
                ascii_row(&mut buf, vals);
            }
        }
        out.write_all(&buf).map_err(wr)?;
    }
    out.flush().map_err(wr)?;
    Ok(())
}
