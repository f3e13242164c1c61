//! The system, interface and device modules: enumeration, opening and closing, their info.

use super::*;

// ---------------------------------------------------------------------------------------
// System

/// # Safety
/// `tl` writable.
#[no_mangle]
pub unsafe extern "C" fn TLOpen(tl: *mut *mut c_void) -> GcError {
    call(|p| {
        if p.system.is_some() {
            return Err(Fail::new(
                err::RESOURCE_IN_USE,
                "the system module is open already",
            ));
        }
        let h = p.add(Module::System);
        p.system = Some(h);
        // SAFETY: the caller's out-pointer.
        unsafe { out(tl, h as *mut c_void, "phSystem") }
    })
}

#[no_mangle]
pub extern "C" fn TLClose(tl: *mut c_void) -> GcError {
    call(|p| {
        p.expect(tl, "system", |m| matches!(m, Module::System))?;
        p.close_device();
        for h in [p.interface.take(), p.system.take()].into_iter().flatten() {
            p.handles.remove(&h);
        }
        Ok(())
    })
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn TLGetInfo(
    tl: *mut c_void,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        p.expect(tl, "system", |m| matches!(m, Module::System))?;
        // SAFETY: the caller's pointers.
        unsafe { tl_info(cmd)?.write(ty, buf, size) }
    })
}

/// # Safety
/// `changed` null or writable.
#[no_mangle]
pub unsafe extern "C" fn TLUpdateInterfaceList(
    tl: *mut c_void,
    changed: *mut u8,
    _timeout_ms: u64,
) -> GcError {
    call(|p| {
        p.expect(tl, "system", |m| matches!(m, Module::System))?;
        if !changed.is_null() {
            // SAFETY: checked non-null; the caller's.
            unsafe { *changed = 0 };
        }
        Ok(())
    })
}

/// # Safety
/// `n` writable.
#[no_mangle]
pub unsafe extern "C" fn TLGetNumInterfaces(tl: *mut c_void, n: *mut u32) -> GcError {
    call(|p| {
        p.expect(tl, "system", |m| matches!(m, Module::System))?;
        let count = if crate::faults::on("many-devices") {
            2
        } else {
            1
        };
        // SAFETY: the caller's out-pointer.
        unsafe { out(n, count, "piNumIfaces") }
    })
}

/// # Safety
/// `id` writable for `*size` bytes or null; `size` valid.
#[no_mangle]
pub unsafe extern "C" fn TLGetInterfaceID(
    tl: *mut c_void,
    index: u32,
    id: *mut c_char,
    size: *mut usize,
) -> GcError {
    call(|p| {
        p.expect(tl, "system", |m| matches!(m, Module::System))?;
        if index != 0 && !crate::faults::on("many-devices") {
            return Err(Fail::new(
                err::INVALID_INDEX,
                "there is one interface (index 0)",
            ));
        }
        // SAFETY: the caller's pointers.
        unsafe { Info::Str(IF_ID.into()).write(std::ptr::null_mut(), id.cast(), size) }
    })
}

/// # Safety
/// `id` a NUL-terminated string; GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn TLGetInterfaceInfo(
    tl: *mut c_void,
    id: *const c_char,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        p.expect(tl, "system", |m| matches!(m, Module::System))?;
        // SAFETY: the caller's string.
        if unsafe { arg_str(id, "sIfaceID") }? != IF_ID {
            return Err(Fail::new(
                err::INVALID_ID,
                format!("no interface but `{IF_ID}`"),
            ));
        }
        // SAFETY: the caller's pointers.
        unsafe { if_info(cmd)?.write(ty, buf, size) }
    })
}

/// # Safety
/// `id` a NUL-terminated string; `iface` writable.
#[no_mangle]
pub unsafe extern "C" fn TLOpenInterface(
    tl: *mut c_void,
    id: *const c_char,
    iface: *mut *mut c_void,
) -> GcError {
    call(|p| {
        p.expect(tl, "system", |m| matches!(m, Module::System))?;
        // SAFETY: the caller's string.
        if unsafe { arg_str(id, "sIfaceID") }? != IF_ID {
            return Err(Fail::new(
                err::INVALID_ID,
                format!("no interface but `{IF_ID}`"),
            ));
        }
        if p.interface.is_some() {
            return Err(Fail::new(
                err::RESOURCE_IN_USE,
                "the interface is open already",
            ));
        }
        let h = p.add(Module::Interface);
        p.interface = Some(h);
        // SAFETY: the caller's out-pointer.
        unsafe { out(iface, h as *mut c_void, "phIface") }
    })
}

