//! Tests for the cloud readers and writers: round trips over every encoding and type,
//! one test per malformed-file error, and the `ply` and `pcd` fuzz targets (hal::fuzz).
use std::fmt::Write as _;
use std::path::PathBuf;

use handeye_hal::PointCloud;
use nalgebra::Point3;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::*;

/// Largest single allocation `f` made on this thread (the test binary's allocator is
/// `handeye_hal::fuzz::TrackingAlloc`, see `lib.rs`).
fn largest_allocation<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let (r, largest) = handeye_hal::fuzz::largest_allocation(f);
    (
        r,
        largest.expect("TrackingAlloc is the test binary's allocator"),
    )
}

// ---------------------------------------------------------------- helpers

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("handeye-cloud-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(name)
}

/// NaN-aware equality; `bits` also demands identical bit patterns (binary encodings).
fn same(a: f32, b: f32, bits: bool) -> bool {
    if bits {
        a.to_bits() == b.to_bits()
    } else {
        a == b || (a.is_nan() && b.is_nan())
    }
}

fn assert_same_cloud(a: &PointCloud, b: &PointCloud, bits: bool) {
    assert_eq!(
        (a.width, a.height, a.points.len()),
        (b.width, b.height, b.points.len())
    );
    for (i, (p, q)) in a.points.iter().zip(&b.points).enumerate() {
        for k in 0..3 {
            assert!(same(p[k], q[k], bits), "point {i}: {p:?} vs {q:?}");
        }
    }
    for (x, y) in [(&a.intensity, &b.intensity), (&a.confidence, &b.confidence)] {
        assert_eq!(x.is_some(), y.is_some());
        if let (Some(x), Some(y)) = (x, y) {
            assert!(x.iter().zip(y).all(|(u, v)| same(*u, *v, bits)));
        }
    }
}

/// A cloud with awkward values: NaN pixels (one with a payload), negatives, tiny and large.
fn sample_cloud(w: u32, h: u32, intensity: bool, confidence: bool, seed: u64) -> PointCloud {
    let mut rng = StdRng::seed_from_u64(seed);
    let n = (w * h) as usize;
    let points = (0..n)
        .map(|i| match i % 7 {
            3 => Point3::new(f32::NAN, f32::NAN, f32::NAN),
            5 => Point3::new(
                f32::from_bits(0x7fc0_1234),
                -0.0,
                f32::from_bits(0xffc0_0001),
            ),
            _ => Point3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0) * 1e-3,
                rng.random_range(0.1f32..5.0) * 1e3,
            ),
        })
        .collect();
    let attr = |on: bool, rng: &mut StdRng| {
        on.then(|| (0..n).map(|_| rng.random_range(0.0..1.0)).collect())
    };
    let intensity = attr(intensity, &mut rng);
    let confidence = attr(confidence, &mut rng);
    PointCloud {
        width: w,
        height: h,
        points,
        intensity,
        confidence,
    }
}

// ---------------------------------------------------------------- PLY generator

#[derive(Debug, Clone, Copy, PartialEq)]
enum Enc {
    Ascii,
    Le,
    Be,
}

/// A PLY file built by hand (independently of `write_ply`), with the knobs the reader must
/// handle: coordinate type, elements and list properties around the vertex data.
#[derive(Debug, Clone)]
struct PlySpec {
    enc: Enc,
    xyz_ty: &'static str,
    grid: Option<(u32, u32)>,
    intensity: Option<&'static str>,
    confidence: bool,
    /// An element with a list property before `vertex` (must be skipped).
    element_before: bool,
    /// A list property inside `vertex` (forces the record-by-record path).
    vertex_list: bool,
    /// A `face` element with `vertex_indices` lists after `vertex`.
    faces_after: bool,
    unit: Option<&'static str>,
}

impl PlySpec {
    fn new(enc: Enc, xyz_ty: &'static str) -> Self {
        PlySpec {
            enc,
            xyz_ty,
            grid: None,
            intensity: None,
            confidence: false,
            element_before: false,
            vertex_list: false,
            faces_after: false,
            unit: None,
        }
    }
}

fn put(buf: &mut Vec<u8>, ty: &str, v: f64, enc: Enc) {
    macro_rules! bin {
        ($x:expr) => {
            match enc {
                Enc::Le => buf.extend_from_slice(&$x.to_le_bytes()),
                Enc::Be => buf.extend_from_slice(&$x.to_be_bytes()),
                Enc::Ascii => {
                    let x = $x;
                    if x != x {
                        buf.extend_from_slice(b"nan ");
                    } else {
                        buf.extend_from_slice(format!("{x} ").as_bytes());
                    }
                }
            }
        };
    }
    match ty {
        "char" | "int8" => bin!(v as i8),
        "uchar" | "uint8" => bin!(v as u8),
        "short" | "int16" => bin!(v as i16),
        "ushort" | "uint16" => bin!(v as u16),
        "int" | "int32" => bin!(v as i32),
        "uint" | "uint32" => bin!(v as u32),
        "float" | "float32" => bin!(v as f32),
        "double" | "float64" => bin!(v),
        _ => panic!("type {ty}"),
    }
}

