//! Safe wrappers over a GenTL producer's modules: the library (`GCInitLib`), the system
//! (`TLOpen`), interfaces, devices, the remote device's port and data streams. Each module closes
//! its handle on drop and keeps its parent alive, so they close in reverse order. The library
//! and system are shared between threads (`Arc`); an interface, its device and stream belong
//! to the one thread that opened them (`Rc`).
//!
//! Every value the producer returns is checked (error codes, sizes, null handles, pointers
//! into our buffers) before it is used: a broken producer gives [`GentlError::Garbage`] or
//! [`GentlError::Call`], never undefined behaviour we can avoid.

use std::ffi::{c_char, c_void, CString};
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;

use handeye_gige::genicam::{load_xml, RegisterPort, XmlUrl};

use crate::error::{GentlError, Result};
use crate::ffi::{self, err, info_type, Api, GcError, Handle};
use crate::host::watched;

/// Longest string accepted from a producer (ids, names, URLs), bytes: a path's length limit.
const MAX_STRING: usize = 4096;
/// How long the producer may take to update its interface and device lists.
const LIST_TIMEOUT: Duration = Duration::from_secs(2);

/// A loaded and initialised producer (`GCInitLib` done; `GCCloseLib` on drop).
pub(crate) struct Lib {
    pub(crate) api: Api,
    pub(crate) path: PathBuf,
    /// The one system module of this producer (GenTL allows one `TLOpen` per process).
    system: Mutex<Weak<System>>,
}

impl std::fmt::Debug for Lib {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Lib").field("path", &self.path).finish()
    }
}

/// Producers loaded in this process: a producer is initialised once (`GCInitLib` twice is an
/// error) and shared by every camera and probe that names it.
static LOADED: Mutex<Vec<Weak<Lib>>> = Mutex::new(Vec::new());

impl Lib {
    /// Load and initialise the producer at `path`, or share the one loaded already.
    pub(crate) fn load(path: &Path) -> Result<Arc<Self>> {
        let path = path.canonicalize().map_err(|e| GentlError::Load {
            path: path.to_owned(),
            detail: e.to_string(),
        })?;
        let mut loaded = LOADED.lock().unwrap_or_else(|p| p.into_inner());
        loaded.retain(|w| w.strong_count() > 0);
        if let Some(lib) = loaded
            .iter()
            .filter_map(Weak::upgrade)
            .find(|l| l.path == path)
        {
            return Ok(lib);
        }
        let api = watched("dlopen (the producer's initialisers)", None, || {
            Api::load(&path)
        })?;
        // SAFETY: GCInitLib takes no arguments; the function pointer comes from the loaded
        // library, which `api` keeps loaded.
        let code = watched("GCInitLib", None, || unsafe { (api.gc_init_lib)() });
        if code != err::SUCCESS {
            // Not initialised: no Lib (whose drop runs GCCloseLib) is made.
            return Err(api_error(&api, "GCInitLib", code));
        }
        let lib = Arc::new(Self {
            api,
            path,
            system: Mutex::new(Weak::new()),
        });
        loaded.push(Arc::downgrade(&lib));
        Ok(lib)
    }

    /// An error for `function` having returned `code`.
    pub(crate) fn error(&self, function: &'static str, code: GcError) -> GentlError {
        api_error(&self.api, function, code)
    }
    /// `Ok` when `code` is success, else the producer's error.
    pub(crate) fn check(&self, function: &'static str, code: GcError) -> Result<()> {
        if code == err::SUCCESS {
            Ok(())
        } else {
            Err(self.error(function, code))
        }
    }

    /// The system module (`TLOpen`), shared while anyone holds it.
    pub(crate) fn system(self: &Arc<Self>) -> Result<Arc<System>> {
        let mut slot = self.system.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(s) = slot.upgrade() {
            return Ok(s);
        }
        let mut handle: Handle = std::ptr::null_mut();
        // SAFETY: `handle` is a valid out-pointer for one handle.
        let code = watched("TLOpen", None, || unsafe {
            (self.api.tl_open)(&mut handle)
        });
        self.check("TLOpen", code)?;
        non_null("TLOpen", handle)?;
        let s = Arc::new(System {
            lib: Arc::clone(self),
            handle,
        });
        *slot = Arc::downgrade(&s);
        Ok(s)
    }
}

impl Drop for Lib {
    fn drop(&mut self) {
        // SAFETY: every module holds an `Arc<Lib>`, so all handles are closed by now.
        let code = unsafe { (self.api.gc_close_lib)() };
        if code != err::SUCCESS {
            tracing::warn!(code, "GCCloseLib failed");
        }
    }
}

/// The producer's text for its last error (`GCGetLastError`), or "".
fn last_error_text(api: &Api) -> String {
    let mut code: GcError = 0;
    let mut buf = vec![0u8; 1024];
    let mut size = buf.len();
    // SAFETY: `buf` is writable for `size` bytes and `code` for one GC_ERROR, as the
    // function's contract requires.
    let r =
        unsafe { (api.gc_get_last_error)(&mut code, buf.as_mut_ptr().cast::<c_char>(), &mut size) };
    if r != err::SUCCESS {
        return String::new();
    }
    c_string(&buf, size)
}

