//! PLY (Stanford polygon format) reading and writing: ascii, binary_little_endian and
//! binary_big_endian; the `vertex` element's x, y, z (any numeric type), intensity and
//! confidence; every other element and property (lists included) skipped.
use std::io::Write as _;
use std::path::Path;

use handeye_hal::PointCloud;
use nalgebra::Point3;

use super::scalar::{nonblank_lines, read_column, read_points, tokens, Column, Scalar};
use super::CloudFormat::Ply as FMT;
use super::{ascii_row, check_cloud, is_confidence, is_intensity, unit_scale, CloudError};

/// Headers longer than this are refused (real ones are a few hundred bytes).
const MAX_HEADER_BYTES: usize = 1 << 20;

/// How [`write_ply`] encodes the vertex data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PlyEncoding {
    /// Text, one vertex per line (large and slow; for inspection and small clouds).
    Ascii,
    /// Little-endian binary `float32` (the default: compact, fast, what most tools write).
    #[default]
    BinaryLittleEndian,
    /// Big-endian binary `float32`.
    BinaryBigEndian,
}

impl PlyEncoding {
    fn header_name(self) -> &'static str {
        match self {
            PlyEncoding::Ascii => "ascii",
            PlyEncoding::BinaryLittleEndian => "binary_little_endian",
            PlyEncoding::BinaryBigEndian => "binary_big_endian",
        }
    }
}

pub(super) fn has_magic(bytes: &[u8]) -> bool {
    bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n")
}

#[derive(Debug, Clone, Copy)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
}

impl Element {
    /// Record size when every property is a scalar.
    fn fixed_stride(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => Some(s.size()),
                Kind::List { .. } => None,
            })
            .sum()
    }
}

#[derive(Debug)]
struct Header {
    encoding: PlyEncoding,
    elements: Vec<Element>,
    /// Our `obj_info width`/`height` (strict: must match the vertex count).
    grid: (Option<u32>, Option<u32>),
    /// PCL's `obj_info num_cols`/`num_rows` (ignored when they do not match the vertex count:
    /// PCL may store only the valid points plus a `range_grid` element).
    pcl_grid: (Option<u32>, Option<u32>),
    scale: f32,
    /// Byte offset of the data section.
    data_offset: usize,
    /// Number of header lines (the data's first line number is this + 1).
    lines: usize,
}

fn bad_header(line: usize, reason: impl Into<String>) -> CloudError {
    CloudError::BadHeader {
        format: FMT,
        line,
        reason: reason.into(),
    }
}

fn parse_type(line: usize, field: &str, t: &str) -> Result<Scalar, CloudError> {
    Ok(match t {
        "char" | "int8" => Scalar::I8,
        "uchar" | "uint8" => Scalar::U8,
        "short" | "int16" => Scalar::I16,
        "ushort" | "uint16" => Scalar::U16,
        "int" | "int32" => Scalar::I32,
        "uint" | "uint32" => Scalar::U32,
        "float" | "float32" => Scalar::F32,
        "double" | "float64" => Scalar::F64,
        _ => {
            return Err(CloudError::UnsupportedType {
                format: FMT,
                line,
                field: field.to_owned(),
                found: t.to_owned(),
            })
        }
    })
}

