//! The GenTL C ABI (GenICam GenTL standard 1.5/1.6, `GenTL.h`): handle types, the enumeration
//! values this crate uses and the producer's functions, resolved from a `.cti` at run time.
//!
//! Written from the standard's header; only what the consumer calls is here.

use std::ffi::{c_char, c_void};
use std::path::Path;

use crate::error::{GentlError, Result};

/// Any GenTL handle (`TL_HANDLE`, `IF_HANDLE`, `DEV_HANDLE`, `DS_HANDLE`, `PORT_HANDLE`,
/// `BUFFER_HANDLE`, `EVENT_HANDLE` are all `void *`).
pub(crate) type Handle = *mut c_void;
/// `GC_ERROR`.
pub(crate) type GcError = i32;

/// `GC_ERR_*` codes (those the consumer tells apart).
pub(crate) mod err {
    pub(crate) const SUCCESS: i32 = 0;
    pub(crate) const TIMEOUT: i32 = -1011;
    pub(crate) const BUFFER_TOO_SMALL: i32 = -1016;

    /// The standard's name of an error code.
    pub(crate) fn name(code: i32) -> &'static str {
        match code {
            0 => "GC_ERR_SUCCESS",
            -1001 => "GC_ERR_ERROR",
            -1002 => "GC_ERR_NOT_INITIALIZED",
            -1003 => "GC_ERR_NOT_IMPLEMENTED",
            -1004 => "GC_ERR_RESOURCE_IN_USE",
            -1005 => "GC_ERR_ACCESS_DENIED",
            -1006 => "GC_ERR_INVALID_HANDLE",
            -1007 => "GC_ERR_INVALID_ID",
            -1008 => "GC_ERR_NO_DATA",
            -1009 => "GC_ERR_INVALID_PARAMETER",
            -1010 => "GC_ERR_IO",
            -1011 => "GC_ERR_TIMEOUT",
            -1012 => "GC_ERR_ABORT",
            -1013 => "GC_ERR_INVALID_BUFFER",
            -1014 => "GC_ERR_NOT_AVAILABLE",
            -1015 => "GC_ERR_INVALID_ADDRESS",
            -1016 => "GC_ERR_BUFFER_TOO_SMALL",
            -1017 => "GC_ERR_INVALID_INDEX",
            -1018 => "GC_ERR_PARSING_CHUNK_DATA",
            -1019 => "GC_ERR_INVALID_VALUE",
            -1020 => "GC_ERR_RESOURCE_EXHAUSTED",
            -1021 => "GC_ERR_OUT_OF_MEMORY",
            -1022 => "GC_ERR_BUSY",
            -1023 => "GC_ERR_AMBIGUOUS",
            _ => "a producer-specific error",
        }
    }
}

/// `INFO_DATATYPE` values.
pub(crate) mod info_type {
    pub(crate) const INT32: i32 = 5;
    pub(crate) const UINT32: i32 = 6;
    pub(crate) const INT64: i32 = 7;
    pub(crate) const UINT64: i32 = 8;
    pub(crate) const PTR: i32 = 10;
    pub(crate) const BOOL8: i32 = 11;
    pub(crate) const SIZET: i32 = 12;
    pub(crate) const PTRDIFF: i32 = 14;
}

/// `DEVICE_INFO_CMD` values.
pub(crate) mod device_info {
    pub(crate) const VENDOR: i32 = 1;
    pub(crate) const MODEL: i32 = 2;
    pub(crate) const TLTYPE: i32 = 3;
    pub(crate) const DISPLAYNAME: i32 = 4;
    pub(crate) const SERIAL_NUMBER: i32 = 7;
    pub(crate) const VERSION: i32 = 8;
}

/// `DEVICE_ACCESS_CONTROL`: read/write for this process, read-only for others.
pub(crate) const DEVICE_ACCESS_CONTROL: i32 = 3;
/// `ACQ_START_FLAGS_DEFAULT`.
pub(crate) const ACQ_START_FLAGS_DEFAULT: i32 = 0;
/// `ACQ_STOP_FLAGS_KILL`: stop now, leaving a buffer being filled in the input pool.
pub(crate) const ACQ_STOP_FLAGS_KILL: i32 = 1;
/// `ACQ_QUEUE_ALL_DISCARD`: discard the input pool and the output queue.
pub(crate) const ACQ_QUEUE_ALL_DISCARD: i32 = 4;
/// `EVENT_NEW_BUFFER`.
pub(crate) const EVENT_NEW_BUFFER: i32 = 1;
/// `GENTL_INFINITE`: acquire until stopped.
pub(crate) const GENTL_INFINITE: u64 = u64::MAX;