// ---------------------------------------------------------------------------------------
// Interface

#[no_mangle]
pub extern "C" fn IFClose(iface: *mut c_void) -> GcError {
    call(|p| {
        p.expect(iface, "interface", |m| matches!(m, Module::Interface))?;
        p.close_device();
        if let Some(h) = p.interface.take() {
            p.handles.remove(&h);
        }
        Ok(())
    })
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn IFGetInfo(
    iface: *mut c_void,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        p.expect(iface, "interface", |m| matches!(m, Module::Interface))?;
        // SAFETY: the caller's pointers.
        unsafe { if_info(cmd)?.write(ty, buf, size) }
    })
}

/// # Safety
/// `tl` writable.
#[no_mangle]
pub unsafe extern "C" fn IFGetParentTL(iface: *mut c_void, tl: *mut *mut c_void) -> GcError {
    call(|p| {
        p.expect(iface, "interface", |m| matches!(m, Module::Interface))?;
        let h = p.system.unwrap_or(0);
        // SAFETY: the caller's out-pointer.
        unsafe { out(tl, h as *mut c_void, "phSystem") }
    })
}

/// # Safety
/// `changed` null or writable.
#[no_mangle]
pub unsafe extern "C" fn IFUpdateDeviceList(
    iface: *mut c_void,
    changed: *mut u8,
    _timeout_ms: u64,
) -> GcError {
    call(|p| {
        p.expect(iface, "interface", |m| matches!(m, Module::Interface))?;
        if !changed.is_null() {
            // SAFETY: checked non-null; the caller's.
            unsafe { *changed = 0 };
        }
        Ok(())
    })
}

/// # Safety
/// `n` writable.
#[no_mangle]
pub unsafe extern "C" fn IFGetNumDevices(iface: *mut c_void, n: *mut u32) -> GcError {
    call(|p| {
        p.expect(iface, "interface", |m| matches!(m, Module::Interface))?;
        let count = if crate::faults::on("many-devices") {
            1024
        } else {
            1
        };
        // SAFETY: the caller's out-pointer.
        unsafe { out(n, count, "piNumDevices") }
    })
}

/// # Safety
/// `id` writable for `*size` bytes or null; `size` valid.
#[no_mangle]
pub unsafe extern "C" fn IFGetDeviceID(
    iface: *mut c_void,
    index: u32,
    id: *mut c_char,
    size: *mut usize,
) -> GcError {
    call(|p| {
        p.expect(iface, "interface", |m| matches!(m, Module::Interface))?;
        if index != 0 && !crate::faults::on("many-devices") {
            return Err(Fail::new(
                err::INVALID_INDEX,
                "there is one device (index 0)",
            ));
        }
        let dev = p.device_id().to_string();
        // SAFETY: the caller's pointers.
        unsafe { Info::Str(dev).write(std::ptr::null_mut(), id.cast(), size) }
    })
}

fn check_device_id(p: &Producer, id: *const c_char) -> Res {
    // SAFETY: the caller's NUL-terminated string (GenTL contract).
    let id = unsafe { arg_str(id, "sDeviceID") }?;
    if id == p.device_id() {
        Ok(())
    } else {
        Err(Fail::new(
            err::INVALID_ID,
            format!("no device `{id}`; this producer has `{}`", p.device_id()),
        ))
    }
}

/// # Safety
/// `id` a NUL-terminated string; GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn IFGetDeviceInfo(
    iface: *mut c_void,
    id: *const c_char,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        p.expect(iface, "interface", |m| matches!(m, Module::Interface))?;
        check_device_id(p, id)?;
        // SAFETY: the caller's pointers.
        unsafe { p.device_info(cmd)?.write(ty, buf, size) }
    })
}