fn parse_header(bytes: &[u8]) -> Result<Header, CloudError> {
    if !has_magic(bytes) {
        return Err(super::no_magic(bytes));
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut grid = (None, None);
    let mut pcl_grid = (None, None);
    let mut scale = 1.0;
    let mut pos = 0usize;
    let mut line_no = 0usize;
    loop {
        let Some((keyword, words)) =
            super::next_header_line(bytes, &mut pos, &mut line_no, MAX_HEADER_BYTES, FMT)?
        else {
            let where_ = if pos >= bytes.len() {
                "before the end of the file".to_owned()
            } else {
                format!("within the first {MAX_HEADER_BYTES} bytes")
            };
            return Err(bad_header(
                line_no,
                format!("no `end_header` line {where_}"),
            ));
        };
        match keyword {
            "ply" if line_no == 1 => {}
            "format" => {
                let found = words.first().copied().unwrap_or("");
                encoding = Some(match found {
                    "ascii" => PlyEncoding::Ascii,
                    "binary_little_endian" => PlyEncoding::BinaryLittleEndian,
                    "binary_big_endian" => PlyEncoding::BinaryBigEndian,
                    _ => {
                        return Err(CloudError::UnknownEncoding {
                            format: FMT,
                            line: line_no,
                            found: found.to_owned(),
                            expected: "ascii, binary_little_endian or binary_big_endian",
                        })
                    }
                });
            }
            "comment" | "obj_info" => {
                if let [key, value] = words.as_slice() {
                    let dim = |v: &str| {
                        v.parse::<u32>().map_err(|_| {
                            bad_header(
                                line_no,
                                format!("`{key}` value `{v}` is not a whole number"),
                            )
                        })
                    };
                    match key.to_ascii_lowercase().as_str() {
                        "width" => grid.0 = Some(dim(value)?),
                        "height" => grid.1 = Some(dim(value)?),
                        "num_cols" => pcl_grid.0 = Some(dim(value)?),
                        "num_rows" => pcl_grid.1 = Some(dim(value)?),
                        "unit" | "units" => {
                            scale = unit_scale(value).ok_or_else(|| {
                                bad_header(
                                    line_no,
                                    format!(
                                        "unknown unit `{}` (expected m, cm, mm or um)",
                                        handeye_hal::limits::Quoted(value)
                                    ),
                                )
                            })?
                        }
                        _ => {}
                    }
                }
            }
            "element" => {
                let [name, count] = words.as_slice() else {
                    return Err(bad_header(line_no, "expected `element <name> <count>`"));
                };
                let count = count.parse::<u64>().map_err(|_| {
                    bad_header(
                        line_no,
                        format!("element `{name}` count `{count}` is not a whole number"),
                    )
                })?;
                elements.push(Element {
                    name: (*name).to_owned(),
                    count,
                    props: Vec::new(),
                });
            }
            "property" => {
                let Some(el) = elements.last_mut() else {
                    return Err(bad_header(line_no, "`property` before any `element`"));
                };
                let prop = match words.as_slice() {
                    ["list", ct, it, name] => {
                        let count = parse_type(line_no, name, ct)?;
                        if !count.is_integer() {
                            return Err(bad_header(
                                line_no,
                                format!("list `{name}` has a non-integer count type `{ct}`"),
                            ));
                        }
                        Property {
                            name: (*name).to_owned(),
                            kind: Kind::List { count, item: parse_type(line_no, name, it)? },
                        }
                    }
                    [ty, name] if *ty != "list" => Property {
                        name: (*name).to_owned(),
                        kind: Kind::Scalar(parse_type(line_no, name, ty)?),
                    },
                    _ => {
                        return Err(bad_header(
                            line_no,
                            "expected `property <type> <name>` or `property list <count type> <item type> <name>`",
                        ))
                    }
                };
                el.props.push(prop);
            }
            "end_header" => break,
            other => {
                return Err(bad_header(
                    line_no,
                    format!(
                        "unknown header keyword `{}`",
                        handeye_hal::limits::Quoted(other)
                    ),
                ));
            }
        }
    }
    let encoding =
        encoding.ok_or_else(|| bad_header(line_no, "no `format` line before `end_header`"))?;
    Ok(Header {
        encoding,
        elements,
        grid,
        pcl_grid,
        scale,
        data_offset: pos,
        lines: line_no,
    })
}

/// What we take from the vertex element: property indices.
#[derive(Debug)]
struct Wanted {
    xyz: [usize; 3],
    intensity: Option<usize>,
    confidence: Option<usize>,
}

fn wanted(el: &Element) -> Result<Wanted, CloudError> {
    let find = |axis: &str| {
        el.props
            .iter()
            .position(|p| p.name == axis)
            .ok_or_else(|| CloudError::Missing {
                format: FMT,
                what: format!("vertex property `{axis}`"),
            })
    };
    let xyz = [find("x")?, find("y")?, find("z")?];
    for &i in &xyz {
        if let Kind::List { .. } = el.props[i].kind {
            return Err(CloudError::BadHeader {
                format: FMT,
                line: 0,
                reason: format!(
                    "vertex property `{}` is a list, expected a number",
                    el.props[i].name
                ),
            });
        }
    }
    let scalar_named = |f: fn(&str) -> bool| {
        el.props
            .iter()
            .position(|p| f(&p.name) && matches!(p.kind, Kind::Scalar(_)))
    };
    Ok(Wanted {
        xyz,
        intensity: scalar_named(is_intensity),
        confidence: scalar_named(is_confidence),
    })
}

/// Parses PLY bytes (any of the three encodings) into a cloud in metres.
pub fn read_ply(bytes: &[u8]) -> Result<PointCloud, CloudError> {
    let h = parse_header(bytes)?;
    let vi = h
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| CloudError::Missing {
            format: FMT,
            what: "`element vertex` in the header".to_owned(),
        })?;
    let vertex = &h.elements[vi];
    let want = wanted(vertex)?;
    let data = &bytes[h.data_offset..];
    let n_u64 = vertex.count;
    if n_u64 > u64::from(u32::MAX) || n_u64 > data.len() as u64 {
        return Err(CloudError::AbsurdCount {
            format: FMT,
            what: "`vertex` elements".to_owned(),
            count: n_u64,
            available: data.len() as u64,
        });
    }
    let n = n_u64 as usize;
    let (points, intensity, confidence) = match h.encoding {
        PlyEncoding::Ascii => read_ascii(&h, vi, &want, data)?,
        PlyEncoding::BinaryLittleEndian => read_binary(&h, vi, &want, bytes, false)?,
        PlyEncoding::BinaryBigEndian => read_binary(&h, vi, &want, bytes, true)?,
    };
    debug_assert_eq!(points.len(), n);
    let (width, height) = organization(&h, n)?;
    Ok(PointCloud {
        width,
        height,
        points,
        intensity,
        confidence,
    })
}