/// Builds the file and the cloud the reader must return.
fn build_ply(spec: &PlySpec, n: usize, seed: u64) -> (Vec<u8>, PointCloud) {
    let mut rng = StdRng::seed_from_u64(seed);
    let float = matches!(spec.xyz_ty, "float" | "float32" | "double" | "float64");
    let scale = match spec.unit {
        Some("mm") => 1e-3,
        Some("cm") => 1e-2,
        _ => 1.0,
    };
    let mut h = String::new();
    let fmt = match spec.enc {
        Enc::Ascii => "ascii",
        Enc::Le => "binary_little_endian",
        Enc::Be => "binary_big_endian",
    };
    writeln!(
        h,
        "ply\nformat {fmt} 1.0\ncomment generated by the handeye tests"
    )
    .expect("fmt");
    if let Some(u) = spec.unit {
        writeln!(h, "comment unit {u}").expect("fmt");
    }
    if let Some((w, hh)) = spec.grid {
        writeln!(h, "obj_info width {w}\nobj_info height {hh}").expect("fmt");
    }
    if spec.element_before {
        h.push_str("element camera 2\nproperty float view_px\nproperty list uchar int tags\nproperty uchar flag\n");
    }
    writeln!(h, "element vertex {n}").expect("fmt");
    h.push_str("property uchar red\n");
    for a in ["x", "y", "z"] {
        writeln!(h, "property {} {a}", spec.xyz_ty).expect("fmt");
        if a == "x" && spec.vertex_list {
            h.push_str("property list uchar float extras\n");
        }
    }
    if let Some(name) = spec.intensity {
        writeln!(h, "property ushort {name}").expect("fmt");
    }
    if spec.confidence {
        h.push_str("property double confidence\n");
    }
    h.push_str("property int16 label\n");
    if spec.faces_after {
        h.push_str("element face 3\nproperty list uchar int vertex_indices\n");
    }
    h.push_str("end_header\n");
    let mut buf = h.into_bytes();
    let enc = spec.enc;
    let eol = |buf: &mut Vec<u8>| {
        if enc == Enc::Ascii {
            buf.push(b'\n');
        }
    };
    if spec.element_before {
        for k in 0..2 {
            put(&mut buf, "float", 1.5, enc);
            put(&mut buf, "uchar", k as f64 + 1.0, enc);
            for t in 0..=k {
                put(&mut buf, "int", t as f64 * 1000.0, enc);
            }
            put(&mut buf, "uchar", 7.0, enc);
            eol(&mut buf);
        }
    }
    let mut points = Vec::with_capacity(n);
    let mut intensity = Vec::new();
    let mut confidence = Vec::new();
    for i in 0..n {
        let c: [f64; 3] = if float {
            if i % 5 == 2 {
                [f64::NAN; 3]
            } else {
                [0, 1, 2].map(|_| f64::from(rng.random_range(-3.0f32..3.0)))
            }
        } else {
            [0, 1, 2].map(|_| f64::from(rng.random_range(0..100u8)))
        };
        put(&mut buf, "uchar", 200.0, enc);
        for (a, v) in c.iter().enumerate() {
            put(&mut buf, spec.xyz_ty, *v, enc);
            if a == 0 && spec.vertex_list {
                let len = i % 3;
                put(&mut buf, "uchar", len as f64, enc);
                for _ in 0..len {
                    put(&mut buf, "float", -9.0, enc);
                }
            }
        }
        let it = f64::from(rng.random_range(0..60000u16));
        if spec.intensity.is_some() {
            put(&mut buf, "ushort", it, enc);
            intensity.push(it as f32);
        }
        let cf = f64::from(rng.random_range(0.0f32..1.0));
        if spec.confidence {
            put(&mut buf, "double", cf, enc);
            confidence.push(cf as f32);
        }
        put(&mut buf, "int16", -3.0, enc);
        eol(&mut buf);
        points.push(Point3::new(
            c[0] as f32 * scale,
            c[1] as f32 * scale,
            c[2] as f32 * scale,
        ));
    }
    if spec.faces_after {
        for _ in 0..3 {
            put(&mut buf, "uchar", 3.0, enc);
            for v in 0..3 {
                put(&mut buf, "int", v as f64, enc);
            }
            eol(&mut buf);
        }
    }
    let (width, height) = spec.grid.unwrap_or((n as u32, 1));
    let cloud = PointCloud {
        width,
        height,
        points,
        intensity: spec.intensity.map(|_| intensity),
        confidence: spec.confidence.then_some(confidence),
    };
    (buf, cloud)
}

