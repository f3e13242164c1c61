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

mod stream;

pub(crate) use stream::{Delivery, Part, Stream};

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