fn organization(h: &Header, n: usize) -> Result<(u32, u32), CloudError> {
    let n32 = n as u32; // checked ≤ u32::MAX by the caller
    match h.grid {
        (Some(w), Some(hh)) => {
            if u64::from(w) * u64::from(hh) != n as u64 {
                return Err(bad_header(
                    0,
                    format!("`obj_info width {w}` × `height {hh}` does not match the {n} vertices"),
                ));
            }
            Ok((w, hh))
        }
        (None, None) => match h.pcl_grid {
            (Some(w), Some(hh)) if u64::from(w) * u64::from(hh) == n as u64 => Ok((w, hh)),
            _ => Ok((n32, 1)),
        },
        _ => Err(bad_header(
            0,
            "header gives only one of `width`/`height`; give both or neither",
        )),
    }
}

type Columns = (Vec<Point3<f32>>, Option<Vec<f32>>, Option<Vec<f32>>);

/// Binary: skip the elements before `vertex`, then read it in one pass.
fn read_binary(
    h: &Header,
    vi: usize,
    want: &Wanted,
    bytes: &[u8],
    big: bool,
) -> Result<Columns, CloudError> {
    let mut pos = h.data_offset;
    for el in &h.elements[..vi] {
        pos = skip_binary(el, bytes, pos, big)?;
    }
    let vertex = &h.elements[vi];
    let n = vertex.count as usize;
    let available = (bytes.len() - pos) as u64;
    match vertex.fixed_stride() {
        Some(stride) => {
            let need = (n as u64).saturating_mul(stride as u64);
            if need > available {
                return Err(CloudError::Truncated {
                    format: FMT,
                    what: format!("{n} vertices of {stride} bytes (element `vertex`)"),
                    expected_bytes: need,
                    offset: pos as u64,
                    available,
                });
            }
            let block = &bytes[pos..pos + need as usize];
            let mut offsets = Vec::with_capacity(vertex.props.len());
            let mut off = 0;
            for p in &vertex.props {
                offsets.push(off);
                if let Kind::Scalar(s) = p.kind {
                    off += s.size();
                }
            }
            let col = |i: usize| {
                // A fixed-stride element has no list properties; the list arm is never taken.
                let ty = match vertex.props[i].kind {
                    Kind::Scalar(s) => s,
                    Kind::List { count, .. } => count,
                };
                Column {
                    base: offsets[i],
                    stride,
                    ty,
                    big_endian: big,
                }
            };
            let xyz = want.xyz.map(col);
            let points = read_points(block, n, xyz, h.scale);
            let intensity = want.intensity.map(|i| read_column(block, n, col(i)));
            let confidence = want.confidence.map(|i| read_column(block, n, col(i)));
            Ok((points, intensity, confidence))
        }
        None => read_binary_lists(vertex, want, bytes, pos, big, h.scale),
    }
}

