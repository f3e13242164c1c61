//! Ports: the remote device's registers and XML URL, the modules' port info.

use super::*;

// ---------------------------------------------------------------------------------------
// Ports: the remote device's registers; the GenTL modules' own ports hold their SFNC node
// maps (`nodemaps`).

fn remote(p: &Producer, port: *mut c_void) -> Res {
    match p.get(port)? {
        Module::RemotePort => Ok(()),
        _ => Err(Fail::new(
            err::NOT_AVAILABLE,
            "this module's port has no registers (only the remote device's port does)",
        )),
    }
}

/// The port's XML URL: the remote device's, or a module's node map.
fn port_url(p: &Producer, port: *mut c_void) -> Res<String> {
    match nodemaps::Kind::of(p.get(port)?) {
        Some(kind) => Ok(nodemaps::url(&kind)),
        None => {
            remote(p, port)?;
            Ok(p.camera()?.device.xml_url())
        }
    }
}

fn port_error(e: PortError, address: u64) -> Fail {
    let code = match e {
        PortError::InvalidAddress => err::INVALID_ADDRESS,
        PortError::AccessDenied => err::ACCESS_DENIED,
        _ => err::INVALID_VALUE,
    };
    Fail::new(code, format!("register 0x{address:x}: {e}"))
}

/// # Safety
/// `buf` writable for `*size` bytes; `size` valid.
#[no_mangle]
pub unsafe extern "C" fn GCReadPort(
    port: *mut c_void,
    address: u64,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        let module = nodemaps::Kind::of(p.get(port)?);
        if module.is_none() {
            remote(p, port)?;
        }
        if buf.is_null() || size.is_null() {
            return Err(Fail::new(
                err::INVALID_PARAMETER,
                "pBuffer or piSize is NULL",
            ));
        }
        // SAFETY: the caller's buffer of `*size` bytes (GenTL contract).
        let dst = unsafe { std::slice::from_raw_parts_mut(buf.cast::<u8>(), *size) };
        if let Some(kind) = module {
            return nodemaps::read(p, &kind, address, dst);
        }
        p.camera()?
            .device
            .read(address, dst)
            .map_err(|e| port_error(e, address))?;
        // camera.xml's Scan3dCoordinateScale and Scan3dCoordinateOffset (f64, big-endian).
        for (reg, fault, value) in [
            (0xA100, "scale-zero", 0.0f64),
            (0xA108, "offset-1e30", 1e30),
        ] {
            if address == reg && dst.len() == 8 && crate::faults::on(fault) {
                dst.copy_from_slice(&value.to_be_bytes());
            }
        }
        Ok(())
    })
}

/// # Safety
/// `buf` readable for `*size` bytes; `size` valid.
#[no_mangle]
pub unsafe extern "C" fn GCWritePort(
    port: *mut c_void,
    address: u64,
    buf: *const c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        let module = nodemaps::Kind::of(p.get(port)?);
        if module.is_none() {
            remote(p, port)?;
        }
        if buf.is_null() || size.is_null() {
            return Err(Fail::new(
                err::INVALID_PARAMETER,
                "pBuffer or piSize is NULL",
            ));
        }
        // SAFETY: the caller's buffer of `*size` bytes (GenTL contract).
        let src = unsafe { std::slice::from_raw_parts(buf.cast::<u8>(), *size) };
        if let Some(kind) = module {
            return nodemaps::write(&kind, address, src);
        }
        // camera.xml's AcquisitionStartReg.
        if address == 0xA014 {
            crate::faults::at("AcquisitionStart");
        }
        p.camera()?
            .device
            .write(address, src)
            .map_err(|e| port_error(e, address))
    })
}

/// `PORT_REGISTER_STACK_ENTRY`.
#[repr(C)]
#[derive(Debug)]
pub struct PortRegisterStackEntry {
    pub(crate) address: u64,
    pub(crate) buffer: *mut c_void,
    pub(crate) size: usize,
}

/// # Safety
/// `entries` holds `*n` entries, each with a buffer of its size.
#[no_mangle]
pub unsafe extern "C" fn GCReadPortStacked(
    port: *mut c_void,
    entries: *mut PortRegisterStackEntry,
    n: *mut usize,
) -> GcError {
    // SAFETY: the caller's entries; each entry's buffer is writable for its size.
    unsafe {
        stacked(port, entries, n, |port, e, size| {
            GCReadPort(port, e.address, e.buffer, size)
        })
    }
}

/// # Safety
/// `entries` holds `*n` entries, each with a buffer of its size.
#[no_mangle]
pub unsafe extern "C" fn GCWritePortStacked(
    port: *mut c_void,
    entries: *mut PortRegisterStackEntry,
    n: *mut usize,
) -> GcError {
    // SAFETY: the caller's entries; each entry's buffer is readable for its size.
    unsafe {
        stacked(port, entries, n, |port, e, size| {
            GCWritePort(port, e.address, e.buffer, size)
        })
    }
}

