//! Datagrams in batches: one `recvmmsg` / `sendmmsg` system call for many packets on Linux,
//! one call per datagram elsewhere. The stream receiver takes packets with [`RecvBatch`]; the
//! simulated camera sends them with [`send_all`].

use std::net::{SocketAddr, UdpSocket};
use std::time::Duration;

/// Datagrams taken per receive call.
pub(crate) const BATCH: usize = 64;

/// Preallocated buffers for a batch of datagrams (one `recvmmsg` call on Linux): no
/// allocation and one system call for up to [`BATCH`] packets.
#[derive(Debug, Default)]
pub(crate) struct RecvBatch {
    slot: usize,
    data: Vec<u8>,
    /// Datagram lengths; longer than `slot` means truncated.
    lens: Vec<usize>,
}

impl RecvBatch {
    pub(crate) fn new(packet_size: usize) -> Self {
        // A datagram of the negotiated packet size is `packet_size - 28` bytes; leave slack
        // and treat anything longer than a slot as malformed (truncated).
        let slot = (packet_size.clamp(576, 65_536) + 256).min(65_536);
        Self {
            slot,
            data: vec![0; slot * BATCH],
            lens: Vec::with_capacity(BATCH),
        }
    }

    /// Datagram `i` of the last receive; `None` when it was truncated.
    pub(crate) fn packet(&self, i: usize) -> Option<&[u8]> {
        let n = *self.lens.get(i)?;
        (n <= self.slot).then(|| &self.data[i * self.slot..i * self.slot + n])
    }

    /// Wait (up to the socket's read timeout) for one datagram, then take what else is
    /// queued, up to a batch. Returns the number received.
    #[cfg(target_os = "linux")]
    pub(crate) fn recv(&mut self, sock: &UdpSocket) -> std::io::Result<usize> {
        use std::os::fd::AsRawFd;
        self.lens.clear();
        let slot = self.slot;
        let base = self.data.as_mut_ptr();
        // SAFETY: all-zero bytes are valid iovec/mmsghdr values (null pointers, zero lengths).
        let mut iovs: [libc::iovec; BATCH] = unsafe { std::mem::zeroed() };
        let mut msgs: [libc::mmsghdr; BATCH] = unsafe { std::mem::zeroed() };
        for (i, (iov, m)) in iovs.iter_mut().zip(msgs.iter_mut()).enumerate() {
            // SAFETY: `i * slot` is within `data` (BATCH slots of `slot` bytes).
            iov.iov_base = unsafe { base.add(i * slot) }.cast();
            iov.iov_len = slot;
            m.msg_hdr.msg_iov = iov;
            m.msg_hdr.msg_iovlen = 1;
        }
        // SAFETY: every mmsghdr points at one iovec covering its own slot of `data`, which
        // outlives the call; the kernel writes at most `slot` bytes per slot and the lengths.
        let n = unsafe {
            libc::recvmmsg(
                sock.as_raw_fd(),
                msgs.as_mut_ptr(),
                BATCH as libc::c_uint,
                libc::MSG_WAITFORONE,
                std::ptr::null_mut(),
            )
        };
        if n < 0 {
            return Err(std::io::Error::last_os_error());
        }
        let n = n as usize;
        for m in &msgs[..n] {
            let truncated = m.msg_hdr.msg_flags & libc::MSG_TRUNC != 0;
            self.lens.push(if truncated {
                usize::MAX
            } else {
                m.msg_len as usize
            });
        }
        Ok(n)
    }

    /// Portable fallback: one datagram per call.
    #[cfg(not(target_os = "linux"))]
    pub(crate) fn recv(&mut self, sock: &UdpSocket) -> std::io::Result<usize> {
        self.lens.clear();
        let (n, _) = sock.recv_from(&mut self.data[..self.slot])?;
        self.lens.push(n);
        Ok(1)
    }
}

/// Datagrams per `sendmmsg` call.
pub(crate) const SEND_BATCH: usize = 32;

/// Send the queued datagrams to `dest` (one `sendmmsg` per [`SEND_BATCH`] on Linux) and clear
/// the queue. A full host queue (`ENOBUFS`) gets one short back-off; other errors drop the rest.
#[cfg(target_os = "linux")]
pub(crate) fn send_all(sock: &UdpSocket, dest: SocketAddr, out: &mut Vec<&[u8]>) {
    use std::os::fd::AsRawFd;
    let addr = socket2::SockAddr::from(dest);
    let mut sent = 0;
    let mut retried = false;
    while sent < out.len() {
        let rest = &out[sent..(sent + SEND_BATCH).min(out.len())];
        // SAFETY: all-zero bytes are valid iovec/mmsghdr values (null pointers, zero lengths).
        let mut iovs: [libc::iovec; SEND_BATCH] = unsafe { std::mem::zeroed() };
        let mut msgs: [libc::mmsghdr; SEND_BATCH] = unsafe { std::mem::zeroed() };
        for ((p, iov), m) in rest.iter().zip(iovs.iter_mut()).zip(msgs.iter_mut()) {
            iov.iov_base = p.as_ptr().cast_mut().cast();
            iov.iov_len = p.len();
            m.msg_hdr.msg_name = addr.as_ptr().cast_mut().cast();
            m.msg_hdr.msg_namelen = addr.len();
            m.msg_hdr.msg_iov = iov;
            m.msg_hdr.msg_iovlen = 1;
        }
        // SAFETY: the first `rest.len()` headers point at live iovecs over live packets and at
        // `addr`; the kernel only reads them (and writes `msg_len`).
        let n = unsafe {
            libc::sendmmsg(
                sock.as_raw_fd(),
                msgs.as_mut_ptr(),
                rest.len() as libc::c_uint,
                0,
            )
        };
        if n >= 0 {
            sent += n as usize;
            continue;
        }
        let e = std::io::Error::last_os_error();
        if e.raw_os_error() == Some(libc::ENOBUFS) && !retried {
            // The host is not keeping up; back off briefly.
            retried = true;
            std::thread::sleep(Duration::from_micros(200));
        } else {
            tracing::debug!("send failed, {} packets lost: {e}", out.len() - sent);
            break;
        }
    }
    out.clear();
}

/// Portable fallback: one `send_to` per datagram.
#[cfg(not(target_os = "linux"))]
pub(crate) fn send_all(sock: &UdpSocket, dest: SocketAddr, out: &mut Vec<&[u8]>) {
    for p in out.drain(..) {
        if let Err(e) = sock.send_to(p, dest) {
            tracing::debug!("send failed: {e}");
        }
    }
}
