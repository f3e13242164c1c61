//! The host process: `handeye gentl-host` (the binary calls [`serve`]), the one process that
//! loads a GenTL producer. It reads [`Request`]s on stdin and answers on its stdout, and
//! announces each producer call that may block ([`watched`]) so that the camera side
//! ([`GentlCamera`](crate::GentlCamera)) can kill it past the call's deadline. A producer that
//! blocks, aborts, leaks or calls `exit()` takes only this process with it.
//!
//! The producer never writes into the pipe: the protocol keeps a duplicate of stdout, and
//! stdout itself is pointed at stderr before the producer is loaded. When stdin closes (the
//! camera was dropped, or the daemon died) the device is closed and the process ends; a
//! producer that does not close within [`CLOSE_GRACE`] is left behind by `_exit`.

use std::fs::File;
use std::io::Write;
use std::os::fd::FromRawFd;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{mpsc, Mutex};
use std::time::Duration;

use handeye_hal::HalError;

use crate::camera::GentlOptions;
use crate::device::{self, Open};
use crate::error::GentlError;
use crate::wire::{self, Answer, Failure, FailureClass, Request, Tag};

/// How long the device may take to close after the camera side went away.
pub(crate) const CLOSE_GRACE: Duration = Duration::from_secs(2);

/// The protocol's output (a duplicate of the original stdout); `None` outside a host.
static SINK: Mutex<Option<File>> = Mutex::new(None);
/// The budget of a producer call without one of its own, milliseconds.
static CALL_BUDGET_MS: AtomicU64 = AtomicU64::new(10_000);

fn send(tag: Tag, body: &[u8]) {
    let mut sink = SINK.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(out) = sink.as_mut() {
        // The camera side is gone: stdin closes too, and the reader thread ends the process.
        let _ = wire::write_frame(out, tag, body);
    }
}

/// Run `f`, a producer call that may block, announced to the camera side as `call` with
/// `budget` (the call budget of the request when `None`). Outside a host it just runs `f`.
pub(crate) fn watched<T>(call: &str, budget: Option<Duration>, f: impl FnOnce() -> T) -> T {
    let ms = budget.map_or_else(
        || CALL_BUDGET_MS.load(Ordering::Relaxed),
        |b| u64::try_from(b.as_millis()).unwrap_or(u64::MAX),
    );
    send(Tag::Begin, &wire::json(&(call, ms)));
    let out = f();
    send(Tag::End, &[]);
    out
}

fn failure(e: GentlError) -> Answer {
    let message = e.to_string();
    let class = match HalError::from(e) {
        HalError::Timeout { timeout, .. } => FailureClass::FrameTimeout {
            timeout_ms: u64::try_from(timeout.as_millis()).unwrap_or(u64::MAX),
        },
        HalError::Connection { .. } => FailureClass::Connection,
        _ => FailureClass::Protocol,
    };
    Answer::Failed(Failure { message, class })
}

fn answer(a: &Answer) {
    send(Tag::Answer, &wire::json(a));
}

/// Serve the camera side on stdin/stdout until stdin closes; the process' exit code.
///
/// Must be called before anything else writes to stdout, on the process' main thread.
pub fn serve() -> std::process::ExitCode {
    // SAFETY: dup/dup2 on the standard descriptors, which this process owns; the duplicate
    // becomes the protocol's File (its only owner).
    let proto = unsafe {
        let fd = libc::dup(1);
        if fd < 0 || libc::dup2(2, 1) < 0 {
            eprintln!(
                "gentl-host: cannot set up its output: {}",
                std::io::Error::last_os_error()
            );
            return std::process::ExitCode::from(2);
        }
        File::from_raw_fd(fd)
    };
    *SINK.lock().unwrap_or_else(|p| p.into_inner()) = Some(proto);
    let (tx, rx) = mpsc::channel::<Request>();
    let reader = std::thread::Builder::new()
        .name("gentl-host-input".into())
        .spawn(move || {
            let mut stdin = std::io::stdin().lock();
            while let Ok(Some((Tag::Request, body))) = wire::read_frame(&mut stdin) {
                let Ok(r) = serde_json::from_slice::<Request>(&body) else {
                    break;
                };
                if tx.send(r).is_err() {
                    break;
                }
            }
            drop(tx);
            // The camera side is gone: give the device its close, then end whatever the
            // producer is doing.
            std::thread::sleep(CLOSE_GRACE);
            // SAFETY: _exit ends the process without running anything of the producer's.
            unsafe { libc::_exit(0) }
        });
    if let Err(e) = reader {
        eprintln!("gentl-host: cannot start its input thread: {e}");
        return std::process::ExitCode::from(2);
    }
    let mut open: Option<Open> = None;
    while let Ok(request) = rx.recv() {
        match request {
            Request::List {
                producer,
                call_timeout_ms,
            } => {
                CALL_BUDGET_MS.store(call_timeout_ms, Ordering::Relaxed);
                answer(&match device::list_devices(Path::new(&producer)) {
                    Ok(list) => Answer::Listed(list),
                    Err(e) => failure(e),
                });
            }
            Request::Open {
                producer,
                device,
                confidence,
                trigger,
                settings,
                call_timeout_ms,
            } => {
                CALL_BUDGET_MS.store(call_timeout_ms, Ordering::Relaxed);
                open = None;
                let options = GentlOptions {
                    device,
                    confidence,
                    trigger,
                    settings,
                    ..GentlOptions::default()
                };
                answer(&match device::open(Path::new(&producer), options) {
                    Ok(o) => {
                        open = Some(o);
                        Answer::Opened
                    }
                    Err(e) => failure(e),
                });
            }
            Request::Features => answer(&match open.as_mut() {
                Some(o) => Answer::Features(o.features()),
                None => failure(GentlError::Closed("no device is open".into())),
            }),
            Request::Info => answer(&match open.as_mut() {
                Some(o) => o.camera_info().map_or_else(failure, Answer::Info),
                None => failure(GentlError::Closed("no device is open".into())),
            }),
            Request::Capture {
                frames,
                frame_timeout_ms,
                exposure_us,
            } => {
                let Some(o) = open.as_mut() else {
                    answer(&failure(GentlError::Closed("no device is open".into())));
                    continue;
                };
                let r = exposure_us
                    .map_or(Ok(()), |us| o.set_exposure(Duration::from_micros(us)))
                    .and_then(|()| o.capture(frames, Duration::from_millis(frame_timeout_ms)));
                match r {
                    Ok((clouds, stats)) => {
                        answer(&Answer::Captured {
                            clouds: u32::try_from(clouds.len()).unwrap_or(u32::MAX),
                            stats,
                        });
                        for c in &clouds {
                            send(Tag::Cloud, &wire::encode_cloud(c));
                        }
                    }
                    Err(e) => answer(&failure(e)),
                }
            }
        }
    }
    // Input closed: the device closes in order (stream, device, interface, system, library).
    drop(open);
    let _ = std::io::stderr().flush();
    std::process::ExitCode::SUCCESS
}