/// `access` on each of the `*n` `entries` in order, stopping at the first error.
///
/// # Safety
/// `entries` null or holding `*n` entries; `access` is sound for each entry's buffer.
unsafe fn stacked(
    port: *mut c_void,
    entries: *mut PortRegisterStackEntry,
    n: *mut usize,
    access: impl Fn(*mut c_void, &PortRegisterStackEntry, *mut usize) -> GcError,
) -> GcError {
    if entries.is_null() || n.is_null() {
        return call(|_| Err(Fail::new(err::INVALID_PARAMETER, "NULL argument")));
    }
    // SAFETY: the caller's `*n` entries.
    let list = unsafe { std::slice::from_raw_parts_mut(entries, *n) };
    for e in list {
        let mut size = e.size;
        let code = access(port, e, &mut size);
        if code != err::SUCCESS {
            return code;
        }
    }
    err::SUCCESS
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn GCGetPortInfo(
    port: *mut c_void,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        let m = p.get(port)?;
        let (module, name) = match m {
            Module::System => ("TLSystem", "TLPort"),
            Module::Interface => ("TLInterface", "TLPort"),
            Module::Device => ("TLDevice", "TLPort"),
            Module::RemotePort => ("Device", "Device"),
            Module::Stream(_) => ("TLDataStream", "TLPort"),
            Module::Buffer => ("TLBuffer", "TLPort"),
            Module::Event(_) => {
                return Err(Fail::new(
                    err::INVALID_HANDLE,
                    "an event handle is not a port",
                ))
            }
        };
        let remote = matches!(m, Module::RemotePort);
        let info = match cmd {
            0 => Info::Str(if remote {
                p.device_id().to_string()
            } else {
                TL_ID.into()
            }),
            1 => Info::Str(p.options.vendor.clone()),
            2 => Info::Str(p.options.model.clone()),
            3 => Info::Str(TL_TYPE.into()),
            4 => Info::Str(module.into()),
            5 => Info::Bool(false),
            6 => Info::Bool(remote),
            7 | 8 => Info::Bool(remote),
            9 => Info::Bool(false),
            10 => Info::Bool(!remote),
            11 => Info::Str(p.options.version.clone()),
            12 => Info::Str(name.into()),
            _ => return Err(unknown_cmd("PORT_INFO_CMD", cmd)),
        };
        // SAFETY: the caller's pointers.
        unsafe { info.write(ty, buf, size) }
    })
}

/// # Safety
/// `n` writable.
#[no_mangle]
pub unsafe extern "C" fn GCGetNumPortURLs(port: *mut c_void, n: *mut u32) -> GcError {
    call(|p| {
        port_url(p, port)?;
        // SAFETY: the caller's out-pointer.
        unsafe { out(n, 1, "piNumURLs") }
    })
}

/// # Safety
/// `url` writable for `*size` bytes or null; `size` valid.
#[no_mangle]
pub unsafe extern "C" fn GCGetPortURL(
    port: *mut c_void,
    url: *mut c_char,
    size: *mut usize,
) -> GcError {
    call(|p| {
        let u = port_url(p, port)?;
        // SAFETY: the caller's pointers.
        unsafe { Info::Str(u).write(std::ptr::null_mut(), url.cast(), size) }
    })
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn GCGetPortURLInfo(
    port: *mut c_void,
    index: u32,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        let url = port_url(p, port)?;
        if index != 0 {
            return Err(Fail::new(
                err::INVALID_INDEX,
                "a port has one URL (index 0)",
            ));
        }
        // `Local:NAME;ADDRESS;LENGTH` (hex).
        let mut fields = url.split_once(':').map_or("", |(_, rest)| rest).split(';');
        let name = fields.next().unwrap_or_default().to_string();
        let hex = |s: Option<&str>| u64::from_str_radix(s.unwrap_or_default(), 16).unwrap_or(0);
        let (address, length) = (hex(fields.next()), hex(fields.next()));
        let info = match cmd {
            0 => Info::Str(url),
            1 => Info::I32(1),
            2 => Info::I32(1),
            3 => Info::I32(1),
            4 | 5 => Info::I32(0),
            7 => Info::U64(address),
            8 => Info::U64(length),
            9 => Info::I32(0),
            10 => Info::Str(name),
            _ => return Err(Fail::new(err::NOT_AVAILABLE, format!("URL_INFO_CMD {cmd}"))),
        };
        // SAFETY: the caller's pointers.
        unsafe { info.write(ty, buf, size) }
    })
}
