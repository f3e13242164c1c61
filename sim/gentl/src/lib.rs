//! The simulated 3D camera as a GenTL producer: this crate builds `libhandeye_gentl_sim.so`,
//! a `.cti` that any GenTL consumer (harvesters, Halcon, `handeye`'s `gentl` camera backend)
//! loads. It serves the scene of `handeye sim camera` (the robot rendered by the scan
//! simulator, following a UR controller over RTDE) with that camera's GenApi XML and
//! registers, through one system, one interface and one device.
//!
//! A `.cti` gets no command line: the scene is chosen by the environment variable
//! `HANDEYE_SIM_CAMERA_ARGS`, holding `handeye sim camera`'s scene options
//! (`--robot 127.0.0.1 --factory-calibration 7 --width 640 --height 480`, …; without it: a
//! UR5e standing still at a generated view of its base). The remote device's XML is at a
//! `local:` URL of its port; each buffer is a multi-part payload: Range as `Coord3D_ABC32f`
//! (millimetres, NaN where nothing was measured), then Confidence16 when
//! `ComponentEnable[Confidence]` is set.
//!
//! Layout: `abi` (error codes, `...GetInfo` conventions), `stream` (buffers, queues,
//! the acquisition thread), this file (the module handles and the exported C functions).
#![allow(non_snake_case)] // the GenTL standard's function names

mod abi;
mod stream;

use std::collections::HashMap;
use std::ffi::{c_char, c_void};
use std::sync::{Arc, Mutex};

use abi::{arg_str, err, out, Fail, GcError, Info, Res};
use handeye_gige::sim::{PortError, SimDevice, SimOptions};
use handeye_sim_scene::SceneArgs;
use stream::{lock, Camera, Slot, Stream};

/// The environment variable holding the scene options.
const ARGS_ENV: &str = "HANDEYE_SIM_CAMERA_ARGS";
/// Ids of the one system, interface and data stream.
const TL_ID: &str = "handeye-sim";
const IF_ID: &str = "handeye-sim-if0";
const STREAM_ID: &str = "Stream0";
const TL_TYPE: &str = "Custom";

/// `HANDEYE_SIM_CAMERA_ARGS` as `handeye sim camera` reads its scene options.
#[derive(Debug, clap::Parser)]
#[command(name = ARGS_ENV, no_binary_name = true, disable_version_flag = true)]
struct EnvArgs {
    #[command(flatten)]
    scene: SceneArgs,
}

/// The scene options from the environment.
fn scene_args() -> Res<SceneArgs> {
    use clap::Parser as _;
    let text = match std::env::var(ARGS_ENV) {
        Ok(t) => t,
        Err(std::env::VarError::NotPresent) => String::new(),
        Err(std::env::VarError::NotUnicode(_)) => {
            return Err(Fail::new(
                err::INVALID_PARAMETER,
                format!("{ARGS_ENV} is not UTF-8"),
            ))
        }
    };
    let words = shlex::split(&text).ok_or_else(|| {
        Fail::new(
            err::INVALID_PARAMETER,
            format!("{ARGS_ENV}: unbalanced quotes in `{text}`"),
        )
    })?;
    EnvArgs::try_parse_from(words).map(|a| a.scene).map_err(|e| {
        let text = e.render().to_string();
        let first = text.lines().next().unwrap_or_default();
        Fail::new(
            err::INVALID_PARAMETER,
            format!(
                "{ARGS_ENV}: {}; it takes the scene options of `handeye sim camera --help` (not --bind or --loss)",
                first.trim_start_matches("error: ")
            ),
        )
    })
}

/// What a handle stands for.
#[derive(Debug, Clone)]
enum Module {
    System,
    Interface,
    Device,
    /// The remote device's port (`DevGetPort`).
    RemotePort,
    Stream(Arc<Stream>),
    /// A buffer announced to the data stream (its slot lives in the stream).
    Buffer,
    /// The new-buffer event of a stream.
    Event(Arc<Stream>),
}

/// The library's state between `GCInitLib` and `GCCloseLib`.
#[derive(Debug)]
struct Producer {
    handles: HashMap<usize, Module>,
    next: usize,
    args: SceneArgs,
    options: SimOptions,
    system: Option<usize>,
    interface: Option<usize>,
    device: Option<usize>,
    remote: Option<usize>,
    stream: Option<usize>,
    /// Built when the device is first opened (meshes load, the RTDE follower starts) and
    /// kept until `GCCloseLib`.
    camera: Option<Arc<Camera>>,
}

static PRODUCER: Mutex<Option<Producer>> = Mutex::new(None);

thread_local! {
    static LAST_ERROR: std::cell::RefCell<(GcError, String)> =
        const { std::cell::RefCell::new((0, String::new())) };
}

impl Producer {
    fn add(&mut self, m: Module) -> usize {
        self.next += 0x10;
        self.handles.insert(self.next, m);
        self.next
    }

    fn get(&self, h: *mut c_void) -> Res<&Module> {
        self.handles
            .get(&(h as usize))
            .ok_or_else(|| Fail::new(err::INVALID_HANDLE, "not a handle of this producer"))
    }

    fn expect(&self, h: *mut c_void, want: &str, ok: fn(&Module) -> bool) -> Res<&Module> {
        let m = self.get(h)?;
        if ok(m) {
            Ok(m)
        } else {
            Err(Fail::new(
                err::INVALID_HANDLE,
                format!("not a {want} handle"),
            ))
        }
    }

    fn stream(&self, h: *mut c_void) -> Res<Arc<Stream>> {
        match self.get(h)? {
            Module::Stream(s) => Ok(Arc::clone(s)),
            _ => Err(Fail::new(err::INVALID_HANDLE, "not a data stream handle")),
        }
    }

    fn camera(&self) -> Res<Arc<Camera>> {
        self.camera
            .clone()
            .ok_or_else(|| Fail::new(err::NOT_AVAILABLE, "the device is not open"))
    }

    fn device_id(&self) -> &str {
        &self.options.serial
    }