/// Reads a list's length at `pos`; errors on truncation and negative lengths.
fn list_len(
    bytes: &[u8],
    pos: usize,
    count: Scalar,
    big: bool,
    el: &Element,
    prop: &Property,
    k: u64,
) -> Result<usize, CloudError> {
    let v = count
        .read_int(bytes, pos, big)
        .ok_or_else(|| truncated_at(el, k, pos, bytes))?;
    usize::try_from(v).map_err(|_| CloudError::BadData {
        format: FMT,
        location: format!(
            "byte offset {pos}, element `{}` #{k}, list `{}`",
            el.name, prop.name
        ),
        reason: format!("negative list length {v}"),
    })
}

fn truncated_at(el: &Element, k: u64, pos: usize, bytes: &[u8]) -> CloudError {
    CloudError::Truncated {
        format: FMT,
        what: format!("element `{}` #{k} of {}", el.name, el.count),
        expected_bytes: 1,
        offset: pos as u64,
        available: bytes.len().saturating_sub(pos) as u64,
    }
}

/// Advances over one record of `el` starting at `pos` (any properties, lists included).
fn skip_record(
    el: &Element,
    bytes: &[u8],
    mut pos: usize,
    big: bool,
    k: u64,
) -> Result<usize, CloudError> {
    for p in &el.props {
        match p.kind {
            Kind::Scalar(s) => pos += s.size(),
            Kind::List { count, item } => {
                let len = list_len(bytes, pos, count, big, el, p, k)?;
                pos += count.size();
                pos = len
                    .checked_mul(item.size())
                    .and_then(|b| pos.checked_add(b))
                    .filter(|&e| e <= bytes.len())
                    .ok_or_else(|| truncated_at(el, k, pos, bytes))?;
            }
        }
        if pos > bytes.len() {
            return Err(truncated_at(el, k, pos, bytes));
        }
    }
    Ok(pos)
}

/// Skips a whole element in binary data, returning the position after it.
fn skip_binary(el: &Element, bytes: &[u8], pos: usize, big: bool) -> Result<usize, CloudError> {
    let available = (bytes.len() - pos) as u64;
    if let Some(stride) = el.fixed_stride() {
        let need = el.count.saturating_mul(stride as u64);
        if need > available {
            return Err(CloudError::Truncated {
                format: FMT,
                what: format!(
                    "{} records of {stride} bytes (element `{}`)",
                    el.count, el.name
                ),
                expected_bytes: need,
                offset: pos as u64,
                available,
            });
        }
        return Ok(pos + need as usize);
    }
    // Each record has a list, so it takes at least one byte: the loop ends within the file.
    let mut pos = pos;
    for k in 0..el.count {
        pos = skip_record(el, bytes, pos, big, k)?;
    }
    Ok(pos)
}