/// An error for `function` having returned `code`, with the producer's text.
fn api_error(api: &Api, function: &'static str, code: GcError) -> GentlError {
    let text = last_error_text(api);
    GentlError::Call {
        function,
        code,
        name: err::name(code),
        message: if text.is_empty() {
            String::new()
        } else {
            format!(": {text}")
        },
    }
}

fn non_null(function: &'static str, h: Handle) -> Result<Handle> {
    if h.is_null() {
        Err(GentlError::garbage(function, "a null handle with success"))
    } else {
        Ok(h)
    }
}

/// Text up to `size` bytes (and the first NUL) of a C string buffer, control characters removed.
fn c_string(buf: &[u8], size: usize) -> String {
    let bytes = &buf[..size.min(buf.len())];
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    handeye_hal::limits::sanitize_message(&String::from_utf8_lossy(&bytes[..end]))
}

/// Call an info function `f(type, buffer, size)` into a buffer that grows as the producer asks
/// (up to [`MAX_STRING`]); returns the type and the bytes written.
fn query_bytes(
    lib: &Lib,
    function: &'static str,
    mut f: impl FnMut(*mut i32, *mut c_void, *mut usize) -> GcError,
) -> Result<(i32, Vec<u8>)> {
    let mut cap = 256;
    loop {
        let mut buf = vec![0u8; cap];
        let mut size = cap;
        let mut ty = 0i32;
        let code = f(&mut ty, buf.as_mut_ptr().cast(), &mut size);
        if code == err::BUFFER_TOO_SMALL && cap < MAX_STRING {
            cap = size.clamp(cap * 2, MAX_STRING);
            continue;
        }
        lib.check(function, code)?;
        if size > cap {
            return Err(GentlError::garbage(
                function,
                format!("wrote {size} bytes into a buffer of {cap}"),
            ));
        }
        buf.truncate(size);
        return Ok((ty, buf));
    }
}

/// A string info value.
fn query_string(
    lib: &Lib,
    function: &'static str,
    f: impl FnMut(*mut i32, *mut c_void, *mut usize) -> GcError,
) -> Result<String> {
    let (_, b) = query_bytes(lib, function, f)?;
    Ok(c_string(&b, b.len()))
}

/// A numeric info value (any integer, size or pointer type) as u64.
fn query_number(
    lib: &Lib,
    function: &'static str,
    mut f: impl FnMut(*mut i32, *mut c_void, *mut usize) -> GcError,
) -> Result<u64> {
    let mut buf = [0u8; 8];
    let mut size = buf.len();
    let mut ty = 0i32;
    let code = f(&mut ty, buf.as_mut_ptr().cast(), &mut size);
    lib.check(function, code)?;
    let v = match (ty, size) {
        (info_type::BOOL8, 1) => u64::from(buf[0] != 0),
        (info_type::INT32 | info_type::UINT32, 4) => {
            u64::from(u32::from_ne_bytes([buf[0], buf[1], buf[2], buf[3]]))
        }
        (
            info_type::INT64
            | info_type::UINT64
            | info_type::SIZET
            | info_type::PTR
            | info_type::PTRDIFF,
            8,
        ) => u64::from_ne_bytes(buf),
        // Some producers leave the type unset: trust a plausible size.
        (_, 8) => u64::from_ne_bytes(buf),
        (_, 4) => u64::from(u32::from_ne_bytes([buf[0], buf[1], buf[2], buf[3]])),
        (_, 1) => u64::from(buf[0]),
        (ty, size) => {
            return Err(GentlError::garbage(
                function,
                format!("a number of type {ty} and {size} bytes"),
            ))
        }
    };
    Ok(v)
}

/// An id by index (`TLGetInterfaceID`, `IFGetDeviceID`, `DevGetDataStreamID`).
fn query_id(
    lib: &Lib,
    function: &'static str,
    mut f: impl FnMut(*mut c_char, *mut usize) -> GcError,
) -> Result<String> {
    let s = query_string(lib, function, |_, buf, size| f(buf.cast(), size))?;
    if s.is_empty() {
        return Err(GentlError::garbage(function, "an empty id"));
    }
    Ok(s)
}

fn c_id(function: &'static str, id: &str) -> Result<CString> {
    CString::new(id).map_err(|_| GentlError::garbage(function, "an id with a NUL inside"))
}

/// A count, bounded (`TLGetNumInterfaces`, `IFGetNumDevices`, …).
fn query_count(
    lib: &Lib,
    function: &'static str,
    max: u32,
    f: impl FnOnce(*mut u32) -> GcError,
) -> Result<u32> {
    let mut n = 0u32;
    lib.check(function, f(&mut n))?;
    if n > max {
        return Err(GentlError::garbage(
            function,
            format!("{n} (at most {max} expected)"),
        ));
    }
    Ok(n)
}

/// The system module of a producer.
pub(crate) struct System {
    lib: Arc<Lib>,
    handle: Handle,
}