    fn device_info(&self, cmd: i32) -> Res<Info> {
        let o = &self.options;
        Ok(match cmd {
            0 | 7 => Info::Str(o.serial.clone()),
            1 => Info::Str(o.vendor.clone()),
            2 => Info::Str(o.model.clone()),
            3 => Info::Str(TL_TYPE.into()),
            4 => Info::Str(format!("{} {} ({})", o.vendor, o.model, o.serial)),
            5 => Info::I32(if self.device.is_some() {
                abi::ACCESS_STATUS_OPEN_READWRITE
            } else {
                abi::ACCESS_STATUS_READWRITE
            }),
            6 => Info::Str(String::new()),
            8 => Info::Str(o.version.clone()),
            9 => Info::U64(1_000_000_000),
            _ => return Err(unknown_cmd("DEVICE_INFO_CMD", cmd)),
        })
    }

    /// Opens the device: builds the scene and the simulated camera's registers (once).
    fn open_device(&mut self) -> Res<()> {
        if self.camera.is_none() {
            let (source, scene) = self.args.frame_source().map_err(|e| {
                Fail::new(
                    err::ERROR,
                    format!("the simulated camera's scene ({ARGS_ENV}): {e:#}"),
                )
            })?;
            let device = SimDevice::new(source.as_ref(), &self.options)
                .map_err(|e| Fail::new(err::ERROR, format!("the simulated camera: {e}")))?;
            eprintln!(
                "handeye GenTL producer: simulated 3D camera {} ({}x{}, {scene})",
                self.options.serial, self.args.width, self.args.height
            );
            self.camera = Some(Arc::new(Camera {
                device,
                source: Mutex::new(source),
            }));
        }
        Ok(())
    }

    /// Closes the data stream (stopping acquisition) and forgets its buffers and event.
    fn close_stream(&mut self) {
        if let Some(h) = self.stream.take() {
            if let Some(Module::Stream(s)) = self.handles.remove(&h) {
                let _ = s.stop();
                // A thread still waiting for a new buffer (even without a timeout) returns.
                lock(&s.state).killed = true;
                s.cond.notify_all();
                let st = lock(&s.state);
                let mut gone: Vec<usize> = st.buffers.keys().copied().collect();
                gone.extend(st.event);
                drop(st);
                for b in gone {
                    self.handles.remove(&b);
                }
            }
        }
    }

    fn close_device(&mut self) {
        self.close_stream();
        for h in [self.remote.take(), self.device.take()]
            .into_iter()
            .flatten()
        {
            self.handles.remove(&h);
        }
    }
}

fn unknown_cmd(what: &str, cmd: i32) -> Fail {
    Fail::new(
        err::INVALID_PARAMETER,
        format!("{what} {cmd} is not answered by this producer"),
    )
}

/// Runs an exported function's body under the library lock; records a failure for
/// `GCGetLastError`; a panic becomes `GC_ERR_ERROR` instead of unwinding into C.
fn call(f: impl FnOnce(&mut Producer) -> Res) -> GcError {
    finish(std::panic::catch_unwind(std::panic::AssertUnwindSafe(
        || {
            let mut guard = lock(&PRODUCER);
            match guard.as_mut() {
                Some(p) => f(p),
                None => Err(Fail::new(err::NOT_INITIALIZED, "GCInitLib was not called")),
            }
        },
    )))
}

/// As [`call`], without holding the library lock while `f` runs (for calls that wait).
fn call_unlocked(f: impl FnOnce() -> Res) -> GcError {
    finish(std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)))
}

fn finish(r: std::thread::Result<Res>) -> GcError {
    let r = r.unwrap_or_else(|_| Err(Fail::new(err::ERROR, "the producer panicked")));
    match r {
        Ok(()) => err::SUCCESS,
        Err(f) => {
            LAST_ERROR.with(|e| *e.borrow_mut() = (f.code, f.text.clone()));
            f.code
        }
    }
}

/// The path of this library (for `TL_INFO_PATHNAME`).
fn own_path() -> String {
    // SAFETY: `dladdr` only reads the address of a function of this library and fills `info`.
    unsafe {
        let mut info: libc::Dl_info = std::mem::zeroed();
        let addr = own_path as *const c_void;
        if libc::dladdr(addr, &mut info) != 0 && !info.dli_fname.is_null() {
            return std::ffi::CStr::from_ptr(info.dli_fname)
                .to_string_lossy()
                .into_owned();
        }
    }
    String::new()
}

fn tl_info(cmd: i32) -> Res<Info> {
    let path = own_path();
    Ok(match cmd {
        0 => Info::Str(TL_ID.into()),
        1 => Info::Str(SimOptions::default().vendor),
        2 => Info::Str("handeye simulated 3D camera producer".into()),
        3 => Info::Str(env!("CARGO_PKG_VERSION").into()),
        4 => Info::Str(TL_TYPE.into()),
        5 => Info::Str(
            std::path::Path::new(&path)
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
        ),
        6 => Info::Str(path),
        7 => Info::Str("handeye simulated 3D camera".into()),
        8 => Info::I32(0),
        9 => Info::U32(1),
        10 => Info::U32(5),
        _ => return Err(unknown_cmd("TL_INFO_CMD", cmd)),
    })
}

fn if_info(cmd: i32) -> Res<Info> {
    Ok(match cmd {
        0 => Info::Str(IF_ID.into()),
        1 => Info::Str("handeye simulated interface".into()),
        2 => Info::Str(TL_TYPE.into()),
        _ => return Err(unknown_cmd("INTERFACE_INFO_CMD", cmd)),
    })
}

// ---------------------------------------------------------------------------------------
// Library

#[no_mangle]
pub extern "C" fn GCInitLib() -> GcError {
    finish(std::panic::catch_unwind(|| {
        let mut guard = lock(&PRODUCER);
        if guard.is_some() {
            return Err(Fail::new(
                err::RESOURCE_IN_USE,
                "GCInitLib was called already",
            ));
        }
        let args = scene_args()?;
        let options = args.options();
        *guard = Some(Producer {
            handles: HashMap::new(),
            next: 0x1000,
            args,
            options,
            system: None,
            interface: None,
            device: None,
            remote: None,
            stream: None,
            camera: None,
        });
        Ok(())
    }))
}

