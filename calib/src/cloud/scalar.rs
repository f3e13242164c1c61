//! Numeric field types shared by the PLY and PCD readers, and the column reader that turns
//! raw record bytes into `f32` values in one tight (optionally parallel) pass.
use nalgebra::Point3;
use rayon::prelude::*;

/// Below this many points the readers stay on one thread (rayon's start-up costs more).
const PARALLEL_MIN_POINTS: usize = 200_000;

/// A fixed-size numeric type as stored in a point-cloud file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl Scalar {
    /// Bytes one value takes.
    pub(crate) fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::I64 | Scalar::U64 | Scalar::F64 => 8,
        }
    }

    /// Whether this is an integer type (usable as a PLY list count).
    pub(crate) fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// The value at `off` in `b` as `f32`; `None` when `b` is too short.
    #[inline(always)]
    pub(crate) fn read_f32(self, b: &[u8], off: usize, big: bool) -> Option<f32> {
        Some(match self {
            Scalar::F32 => {
                let a = arr::<4>(b, off)?;
                if big {
                    f32::from_be_bytes(a)
                } else {
                    f32::from_le_bytes(a)
                }
            }
            Scalar::F64 => {
                let a = arr::<8>(b, off)?;
                (if big {
                    f64::from_be_bytes(a)
                } else {
                    f64::from_le_bytes(a)
                }) as f32
            }
            _ => self.read_int(b, off, big)? as f32,
        })
    }

    /// The integer value at `off` (integer types only; floats are truncated toward zero).
    #[inline(always)]
    pub(crate) fn read_int(self, b: &[u8], off: usize, big: bool) -> Option<i128> {
        macro_rules! int {
            ($t:ty, $n:literal) => {{
                let a = arr::<$n>(b, off)?;
                i128::from(if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                })
            }};
        }
        Some(match self {
            Scalar::I8 => int!(i8, 1),
            Scalar::U8 => int!(u8, 1),
            Scalar::I16 => int!(i16, 2),
            Scalar::U16 => int!(u16, 2),
            Scalar::I32 => int!(i32, 4),
            Scalar::U32 => int!(u32, 4),
            Scalar::I64 => int!(i64, 8),
            Scalar::U64 => int!(u64, 8),
            Scalar::F32 | Scalar::F64 => {
                let v = self.read_f32(b, off, big)?;
                if !v.is_finite() {
                    return None;
                }
                v as i128
            }
        })
    }

    /// Parses one ASCII token of this type as `f32` (floats: Rust's correctly rounded parser,
    /// accepting `nan`/`inf`; integers: checked against the type's range).
    pub(crate) fn parse_f32(self, tok: &[u8]) -> Option<f32> {
        let s = std::str::from_utf8(tok).ok()?;
        match self {
            Scalar::F32 => s.parse::<f32>().ok(),
            Scalar::F64 => s.parse::<f64>().ok().map(|v| v as f32),
            _ => self.parse_int(tok).map(|v| v as f32),
        }
    }

    /// Parses one ASCII integer token and checks it fits this (integer) type.
    pub(crate) fn parse_int(self, tok: &[u8]) -> Option<i128> {
        let v: i128 = std::str::from_utf8(tok).ok()?.parse().ok()?;
        let (lo, hi): (i128, i128) = match self {
            Scalar::I8 => (i8::MIN.into(), i8::MAX.into()),
            Scalar::U8 => (0, u8::MAX.into()),
            Scalar::I16 => (i16::MIN.into(), i16::MAX.into()),
            Scalar::U16 => (0, u16::MAX.into()),
            Scalar::I32 => (i32::MIN.into(), i32::MAX.into()),
            Scalar::U32 => (0, u32::MAX.into()),
            Scalar::I64 => (i64::MIN.into(), i64::MAX.into()),
            Scalar::U64 => (0, u64::MAX.into()),
            Scalar::F32 | Scalar::F64 => return None,
        };
        (lo..=hi).contains(&v).then_some(v)
    }
}

#[inline(always)]
fn arr<const N: usize>(b: &[u8], off: usize) -> Option<[u8; N]> {
    b.get(off..off.checked_add(N)?)?.try_into().ok()
}

/// Where the values of one field live in a binary block: value `i` starts at
/// `base + i * stride`. Covers interleaved records (PLY, PCD `binary`) and column blocks
/// (PCD `binary_compressed`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Column {
    pub(crate) base: usize,
    pub(crate) stride: usize,
    pub(crate) ty: Scalar,
    pub(crate) big_endian: bool,
}

impl Column {
    /// Value `i`; NaN if out of range (the callers check the block size first, so this
    /// only keeps a corrupt layout from panicking).
    #[inline(always)]
    fn get(&self, data: &[u8], i: usize) -> f32 {
        self.ty
            .read_f32(data, self.base + i * self.stride, self.big_endian)
            .unwrap_or(f32::NAN)
    }
}

/// Reads `n` points from `data` (already checked to hold them), scaling coordinates by
/// `scale` (file unit → metres).
pub(crate) fn read_points(data: &[u8], n: usize, xyz: [Column; 3], scale: f32) -> Vec<Point3<f32>> {
    let [cx, cy, cz] = xyz;
    let point = |i: usize| {
        Point3::new(
            cx.get(data, i) * scale,
            cy.get(data, i) * scale,
            cz.get(data, i) * scale,
        )
    };
    if n >= PARALLEL_MIN_POINTS {
        (0..n)
            .into_par_iter()
            .with_min_len(16_384)
            .map(point)
            .collect()
    } else {
        (0..n).map(point).collect()
    }
}

/// Reads `n` values of one column as `f32`.
pub(crate) fn read_column(data: &[u8], n: usize, c: Column) -> Vec<f32> {
    if n >= PARALLEL_MIN_POINTS {
        (0..n)
            .into_par_iter()
            .with_min_len(16_384)
            .map(|i| c.get(data, i))
            .collect()
    } else {
        (0..n).map(|i| c.get(data, i)).collect()
    }
}

/// Iterator over the whitespace-separated tokens of one ASCII line.
pub(crate) fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|b| matches!(b, b' ' | b'\t' | b'\r' | b'\x0b' | b'\x0c'))
        .filter(|t| !t.is_empty())
}

/// Iterator over `(line_number, line)` of an ASCII block, skipping blank lines; line numbers
/// count from `first_line`.
pub(crate) fn nonblank_lines(
    data: &[u8],
    first_line: usize,
) -> impl Iterator<Item = (usize, &[u8])> {
    data.split(|&b| b == b'\n')
        .enumerate()
        .map(move |(k, l)| (first_line + k, l))
        .filter(|(_, l)| tokens(l).next().is_some())
}