// SAFETY: the GenTL standard requires a producer's functions to be thread-safe; the handle is
// an opaque token that this type only passes back to the producer.
unsafe impl Send for System {}
// SAFETY: as above; no method mutates Rust-side state.
unsafe impl Sync for System {}

impl std::fmt::Debug for System {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("System")
            .field("lib", &self.lib.path)
            .finish()
    }
}

impl Drop for System {
    fn drop(&mut self) {
        // SAFETY: the handle came from TLOpen and every interface holding it is gone.
        let code = unsafe { (self.lib.api.tl_close)(self.handle) };
        if code != err::SUCCESS {
            tracing::warn!(code, "TLClose failed");
        }
    }
}

/// What an interface tells about one of its devices.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct DeviceInfo {
    /// The producer's device id (unique within the interface).
    pub id: String,
    /// Vendor name.
    pub vendor: String,
    /// Model name.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// Device version.
    pub version: String,
    /// Transport layer technology (`GEV`, `U3V`, `Custom`, …).
    pub tl_type: String,
    /// A name for people.
    pub display_name: String,
}

/// Most interfaces, devices, streams or parts believed from a producer.
const MAX_ITEMS: u32 = 1024;

impl System {
    /// The producer's interface ids (after `TLUpdateInterfaceList`).
    pub(crate) fn interfaces(&self) -> Result<Vec<String>> {
        let api = &self.lib.api;
        let mut changed = 0u8;
        // SAFETY: a valid system handle and an out-pointer for one bool8.
        let code = watched("TLUpdateInterfaceList", None, || unsafe {
            (api.tl_update_interface_list)(
                self.handle,
                &mut changed,
                LIST_TIMEOUT.as_millis() as u64,
            )
        });
        self.lib.check("TLUpdateInterfaceList", code)?;
        // SAFETY: a valid system handle and an out-pointer for one u32.
        let n = query_count(&self.lib, "TLGetNumInterfaces", MAX_ITEMS, |n| unsafe {
            (api.tl_get_num_interfaces)(self.handle, n)
        })?;
        (0..n)
            .map(|i| {
                query_id(&self.lib, "TLGetInterfaceID", |buf, size| {
                    // SAFETY: `buf` is writable for `*size` bytes (query_bytes' buffer).
                    unsafe { (api.tl_get_interface_id)(self.handle, i, buf, size) }
                })
            })
            .collect()
    }

    /// Open an interface by id.
    pub(crate) fn open_interface(self: &Arc<Self>, id: &str) -> Result<Interface> {
        let cid = c_id("TLOpenInterface", id)?;
        let mut handle: Handle = std::ptr::null_mut();
        // SAFETY: a valid system handle, a NUL-terminated id and an out-pointer for a handle.
        let code = watched("TLOpenInterface", None, || unsafe {
            (self.lib.api.tl_open_interface)(self.handle, cid.as_ptr(), &mut handle)
        });
        self.lib.check("TLOpenInterface", code)?;
        Ok(Interface {
            system: Arc::clone(self),
            handle: non_null("TLOpenInterface", handle)?,
        })
    }
}

/// An open interface.
pub(crate) struct Interface {
    system: Arc<System>,
    handle: Handle,
}

impl Drop for Interface {
    fn drop(&mut self) {
        // SAFETY: the handle came from TLOpenInterface and its devices are closed (they hold
        // an Arc of this interface).
        let code = unsafe { (self.system.lib.api.if_close)(self.handle) };
        if code != err::SUCCESS {
            tracing::warn!(code, "IFClose failed");
        }
    }
}

impl Interface {
    fn lib(&self) -> &Lib {
        &self.system.lib
    }

    /// The interface's devices (after `IFUpdateDeviceList`), with what it tells about them; at
    /// most `limit` (what is left of the bound on all interfaces' devices together).
    pub(crate) fn devices(&self, limit: usize) -> Result<Vec<DeviceInfo>> {
        let lib = self.lib();
        let api = &lib.api;
        let mut changed = 0u8;
        // SAFETY: a valid interface handle and an out-pointer for one bool8.
        let code = watched("IFUpdateDeviceList", None, || unsafe {
            (api.if_update_device_list)(self.handle, &mut changed, LIST_TIMEOUT.as_millis() as u64)
        });
        lib.check("IFUpdateDeviceList", code)?;
        // SAFETY: a valid interface handle and an out-pointer for one u32.
        let n = query_count(lib, "IFGetNumDevices", MAX_ITEMS, |n| unsafe {
            (api.if_get_num_devices)(self.handle, n)
        })?;
        if n as usize > limit {
            return Err(GentlError::garbage(
                "IFGetNumDevices",
                format!(
                    "{n} more devices, over the {} accepted from one producer in all \
                     interfaces together",
                    crate::device::MAX_DEVICES
                ),
            ));
        }
        let mut out = Vec::new();
        for i in 0..n {
            let id = query_id(lib, "IFGetDeviceID", |buf, size| {
                // SAFETY: `buf` is writable for `*size` bytes.
                unsafe { (api.if_get_device_id)(self.handle, i, buf, size) }
            })?;
            let cid = c_id("IFGetDeviceInfo", &id)?;
            // Optional strings: a producer may not implement every one.
            let info = |cmd: i32| {
                query_string(lib, "IFGetDeviceInfo", |ty, buf, size| {
                    // SAFETY: a valid handle, a NUL-terminated id, out-pointers for the type
                    // and size, and `buf` writable for `*size` bytes.
                    unsafe {
                        (api.if_get_device_info)(self.handle, cid.as_ptr(), cmd, ty, buf, size)
                    }
                })
                .unwrap_or_default()
            };
            out.push(DeviceInfo {
                vendor: info(ffi::device_info::VENDOR),
                model: info(ffi::device_info::MODEL),
                serial: info(ffi::device_info::SERIAL_NUMBER),
                version: info(ffi::device_info::VERSION),
                tl_type: info(ffi::device_info::TLTYPE),
                display_name: info(ffi::device_info::DISPLAYNAME),
                id,
            });
        }
        Ok(out)
    }

