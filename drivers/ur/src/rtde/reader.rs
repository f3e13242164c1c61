//! The bounds-checked big-endian cursor every RTDE and primary-interface decoder reads with.

use super::P;
use crate::UrError;

/// Big-endian cursor over a byte slice; every read is bounds-checked.
#[derive(Debug)]
pub struct Reader<'a> {
    buf: &'a [u8],
    what: &'static str,
}

impl<'a> Reader<'a> {
    /// Read from `buf`; errors name RTDE.
    pub fn new(buf: &'a [u8]) -> Self {
        Self { buf, what: P }
    }

    /// Read from `buf`; errors name `protocol`.
    pub fn for_protocol(buf: &'a [u8], protocol: &'static str) -> Self {
        Self {
            buf,
            what: protocol,
        }
    }

    /// Bytes left.
    pub fn remaining(&self) -> usize {
        self.buf.len()
    }

    /// Take `n` bytes.
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], UrError> {
        if self.buf.len() < n {
            return Err(UrError::malformed(
                self.what,
                format!(
                    "truncated: needed {n} more bytes, only {} left",
                    self.buf.len()
                ),
            ));
        }
        let (a, b) = self.buf.split_at(n);
        self.buf = b;
        Ok(a)
    }

    /// The rest.
    pub fn rest(&mut self) -> &'a [u8] {
        std::mem::take(&mut self.buf)
    }

    fn arr<const N: usize>(&mut self) -> Result<[u8; N], UrError> {
        let s = self.take(N)?;
        let mut a = [0; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    /// uint8
    pub fn u8(&mut self) -> Result<u8, UrError> {
        Ok(self.arr::<1>()?[0])
    }
    /// int8
    pub fn i8(&mut self) -> Result<i8, UrError> {
        Ok(i8::from_be_bytes(self.arr()?))
    }
    /// uint16
    pub fn u16(&mut self) -> Result<u16, UrError> {
        Ok(u16::from_be_bytes(self.arr()?))
    }
    /// uint32
    pub fn u32(&mut self) -> Result<u32, UrError> {
        Ok(u32::from_be_bytes(self.arr()?))
    }
    /// int32
    pub fn i32(&mut self) -> Result<i32, UrError> {
        Ok(i32::from_be_bytes(self.arr()?))
    }
    /// uint64
    pub fn u64(&mut self) -> Result<u64, UrError> {
        Ok(u64::from_be_bytes(self.arr()?))
    }
    /// float64
    pub fn f64(&mut self) -> Result<f64, UrError> {
        Ok(f64::from_be_bytes(self.arr()?))
    }
}
