//! The data stream module: announced buffers, acquisition, and every part of a delivered
//! buffer checked against the memory we lent before it is copied.

use std::ffi::c_void;
use std::rc::Rc;
use std::sync::Arc;
use std::time::Duration;

use super::{c_id, non_null, query_count, query_id, query_number, Device, Lib, MAX_ITEMS};
use crate::error::{GentlError, Result};
use crate::ffi::{self, err, Handle};
use crate::host::watched;

impl Device {
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