    /// Open a device by id, read/write for this process (`DEVICE_ACCESS_CONTROL`).
    pub(crate) fn open_device(self: &Rc<Self>, id: &str) -> Result<Device> {
        let cid = c_id("IFOpenDevice", id)?;
        let api = &self.lib().api;
        let mut handle: Handle = std::ptr::null_mut();
        // SAFETY: a valid interface handle, a NUL-terminated id and an out-pointer.
        let code = watched("IFOpenDevice", None, || unsafe {
            (api.if_open_device)(
                self.handle,
                cid.as_ptr(),
                ffi::DEVICE_ACCESS_CONTROL,
                &mut handle,
            )
        });
        self.lib().check("IFOpenDevice", code)?;
        let handle = non_null("IFOpenDevice", handle)?;
        let mut dev = Device {
            iface: Rc::clone(self),
            handle,
            port: std::ptr::null_mut(),
        };
        let mut port: Handle = std::ptr::null_mut();
        // SAFETY: a valid device handle and an out-pointer.
        let code = unsafe { (api.dev_get_port)(dev.handle, &mut port) };
        self.lib().check("DevGetPort", code)?;
        dev.port = non_null("DevGetPort", port)?;
        Ok(dev)
    }
}

/// An open device and its remote device port.
pub(crate) struct Device {
    iface: Rc<Interface>,
    handle: Handle,
    /// The remote device's register port (no handle of its own to close).
    port: Handle,
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: the handle came from IFOpenDevice; its streams hold an Arc of this device and
        // are closed.
        let code = unsafe { (self.lib().api.dev_close)(self.handle) };
        if code != err::SUCCESS {
            tracing::warn!(code, "DevClose failed");
        }
    }
}

impl Device {
    fn lib(&self) -> &Arc<Lib> {
        &self.iface.system.lib
    }

    /// Register access to the remote device (for the GenApi node map).
    pub(crate) fn remote_port(self: &Rc<Self>) -> RemotePort {
        RemotePort {
            device: Rc::clone(self),
        }
    }

    /// The remote device's GenICam XML, from the first of its port's URLs that loads (a
    /// relative `File:` path is relative to `base`, the producer's directory).
    pub(crate) fn remote_xml(self: &Rc<Self>, base: Option<&Path>) -> Result<String> {
        let lib = self.lib();
        let api = &lib.api;
        // SAFETY: a valid port handle and an out-pointer for one u32.
        let n = query_count(lib, "GCGetNumPortURLs", 16, |n| unsafe {
            (api.gc_get_num_port_urls)(self.port, n)
        })?;
        let mut errors = Vec::new();
        let mut port = self.remote_port();
        for i in 0..n {
            let url = query_string(lib, "GCGetPortURLInfo", |ty, buf, size| {
                // SAFETY: a valid port handle, out-pointers, `buf` writable for `*size` bytes.
                unsafe {
                    (api.gc_get_port_url_info)(self.port, i, ffi::URL_INFO_URL, ty, buf, size)
                }
            })?;
            let loaded = watched("reading the remote device's XML (GCReadPort)", None, || {
                XmlUrl::parse(&url).and_then(|u| {
                    load_xml(u, base, |address, length| {
                        let mut buf = vec![0u8; length];
                        port.read_mem(i64::from(address), &mut buf).map_err(|e| {
                            handeye_gige::GigeError::InvalidArgument(format!(
                                "reading the XML at 0x{address:x}: {e}"
                            ))
                        })?;
                        Ok(buf)
                    })
                })
            });
            match loaded {
                Ok(xml) => return Ok(xml),
                Err(e) => errors.push(format!("`{url}`: {e}")),
            }
        }
        Err(GentlError::garbage(
            "GCGetPortURLInfo",
            if errors.is_empty() {
                "no XML URL for the remote device".to_owned()
            } else {
                format!("no loadable XML: {}", errors.join("; "))
            },
        ))
    }