// ---------------------------------------------------------------- PLY round trips

#[test]
fn ply_reads_every_encoding_type_and_layout() {
    let mut cases = 0;
    for enc in [Enc::Ascii, Enc::Le, Enc::Be] {
        for ty in [
            "float", "float32", "double", "float64", "int", "short", "uchar", "uint16",
        ] {
            for variant in 0..6 {
                let mut s = PlySpec::new(enc, ty);
                match variant {
                    0 => {}
                    1 => {
                        s.grid = Some((4, 3));
                        s.intensity = Some("intensity");
                        s.confidence = true;
                    }
                    2 => {
                        s.element_before = true;
                        s.faces_after = true;
                        s.intensity = Some("scalar_Intensity");
                    }
                    3 => {
                        s.vertex_list = true;
                        s.confidence = true;
                        s.faces_after = true;
                    }
                    4 => {
                        s.unit = Some("mm");
                        s.grid = Some((2, 6));
                        s.element_before = true;
                        s.vertex_list = true;
                    }
                    _ => s.unit = Some("cm"),
                }
                let (bytes, want) = build_ply(&s, 12, cases);
                let got = read_ply(&bytes).unwrap_or_else(|e| panic!("{s:?}: {e}"));
                assert_same_cloud(&got, &want, false);
                cases += 1;
            }
        }
    }
    assert_eq!(cases, 144);
}

#[test]
fn ply_write_read_round_trips() {
    for enc in [
        PlyEncoding::Ascii,
        PlyEncoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian,
    ] {
        for (w, h) in [(6, 5), (17, 1), (0, 1)] {
            for (inten, conf) in [(false, false), (true, false), (false, true), (true, true)] {
                let cloud = sample_cloud(w, h, inten, conf, u64::from(w * 10 + h));
                let path = tmp(&format!("rt-{enc:?}-{w}x{h}-{inten}-{conf}.ply"));
                write_ply(&path, &cloud, enc).expect("write");
                let back = read_cloud(&path).expect("read");
                // Binary keeps NaN payloads bit for bit; ASCII keeps values and NaN-ness.
                assert_same_cloud(&back, &cloud, enc != PlyEncoding::Ascii);
                assert_eq!(back.is_organized(), h > 1);
                std::fs::remove_file(&path).expect("rm");
            }
        }
    }
}

#[test]
fn ply_reads_pcl_organized_convention() {
    let (bytes, mut want) = build_ply(&PlySpec::new(Enc::Le, "float"), 6, 1);
    let text = String::from_utf8_lossy(&bytes[..20]).into_owned();
    assert!(text.starts_with("ply\nformat binary_"));
    let patched = [
        &b"ply\nobj_info num_cols 3\nobj_info num_rows 2\n"[..],
        &bytes[4..],
    ]
    .concat();
    want.width = 3;
    want.height = 2;
    assert_same_cloud(&read_ply(&patched).expect("read"), &want, true);
    // A PCL grid that does not match the vertex count (valid points only) reads unorganized.
    let sparse = [
        &b"ply\nobj_info num_cols 4\nobj_info num_rows 2\n"[..],
        &bytes[4..],
    ]
    .concat();
    assert!(!read_ply(&sparse).expect("read").is_organized());
}

// ---------------------------------------------------------------- PCD round trips

/// A greedy LZF compressor (test only) so the `binary_compressed` reader sees literals,
/// short and long back-references.
fn lzf_compress(input: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut lit: Vec<u8> = Vec::new();
    let flush = |out: &mut Vec<u8>, lit: &mut Vec<u8>| {
        for chunk in lit.chunks(32) {
            out.push((chunk.len() - 1) as u8);
            out.extend_from_slice(chunk);
        }
        lit.clear();
    };
    let mut i = 0;
    while i < input.len() {
        let mut best = (0, 0);
        for back in 1..=i.min(8192) {
            let mut len = 0;
            while i + len < input.len() && len < 264 && input[i + len - back] == input[i + len] {
                len += 1;
            }
            if len > best.0 {
                best = (len, back);
            }
        }
        let (len, back) = best;
        if len >= 3 {
            flush(&mut out, &mut lit);
            let off = back - 1;
            let l = len - 2;
            if l < 7 {
                out.push(((l << 5) | (off >> 8)) as u8);
            } else {
                out.push(((7 << 5) | (off >> 8)) as u8);
                out.push((l - 7) as u8);
            }
            out.push((off & 0xff) as u8);
            i += len;
        } else {
            lit.push(input[i]);
            i += 1;
        }
    }
    flush(&mut out, &mut lit);
    out
}