/// # Safety
/// `id` a NUL-terminated string; `dev` writable.
#[no_mangle]
pub unsafe extern "C" fn IFOpenDevice(
    iface: *mut c_void,
    id: *const c_char,
    _access: i32,
    dev: *mut *mut c_void,
) -> GcError {
    call(|p| {
        p.expect(iface, "interface", |m| matches!(m, Module::Interface))?;
        check_device_id(p, id)?;
        if p.device.is_some() {
            return Err(Fail::new(
                err::RESOURCE_IN_USE,
                "the device is open already",
            ));
        }
        p.open_device()?;
        let h = p.add(Module::Device);
        p.device = Some(h);
        let r = p.add(Module::RemotePort);
        p.remote = Some(r);
        // SAFETY: the caller's out-pointer.
        unsafe { out(dev, h as *mut c_void, "phDevice") }
    })
}

// ---------------------------------------------------------------------------------------
// Device

#[no_mangle]
pub extern "C" fn DevClose(dev: *mut c_void) -> GcError {
    call(|p| {
        p.expect(dev, "device", |m| matches!(m, Module::Device))?;
        p.close_device();
        Ok(())
    })
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn DevGetInfo(
    dev: *mut c_void,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        p.expect(dev, "device", |m| matches!(m, Module::Device))?;
        // SAFETY: the caller's pointers.
        unsafe { p.device_info(cmd)?.write(ty, buf, size) }
    })
}

/// # Safety
/// `iface` writable.
#[no_mangle]
pub unsafe extern "C" fn DevGetParentIF(dev: *mut c_void, iface: *mut *mut c_void) -> GcError {
    call(|p| {
        p.expect(dev, "device", |m| matches!(m, Module::Device))?;
        let h = p.interface.unwrap_or(0);
        // SAFETY: the caller's out-pointer.
        unsafe { out(iface, h as *mut c_void, "phIface") }
    })
}

/// # Safety
/// `port` writable.
#[no_mangle]
pub unsafe extern "C" fn DevGetPort(dev: *mut c_void, port: *mut *mut c_void) -> GcError {
    call(|p| {
        p.expect(dev, "device", |m| matches!(m, Module::Device))?;
        let h = p.remote.unwrap_or(0);
        // SAFETY: the caller's out-pointer.
        unsafe { out(port, h as *mut c_void, "phRemoteDev") }
    })
}

/// # Safety
/// `n` writable.
#[no_mangle]
pub unsafe extern "C" fn DevGetNumDataStreams(dev: *mut c_void, n: *mut u32) -> GcError {
    call(|p| {
        p.expect(dev, "device", |m| matches!(m, Module::Device))?;
        // SAFETY: the caller's out-pointer.
        unsafe { out(n, 1, "piNumDataStreams") }
    })
}

/// # Safety
/// `id` writable for `*size` bytes or null; `size` valid.
#[no_mangle]
pub unsafe extern "C" fn DevGetDataStreamID(
    dev: *mut c_void,
    index: u32,
    id: *mut c_char,
    size: *mut usize,
) -> GcError {
    call(|p| {
        p.expect(dev, "device", |m| matches!(m, Module::Device))?;
        if index != 0 {
            return Err(Fail::new(
                err::INVALID_INDEX,
                "there is one data stream (index 0)",
            ));
        }
        // SAFETY: the caller's pointers.
        unsafe { Info::Str(STREAM_ID.into()).write(std::ptr::null_mut(), id.cast(), size) }
    })
}

/// # Safety
/// `id` a NUL-terminated string; `ds` writable.
#[no_mangle]
pub unsafe extern "C" fn DevOpenDataStream(
    dev: *mut c_void,
    id: *const c_char,
    ds: *mut *mut c_void,
) -> GcError {
    call(|p| {
        p.expect(dev, "device", |m| matches!(m, Module::Device))?;
        // SAFETY: the caller's string.
        if unsafe { arg_str(id, "sDataStreamID") }? != STREAM_ID {
            return Err(Fail::new(
                err::INVALID_ID,
                format!("no data stream but `{STREAM_ID}`"),
            ));
        }
        if p.stream.is_some() {
            return Err(Fail::new(
                err::RESOURCE_IN_USE,
                "the data stream is open already",
            ));
        }
        let s = Arc::new(Stream::new(p.camera()?));
        let h = p.add(Module::Stream(s));
        p.stream = Some(h);
        // SAFETY: the caller's out-pointer.
        unsafe { out(ds, h as *mut c_void, "phDataStream") }
    })
}