    /// Open the device's first data stream and register its new-buffer event.
    pub(crate) fn open_stream(self: &Rc<Self>) -> Result<Stream> {
        let lib = self.lib();
        let api = &lib.api;
        // SAFETY: a valid device handle and an out-pointer for one u32.
        let n = query_count(lib, "DevGetNumDataStreams", MAX_ITEMS, |n| unsafe {
            (api.dev_get_num_data_streams)(self.handle, n)
        })?;
        if n == 0 {
            return Err(GentlError::garbage(
                "DevGetNumDataStreams",
                "the device has no data stream",
            ));
        }
        let id = query_id(lib, "DevGetDataStreamID", |buf, size| {
            // SAFETY: `buf` is writable for `*size` bytes.
            unsafe { (api.dev_get_data_stream_id)(self.handle, 0, buf, size) }
        })?;
        let cid = c_id("DevOpenDataStream", &id)?;
        let mut handle: Handle = std::ptr::null_mut();
        // SAFETY: a valid device handle, a NUL-terminated id and an out-pointer.
        let code = unsafe { (api.dev_open_data_stream)(self.handle, cid.as_ptr(), &mut handle) };
        lib.check("DevOpenDataStream", code)?;
        let mut stream = Stream {
            device: Rc::clone(self),
            handle: non_null("DevOpenDataStream", handle)?,
            event: std::ptr::null_mut(),
            buffers: Vec::new(),
        };
        let mut event: Handle = std::ptr::null_mut();
        // SAFETY: a valid stream handle and an out-pointer for the event handle.
        let code =
            unsafe { (api.gc_register_event)(stream.handle, ffi::EVENT_NEW_BUFFER, &mut event) };
        lib.check("GCRegisterEvent", code)?;
        stream.event = non_null("GCRegisterEvent", event)?;
        Ok(stream)
    }
}

/// The remote device's register port, for the GenApi node map.
pub(crate) struct RemotePort {
    device: Rc<Device>,
}

impl std::fmt::Debug for RemotePort {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemotePort").finish_non_exhaustive()
    }
}

impl RegisterPort for RemotePort {
    fn read_mem(
        &mut self,
        address: i64,
        buf: &mut [u8],
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
        let lib = self.device.lib();
        let mut size = buf.len();
        // SAFETY: a valid port handle; `buf` is writable for `size` bytes.
        let code = unsafe {
            (lib.api.gc_read_port)(
                self.device.port,
                address as u64,
                buf.as_mut_ptr().cast(),
                &mut size,
            )
        };
        lib.check("GCReadPort", code)?;
        if size != buf.len() {
            return Err(Box::new(GentlError::garbage(
                "GCReadPort",
                format!("read {size} of {} bytes at 0x{address:x}", buf.len()),
            )));
        }
        Ok(())
    }

    fn write_mem(
        &mut self,
        address: i64,
        data: &[u8],
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
        let lib = self.device.lib();
        let mut size = data.len();
        // SAFETY: a valid port handle; `data` is readable for `size` bytes.
        let code = unsafe {
            (lib.api.gc_write_port)(
                self.device.port,
                address as u64,
                data.as_ptr().cast(),
                &mut size,
            )
        };
        lib.check("GCWritePort", code)?;
        if size != data.len() {
            return Err(Box::new(GentlError::garbage(
                "GCWritePort",
                format!("wrote {size} of {} bytes at 0x{address:x}", data.len()),
            )));
        }
        Ok(())
    }
}

/// One announced buffer: memory we own, lent to the producer until revoked.
struct Buffer {
    handle: Handle,
    memory: Box<[u8]>,
}

/// An open data stream with its new-buffer event and announced buffers.
pub(crate) struct Stream {
    device: Rc<Device>,
    handle: Handle,
    event: Handle,
    buffers: Vec<Buffer>,
}

/// One part of a delivered buffer, copied out of the producer's buffer.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Part {
    /// GenTL `PARTDATATYPE_ID` (1 2D image, 5 3D image, 9 confidence map, …); for a
    /// single-part buffer, 1.
    pub(crate) data_type: u64,
    /// PFNC pixel format.
    pub(crate) pixel_format: u64,
    /// Width, height, pixels.
    pub(crate) width: u64,
    pub(crate) height: u64,
    /// Padding bytes at the end of each line.
    pub(crate) padding_x: u64,
    /// Data purpose id (component), 0 when the producer does not tell.
    pub(crate) purpose: u64,
    /// The bytes.
    pub(crate) data: Vec<u8>,
}

/// What [`Stream::wait`] got.
#[derive(Debug)]
pub(crate) enum Delivery {
    /// A complete buffer's parts.
    Complete(Vec<Part>),
    /// The producer flagged the buffer incomplete (it was re-queued).
    Incomplete,
}

/// Largest buffer announced, bytes (a 12 MP camera's XYZ + RGBA + SNR is ~250 MB).
pub(crate) const MAX_PAYLOAD: u64 = 1 << 30;
/// Most memory announced to one stream, bytes.
const MAX_POOL: u64 = 2 << 30;

impl Stream {
    fn lib(&self) -> &Arc<Lib> {
        self.device.lib()
    }