/// Binary vertex element with list properties: walk record by record.
fn read_binary_lists(
    el: &Element,
    want: &Wanted,
    bytes: &[u8],
    mut pos: usize,
    big: bool,
    scale: f32,
) -> Result<Columns, CloudError> {
    let n = el.count as usize; // ≤ remaining bytes: checked by the caller
    let mut points = Vec::with_capacity(n);
    let mut intensity = want.intensity.map(|_| Vec::with_capacity(n));
    let mut confidence = want.confidence.map(|_| Vec::with_capacity(n));
    let mut offs = vec![0usize; el.props.len()];
    for k in 0..el.count {
        let start = pos;
        for (i, p) in el.props.iter().enumerate() {
            offs[i] = pos;
            pos = match p.kind {
                Kind::Scalar(s) => pos + s.size(),
                Kind::List { count, item } => {
                    let len = list_len(bytes, pos, count, big, el, p, k)?;
                    len.checked_mul(item.size())
                        .and_then(|b| (pos + count.size()).checked_add(b))
                        .ok_or_else(|| truncated_at(el, k, pos, bytes))?
                }
            };
            if pos > bytes.len() {
                return Err(truncated_at(el, k, start, bytes));
            }
        }
        let get = |i: usize| match el.props[i].kind {
            Kind::Scalar(s) => s.read_f32(bytes, offs[i], big).unwrap_or(f32::NAN),
            Kind::List { .. } => f32::NAN,
        };
        let [x, y, z] = want.xyz.map(get);
        points.push(Point3::new(x * scale, y * scale, z * scale));
        if let (Some(v), Some(i)) = (intensity.as_mut(), want.intensity) {
            v.push(get(i));
        }
        if let (Some(v), Some(i)) = (confidence.as_mut(), want.confidence) {
            v.push(get(i));
        }
    }
    Ok((points, intensity, confidence))
}

/// ASCII: one element record per non-blank line.
fn read_ascii(h: &Header, vi: usize, want: &Wanted, data: &[u8]) -> Result<Columns, CloudError> {
    let mut lines = nonblank_lines(data, h.lines + 1);
    for el in &h.elements[..vi] {
        if el.props.is_empty() {
            continue;
        }
        for k in 0..el.count {
            let (line, text) = lines.next().ok_or_else(|| ascii_short(el, k))?;
            parse_ascii_record(el, text, line, k, &mut |_, _| Ok(()))?;
        }
    }
    let el = &h.elements[vi];
    // Each record takes at least two bytes per property ("0 "), so this bounds the
    // allocation by the file size whatever the header claims.
    let min_bytes = 2 * el.props.len().max(1) as u64;
    if el.count.saturating_mul(min_bytes) > data.len() as u64 + 1 {
        return Err(CloudError::AbsurdCount {
            format: FMT,
            what: format!("`vertex` elements of {} ASCII values", el.props.len()),
            count: el.count,
            available: data.len() as u64,
        });
    }
    let n = el.count as usize;
    let mut points = Vec::with_capacity(n);
    let mut intensity = want.intensity.map(|_| Vec::with_capacity(n));
    let mut confidence = want.confidence.map(|_| Vec::with_capacity(n));
    let mut vals = [f32::NAN; 5];
    let slots = [
        Some(want.xyz[0]),
        Some(want.xyz[1]),
        Some(want.xyz[2]),
        want.intensity,
        want.confidence,
    ];
    for k in 0..el.count {
        let (line, text) = lines.next().ok_or_else(|| ascii_short(el, k))?;
        parse_ascii_record(el, text, line, k, &mut |i, tok| {
            for (slot, v) in slots.iter().zip(vals.iter_mut()) {
                if *slot == Some(i) {
                    let Kind::Scalar(s) = el.props[i].kind else {
                        return Ok(());
                    };
                    *v = s.parse_f32(tok).ok_or_else(|| {
                        format!(
                            "`{}` is not a valid {s:?} number",
                            handeye_hal::limits::Quoted(&String::from_utf8_lossy(tok))
                        )
                    })?;
                }
            }
            Ok(())
        })?;
        super::push_row(&vals, h.scale, &mut points, &mut intensity, &mut confidence);
    }
    Ok((points, intensity, confidence))
}

fn ascii_short(el: &Element, k: u64) -> CloudError {
    CloudError::BadData {
        format: FMT,
        location: format!("end of file, element `{}` #{k}", el.name),
        reason: format!(
            "the header declares {} `{}` records, the file ends after {k}",
            el.count, el.name
        ),
    }
}

/// Receives `(property index, token)` for each scalar of an ASCII record; an `Err` is the
/// reason the token is bad.
type ScalarSink<'a> = dyn FnMut(usize, &[u8]) -> Result<(), String> + 'a;

