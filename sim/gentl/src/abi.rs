//! The GenTL C ABI seen from the producer's side (GenICam GenTL standard 1.5/1.6,
//! `GenTL.h`): error codes, the enumeration values this producer answers, and the
//! `INFO_DATATYPE` convention every `...GetInfo` function follows.

use std::ffi::{c_char, c_void, CStr};

/// `GC_ERROR`.
pub(crate) type GcError = i32;

/// `GC_ERR_*` codes.
pub(crate) mod err {
    pub(crate) const SUCCESS: i32 = 0;
    pub(crate) const ERROR: i32 = -1001;
    pub(crate) const NOT_INITIALIZED: i32 = -1002;
    pub(crate) const NOT_IMPLEMENTED: i32 = -1003;
    pub(crate) const RESOURCE_IN_USE: i32 = -1004;
    pub(crate) const ACCESS_DENIED: i32 = -1005;
    pub(crate) const INVALID_HANDLE: i32 = -1006;
    pub(crate) const INVALID_ID: i32 = -1007;
    pub(crate) const NO_DATA: i32 = -1008;
    pub(crate) const INVALID_PARAMETER: i32 = -1009;
    pub(crate) const TIMEOUT: i32 = -1011;
    pub(crate) const ABORT: i32 = -1012;
    pub(crate) const NOT_AVAILABLE: i32 = -1014;
    pub(crate) const INVALID_ADDRESS: i32 = -1015;
    pub(crate) const BUFFER_TOO_SMALL: i32 = -1016;
    pub(crate) const INVALID_INDEX: i32 = -1017;
    pub(crate) const INVALID_VALUE: i32 = -1019;
}

/// `INFO_DATATYPE` values.
mod info_type {
    pub(super) const STRING: i32 = 1;
    pub(super) const INT32: i32 = 5;
    pub(super) const UINT32: i32 = 6;
    pub(super) const UINT64: i32 = 8;
    pub(super) const PTR: i32 = 10;
    pub(super) const BOOL8: i32 = 11;
    pub(super) const SIZET: i32 = 12;
}

/// `EVENT_NEW_BUFFER`.
pub(crate) const EVENT_NEW_BUFFER: i32 = 1;
/// `GENTL_INFINITE`.
pub(crate) const GENTL_INFINITE: u64 = u64::MAX;
/// `PAYLOAD_TYPE_MULTI_PART`.
pub(crate) const PAYLOAD_TYPE_MULTI_PART: u64 = 10;
/// `PAYLOAD_TYPE_GENDC` (GenICam Data Container).
pub(crate) const PAYLOAD_TYPE_GENDC: u64 = 11;
/// `PIXELFORMAT_NAMESPACE_PFNC_32BIT`.
pub(crate) const PIXELFORMAT_NAMESPACE_PFNC_32BIT: u64 = 4;
/// `DEVICE_ACCESS_STATUS_READWRITE` / `_OPEN_READWRITE`.
pub(crate) const ACCESS_STATUS_READWRITE: i32 = 1;
pub(crate) const ACCESS_STATUS_OPEN_READWRITE: i32 = 5;

/// A failure: the `GC_ERR_*` code and the text `GCGetLastError` gives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Fail {
    pub(crate) code: GcError,
    pub(crate) text: String,
}

impl Fail {
    pub(crate) fn new(code: GcError, text: impl Into<String>) -> Self {
        Self {
            code,
            text: text.into(),
        }
    }
}

/// Result of an exported function's body.
pub(crate) type Res<T = ()> = Result<T, Fail>;

/// One answer of a `...GetInfo` function, typed as the standard types that command.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Info {
    Str(String),
    I32(i32),
    U32(u32),
    U64(u64),
    SizeT(usize),
    Ptr(usize),
    Bool(bool),
}