/// A `binary_compressed` PCD (column layout), with an extra COUNT-3 field to skip.
fn build_pcd_compressed(cloud: &PointCloud) -> Vec<u8> {
    let n = cloud.points.len();
    let mut raw = Vec::new();
    for k in 0..3 {
        for p in &cloud.points {
            raw.extend_from_slice(&p[k].to_le_bytes());
        }
    }
    for _ in 0..n {
        raw.extend_from_slice(&[1, 2, 3, 4, 5, 6]); // normal_q: U2 × 3
    }
    let inten = cloud.intensity.as_ref().expect("intensity");
    for v in inten {
        raw.extend_from_slice(&f64::from(*v).to_le_bytes());
    }
    let z = lzf_compress(&raw);
    let mut f = format!(
        "# .PCD v0.7\nVERSION .7\nFIELDS x y z normal_q intensity\nSIZE 4 4 4 2 8\nTYPE F F F U F\nCOUNT 1 1 1 3 1\nWIDTH {}\nHEIGHT {}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary_compressed\n",
        cloud.width, cloud.height
    )
    .into_bytes();
    f.extend_from_slice(&(z.len() as u32).to_le_bytes());
    f.extend_from_slice(&(raw.len() as u32).to_le_bytes());
    f.extend_from_slice(&z);
    f
}

#[test]
fn pcd_write_read_round_trips() {
    for binary in [false, true] {
        for (w, h) in [(5, 4), (9, 1), (0, 1)] {
            for (inten, conf) in [(false, false), (true, true), (true, false)] {
                let cloud = sample_cloud(w, h, inten, conf, u64::from(w + h));
                let path = tmp(&format!("rt-{binary}-{w}x{h}-{inten}-{conf}.pcd"));
                write_pcd(&path, &cloud, binary).expect("write");
                let back = read_cloud(&path).expect("read");
                assert_same_cloud(&back, &cloud, binary);
                std::fs::remove_file(&path).expect("rm");
            }
        }
    }
}

#[test]
fn pcd_reads_binary_compressed() {
    let mut cloud = sample_cloud(40, 30, true, false, 9);
    // Repetitive data exercises long back-references.
    for p in cloud.points.iter_mut().take(400) {
        *p = Point3::new(1.0, 2.0, 3.0);
    }
    let bytes = build_pcd_compressed(&cloud);
    let back = read_pcd(&bytes).expect("read");
    assert_same_cloud(&back, &cloud, true);
}

#[test]
fn pcd_reads_ascii_with_skipped_fields_and_units() {
    let text = "# .PCD v0.7\n# unit mm\nVERSION 0.7\nFIELDS rgb x y z _ intensity\nSIZE 4 4 4 8 1 1\nTYPE U F F F I U\nCOUNT 1 1 1 1 2 1\nWIDTH 2\nHEIGHT 2\nPOINTS 4\nDATA ascii\n\
                0 1 2 3 0 0 10\n7 nan nan nan 0 0 0\n\n0 -1000 1e3 500.5 0 0 255\n1 0 0 0 0 0 1\n";
    let c = read_pcd(text.as_bytes()).expect("read");
    assert_eq!((c.width, c.height), (2, 2));
    assert_eq!(c.points[0], Point3::new(0.001, 0.002, 0.003));
    assert!(c.points[1].x.is_nan());
    assert_eq!(c.points[2], Point3::new(-1.0, 1.0, 0.5005));
    assert_eq!(c.intensity, Some(vec![10.0, 0.0, 255.0, 1.0]));
    assert_eq!(c.confidence, None);
}

#[test]
fn lzf_decoder_rejects_corrupt_streams() {
    assert!(pcd::lzf_decompress(&[0x20, 0x00], 3).is_err()); // back-reference before start
    assert!(pcd::lzf_decompress(&[5, 1, 2], 6).is_err()); // literal run past the input
    assert!(pcd::lzf_decompress(&[0, 7], 2).is_err()); // too short
    assert_eq!(
        pcd::lzf_decompress(&[0, 7, 0x20, 0x00], 4),
        Ok(vec![7, 7, 7, 7])
    );
}

// ---------------------------------------------------------------- malformed files

fn ply_ok() -> Vec<u8> {
    let mut s = PlySpec::new(Enc::Le, "float");
    s.faces_after = true;
    build_ply(&s, 10, 3).0
}

