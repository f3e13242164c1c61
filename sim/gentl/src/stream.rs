//! The data stream: announced buffers, the input pool and output queue, the new-buffer event,
//! and the acquisition thread that renders the scene into the consumer's buffers while both
//! the stream (`DSStartAcquisition`) and the remote device (`AcquisitionStart`) acquire.

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use handeye_gige::sim::{FrameSource, SimDevice};

use crate::abi::{err, Fail, Res, GENTL_INFINITE};

/// The simulated camera behind the device module: its registers and its scene.
pub(crate) struct Camera {
    pub(crate) device: SimDevice,
    pub(crate) source: Mutex<Box<dyn FrameSource>>,
}

impl std::fmt::Debug for Camera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Camera")
            .field("device", &self.device)
            .finish_non_exhaustive()
    }
}

/// One part of a delivered buffer, where it sits in the buffer and what it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct PartMeta {
    pub(crate) offset: usize,
    pub(crate) size: usize,
    /// `PART_DATATYPE_*` (GVSP's multi-part data types have the same values).
    pub(crate) data_type: u64,
    /// PFNC pixel format.
    pub(crate) format: u64,
    /// `ComponentIDValue`: 1 intensity, 4 range, 6 confidence.
    pub(crate) purpose: u64,
    pub(crate) width: u64,
    pub(crate) height: u64,
}

/// What the last fill left in a buffer.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(crate) struct Filled {
    pub(crate) parts: Vec<PartMeta>,
    pub(crate) size_filled: usize,
    pub(crate) timestamp_ns: u64,
    pub(crate) frame_id: u64,
    /// The frame did not fit (the buffer is smaller than the payload): no parts.
    pub(crate) incomplete: bool,
}

/// An announced buffer.
#[derive(Debug)]
pub(crate) struct Slot {
    /// Start of the memory (the consumer's, or `owned`'s).
    pub(crate) base: usize,
    pub(crate) size: usize,
    /// The consumer's `pPrivate`.
    pub(crate) user: usize,
    /// Memory of `DSAllocAndAnnounceBuffer`, freed on revoke.
    pub(crate) owned: Option<Box<[u8]>>,
    pub(crate) filled: Option<Filled>,
}

/// Counters, queues and flags of a stream.
#[derive(Debug, Default)]
pub(crate) struct StreamState {
    pub(crate) buffers: BTreeMap<usize, Slot>,
    pub(crate) input: VecDeque<usize>,
    pub(crate) output: VecDeque<usize>,
    /// The buffer the acquisition thread is filling.
    pub(crate) filling: Option<usize>,
    pub(crate) acquiring: bool,
    /// Buffers still to deliver in this acquisition (`GENTL_INFINITE`: until stopped).
    pub(crate) to_acquire: u64,
    pub(crate) delivered: u64,
    pub(crate) underrun: u64,
    pub(crate) started: u64,
    /// The new-buffer event's handle, when registered.
    pub(crate) event: Option<usize>,
    /// `EventKill` was called: one waiting `EventGetData` returns `GC_ERR_ABORT`.
    pub(crate) killed: bool,
    pub(crate) frame_id: u64,
}

impl StreamState {
    /// Whether `h` is in the input pool, the output queue or being filled.
    pub(crate) fn is_queued(&self, h: usize) -> bool {
        self.input.contains(&h) || self.output.contains(&h) || self.filling == Some(h)
    }
}

/// A data stream of the device.
#[derive(Debug)]
pub(crate) struct Stream {
    pub(crate) camera: Arc<Camera>,
    pub(crate) state: Mutex<StreamState>,
    /// Signalled when a buffer reaches the output queue, on `EventKill` and on stop.
    pub(crate) cond: Condvar,
    worker: Mutex<Option<JoinHandle<()>>>,
}

pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Stream {
    pub(crate) fn new(camera: Arc<Camera>) -> Self {
        Self {
            camera,
            state: Mutex::new(StreamState::default()),
            cond: Condvar::new(),
            worker: Mutex::new(None),
        }
    }

    /// `DSStartAcquisition`: deliver `count` buffers (`GENTL_INFINITE`: until stopped).
    pub(crate) fn start(self: &Arc<Self>, count: u64) -> Res {
        {
            let mut st = lock(&self.state);
            if st.acquiring {
                return Err(Fail::new(
                    err::RESOURCE_IN_USE,
                    "the stream is acquiring already",
                ));
            }
            if st.buffers.is_empty() {
                return Err(Fail::new(
                    err::INVALID_PARAMETER,
                    "no buffer announced: announce and queue buffers before DSStartAcquisition",
                ));
            }
            if count == 0 {
                return Err(Fail::new(err::INVALID_PARAMETER, "iNumToAcquire is 0"));
            }
            st.acquiring = true;
            st.to_acquire = count;
            st.started += 1;
        }
        // A stopped thread may still be winding down.
        self.join_worker();
        let me = Arc::clone(self);
        let handle = std::thread::Builder::new()
            .name("gentl-sim-acquire".into())
            .spawn(move || acquire(&me))
            .map_err(|e| {
                Fail::new(
                    err::ERROR,
                    format!("cannot start the acquisition thread: {e}"),
                )
            })?;
        *lock(&self.worker) = Some(handle);
        Ok(())
    }

    /// `DSStopAcquisition`: stops and waits for the acquisition thread (a buffer being
    /// filled goes back to the front of the input pool).
    pub(crate) fn stop(&self) -> Res {
        let was = {
            let mut st = lock(&self.state);
            std::mem::replace(&mut st.acquiring, false)
        };
        self.cond.notify_all();
        self.join_worker();
        if was {
            Ok(())
        } else {
            Err(Fail::new(
                err::RESOURCE_IN_USE,
                "the stream is not acquiring",
            ))
        }
    }

    fn join_worker(&self) {
        let handle = lock(&self.worker).take();
        if let Some(h) = handle {
            if h.join().is_err() {
                eprintln!("handeye GenTL producer: the acquisition thread panicked");
            }
        }
    }

    /// `EventGetData` of the new-buffer event: the next delivered buffer within `timeout_ms`.
    pub(crate) fn next_delivered(&self, timeout_ms: u64) -> Res<(usize, usize)> {
        let deadline = (timeout_ms != GENTL_INFINITE)
            .then(|| Instant::now().checked_add(Duration::from_millis(timeout_ms)))
            .flatten();
        let mut st = lock(&self.state);
        loop {
            if st.killed {
                st.killed = false;
                return Err(Fail::new(err::ABORT, "EventKill"));
            }
            if let Some(h) = st.output.pop_front() {
                let user = st.buffers.get(&h).map_or(0, |s| s.user);
                return Ok((h, user));
            }
            let wait = match deadline {
                Some(d) => {
                    let now = Instant::now();
                    if now >= d {
                        return Err(Fail::new(err::TIMEOUT, "no new buffer within the timeout"));
                    }
                    d - now
                }
                None => Duration::from_millis(200),
            };
            st = self
                .cond
                .wait_timeout(st, wait)
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
    }
}

impl Drop for Stream {
    fn drop(&mut self) {
        lock(&self.state).acquiring = false;
        self.join_worker();
    }
}

/// The acquisition thread: at the frame rate, while the remote device acquires, takes the
/// oldest buffer of the input pool, renders a frame into it and queues it for delivery.
fn acquire(stream: &Arc<Stream>) {
    let cam = &stream.camera;
    let mut next = Instant::now();
    let mut last_problem: Option<String> = None;
    loop {
        if !lock(&stream.state).acquiring {
            return;
        }
        if !cam.device.is_acquiring() {
            std::thread::sleep(Duration::from_millis(2));
            next = Instant::now();
            continue;
        }
        let now = Instant::now();
        if now < next {
            std::thread::sleep((next - now).min(Duration::from_millis(20)));
            continue;
        }
        // With the trigger on, a frame per software trigger.
        if !cam.device.take_trigger() {
            std::thread::sleep(Duration::from_millis(2));
            continue;
        }
        let period = Duration::from_secs_f64(1.0 / cam.device.frame_rate().max(0.01));
        next = (next + period).max(now);
        let handle = {
            let mut st = lock(&stream.state);
            match st.input.pop_front() {
                Some(h) => {
                    st.filling = Some(h);
                    h
                }
                None => {
                    // A frame the consumer had no buffer for.
                    st.underrun += 1;
                    continue;
                }
            }
        };
        let frame = lock(&cam.source).next_frame();
        let cloud = match frame {
            Ok(c) => {
                last_problem = None;
                c
            }
            Err(e) => {
                let msg = e.to_string();
                if last_problem.as_deref() != Some(msg.as_str()) {
                    eprintln!("handeye GenTL producer: frame source failed: {msg}");
                    last_problem = Some(msg);
                }
                let mut st = lock(&stream.state);
                st.filling = None;
                st.input.push_front(handle);
                continue;
            }
        };
        let block = cam.device.encode(&cloud);
        let mut st = lock(&stream.state);
        st.filling = None;
        if !st.acquiring {
            st.input.push_front(handle);
            return;
        }
        st.frame_id += 1;
        let frame_id = st.frame_id;
        let Some(slot) = st.buffers.get_mut(&handle) else {
            continue;
        };
        let total: usize = block.parts.iter().map(|(_, d)| d.len()).sum();
        let mut filled = Filled {
            timestamp_ns: block.timestamp,
            frame_id,
            incomplete: total > slot.size,
            ..Filled::default()
        };
        if !filled.incomplete {
            let mut offset = 0;
            for (info, data) in &block.parts {
                // SAFETY: the buffer is announced with `slot.size` writable bytes at
                // `slot.base` (the consumer's promise for DSAnnounceBuffer, ours for
                // DSAllocAndAnnounceBuffer), and `offset + data.len() <= total <= slot.size`.
                unsafe {
                    std::ptr::copy_nonoverlapping(
                        data.as_ptr(),
                        (slot.base as *mut u8).add(offset),
                        data.len(),
                    );
                }
                filled.parts.push(PartMeta {
                    offset,
                    size: data.len(),
                    data_type: u64::from(info.data_type),
                    format: u64::from(info.pixel_format),
                    purpose: u64::from(info.purpose),
                    width: u64::from(info.width),
                    height: u64::from(info.height),
                });
                offset += data.len();
            }
            filled.size_filled = total;
        }
        slot.filled = Some(filled);
        st.output.push_back(handle);
        st.delivered += 1;
        if st.to_acquire != GENTL_INFINITE {
            st.to_acquire -= 1;
            if st.to_acquire == 0 {
                st.acquiring = false;
            }
        }
        drop(st);
        stream.cond.notify_all();
    }
}