impl Info {
    /// Write the answer as GenTL's `...GetInfo` functions do: the type into `*ty` (if not
    /// null); with `buf` null only the size needed into `*size`; else the value, failing with
    /// `GC_ERR_BUFFER_TOO_SMALL` when `*size` is short. Strings are NUL-terminated.
    ///
    /// # Safety
    /// `ty` null or writable; `size` null or valid; `buf` null or writable for `*size` bytes.
    pub(crate) unsafe fn write(&self, ty: *mut i32, buf: *mut c_void, size: *mut usize) -> Res {
        let (code, bytes): (i32, Vec<u8>) = match self {
            Info::Str(s) => {
                let mut b = s.as_bytes().to_vec();
                b.push(0);
                (info_type::STRING, b)
            }
            Info::I32(v) => (info_type::INT32, v.to_ne_bytes().to_vec()),
            Info::U32(v) => (info_type::UINT32, v.to_ne_bytes().to_vec()),
            Info::U64(v) => (info_type::UINT64, v.to_ne_bytes().to_vec()),
            Info::SizeT(v) => (info_type::SIZET, v.to_ne_bytes().to_vec()),
            Info::Ptr(v) => (info_type::PTR, v.to_ne_bytes().to_vec()),
            Info::Bool(v) => (info_type::BOOL8, vec![u8::from(*v)]),
        };
        if !ty.is_null() {
            // SAFETY: the caller's pointer, checked non-null.
            unsafe { *ty = code };
        }
        // SAFETY: as the caller promises.
        unsafe { write_bytes(&bytes, buf, size) }
    }
}

/// Copy `bytes` out the way GenTL does for strings and buffers (size query with a null `buf`).
///
/// # Safety
/// `size` null or valid; `buf` null or writable for `*size` bytes.
unsafe fn write_bytes(bytes: &[u8], buf: *mut c_void, size: *mut usize) -> Res {
    if size.is_null() {
        return Err(Fail::new(err::INVALID_PARAMETER, "piSize is NULL"));
    }
    // SAFETY: checked non-null; the caller's.
    let have = unsafe { *size };
    // SAFETY: as above.
    unsafe { *size = bytes.len() };
    if buf.is_null() {
        return Ok(());
    }
    if have < bytes.len() {
        return Err(Fail::new(
            err::BUFFER_TOO_SMALL,
            format!("{} bytes needed, {have} given", bytes.len()),
        ));
    }
    // SAFETY: `buf` is writable for `have >= bytes.len()` bytes (the caller's promise).
    unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), buf.cast::<u8>(), bytes.len()) };
    Ok(())
}

/// A string argument (an id): UTF-8 up to its NUL.
///
/// # Safety
/// `s` null or a NUL-terminated string.
pub(crate) unsafe fn arg_str(s: *const c_char, what: &str) -> Res<String> {
    if s.is_null() {
        return Err(Fail::new(err::INVALID_PARAMETER, format!("{what} is NULL")));
    }
    // SAFETY: the caller's NUL-terminated string.
    let c = unsafe { CStr::from_ptr(s) };
    c.to_str()
        .map(str::to_owned)
        .map_err(|_| Fail::new(err::INVALID_ID, format!("{what} is not UTF-8")))
}

/// Store `v` through an out-pointer.
///
/// # Safety
/// `p` null or writable.
pub(crate) unsafe fn out<T>(p: *mut T, v: T, what: &str) -> Res {
    if p.is_null() {
        return Err(Fail::new(err::INVALID_PARAMETER, format!("{what} is NULL")));
    }
    // SAFETY: checked non-null; the caller's out-pointer.
    unsafe { p.write(v) };
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn info_answers_size_queries_and_refuses_short_buffers() {
        let info = Info::Str("SIM0001".into());
        let (mut ty, mut size) = (0, 0usize);
        // SAFETY: valid out-pointers; a null buffer asks for the size.
        unsafe { info.write(&mut ty, std::ptr::null_mut(), &mut size) }.expect("size");
        assert_eq!((ty, size), (info_type::STRING, 8));
        let mut short = [0u8; 4];
        let mut n = short.len();
        // SAFETY: `short` is writable for `n` bytes.
        let e = unsafe { info.write(&mut ty, short.as_mut_ptr().cast(), &mut n) }
            .expect_err("too small");
        assert_eq!(e.code, err::BUFFER_TOO_SMALL);
        let mut buf = [0xFFu8; 16];
        let mut n = buf.len();
        // SAFETY: `buf` is writable for `n` bytes.
        unsafe { info.write(&mut ty, buf.as_mut_ptr().cast(), &mut n) }.expect("fits");
        assert_eq!(&buf[..n], b"SIM0001\0");
        let mut v = [0u8; 8];
        let mut n = 8;
        // SAFETY: `v` is writable for `n` bytes.
        unsafe { Info::U64(1 << 40).write(&mut ty, v.as_mut_ptr().cast(), &mut n) }.expect("u64");
        assert_eq!(
            (u64::from_ne_bytes(v), ty, n),
            (1 << 40, info_type::UINT64, 8)
        );
    }
}