fn replace(bytes: &[u8], from: &str, to: &str) -> Vec<u8> {
    let text = String::from_utf8_lossy(bytes).into_owned();
    let i = text.find(from).expect("pattern");
    [&bytes[..i], to.as_bytes(), &bytes[i + from.len()..]].concat()
}

fn err_text(r: Result<PointCloud, CloudError>) -> (CloudError, String) {
    let e = r.expect_err("must fail");
    let msg = e.to_string();
    (e, msg)
}

#[test]
fn missing_magic_is_reported() {
    for bytes in [
        &b""[..],
        b"solid cube\n",
        b"PLY\nformat ascii 1.0\n",
        b"\x00\x01\x02",
    ] {
        let (e, msg) = err_text(read_cloud_bytes(bytes));
        assert!(matches!(e, CloudError::NoMagic { .. }), "{e:?}");
        assert!(
            msg.contains("not a point-cloud file") && msg.contains("re-export"),
            "{msg}"
        );
    }
    let (e, _) = err_text(read_pcd(b"ply\n"));
    assert!(matches!(e, CloudError::NoMagic { .. }));
}

#[test]
fn unknown_encoding_is_reported() {
    let (e, msg) = err_text(read_ply(&replace(
        &ply_ok(),
        "binary_little_endian",
        "binary_middle_endian",
    )));
    assert!(
        matches!(e, CloudError::UnknownEncoding { line: 2, .. }),
        "{e:?}"
    );
    assert!(
        msg.contains("binary_middle_endian") && msg.contains("line 2"),
        "{msg}"
    );
    let pcd = b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nDATA zip\n";
    let (e, msg) = err_text(read_pcd(pcd));
    assert!(
        matches!(e, CloudError::UnknownEncoding { line: 6, .. }),
        "{e:?}"
    );
    assert!(msg.contains("`zip`"), "{msg}");
}