/// `STREAM_INFO_CMD` values.
pub(crate) mod stream_info {
    pub(crate) const PAYLOAD_SIZE: i32 = 7;
    pub(crate) const DEFINES_PAYLOADSIZE: i32 = 9;
    pub(crate) const BUF_ANNOUNCE_MIN: i32 = 12;
}

/// `BUFFER_INFO_CMD` values.
pub(crate) mod buffer_info {
    pub(crate) const BASE: i32 = 0;
    pub(crate) const IS_INCOMPLETE: i32 = 7;
    pub(crate) const SIZE_FILLED: i32 = 9;
    pub(crate) const WIDTH: i32 = 10;
    pub(crate) const HEIGHT: i32 = 11;
    pub(crate) const XPADDING: i32 = 14;
    pub(crate) const IMAGEOFFSET: i32 = 18;
    pub(crate) const PAYLOADTYPE: i32 = 19;
    pub(crate) const PIXELFORMAT: i32 = 20;
}

/// `BUFFER_PART_INFO_CMD` values.
pub(crate) mod part_info {
    pub(crate) const BASE: i32 = 0;
    pub(crate) const DATA_SIZE: i32 = 1;
    pub(crate) const DATA_TYPE: i32 = 2;
    pub(crate) const DATA_FORMAT: i32 = 3;
    pub(crate) const WIDTH: i32 = 5;
    pub(crate) const HEIGHT: i32 = 6;
    pub(crate) const XPADDING: i32 = 9;
    pub(crate) const DATA_PURPOSE_ID: i32 = 13;
}

/// `PAYLOADTYPE_INFO_IDS` values.
pub(crate) mod payload_type {
    pub(crate) const CHUNK_ONLY: usize = 8;
    pub(crate) const MULTI_PART: usize = 10;
    /// A GenDC container (GenICam Data Container).
    pub(crate) const GENDC: usize = 11;
}

/// `PARTDATATYPE_CHUNKDATA`: a part (or a chunk-only buffer) of chunk data.
pub(crate) const PART_DATATYPE_CHUNKDATA: u64 = 10;

/// `URL_INFO_CMD`: `URL_INFO_URL` (STRING).
pub(crate) const URL_INFO_URL: i32 = 0;

/// `EVENT_NEW_BUFFER_DATA` (packed, two pointers).
#[repr(C, packed)]
#[derive(Debug, Clone, Copy)]
pub(crate) struct EventNewBufferData {
    pub(crate) buffer: Handle,
    pub(crate) user_pointer: *mut c_void,
}

type InfoFn = unsafe extern "C" fn(Handle, i32, *mut i32, *mut c_void, *mut usize) -> GcError;
type IdFn = unsafe extern "C" fn(Handle, u32, *mut c_char, *mut usize) -> GcError;
type CountFn = unsafe extern "C" fn(Handle, *mut u32) -> GcError;
type UpdateFn = unsafe extern "C" fn(Handle, *mut u8, u64) -> GcError;
type CloseFn = unsafe extern "C" fn(Handle) -> GcError;
type OpenByIdFn = unsafe extern "C" fn(Handle, *const c_char, *mut Handle) -> GcError;

macro_rules! api {
    ($($field:ident: $sym:literal => $ty:ty,)*) => {
        /// The producer's functions, resolved once when it is loaded.
        pub(crate) struct Api {
            $(pub(crate) $field: $ty,)*
            /// Keeps the library mapped while the function pointers above are used.
            _lib: libloading::Library,
        }

        impl Api {
            /// Load `path` and resolve every function this crate calls.
            pub(crate) fn load(path: &Path) -> Result<Self> {
                // SAFETY: loading a GenTL producer runs its initialisers; that is what the
                // user asked for by naming it (as any GenTL consumer does).
                let lib = unsafe { libloading::Library::new(path) }.map_err(|e| {
                    GentlError::Load { path: path.to_owned(), detail: e.to_string() }
                })?;
                $(
                    // SAFETY: the symbol is the GenTL function of this name, whose C signature
                    // (from the standard's GenTL.h) is `$ty`; the pointer is copied out and
                    // used only while `_lib` keeps the library loaded.
                    let $field: $ty = *unsafe { lib.get::<$ty>(concat!($sym, "\0").as_bytes()) }
                        .map_err(|e| GentlError::Load {
                            path: path.to_owned(),
                            detail: format!("not a GenTL producer: no `{}` ({e})", $sym),
                        })?;
                )*
                Ok(Self { $($field,)* _lib: lib })
            }
        }
    };
}