    fn info(&self, cmd: i32) -> Result<u64> {
        let api = &self.lib().api;
        query_number(self.lib(), "DSGetInfo", |ty, buf, size| {
            // SAFETY: a valid stream handle; out-pointers; `buf` writable for `*size` bytes.
            unsafe { (api.ds_get_info)(self.handle, cmd, ty, buf, size) }
        })
    }

    /// Payload size the stream defines itself, if it does (`STREAM_INFO_DEFINES_PAYLOADSIZE`).
    pub(crate) fn payload_size(&self) -> Option<u64> {
        match self.info(ffi::stream_info::DEFINES_PAYLOADSIZE) {
            Ok(1) => self.info(ffi::stream_info::PAYLOAD_SIZE).ok(),
            _ => None,
        }
    }

    /// Announce `count` buffers of `size` bytes (at least what the producer asks for, at most
    /// 16 and 2 GiB in all), queue them and start acquisition.
    pub(crate) fn start(&mut self, size: u64, count: usize) -> Result<()> {
        if size == 0 || size > MAX_PAYLOAD {
            return Err(GentlError::garbage(
                "PayloadSize",
                format!("{size} bytes per buffer (at most {MAX_PAYLOAD})"),
            ));
        }
        let min = self
            .info(ffi::stream_info::BUF_ANNOUNCE_MIN)
            .unwrap_or(1)
            .min(16) as usize;
        // Bounded pool: at most 16 buffers and MAX_POOL bytes in all.
        let count = count
            .max(min)
            .clamp(1, 16)
            .min((MAX_POOL / size).max(1) as usize);
        let lib = Arc::clone(self.lib());
        let api = &lib.api;
        for _ in 0..count {
            let mut memory = vec![0u8; size as usize].into_boxed_slice();
            let mut handle: Handle = std::ptr::null_mut();
            // SAFETY: `memory` is ours, writable for `size` bytes, and stays allocated (never
            // moved: a boxed slice) until DSRevokeBuffer returns it in `stop`/drop.
            let code = unsafe {
                (api.ds_announce_buffer)(
                    self.handle,
                    memory.as_mut_ptr().cast(),
                    memory.len(),
                    std::ptr::null_mut(),
                    &mut handle,
                )
            };
            self.lib().check("DSAnnounceBuffer", code)?;
            let handle = non_null("DSAnnounceBuffer", handle)?;
            self.buffers.push(Buffer { handle, memory });
            // SAFETY: a buffer handle this stream announced.
            let code = unsafe { (api.ds_queue_buffer)(self.handle, handle) };
            self.lib().check("DSQueueBuffer", code)?;
        }
        // SAFETY: a valid stream handle with queued buffers.
        let code = watched("DSStartAcquisition", None, || unsafe {
            (api.ds_start_acquisition)(
                self.handle,
                ffi::ACQ_START_FLAGS_DEFAULT,
                ffi::GENTL_INFINITE,
            )
        });
        self.lib().check("DSStartAcquisition", code)
    }

    /// Wait up to `timeout` for the next buffer, copy its parts out and queue it again.
    /// `Ok(None)` on timeout.
    pub(crate) fn wait(&mut self, timeout: Duration) -> Result<Option<Delivery>> {
        let api = &self.lib().api;
        let mut data = ffi::EventNewBufferData {
            buffer: std::ptr::null_mut(),
            user_pointer: std::ptr::null_mut(),
        };
        let mut size = std::mem::size_of::<ffi::EventNewBufferData>();
        // SAFETY: a valid event handle; `data` is writable for `size` bytes.
        let budget = timeout + crate::camera::FRAME_GRACE;
        let code = watched("EventGetData", Some(budget), || unsafe {
            (api.event_get_data)(
                self.event,
                (&raw mut data).cast(),
                &mut size,
                timeout.as_millis().min(u128::from(u64::MAX - 1)) as u64,
            )
        });
        if code == err::TIMEOUT {
            return Ok(None);
        }
        self.lib().check("EventGetData", code)?;
        if size != std::mem::size_of::<ffi::EventNewBufferData>() {
            return Err(GentlError::garbage(
                "EventGetData",
                format!("{size} bytes of new-buffer event data"),
            ));
        }
        let handle = data.buffer;
        let Some(index) = self.buffers.iter().position(|b| b.handle == handle) else {
            return Err(GentlError::garbage(
                "EventGetData",
                "a buffer handle this stream never announced",
            ));
        };
        let read = self.read_buffer(index);
        // SAFETY: a buffer handle this stream announced, now delivered to us.
        let code = unsafe { (api.ds_queue_buffer)(self.handle, handle) };
        let parts = read?;
        self.lib().check("DSQueueBuffer", code)?;
        Ok(Some(parts))
    }

    fn buffer_number(&self, handle: Handle, cmd: i32) -> Result<u64> {
        let api = &self.lib().api;
        query_number(self.lib(), "DSGetBufferInfo", |ty, buf, size| {
            // SAFETY: valid stream and buffer handles; `buf` writable for `*size` bytes.
            unsafe { (api.ds_get_buffer_info)(self.handle, handle, cmd, ty, buf, size) }
        })
    }