#[test]
fn truncated_data_is_reported() {
    let ok = ply_ok();
    let hdr = String::from_utf8_lossy(&ok)
        .find("end_header\n")
        .expect("hdr")
        + 11;
    let cut = &ok[..hdr + 10 * 15 - 7]; // 10 vertices of 15 bytes, minus 7
    let (e, msg) = err_text(read_ply(cut));
    match e {
        CloudError::Truncated {
            expected_bytes,
            available,
            offset,
            ..
        } => {
            assert_eq!((expected_bytes, available, offset), (150, 143, hdr as u64));
        }
        other => panic!("{other:?}"),
    }
    assert!(
        msg.contains("10 vertices of 15 bytes") && msg.contains("150 bytes"),
        "{msg}"
    );
    // PCD binary.
    let cloud = sample_cloud(4, 4, false, false, 1);
    let path = tmp("trunc.pcd");
    write_pcd(&path, &cloud, true).expect("write");
    let bytes = std::fs::read(&path).expect("read");
    let (e, msg) = err_text(read_pcd(&bytes[..bytes.len() - 1]));
    assert!(
        matches!(
            e,
            CloudError::Truncated {
                expected_bytes: 192,
                available: 191,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(msg.contains("16 points of 12 bytes"), "{msg}");
    // ASCII ending early.
    let (bytes, _) = build_ply(&PlySpec::new(Enc::Ascii, "float"), 5, 1);
    let text = String::from_utf8_lossy(&bytes).into_owned();
    let last = text.trim_end().rfind('\n').expect("lines");
    let (e, msg) = err_text(read_ply(&bytes[..last + 1]));
    assert!(matches!(e, CloudError::BadData { .. }), "{e:?}");
    assert!(
        msg.contains("declares 5 `vertex` records, the file ends after 4"),
        "{msg}"
    );
}

#[test]
fn absurd_counts_are_refused_before_allocating() {
    for count in ["4000000000", "18446744073709551615", "5000000"] {
        let bytes = replace(
            &ply_ok(),
            "element vertex 10",
            &format!("element vertex {count}"),
        );
        let (r, largest) = largest_allocation(|| read_ply(&bytes));
        let (e, msg) = err_text(r);
        assert!(matches!(e, CloudError::AbsurdCount { .. }), "{e:?}");
        assert!(
            msg.contains(count) && msg.contains("header is corrupt"),
            "{msg}"
        );
        assert!(largest < 1 << 16, "allocated {largest} bytes");
    }
    // Plausible for one byte per vertex but not for the stride: truncated, not absurd.
    let bytes = replace(&ply_ok(), "element vertex 10", "element vertex 100");
    assert!(matches!(
        read_ply(&bytes),
        Err(CloudError::Truncated { .. })
    ));
    // An element before vertex with a huge count.
    let bytes = replace(
        &ply_ok(),
        "element vertex",
        "element junk 99999999999\nproperty float a\nelement vertex",
    );
    assert!(matches!(
        read_ply(&bytes),
        Err(CloudError::Truncated { .. })
    ));
    let pcd = b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 3000000000\nHEIGHT 3000000000\nDATA binary\n";
    let (e, msg) = err_text(read_pcd(pcd));
    assert!(matches!(e, CloudError::AbsurdCount { .. }), "{e:?}");
    assert!(msg.contains("9000000000000000000 points"), "{msg}");
    // ASCII: more points than the file could hold at two bytes per value.
    let pcd = b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 100\nDATA ascii\n1 2 3\n";
    assert!(matches!(
        read_pcd(pcd),
        Err(CloudError::AbsurdCount { count: 100, .. })
    ));
    // Compressed: declared size far beyond what LZF can expand to.
    let mut pcd = b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1000000\nDATA binary_compressed\n".to_vec();
    pcd.extend_from_slice(&4u32.to_le_bytes());
    pcd.extend_from_slice(&12_000_000u32.to_le_bytes());
    pcd.extend_from_slice(&[0u8; 1_000_000]);
    let (r, largest) = largest_allocation(|| read_pcd(&pcd));
    assert!(
        matches!(
            r,
            Err(CloudError::AbsurdCount {
                count: 12_000_000,
                ..
            })
        ),
        "{r:?}"
    );
    assert!(largest < 1 << 16);
}

#[test]
fn missing_coordinates_are_reported() {
    let (e, msg) = err_text(read_ply(&replace(
        &ply_ok(),
        "property float y",
        "property float why",
    )));
    assert!(matches!(e, CloudError::Missing { .. }), "{e:?}");
    assert!(
        msg.contains("vertex property `y`") && msg.contains("re-export"),
        "{msg}"
    );
    let (e, msg) = err_text(read_ply(&replace(
        &ply_ok(),
        "element vertex",
        "element points",
    )));
    assert!(matches!(e, CloudError::Missing { .. }), "{e:?}");
    assert!(msg.contains("element vertex"), "{msg}");
    let pcd = b"VERSION .7\nFIELDS x y\nSIZE 4 4\nTYPE F F\nWIDTH 1\nDATA ascii\n1 2\n";
    let (e, msg) = err_text(read_pcd(pcd));
    assert!(
        matches!(e, CloudError::Missing { .. }) && msg.contains("field `z`"),
        "{msg}"
    );
}

#[test]
fn bad_ascii_numbers_are_reported_with_line_and_property() {
    let (bytes, _) = build_ply(&PlySpec::new(Enc::Ascii, "float"), 5, 2);
    let text = String::from_utf8_lossy(&bytes).into_owned();
    let mut lines: Vec<&str> = text.lines().collect();
    let hdr = lines.iter().position(|l| *l == "end_header").expect("hdr");
    let mut toks: Vec<String> = lines[hdr + 3].split(' ').map(str::to_owned).collect();
    toks[2] = "1.2.3".to_owned(); // property `y` (after `red` and `x`)
    let bad_line = toks.join(" ");
    lines[hdr + 3] = &bad_line;
    let (e, msg) = err_text(read_ply(lines.join("\n").as_bytes()));
    assert!(matches!(e, CloudError::BadData { .. }), "{e:?}");
    let line_no = hdr + 4;
    assert!(
        msg.contains(&format!("line {line_no}"))
            && msg.contains("`vertex` #2")
            && msg.contains("`y`")
            && msg.contains("1.2.3"),
        "{msg}"
    );
    // Integer property out of range.
    let mut toks: Vec<String> = lines[hdr + 1].split(' ').map(str::to_owned).collect();
    toks[0] = "300".to_owned(); // `red` is uchar, but not read: only counted
    toks[1] = "x".to_owned();
    let l = toks.join(" ");
    lines[hdr + 1] = &l;
    let (e, msg) = err_text(read_ply(lines.join("\n").as_bytes()));
    assert!(
        matches!(e, CloudError::BadData { .. }) && msg.contains("property `x`"),
        "{msg}"
    );
    let pcd =
        b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nDATA ascii\n1 2 3\n1 zz 3\n";
    let (e, msg) = err_text(read_pcd(pcd));
    assert!(matches!(e, CloudError::BadData { .. }), "{e:?}");
    assert!(
        msg.contains("line 8") && msg.contains("field `y`") && msg.contains("`zz`"),
        "{msg}"
    );
    let pcd =
        b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nDATA ascii\n10 20 30\n10 30\n";
    let (_, msg) = err_text(read_pcd(pcd));
    assert!(msg.contains("has 2 values, the header declares 3"), "{msg}");
}

#[test]
fn unsupported_types_and_bad_headers_are_reported() {
    let (e, msg) = err_text(read_ply(&replace(
        &ply_ok(),
        "property float z",
        "property half z",
    )));
    assert!(matches!(e, CloudError::UnsupportedType { .. }), "{e:?}");
    assert!(msg.contains("`half`") && msg.contains("`z`"), "{msg}");
    let pcd = b"VERSION .7\nFIELDS x y z\nSIZE 4 4 2\nTYPE F F F\nWIDTH 1\nDATA binary\n";
    let (e, msg) = err_text(read_pcd(pcd));
    assert!(
        matches!(e, CloudError::UnsupportedType { line: 4, .. }),
        "{e:?}"
    );
    assert!(msg.contains("TYPE F SIZE 2"), "{msg}");
    for (from, to, needle) in [
        (
            "element vertex 10",
            "element vertex ten",
            "is not a whole number",
        ),
        ("end_header", "end_head", "unknown header keyword"),
        (
            "comment generated",
            "comment unit furlong\ncomment generated",
            "unknown unit `furlong`",
        ),
        (
            "element vertex 10",
            "obj_info width 3\nobj_info height 3\nelement vertex 10",
            "does not match the 10 vertices",
        ),
        (
            "element vertex 10",
            "obj_info width 10\nelement vertex 10",
            "only one of",
        ),
        (
            "property float x",
            "property list uchar float x",
            "is a list",
        ),
        (
            "property float x",
            "property list float float q\nproperty float x",
            "non-integer count type",
        ),
    ] {
        let (e, msg) = err_text(read_ply(&replace(&ply_ok(), from, to)));
        assert!(matches!(e, CloudError::BadHeader { .. }), "{from}: {e:?}");
        assert!(msg.contains(needle), "{msg}");
    }
    let (e, _) = err_text(read_ply(b"ply\nformat ascii 1.0\nelement vertex 0\n"));
    assert!(matches!(e, CloudError::BadHeader { .. }));
    let pcd = b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F\nWIDTH 1\nDATA binary\n";
    let (_, msg) = err_text(read_pcd(pcd));
    assert!(msg.contains("TYPE has 2 entries for 3 FIELDS"), "{msg}");
    let pcd = b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nPOINTS 3\nDATA binary\n";
    let (_, msg) = err_text(read_pcd(pcd));
    assert!(msg.contains("POINTS 3 differs from WIDTH 2"), "{msg}");
}

#[test]
fn writers_refuse_inconsistent_clouds() {
    let mut c = sample_cloud(3, 2, true, false, 1);
    c.width = 4;
    let e = write_ply(&tmp("bad.ply"), &c, PlyEncoding::default()).expect_err("must fail");
    assert!(
        matches!(e, CloudError::InconsistentCloud { .. }) && e.to_string().contains("4 × height 2")
    );
    let mut c = sample_cloud(3, 2, true, false, 1);
    c.intensity = Some(vec![0.0; 5]);
    let e = write_pcd(&tmp("bad.pcd"), &c, true).expect_err("must fail");
    assert!(
        e.to_string()
            .contains("intensity has 5 values for 6 points"),
        "{e}"
    );
    let e = read_cloud(&tmp("does-not-exist.ply")).expect_err("must fail");
    assert!(matches!(e, CloudError::Io { action: "open", .. }), "{e:?}");
}

// ---------------------------------------------------------------- fuzz

/// Valid files of every kind, the seeds of the mutation loop.
fn fuzz_seeds() -> Vec<Vec<u8>> {
    let mut seeds = Vec::new();
    for (enc, ty) in [(Enc::Ascii, "float"), (Enc::Le, "double"), (Enc::Be, "int")] {
        let mut s = PlySpec::new(enc, ty);
        s.element_before = true;
        s.faces_after = true;
        s.intensity = Some("intensity");
        s.grid = Some((3, 4));
        seeds.push(build_ply(&s, 12, 5).0);
        s.vertex_list = true;
        s.grid = None;
        seeds.push(build_ply(&s, 12, 6).0);
    }
    let cloud = sample_cloud(4, 3, true, true, 2);
    for binary in [false, true] {
        let path = tmp(&format!("seed-{binary}.pcd"));
        write_pcd(&path, &cloud, binary).expect("write");
        seeds.push(std::fs::read(&path).expect("read"));
    }
    seeds.push(build_pcd_compressed(&sample_cloud(4, 3, true, false, 3)));
    seeds
}

/// Checks a parsed cloud's invariants: as many points as width × height, and every
/// attribute one value per point.
fn check_cloud(c: &PointCloud) -> Result<(), String> {
    if c.points.len() as u64 != u64::from(c.width) * u64::from(c.height) {
        return Err(format!(
            "BUG: {} points for {} × {}",
            c.points.len(),
            c.width,
            c.height
        ));
    }
    for a in [&c.intensity, &c.confidence].into_iter().flatten() {
        assert_eq!(a.len(), c.points.len(), "attribute length");
    }
    Ok(())
}

/// Fuzz targets `ply` and `pcd` (hal::fuzz): mutated files of the format whose seeds `ply`
/// selects are parsed or refused with a message, allocating at most 64 bytes per input byte
/// (+64 KiB) at once; a parsed cloud is consistent.
fn fuzz_cloud(name: &str, ply: bool) {
    let seeds = fuzz_seeds()
        .into_iter()
        .filter(|s| s.starts_with(b"ply") == ply)
        .collect();
    handeye_hal::fuzz::Target::new(name, seeds)
        .allocation_cap(64, 1 << 16)
        .run(|b| {
            read_cloud_bytes(b)
                .map_err(|e| e.to_string())
                .and_then(|c| check_cloud(&c))
        });
}

/// Fuzz target `ply`: every encoding, property type and layout (grid, vertex lists, faces).
#[test]
fn fuzz_ply() {
    fuzz_cloud("ply", true);
}

/// Fuzz target `pcd`: ASCII, binary and binary_compressed.
#[test]
fn fuzz_pcd() {
    fuzz_cloud("pcd", false);
}

/// An error message fit for a terminal: bounded, and no control characters from the input.
fn assert_safe_message(msg: &str) {
    assert!(
        msg.len() < 2048,
        "{}-byte message: {}",
        msg.len(),
        &msg[..200]
    );
    assert!(
        !msg.chars().any(|c| c.is_control()),
        "control character in {msg:?}"
    );
}

/// Issue 16: a 10 MB token or terminal escape bytes where a header word belongs are echoed
/// bounded and escaped; structure-aware cases: every header keyword followed by a huge token,
/// counts and sizes at the integer limits.
#[test]
fn issue_16_hostile_header_tokens_are_echoed_bounded_and_escaped() {
    let long = "9".repeat(10 << 20);
    let tokens = [
        long.as_str(),
        "\u{1b}[2J\u{1b}]0;pwned\u{7}",
        // A PCD comment's mark, no comment in PLY: its control character still echoed.
        "#\u{18}",
        "x\u{202e}y",
        "1e309",
        "-0",
    ];
    let ply_bytes = ply_ok();
    let header_end = ply_bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .expect("header");
    let ply = format!(
        "{}end_header\n0 0 1\n",
        String::from_utf8(ply_bytes[..header_end].to_vec()).expect("ASCII header")
    )
    .replace("binary_little_endian", "ascii");
    let pcd = "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1\nDATA ascii\n1 2 3\n";
    let mut checked = 0;
    for t in tokens {
        // Each word of each header line in turn replaced by the token.
        for (text, end) in [
            (&ply[..], header_end),
            (pcd, pcd.find("DATA").expect("data")),
        ] {
            let mut at = 0;
            while at < end {
                let word_end = text[at..].find([' ', '\n']).map_or(text.len(), |i| at + i);
                let mut bytes = text.as_bytes()[..at].to_vec();
                bytes.extend_from_slice(t.as_bytes());
                bytes.extend_from_slice(&text.as_bytes()[word_end..]);
                if let Err(e) = read_cloud_bytes(&bytes) {
                    assert_safe_message(&e.to_string());
                    checked += 1;
                }
                at = word_end + 1;
            }
        }
    }
    assert!(checked > 50, "only {checked} hostile headers refused");
}

/// Issue 16: a scan path that is a FIFO is refused at once instead of blocking the reader
/// until a writer comes (forever); so is a directory.
#[cfg(unix)]
#[test]
fn issue_16_a_fifo_is_not_read() {
    let fifo = tmp("issue16.fifo.ply");
    let _ = std::fs::remove_file(&fifo);
    let ok = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .expect("mkfifo runs")
        .success();
    assert!(ok);
    let t = std::time::Instant::now();
    let msg = read_cloud(&fifo).expect_err("a FIFO").to_string();
    assert!(
        msg.contains("FIFO (named pipe), not a regular file"),
        "{msg}"
    );
    assert!(t.elapsed().as_secs() < 2);
    let _ = std::fs::remove_file(&fifo);
    let dir = fifo.with_extension("d");
    std::fs::create_dir_all(&dir).expect("dir");
    let msg = read_cloud(&dir).expect_err("a directory").to_string();
    assert!(msg.contains("directory"), "{msg}");
    let _ = std::fs::remove_dir(&dir);
}