api! {
    gc_get_last_error: "GCGetLastError" => unsafe extern "C" fn(*mut GcError, *mut c_char, *mut usize) -> GcError,
    gc_init_lib: "GCInitLib" => unsafe extern "C" fn() -> GcError,
    gc_close_lib: "GCCloseLib" => unsafe extern "C" fn() -> GcError,
    gc_read_port: "GCReadPort" => unsafe extern "C" fn(Handle, u64, *mut c_void, *mut usize) -> GcError,
    gc_write_port: "GCWritePort" => unsafe extern "C" fn(Handle, u64, *const c_void, *mut usize) -> GcError,
    gc_get_num_port_urls: "GCGetNumPortURLs" => CountFn,
    gc_get_port_url_info: "GCGetPortURLInfo" => unsafe extern "C" fn(Handle, u32, i32, *mut i32, *mut c_void, *mut usize) -> GcError,
    gc_register_event: "GCRegisterEvent" => unsafe extern "C" fn(Handle, i32, *mut Handle) -> GcError,
    gc_unregister_event: "GCUnregisterEvent" => unsafe extern "C" fn(Handle, i32) -> GcError,
    event_get_data: "EventGetData" => unsafe extern "C" fn(Handle, *mut c_void, *mut usize, u64) -> GcError,
    event_flush: "EventFlush" => CloseFn,
    tl_open: "TLOpen" => unsafe extern "C" fn(*mut Handle) -> GcError,
    tl_close: "TLClose" => CloseFn,
    tl_update_interface_list: "TLUpdateInterfaceList" => UpdateFn,
    tl_get_num_interfaces: "TLGetNumInterfaces" => CountFn,
    tl_get_interface_id: "TLGetInterfaceID" => IdFn,
    tl_open_interface: "TLOpenInterface" => OpenByIdFn,
    if_close: "IFClose" => CloseFn,
    if_update_device_list: "IFUpdateDeviceList" => UpdateFn,
    if_get_num_devices: "IFGetNumDevices" => CountFn,
    if_get_device_id: "IFGetDeviceID" => IdFn,
    if_get_device_info: "IFGetDeviceInfo" => unsafe extern "C" fn(Handle, *const c_char, i32, *mut i32, *mut c_void, *mut usize) -> GcError,
    if_open_device: "IFOpenDevice" => unsafe extern "C" fn(Handle, *const c_char, i32, *mut Handle) -> GcError,
    dev_get_port: "DevGetPort" => unsafe extern "C" fn(Handle, *mut Handle) -> GcError,
    dev_get_num_data_streams: "DevGetNumDataStreams" => CountFn,
    dev_get_data_stream_id: "DevGetDataStreamID" => IdFn,
    dev_open_data_stream: "DevOpenDataStream" => OpenByIdFn,
    dev_close: "DevClose" => CloseFn,
    ds_announce_buffer: "DSAnnounceBuffer" => unsafe extern "C" fn(Handle, *mut c_void, usize, *mut c_void, *mut Handle) -> GcError,
    ds_flush_queue: "DSFlushQueue" => unsafe extern "C" fn(Handle, i32) -> GcError,
    ds_start_acquisition: "DSStartAcquisition" => unsafe extern "C" fn(Handle, i32, u64) -> GcError,
    ds_stop_acquisition: "DSStopAcquisition" => unsafe extern "C" fn(Handle, i32) -> GcError,
    ds_get_info: "DSGetInfo" => InfoFn,
    ds_close: "DSClose" => CloseFn,
    ds_revoke_buffer: "DSRevokeBuffer" => unsafe extern "C" fn(Handle, Handle, *mut *mut c_void, *mut *mut c_void) -> GcError,
    ds_queue_buffer: "DSQueueBuffer" => unsafe extern "C" fn(Handle, Handle) -> GcError,
    ds_get_buffer_info: "DSGetBufferInfo" => unsafe extern "C" fn(Handle, Handle, i32, *mut i32, *mut c_void, *mut usize) -> GcError,
    ds_get_num_buffer_parts: "DSGetNumBufferParts" => unsafe extern "C" fn(Handle, Handle, *mut u32) -> GcError,
    ds_get_buffer_part_info: "DSGetBufferPartInfo" => unsafe extern "C" fn(Handle, Handle, u32, i32, *mut i32, *mut c_void, *mut usize) -> GcError,
}