#[no_mangle]
pub extern "C" fn GCCloseLib() -> GcError {
    finish(std::panic::catch_unwind(|| {
        // Taken out first: dropping the camera joins threads, not under the lock.
        let taken = lock(&PRODUCER).take();
        match taken {
            Some(mut p) => {
                p.close_device();
                drop(p);
                Ok(())
            }
            None => Err(Fail::new(err::NOT_INITIALIZED, "GCInitLib was not called")),
        }
    }))
}

/// # Safety
/// GenTL's contract: `code` and `size` valid, `text` writable for `*size` bytes or null.
#[no_mangle]
pub unsafe extern "C" fn GCGetLastError(
    code: *mut GcError,
    text: *mut c_char,
    size: *mut usize,
) -> GcError {
    let (c, t) = LAST_ERROR.with(|e| e.borrow().clone());
    call_unlocked(|| {
        // SAFETY: the caller's pointers (GenTL contract).
        unsafe {
            out(code, c, "piErrorCode")?;
            Info::Str(t).write(std::ptr::null_mut(), text.cast(), size)
        }
    })
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn GCGetInfo(
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    // SAFETY: the caller's pointers.
    call_unlocked(|| unsafe { tl_info(cmd)?.write(ty, buf, size) })
}

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
        // SAFETY: the caller's out-pointer.
        unsafe { out(n, 1, "piNumIfaces") }
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
        if index != 0 {
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
        // SAFETY: the caller's out-pointer.
        unsafe { out(n, 1, "piNumDevices") }
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
        if index != 0 {
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

// ---------------------------------------------------------------------------------------
// Ports: the remote device's registers; the GenTL modules' own ports have no registers and
// no XML (consumers then show no module node map).

fn remote(p: &Producer, port: *mut c_void) -> Res {
    match p.get(port)? {
        Module::RemotePort => Ok(()),
        _ => Err(Fail::new(
            err::NOT_AVAILABLE,
            "this module's port has no registers (only the remote device's port does)",
        )),
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
        remote(p, port)?;
        if buf.is_null() || size.is_null() {
            return Err(Fail::new(
                err::INVALID_PARAMETER,
                "pBuffer or piSize is NULL",
            ));
        }
        // SAFETY: the caller's buffer of `*size` bytes (GenTL contract).
        let dst = unsafe { std::slice::from_raw_parts_mut(buf.cast::<u8>(), *size) };
        p.camera()?
            .device
            .read(address, dst)
            .map_err(|e| port_error(e, address))
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
        remote(p, port)?;
        if buf.is_null() || size.is_null() {
            return Err(Fail::new(
                err::INVALID_PARAMETER,
                "pBuffer or piSize is NULL",
            ));
        }
        // SAFETY: the caller's buffer of `*size` bytes (GenTL contract).
        let src = unsafe { std::slice::from_raw_parts(buf.cast::<u8>(), *size) };
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
    address: u64,
    buffer: *mut c_void,
    size: usize,
}

/// # Safety
/// `entries` holds `*n` entries, each with a buffer of its size.
#[no_mangle]
pub unsafe extern "C" fn GCReadPortStacked(
    port: *mut c_void,
    entries: *mut PortRegisterStackEntry,
    n: *mut usize,
) -> GcError {
    if entries.is_null() || n.is_null() {
        return call(|_| Err(Fail::new(err::INVALID_PARAMETER, "NULL argument")));
    }
    // SAFETY: the caller's `*n` entries.
    let list = unsafe { std::slice::from_raw_parts_mut(entries, *n) };
    for e in list {
        let mut size = e.size;
        // SAFETY: the entry's buffer of `size` bytes.
        let code = unsafe { GCReadPort(port, e.address, e.buffer, &mut size) };
        if code != err::SUCCESS {
            return code;
        }
    }
    err::SUCCESS
}

/// # Safety
/// `entries` holds `*n` entries, each with a buffer of its size.
#[no_mangle]
pub unsafe extern "C" fn GCWritePortStacked(
    port: *mut c_void,
    entries: *mut PortRegisterStackEntry,
    n: *mut usize,
) -> GcError {
    if entries.is_null() || n.is_null() {
        return call(|_| Err(Fail::new(err::INVALID_PARAMETER, "NULL argument")));
    }
    // SAFETY: the caller's `*n` entries.
    let list = unsafe { std::slice::from_raw_parts_mut(entries, *n) };
    for e in list {
        let mut size = e.size;
        // SAFETY: the entry's buffer of `size` bytes.
        let code = unsafe { GCWritePort(port, e.address, e.buffer, &mut size) };
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
        remote(p, port)?;
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
        remote(p, port)?;
        let u = p.camera()?.device.xml_url();
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
        remote(p, port)?;
        if index != 0 {
            return Err(Fail::new(
                err::INVALID_INDEX,
                "the remote device has one URL (index 0)",
            ));
        }
        let url = p.camera()?.device.xml_url();
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

// ---------------------------------------------------------------------------------------
// Events

/// # Safety
/// `event` writable.
#[no_mangle]
pub unsafe extern "C" fn GCRegisterEvent(
    source: *mut c_void,
    kind: i32,
    event: *mut *mut c_void,
) -> GcError {
    call(|p| {
        let Module::Stream(s) = p.get(source)?.clone() else {
            return Err(Fail::new(
                err::NOT_IMPLEMENTED,
                "this producer signals only the data stream's new-buffer event",
            ));
        };
        if kind != abi::EVENT_NEW_BUFFER {
            return Err(Fail::new(
                err::NOT_IMPLEMENTED,
                format!("event type {kind}: the data stream signals only EVENT_NEW_BUFFER (1)"),
            ));
        }
        if lock(&s.state).event.is_some() {
            return Err(Fail::new(
                err::RESOURCE_IN_USE,
                "the new-buffer event is registered",
            ));
        }
        let h = p.add(Module::Event(Arc::clone(&s)));
        lock(&s.state).event = Some(h);
        // SAFETY: the caller's out-pointer.
        unsafe { out(event, h as *mut c_void, "phEvent") }
    })
}

#[no_mangle]
pub extern "C" fn GCUnregisterEvent(source: *mut c_void, kind: i32) -> GcError {
    call(|p| {
        let s = p.stream(source)?;
        if kind != abi::EVENT_NEW_BUFFER {
            return Err(Fail::new(
                err::NOT_IMPLEMENTED,
                format!("event type {kind}"),
            ));
        }
        let h = lock(&s.state).event.take();
        match h {
            Some(h) => {
                p.handles.remove(&h);
                Ok(())
            }
            None => Err(Fail::new(
                err::RESOURCE_IN_USE,
                "the event is not registered",
            )),
        }
    })
}

fn event_stream(event: *mut c_void) -> Res<Arc<Stream>> {
    let guard = lock(&PRODUCER);
    let p = guard
        .as_ref()
        .ok_or_else(|| Fail::new(err::NOT_INITIALIZED, "GCInitLib was not called"))?;
    match p.get(event)? {
        Module::Event(s) => Ok(Arc::clone(s)),
        _ => Err(Fail::new(err::INVALID_HANDLE, "not an event handle")),
    }
}

/// `EVENT_NEW_BUFFER_DATA`.
#[repr(C, packed)]
struct NewBufferData {
    buffer: *mut c_void,
    user: *mut c_void,
}

/// # Safety
/// `buf` writable for `*size` bytes; `size` valid.
#[no_mangle]
pub unsafe extern "C" fn EventGetData(
    event: *mut c_void,
    buf: *mut c_void,
    size: *mut usize,
    timeout_ms: u64,
) -> GcError {
    call_unlocked(|| {
        let s = event_stream(event)?;
        let need = std::mem::size_of::<NewBufferData>();
        if size.is_null() || buf.is_null() {
            return Err(Fail::new(
                err::INVALID_PARAMETER,
                "pBuffer or piSize is NULL",
            ));
        }
        // SAFETY: the caller's size.
        if unsafe { *size } < need {
            return Err(Fail::new(
                err::BUFFER_TOO_SMALL,
                format!("{need} bytes needed"),
            ));
        }
        // The library lock is not held while waiting: other calls go on meanwhile.
        let (h, user) = s.next_delivered(timeout_ms)?;
        let data = NewBufferData {
            buffer: h as *mut c_void,
            user: user as *mut c_void,
        };
        // SAFETY: `buf` is writable for `*size >= need` bytes; unaligned write of a packed
        // struct.
        unsafe {
            buf.cast::<NewBufferData>().write_unaligned(data);
            *size = need;
        }
        Ok(())
    })
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn EventGetDataInfo(
    event: *mut c_void,
    data: *const c_void,
    data_size: usize,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call_unlocked(|| {
        event_stream(event)?;
        if data.is_null() || data_size < std::mem::size_of::<NewBufferData>() {
            return Err(Fail::new(
                err::INVALID_PARAMETER,
                "no new-buffer event data",
            ));
        }
        // SAFETY: `data` holds an EVENT_NEW_BUFFER_DATA (checked size).
        let d = unsafe { data.cast::<NewBufferData>().read_unaligned() };
        let info = match cmd {
            // EVENT_DATA_ID, EVENT_DATA_VALUE: the buffer handle and its user pointer.
            0 => Info::Ptr(d.buffer as usize),
            1 => Info::Ptr(d.user as usize),
            _ => return Err(unknown_cmd("EVENT_DATA_INFO_CMD", cmd)),
        };
        // SAFETY: the caller's pointers.
        unsafe { info.write(ty, buf, size) }
    })
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn EventGetInfo(
    event: *mut c_void,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call_unlocked(|| {
        let s = event_stream(event)?;
        let st = lock(&s.state);
        let info = match cmd {
            0 => Info::I32(abi::EVENT_NEW_BUFFER),
            1 => Info::SizeT(st.output.len()),
            2 => Info::U64(st.delivered),
            3 | 4 => Info::SizeT(std::mem::size_of::<NewBufferData>()),
            _ => return Err(unknown_cmd("EVENT_INFO_CMD", cmd)),
        };
        drop(st);
        // SAFETY: the caller's pointers.
        unsafe { info.write(ty, buf, size) }
    })
}

#[no_mangle]
pub extern "C" fn EventFlush(event: *mut c_void) -> GcError {
    call_unlocked(|| {
        let s = event_stream(event)?;
        // The delivered buffers are dropped from the output queue (announced, not queued).
        lock(&s.state).output.clear();
        Ok(())
    })
}

#[no_mangle]
pub extern "C" fn EventKill(event: *mut c_void) -> GcError {
    call_unlocked(|| {
        let s = event_stream(event)?;
        lock(&s.state).killed = true;
        s.cond.notify_all();
        Ok(())
    })
}

// ---------------------------------------------------------------------------------------
// Data stream

#[no_mangle]
pub extern "C" fn DSClose(ds: *mut c_void) -> GcError {
    call(|p| {
        p.stream(ds)?;
        p.close_stream();
        Ok(())
    })
}

/// # Safety
/// `dev` writable.
#[no_mangle]
pub unsafe extern "C" fn DSGetParentDev(ds: *mut c_void, dev: *mut *mut c_void) -> GcError {
    call(|p| {
        p.stream(ds)?;
        let h = p.device.unwrap_or(0);
        // SAFETY: the caller's out-pointer.
        unsafe { out(dev, h as *mut c_void, "phDevice") }
    })
}

/// # Safety
/// `buffer` readable and writable for `size` bytes until revoked; `handle` writable.
#[no_mangle]
pub unsafe extern "C" fn DSAnnounceBuffer(
    ds: *mut c_void,
    buffer: *mut c_void,
    size: usize,
    user: *mut c_void,
    handle: *mut *mut c_void,
) -> GcError {
    call(|p| {
        let s = p.stream(ds)?;
        if buffer.is_null() || size == 0 {
            return Err(Fail::new(
                err::INVALID_PARAMETER,
                "pBuffer is NULL or iSize is 0",
            ));
        }
        let h = p.add(Module::Buffer);
        lock(&s.state).buffers.insert(
            h,
            Slot {
                base: buffer as usize,
                size,
                user: user as usize,
                owned: None,
                filled: None,
            },
        );
        // SAFETY: the caller's out-pointer.
        unsafe { out(handle, h as *mut c_void, "phBuffer") }
    })
}

/// Largest buffer this producer allocates, bytes.
const MAX_ALLOC: usize = 1 << 30;

/// # Safety
/// `handle` writable.
#[no_mangle]
pub unsafe extern "C" fn DSAllocAndAnnounceBuffer(
    ds: *mut c_void,
    size: usize,
    user: *mut c_void,
    handle: *mut *mut c_void,
) -> GcError {
    call(|p| {
        let s = p.stream(ds)?;
        if size == 0 || size > MAX_ALLOC {
            return Err(Fail::new(
                err::INVALID_PARAMETER,
                format!("iSize {size}: expected 1 byte to 1 GiB"),
            ));
        }
        let mut mem = vec![0u8; size].into_boxed_slice();
        let h = p.add(Module::Buffer);
        lock(&s.state).buffers.insert(
            h,
            Slot {
                base: mem.as_mut_ptr() as usize,
                size,
                user: user as usize,
                owned: Some(mem),
                filled: None,
            },
        );
        // SAFETY: the caller's out-pointer.
        unsafe { out(handle, h as *mut c_void, "phBuffer") }
    })
}

/// # Safety
/// `buffer` and `user` null or writable.
#[no_mangle]
pub unsafe extern "C" fn DSRevokeBuffer(
    ds: *mut c_void,
    handle: *mut c_void,
    buffer: *mut *mut c_void,
    user: *mut *mut c_void,
) -> GcError {
    call(|p| {
        let s = p.stream(ds)?;
        let h = handle as usize;
        let mut st = lock(&s.state);
        if st.is_queued(h) {
            return Err(Fail::new(
                err::RESOURCE_IN_USE,
                "the buffer is queued: flush the queues (DSFlushQueue) first",
            ));
        }
        let slot = st
            .buffers
            .remove(&h)
            .ok_or_else(|| Fail::new(err::INVALID_HANDLE, "not a buffer of this stream"))?;
        drop(st);
        p.handles.remove(&h);
        let base = if slot.owned.is_some() { 0 } else { slot.base };
        // SAFETY: the caller's optional out-pointers.
        unsafe {
            if !buffer.is_null() {
                *buffer = base as *mut c_void;
            }
            if !user.is_null() {
                *user = slot.user as *mut c_void;
            }
        }
        Ok(())
    })
}

#[no_mangle]
pub extern "C" fn DSQueueBuffer(ds: *mut c_void, handle: *mut c_void) -> GcError {
    call(|p| {
        let s = p.stream(ds)?;
        let h = handle as usize;
        let mut st = lock(&s.state);
        if st.is_queued(h) {
            return Err(Fail::new(
                err::RESOURCE_IN_USE,
                "the buffer is queued already",
            ));
        }
        let slot = st
            .buffers
            .get_mut(&h)
            .ok_or_else(|| Fail::new(err::INVALID_HANDLE, "not a buffer of this stream"))?;
        slot.filled = None;
        st.input.push_back(h);
        Ok(())
    })
}

/// # Safety
/// `handle` writable.
#[no_mangle]
pub unsafe extern "C" fn DSGetBufferID(
    ds: *mut c_void,
    index: u32,
    handle: *mut *mut c_void,
) -> GcError {
    call(|p| {
        let s = p.stream(ds)?;
        let h = lock(&s.state).buffers.keys().nth(index as usize).copied();
        let h =
            h.ok_or_else(|| Fail::new(err::INVALID_INDEX, "no announced buffer at that index"))?;
        // SAFETY: the caller's out-pointer.
        unsafe { out(handle, h as *mut c_void, "phBuffer") }
    })
}

#[no_mangle]
pub extern "C" fn DSFlushQueue(ds: *mut c_void, operation: i32) -> GcError {
    call(|p| {
        let s = p.stream(ds)?;
        let mut st = lock(&s.state);
        match operation {
            // ACQ_QUEUE_INPUT_TO_OUTPUT
            0 => {
                let moved: Vec<usize> = st.input.drain(..).collect();
                st.output.extend(moved);
                drop(st);
                s.cond.notify_all();
            }
            // ACQ_QUEUE_OUTPUT_DISCARD
            1 => st.output.clear(),
            // ACQ_QUEUE_ALL_TO_INPUT, ACQ_QUEUE_UNQUEUED_TO_INPUT
            2 | 3 => {
                if operation == 2 {
                    st.output.clear();
                }
                let idle: Vec<usize> = st
                    .buffers
                    .keys()
                    .copied()
                    .filter(|h| !st.is_queued(*h))
                    .collect();
                st.input.extend(idle);
            }
            // ACQ_QUEUE_ALL_DISCARD
            4 => {
                st.input.clear();
                st.output.clear();
            }
            _ => return Err(unknown_cmd("ACQ_QUEUE_TYPE", operation)),
        }
        Ok(())
    })
}

#[no_mangle]
pub extern "C" fn DSStartAcquisition(ds: *mut c_void, _flags: i32, count: u64) -> GcError {
    call(|p| p.stream(ds)?.start(count))
}

#[no_mangle]
pub extern "C" fn DSStopAcquisition(ds: *mut c_void, _flags: i32) -> GcError {
    // The stream is looked up under the lock; waiting for its thread is not.
    let mut stream = None;
    let code = call(|p| {
        stream = Some(p.stream(ds)?);
        Ok(())
    });
    match stream {
        Some(s) => call_unlocked(|| s.stop()),
        None => code,
    }
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn DSGetInfo(
    ds: *mut c_void,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        let s = p.stream(ds)?;
        let payload = s.camera.device.payload_size() as usize;
        let st = lock(&s.state);
        let info = match cmd {
            0 => Info::Str(STREAM_ID.into()),
            1 => Info::U64(st.delivered),
            2 => Info::U64(st.underrun),
            3 => Info::SizeT(st.buffers.len()),
            4 => Info::SizeT(st.input.len()),
            5 => Info::SizeT(st.output.len()),
            6 => Info::U64(st.started),
            7 => Info::SizeT(payload),
            8 => Info::Bool(st.acquiring),
            9 => Info::Bool(true),
            10 => Info::Str(TL_TYPE.into()),
            11 => Info::SizeT(0),
            12 => Info::SizeT(1),
            13 => Info::SizeT(1),
            _ => return Err(unknown_cmd("STREAM_INFO_CMD", cmd)),
        };
        drop(st);
        // SAFETY: the caller's pointers.
        unsafe { info.write(ty, buf, size) }
    })
}

/// The buffer's slot data needed to answer info queries.
fn with_slot<T>(
    p: &Producer,
    ds: *mut c_void,
    handle: *mut c_void,
    f: impl FnOnce(&Slot, bool) -> Res<T>,
) -> Res<T> {
    let s = p.stream(ds)?;
    let st = lock(&s.state);
    let h = handle as usize;
    let slot = st
        .buffers
        .get(&h)
        .ok_or_else(|| Fail::new(err::INVALID_HANDLE, "not a buffer of this stream"))?;
    f(slot, st.is_queued(h) && !st.output.contains(&h))
}

fn filled(slot: &Slot) -> Res<&stream::Filled> {
    slot.filled
        .as_ref()
        .ok_or_else(|| Fail::new(err::NO_DATA, "the buffer holds no delivered frame"))
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn DSGetBufferInfo(
    ds: *mut c_void,
    handle: *mut c_void,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        let info = with_slot(p, ds, handle, |slot, queued| {
            // The multi-part buffer's image fields are the Range part's.
            let range = slot
                .filled
                .as_ref()
                .and_then(|f| f.parts.iter().find(|m| m.purpose == 4).copied());
            let range = || range.ok_or_else(|| Fail::new(err::NO_DATA, "no Range part"));
            Ok(match cmd {
                0 => Info::Ptr(slot.base),
                1 => Info::SizeT(slot.size),
                2 => Info::Ptr(slot.user),
                3 | 28 => Info::U64(filled(slot)?.timestamp_ns),
                4 => Info::Bool(slot.filled.is_some()),
                5 => Info::Bool(queued),
                6 => Info::Bool(false),
                7 => Info::Bool(filled(slot)?.incomplete),
                8 => Info::Str(TL_TYPE.into()),
                9 | 27 => Info::SizeT(filled(slot)?.size_filled),
                10 => Info::SizeT(range()?.width as usize),
                11 | 22 => Info::SizeT(range()?.height as usize),
                12..=15 | 23 => Info::SizeT(0),
                16 => Info::U64(filled(slot)?.frame_id),
                17 => Info::Bool(true),
                18 => Info::SizeT(range()?.offset),
                19 => Info::SizeT(abi::PAYLOAD_TYPE_MULTI_PART as usize),
                20 => Info::U64(range()?.format),
                21 => Info::U64(abi::PIXELFORMAT_NAMESPACE_PFNC_32BIT),
                // PIXELENDIANNESS_LITTLE
                26 => Info::I32(1),
                29 | 30 => Info::Bool(false),
                _ => return Err(unknown_cmd("BUFFER_INFO_CMD", cmd)),
            })
        })?;
        // SAFETY: the caller's pointers.
        unsafe { info.write(ty, buf, size) }
    })
}

/// # Safety
/// `n` writable.
#[no_mangle]
pub unsafe extern "C" fn DSGetNumBufferParts(
    ds: *mut c_void,
    handle: *mut c_void,
    n: *mut u32,
) -> GcError {
    call(|p| {
        let parts = with_slot(p, ds, handle, |slot, _| Ok(filled(slot)?.parts.len()))?;
        // SAFETY: the caller's out-pointer.
        unsafe { out(n, parts as u32, "piNumParts") }
    })
}

/// # Safety
/// GenTL's contract for `...GetInfo`.
#[no_mangle]
pub unsafe extern "C" fn DSGetBufferPartInfo(
    ds: *mut c_void,
    handle: *mut c_void,
    index: u32,
    cmd: i32,
    ty: *mut i32,
    buf: *mut c_void,
    size: *mut usize,
) -> GcError {
    call(|p| {
        let info = with_slot(p, ds, handle, |slot, _| {
            let part = *filled(slot)?
                .parts
                .get(index as usize)
                .ok_or_else(|| Fail::new(err::INVALID_INDEX, format!("no part {index}")))?;
            Ok(match cmd {
                0 => Info::Ptr(slot.base + part.offset),
                1 => Info::SizeT(part.size),
                2 => Info::SizeT(part.data_type as usize),
                3 => Info::U64(part.format),
                4 => Info::U64(abi::PIXELFORMAT_NAMESPACE_PFNC_32BIT),
                5 => Info::SizeT(part.width as usize),
                6 | 11 => Info::SizeT(part.height as usize),
                7..=9 => Info::SizeT(0),
                10 | 12 => Info::U64(0),
                13 => Info::U64(part.purpose),
                _ => return Err(unknown_cmd("BUFFER_PART_INFO_CMD", cmd)),
            })
        })?;
        // SAFETY: the caller's pointers.
        unsafe { info.write(ty, buf, size) }
    })
}

// ---------------------------------------------------------------------------------------
// GenTL 1.5/1.6 functions this producer does not offer (chunks, composite buffers, flows,
// segments, stacked info): exported so that consumers resolving every symbol load it.

macro_rules! not_implemented {
    ($($name:ident($($arg:ident: $ty:ty),*);)*) => {$(
        #[no_mangle]
        pub extern "C" fn $name($($arg: $ty),*) -> GcError {
            $(let _ = $arg;)*
            call_unlocked(|| Err(Fail::new(
                err::NOT_IMPLEMENTED,
                concat!(stringify!($name), " is not offered by this producer"),
            )))
        }
    )*};
}

not_implemented! {
    DSGetBufferChunkData(ds: *mut c_void, buffer: *mut c_void, chunks: *mut c_void, n: *mut usize);
    DSAnnounceCompositeBuffer(ds: *mut c_void, n: usize, segments: *mut *mut c_void, sizes: *mut usize, user: *mut c_void, buffer: *mut *mut c_void);
    DSGetBufferInfoStacked(ds: *mut c_void, buffer: *mut c_void, infos: *mut c_void, n: usize);
    DSGetBufferPartInfoStacked(ds: *mut c_void, buffer: *mut c_void, infos: *mut c_void, n: usize);
    DSGetNumFlows(ds: *mut c_void, n: *mut u32);
    DSGetFlowInfo(ds: *mut c_void, index: u32, cmd: i32, ty: *mut i32, buf: *mut c_void, size: *mut usize);
    DSGetNumBufferSegments(ds: *mut c_void, buffer: *mut c_void, n: *mut u32);
    DSGetBufferSegmentInfo(ds: *mut c_void, buffer: *mut c_void, index: u32, cmd: i32, ty: *mut i32, buf: *mut c_void, size: *mut usize);
}

#[cfg(test)]
mod tests {
    use super::*;
    use handeye_gige::decode::pfnc;

    /// The tests that set `HANDEYE_SIM_CAMERA_ARGS` or use the library's one global state run
    /// one at a time.
    static SERIAL: Mutex<()> = Mutex::new(());

    /// The camera.xml register `AcquisitionStart` writes (`AcquisitionStartReg`).
    const ACQ_START_REG: u64 = 0xA014;

    fn ok(code: GcError) {
        let (c, text) = LAST_ERROR.with(|e| e.borrow().clone());
        assert_eq!(code, err::SUCCESS, "last error {c}: {text}");
    }

    fn string(f: impl Fn(*mut c_char, *mut usize) -> GcError) -> String {
        let mut buf = [0u8; 256];
        let mut n = buf.len();
        ok(f(buf.as_mut_ptr().cast(), &mut n));
        String::from_utf8(buf[..n - 1].to_vec()).expect("utf-8")
    }

    fn number(f: impl Fn(*mut i32, *mut c_void, *mut usize) -> GcError) -> u64 {
        let mut v = [0u8; 8];
        let (mut ty, mut n) = (0, v.len());
        ok(f(&mut ty, v.as_mut_ptr().cast(), &mut n));
        let mut wide = [0u8; 8];
        wide[..n].copy_from_slice(&v[..n]);
        u64::from_ne_bytes(wide)
    }

    fn next_buffer(event: *mut c_void, timeout_ms: u64) -> Result<*mut c_void, GcError> {
        let mut data = [0u8; 16];
        let mut n = data.len();
        // SAFETY: `data` is writable for `n` bytes.
        let code = unsafe { EventGetData(event, data.as_mut_ptr().cast(), &mut n, timeout_ms) };
        if code != err::SUCCESS {
            return Err(code);
        }
        assert_eq!(n, 16);
        let h = usize::from_ne_bytes(data[..8].try_into().expect("8 bytes"));
        Ok(h as *mut c_void)
    }

    /// A consumer's whole session, as GenTL orders it: the one device by id, the XML through
    /// the remote port, buffers announced both ways, no frame before `AcquisitionStart`, a
    /// multi-part buffer holding the scene in millimetres, the queue rules, `EventKill`, and
    /// everything closed again.
    #[test]
    fn a_consumer_session_from_init_to_close() {
        let _one = lock(&SERIAL);
        std::env::set_var(ARGS_ENV, "--test-pattern --width 32 --height 24");
        ok(GCInitLib());
        std::env::remove_var(ARGS_ENV);
        assert_eq!(GCInitLib(), err::RESOURCE_IN_USE);
        let mut tl = std::ptr::null_mut();
        // SAFETY (this and every call below): valid pointers to locals, strings NUL-terminated.
        ok(unsafe { TLOpen(&mut tl) });
        let mut n = 0u32;
        ok(unsafe { TLGetNumInterfaces(tl, &mut n) });
        assert_eq!(n, 1);
        let if_id = string(|b, n| unsafe { TLGetInterfaceID(tl, 0, b, n) });
        let mut iface = std::ptr::null_mut();
        let c_if = std::ffi::CString::new(if_id).expect("id");
        ok(unsafe { TLOpenInterface(tl, c_if.as_ptr(), &mut iface) });
        let dev_id = string(|b, n| unsafe { IFGetDeviceID(iface, 0, b, n) });
        assert_eq!(dev_id, "SIM0001");
        let mut dev = std::ptr::null_mut();
        let wrong = c"nope";
        assert_eq!(
            unsafe { IFOpenDevice(iface, wrong.as_ptr(), 3, &mut dev) },
            err::INVALID_ID
        );
        let c_dev = std::ffi::CString::new(dev_id).expect("id");
        ok(unsafe { IFOpenDevice(iface, c_dev.as_ptr(), 3, &mut dev) });
        let mut port = std::ptr::null_mut();
        ok(unsafe { DevGetPort(dev, &mut port) });
        let url = string(|b, n| unsafe {
            GCGetPortURLInfo(port, 0, 0, std::ptr::null_mut(), b.cast(), n)
        });
        assert!(url.starts_with("Local:handeye-sim.xml;"), "{url}");
        let len = number(|t, b, n| unsafe { GCGetPortURLInfo(port, 0, 8, t, b, n) }) as usize;
        let addr = number(|t, b, n| unsafe { GCGetPortURLInfo(port, 0, 7, t, b, n) });
        let mut xml = vec![0u8; len];
        let mut size = len;
        ok(unsafe { GCReadPort(port, addr, xml.as_mut_ptr().cast(), &mut size) });
        assert!(String::from_utf8_lossy(&xml).contains("<RegisterDescription"));
        // The system module's port has no registers.
        let mut word = [0u8; 4];
        let mut size = 4;
        assert_eq!(
            unsafe { GCReadPort(tl, 0xA000, word.as_mut_ptr().cast(), &mut size) },
            err::NOT_AVAILABLE
        );

        let mut ds = std::ptr::null_mut();
        let stream_id = c"Stream0";
        ok(unsafe { DevOpenDataStream(dev, stream_id.as_ptr(), &mut ds) });
        let payload = number(|t, b, n| unsafe { DSGetInfo(ds, 7, t, b, n) }) as usize;
        assert_eq!(payload, 32 * 24 * 12);
        let mut mine = vec![0u8; payload];
        let mut bufs = [std::ptr::null_mut(); 3];
        ok(unsafe {
            DSAnnounceBuffer(
                ds,
                mine.as_mut_ptr().cast(),
                payload,
                7 as *mut c_void,
                &mut bufs[0],
            )
        });
        for b in &mut bufs[1..] {
            ok(unsafe { DSAllocAndAnnounceBuffer(ds, payload, std::ptr::null_mut(), b) });
        }
        for b in bufs {
            ok(DSQueueBuffer(ds, b));
        }
        assert_eq!(DSQueueBuffer(ds, bufs[0]), err::RESOURCE_IN_USE);
        let mut event = std::ptr::null_mut();
        ok(unsafe { GCRegisterEvent(ds, abi::EVENT_NEW_BUFFER, &mut event) });
        ok(DSStartAcquisition(ds, 0, abi::GENTL_INFINITE));
        // The stream runs, the device does not: no frame.
        assert_eq!(next_buffer(event, 300), Err(err::TIMEOUT));
        let mut size = 4;
        ok(unsafe {
            GCWritePort(
                port,
                ACQ_START_REG,
                1u32.to_be_bytes().as_ptr().cast(),
                &mut size,
            )
        });
        let b = next_buffer(event, 5_000).expect("a buffer");
        assert_eq!(b, bufs[0], "the oldest queued buffer first");
        assert_eq!(
            number(|t, v, n| unsafe { DSGetBufferInfo(ds, b, 2, t, v, n) }),
            7
        );
        assert_eq!(
            number(|t, v, n| unsafe { DSGetBufferInfo(ds, b, 19, t, v, n) }),
            10
        );
        let mut parts = 0u32;
        ok(unsafe { DSGetNumBufferParts(ds, b, &mut parts) });
        assert_eq!(parts, 1);
        let part = |cmd| number(|t, v, n| unsafe { DSGetBufferPartInfo(ds, b, 0, cmd, t, v, n) });
        assert_eq!(part(3), u64::from(pfnc::COORD3D_ABC32F));
        assert_eq!(part(13), 4, "Range");
        assert_eq!((part(5), part(6), part(1)), (32, 24, payload as u64));
        assert_eq!(part(0), mine.as_ptr() as u64);
        let expected = handeye_gige::sim::SceneSource::new(32, 24).render();
        for (i, p) in expected.points.iter().enumerate() {
            let got: Vec<f32> = (0..3)
                .map(|k| {
                    let o = 12 * i + 4 * k;
                    f32::from_le_bytes(mine[o..o + 4].try_into().expect("4 bytes"))
                })
                .collect();
            if p.x.is_nan() {
                assert!(got.iter().all(|c| c.is_nan()), "point {i}: {got:?}");
            } else {
                assert_eq!(got, [p.x * 1000.0, p.y * 1000.0, p.z * 1000.0], "point {i}");
            }
        }
        // Delivered, not queued: revoking is refused until it is flushed out of the queues.
        let mut base = std::ptr::null_mut();
        let mut user = std::ptr::null_mut();
        assert_eq!(
            unsafe { DSRevokeBuffer(ds, bufs[1], &mut base, &mut user) },
            err::RESOURCE_IN_USE
        );
        ok(EventKill(event));
        assert_eq!(next_buffer(event, 5_000), Err(err::ABORT));
        ok(DSStopAcquisition(ds, 1));
        ok(DSFlushQueue(ds, 4));
        for b in bufs {
            ok(unsafe { DSRevokeBuffer(ds, b, &mut base, &mut user) });
        }
        assert_eq!(user as usize, 0);
        ok(GCUnregisterEvent(ds, abi::EVENT_NEW_BUFFER));
        ok(DSClose(ds));
        ok(DevClose(dev));
        ok(IFClose(iface));
        ok(TLClose(tl));
        ok(GCCloseLib());
        assert_eq!(unsafe { TLOpen(&mut tl) }, err::NOT_INITIALIZED);
    }

    #[test]
    fn scene_options_come_from_the_environment_as_sim_camera_reads_them() {
        let _one = lock(&SERIAL);
        let parse = |s: &str| {
            use clap::Parser as _;
            EnvArgs::try_parse_from(shlex::split(s).expect("quotes")).map(|a| a.scene)
        };
        let a = parse("--robot 127.0.0.1 --width 320 --height 240 --serial 'A B'").expect("ok");
        assert_eq!((a.width, a.height, a.serial.as_str()), (320, 240, "A B"));
        assert_eq!(a.robot.as_deref(), Some("127.0.0.1"));
        let e = parse("--bind 127.0.0.1").expect_err("not a scene option");
        assert!(e.to_string().contains("--bind"), "{e}");
        // The failure GCInitLib reports names the variable and what it takes.
        std::env::set_var(ARGS_ENV, "--width 320 --loss 0.1");
        let f = scene_args().expect_err("--loss is the GigE camera's");
        std::env::remove_var(ARGS_ENV);
        assert_eq!(f.code, err::INVALID_PARAMETER);
        assert!(
            f.text
                .starts_with("HANDEYE_SIM_CAMERA_ARGS: unexpected argument '--loss'")
                && f.text.contains("handeye sim camera --help"),
            "{}",
            f.text
        );
    }
}