    fn part_number(&self, handle: Handle, part: u32, cmd: i32) -> Result<u64> {
        let api = &self.lib().api;
        query_number(self.lib(), "DSGetBufferPartInfo", |ty, buf, size| {
            // SAFETY: valid stream and buffer handles; `buf` writable for `*size` bytes.
            unsafe { (api.ds_get_buffer_part_info)(self.handle, handle, part, cmd, ty, buf, size) }
        })
    }

    /// Copy `len` bytes at the producer's pointer `ptr` out of buffer `index`, refusing a
    /// range outside the memory we announced.
    fn copy_out(
        &self,
        index: usize,
        function: &'static str,
        ptr: u64,
        len: u64,
    ) -> Result<Vec<u8>> {
        let (o, len) = self.range_in(index, function, ptr, len)?;
        Ok(self.buffers[index].memory[o..o + len].to_vec())
    }

    /// The offset and length in buffer `index` of `len` bytes at the producer's pointer
    /// `ptr`, refusing a range outside the memory we announced.
    fn range_in(
        &self,
        index: usize,
        function: &'static str,
        ptr: u64,
        len: u64,
    ) -> Result<(usize, usize)> {
        let mem = &self.buffers[index].memory;
        let start = mem.as_ptr() as u64;
        let offset = ptr.checked_sub(start).filter(|o| {
            o.checked_add(len)
                .is_some_and(|end| end <= mem.len() as u64)
        });
        match offset {
            // Both fit in usize: within `mem`.
            Some(o) => Ok((o as usize, len as usize)),
            None => Err(GentlError::garbage(
                function,
                format!(
                    "{len} bytes at {ptr:#x}, outside the {} byte buffer at {start:#x} we announced",
                    mem.len()
                ),
            )),
        }
    }

    fn read_buffer(&self, index: usize) -> Result<Delivery> {
        let h = self.buffers[index].handle;
        if self
            .buffer_number(h, ffi::buffer_info::IS_INCOMPLETE)
            .unwrap_or(0)
            != 0
        {
            return Ok(Delivery::Incomplete);
        }
        let payload = self
            .buffer_number(h, ffi::buffer_info::PAYLOADTYPE)
            .unwrap_or(1) as usize;
        if payload == ffi::payload_type::GENDC {
            return Err(GentlError::Unsupported(
                "the producer delivers a GenDC container (GenTL payload type 11), which this \
                 driver does not read; set GenDCStreamingMode to Off (or the producer's \
                 equivalent) so that the camera sends multi-part buffers"
                    .into(),
            ));
        }
        let mut parts = Vec::new();
        if payload == ffi::payload_type::MULTI_PART {
            let api = &self.lib().api;
            // SAFETY: valid stream and buffer handles, an out-pointer for one u32.
            let n = query_count(self.lib(), "DSGetNumBufferParts", 64, |n| unsafe {
                (api.ds_get_num_buffer_parts)(self.handle, h, n)
            })?;
            // Where each part lies, checked all together before anything is copied: inside
            // the buffer and not overlapping, so the copies are at most the buffer's size.
            let mut ranges = Vec::with_capacity(n as usize);
            for i in 0..n {
                let num = |cmd| self.part_number(h, i, cmd);
                let base = num(ffi::part_info::BASE)?;
                let size = num(ffi::part_info::DATA_SIZE)?;
                ranges.push(self.range_in(index, "DSGetBufferPartInfo", base, size)?);
            }
            check_disjoint(&ranges)?;
            let mem = &self.buffers[index].memory;
            for (i, &(start, len)) in (0..n).zip(&ranges) {
                let num = |cmd| self.part_number(h, i, cmd);
                parts.push(Part {
                    data_type: num(ffi::part_info::DATA_TYPE)?,
                    pixel_format: num(ffi::part_info::DATA_FORMAT)?,
                    width: num(ffi::part_info::WIDTH)?,
                    height: num(ffi::part_info::HEIGHT)?,
                    padding_x: num(ffi::part_info::XPADDING).unwrap_or(0),
                    purpose: num(ffi::part_info::DATA_PURPOSE_ID).unwrap_or(0),
                    data: mem[start..start + len].to_vec(),
                });
            }
        } else {
            let num = |cmd| self.buffer_number(h, cmd);
            let base = num(ffi::buffer_info::BASE)?;
            let offset = num(ffi::buffer_info::IMAGEOFFSET).unwrap_or(0);
            let filled = num(ffi::buffer_info::SIZE_FILLED)?;
            let len = filled.checked_sub(offset).ok_or_else(|| {
                GentlError::garbage(
                    "DSGetBufferInfo",
                    format!("image offset {offset} past the {filled} bytes filled"),
                )
            })?;
            if payload == ffi::payload_type::CHUNK_ONLY {
                // Chunk data only: one chunk part; the decoder finds the range chunk.
                parts.push(Part {
                    data_type: ffi::PART_DATATYPE_CHUNKDATA,
                    pixel_format: 0,
                    width: 0,
                    height: 0,
                    padding_x: 0,
                    purpose: 0,
                    data: self.copy_out(index, "DSGetBufferInfo", base, filled)?,
                });
                return Ok(Delivery::Complete(parts));
            }
            parts.push(Part {
                data_type: 1,
                pixel_format: num(ffi::buffer_info::PIXELFORMAT)?,
                width: num(ffi::buffer_info::WIDTH)?,
                height: num(ffi::buffer_info::HEIGHT)?,
                padding_x: num(ffi::buffer_info::XPADDING).unwrap_or(0),
                purpose: 0,
                data: self.copy_out(index, "DSGetBufferInfo", base.saturating_add(offset), len)?,
            });
        }
        Ok(Delivery::Complete(parts))
    }

