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
//! `HANDEYE_SIM_GENTL_FAULT` makes it a hostile producer for tests (`faults`: calls that
//! block, abort or exit, parts and values that lie).
//!
//! Layout: `abi` (error codes, `...GetInfo` conventions), this file (the library's state, the
//! handles, `GCInitLib`/`GCCloseLib`/`GCGetInfo`/`GCGetLastError`), `modules` (system,
//! interface, device), `ports` (the remote device's registers and XML; the modules' node maps
//! in `nodemaps`), `datastream` (its C functions) over `stream` (buffers, queues, the
//! acquisition thread).
#![allow(non_snake_case)] // the GenTL standard's function names

mod abi;
mod datastream;
mod faults;
mod modules;
mod nodemaps;
mod ports;
mod stream;

pub use datastream::*;
pub use modules::*;
pub use ports::*;

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
mod tests;