/// Walks the tokens of one ASCII record, calling `scalar(prop_index, token)` for scalar
/// properties; errors name the line, record and property.
fn parse_ascii_record(
    el: &Element,
    text: &[u8],
    line: usize,
    k: u64,
    scalar: &mut ScalarSink<'_>,
) -> Result<(), CloudError> {
    let err = |prop: &str, reason: String| CloudError::BadData {
        format: FMT,
        location: format!("line {line}, element `{}` #{k}, property `{prop}`", el.name),
        reason,
    };
    let mut toks = tokens(text);
    for (i, p) in el.props.iter().enumerate() {
        let tok = toks
            .next()
            .ok_or_else(|| err(&p.name, "the line has too few values".to_owned()))?;
        match p.kind {
            Kind::Scalar(_) => scalar(i, tok).map_err(|r| err(&p.name, r))?,
            Kind::List { count, .. } => {
                let len = count.parse_int(tok).filter(|&v| v >= 0).ok_or_else(|| {
                    err(
                        &p.name,
                        format!(
                            "list length `{}` is not a valid count",
                            handeye_hal::limits::Quoted(&String::from_utf8_lossy(tok))
                        ),
                    )
                })?;
                for _ in 0..len {
                    toks.next().ok_or_else(|| {
                        err(
                            &p.name,
                            format!("the list declares {len} items, the line has fewer"),
                        )
                    })?;
                }
            }
        }
    }
    if toks.next().is_some() {
        return Err(err(
            &el.props.last().map(|p| p.name.clone()).unwrap_or_default(),
            format!(
                "the line has more values than the {} properties the header declares",
                el.props.len()
            ),
        ));
    }
    Ok(())
}

/// Writes a cloud as PLY in one buffered pass: `float32` x, y, z, then `intensity` and
/// `confidence` when present, with `obj_info width/height` for the grid and `comment unit m`.
///
/// Blocks on file I/O. Overwrites `path`.
pub fn write_ply(path: &Path, cloud: &PointCloud, encoding: PlyEncoding) -> Result<(), CloudError> {
    check_cloud(cloud)?;
    let file = std::fs::File::create(path).map_err(|e| CloudError::io("create", path, e))?;
    let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
    let wr = |e| CloudError::io("write", path, e);
    let mut header = format!(
        "ply\nformat {} 1.0\ncomment written by handeye\ncomment unit m\nobj_info width {}\nobj_info height {}\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n",
        encoding.header_name(),
        cloud.width,
        cloud.height,
        cloud.points.len()
    );
    let attrs: Vec<&[f32]> = [&cloud.intensity, &cloud.confidence]
        .iter()
        .filter_map(|a| a.as_deref())
        .collect();
    if cloud.intensity.is_some() {
        header.push_str("property float intensity\n");
    }
    if cloud.confidence.is_some() {
        header.push_str("property float confidence\n");
    }
    header.push_str("end_header\n");
    out.write_all(header.as_bytes()).map_err(wr)?;
    const CHUNK: usize = 1 << 15;
    let mut buf: Vec<u8> = Vec::with_capacity(CHUNK * 20 * 4);
    for (c, pts) in cloud.points.chunks(CHUNK).enumerate() {
        buf.clear();
        let base = c * CHUNK;
        for (j, p) in pts.iter().enumerate() {
            let vals = [p.x, p.y, p.z];
            let extra = attrs.iter().map(|a| a[base + j]);
            match encoding {
                PlyEncoding::BinaryLittleEndian => {
                    for v in vals.into_iter().chain(extra) {
                        buf.extend_from_slice(&v.to_le_bytes());
                    }
                }
                PlyEncoding::BinaryBigEndian => {
                    for v in vals.into_iter().chain(extra) {
                        buf.extend_from_slice(&v.to_be_bytes());
                    }
                }
                PlyEncoding::Ascii => {
                    ascii_row(&mut buf, vals.into_iter().chain(extra));
                }
            }
        }
        out.write_all(&buf).map_err(wr)?;
    }
    out.flush().map_err(wr)?;
    Ok(())
}