    /// Stop acquisition, discard queued buffers and revoke them all.
    pub(crate) fn stop(&mut self) -> Result<()> {
        let api = &self.lib().api;
        // SAFETY: a valid stream handle.
        let stop = watched("DSStopAcquisition", None, || unsafe {
            (api.ds_stop_acquisition)(self.handle, ffi::ACQ_STOP_FLAGS_KILL)
        });
        // SAFETY: a valid stream handle.
        let flush = watched("DSFlushQueue", None, || unsafe {
            (api.ds_flush_queue)(self.handle, ffi::ACQ_QUEUE_ALL_DISCARD)
        });
        // SAFETY: a valid event handle.
        let events = unsafe { (api.event_flush)(self.event) };
        let revoke = self.revoke();
        self.lib().check("DSStopAcquisition", stop)?;
        self.lib().check("DSFlushQueue", flush)?;
        self.lib().check("EventFlush", events)?;
        revoke
    }

    /// Revoke every announced buffer; memory the producer will not give back is leaked, never
    /// freed under it.
    fn revoke(&mut self) -> Result<()> {
        let lib = Arc::clone(self.lib());
        let api = &lib.api;
        let mut first_error = None;
        for b in std::mem::take(&mut self.buffers) {
            let mut base: *mut c_void = std::ptr::null_mut();
            let mut private: *mut c_void = std::ptr::null_mut();
            // SAFETY: a buffer handle this stream announced; out-pointers for two pointers.
            let code =
                unsafe { (api.ds_revoke_buffer)(self.handle, b.handle, &mut base, &mut private) };
            if code != err::SUCCESS {
                // The producer may still write into it: keep it allocated for the process' life.
                std::mem::forget(b.memory);
                first_error.get_or_insert_with(|| self.lib().error("DSRevokeBuffer", code));
            }
        }
        first_error.map_or(Ok(()), Err)
    }
}

impl Drop for Stream {
    fn drop(&mut self) {
        if !self.buffers.is_empty() {
            if let Err(e) = self.stop() {
                tracing::warn!("closing the GenTL stream: {e}");
            }
        }
        let api = &self.lib().api;
        if !self.event.is_null() {
            // SAFETY: the stream handle is valid and the event was registered on it.
            let code = unsafe { (api.gc_unregister_event)(self.handle, ffi::EVENT_NEW_BUFFER) };
            if code != err::SUCCESS {
                tracing::warn!(code, "GCUnregisterEvent failed");
            }
        }
        // SAFETY: the handle came from DevOpenDataStream; all its buffers are revoked.
        let code = unsafe { (api.ds_close)(self.handle) };
        if code != err::SUCCESS {
            tracing::warn!(code, "DSClose failed");
        }
    }
}

/// Parts of one buffer must not overlap (ranges are offset and length): a producer whose 64
/// parts each cover the whole buffer would otherwise have it copied 64 times.
fn check_disjoint(ranges: &[(usize, usize)]) -> Result<()> {
    let mut sorted: Vec<(usize, usize)> = ranges.iter().copied().filter(|r| r.1 > 0).collect();
    sorted.sort_unstable();
    for w in sorted.windows(2) {
        let ((a, a_len), (b, b_len)) = (w[0], w[1]);
        if a + a_len > b {
            return Err(GentlError::garbage(
                "DSGetBufferPartInfo",
                format!(
                    "parts that overlap: {a_len} bytes at offset {a} and {b_len} bytes at \
                     offset {b} of the buffer"
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 46: parts must not overlap (64 parts each covering the whole buffer are
    /// refused, not copied 64 times); adjacent and empty parts pass.
    #[test]
    fn issue_46_overlapping_parts_are_refused() {
        assert!(check_disjoint(&[(0, 10), (10, 5), (15, 0), (15, 1)]).is_ok());
        assert!(check_disjoint(&[(20, 4), (0, 20)]).is_ok(), "any order");
        let whole = vec![(0, 1 << 20); 64];
        let e = check_disjoint(&whole).expect_err("64 whole").to_string();
        assert!(
            e.contains("parts that overlap: 1048576 bytes at offset 0"),
            "{e}"
        );
        let e = check_disjoint(&[(0, 10), (9, 2)])
            .expect_err("one byte")
            .to_string();
        assert!(e.contains("offset 9"), "{e}");
    }
}
