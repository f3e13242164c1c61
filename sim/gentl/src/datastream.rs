//! The data stream's functions: buffers, queues, acquisition, the new-buffer event.

use super::*;

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
    crate::faults::at("EventGetData");
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
    crate::faults::at("DSStartAcquisition");
    call(|p| p.stream(ds)?.start(count))
}

#[no_mangle]
pub extern "C" fn DSStopAcquisition(ds: *mut c_void, _flags: i32) -> GcError {
    crate::faults::at("DSStopAcquisition");
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
        // A camera left in GenDCStreamingMode On (issue 44's refusal test).
        let gendc = p.camera().is_ok_and(|c| c.device.gendc_streaming());
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
                19 if gendc => Info::SizeT(abi::PAYLOAD_TYPE_GENDC as usize),
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
        let mut parts = with_slot(p, ds, handle, |slot, _| Ok(filled(slot)?.parts.len()))?;
        if crate::faults::on("overlapping-parts") {
            parts = 64;
        }
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
            let all = &filled(slot)?.parts;
            let overlapping = crate::faults::on("overlapping-parts");
            let at = if overlapping {
                index as usize % all.len().max(1)
            } else {
                index as usize
            };
            let part = *all
                .get(at)
                .ok_or_else(|| Fail::new(err::INVALID_INDEX, format!("no part {index}")))?;
            let range = part.format == u64::from(handeye_gige::decode::pfnc::COORD3D_ABC32F);
            Ok(match cmd {
                0 if overlapping => Info::Ptr(slot.base),
                0 => Info::Ptr(slot.base + part.offset),
                1 if overlapping => Info::SizeT(slot.size),
                1 if range && crate::faults::on("short-part") => Info::SizeT(part.size - 4),
                1 => Info::SizeT(part.size),
                2 => Info::SizeT(part.data_type as usize),
                3 if range && crate::faults::on("lying-format") => {
                    Info::U64(u64::from(handeye_gige::decode::pfnc::COORD3D_C16))
                }
                3 => Info::U64(part.format),
                4 => Info::U64(abi::PIXELFORMAT_NAMESPACE_PFNC_32BIT),
                5 if crate::faults::on("zero-width") => Info::SizeT(0),
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
