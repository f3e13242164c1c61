//! RTDE framing: package types, the 3-byte size-and-type header, and cutting frames off a byte
//! buffer or an async stream.

use super::P;
use crate::UrError;

/// RTDE package types.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
#[allow(missing_docs)]
pub enum PackageType {
    RequestProtocolVersion = b'V',
    GetUrcontrolVersion = b'v',
    TextMessage = b'M',
    DataPackage = b'U',
    SetupOutputs = b'O',
    SetupInputs = b'I',
    Start = b'S',
    Pause = b'P',
}

impl PackageType {
    /// From the header byte.
    pub fn from_byte(b: u8) -> Result<Self, UrError> {
        Ok(match b {
            b'V' => PackageType::RequestProtocolVersion,
            b'v' => PackageType::GetUrcontrolVersion,
            b'M' => PackageType::TextMessage,
            b'U' => PackageType::DataPackage,
            b'O' => PackageType::SetupOutputs,
            b'I' => PackageType::SetupInputs,
            b'S' => PackageType::Start,
            b'P' => PackageType::Pause,
            other => {
                return Err(UrError::malformed(
                    P,
                    format!("unknown package type {other}"),
                ))
            }
        })
    }
}

/// A raw package: type plus payload (header stripped).
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Package type.
    pub kind: PackageType,
    /// Payload after the 3-byte header.
    pub payload: Vec<u8>,
}

impl Frame {
    /// Build a frame.
    pub fn new(kind: PackageType, payload: Vec<u8>) -> Self {
        Self { kind, payload }
    }

    /// Encode with header. Fails if the payload does not fit the 16-bit size.
    pub fn encode(&self) -> Result<Vec<u8>, UrError> {
        let size = self.payload.len() + 3;
        let size16 = u16::try_from(size).map_err(|_| {
            UrError::InvalidArgument(format!("RTDE package of {size} bytes exceeds 65535"))
        })?;
        let mut out = Vec::with_capacity(size);
        out.extend_from_slice(&size16.to_be_bytes());
        out.push(self.kind as u8);
        out.extend_from_slice(&self.payload);
        Ok(out)
    }

    /// Cut one frame off the front of `buf`: `Ok(None)` if more bytes are needed, otherwise the
    /// frame and how many bytes it used. Errors on an impossible size or an unknown type.
    pub fn split(buf: &[u8]) -> Result<Option<(Frame, usize)>, UrError> {
        if buf.len() < 3 {
            return Ok(None);
        }
        let size = usize::from(u16::from_be_bytes([buf[0], buf[1]]));
        if size < 3 {
            return Err(UrError::malformed(
                P,
                format!("package size {size} is smaller than its 3-byte header"),
            ));
        }
        let kind = PackageType::from_byte(buf[2])?;
        if buf.len() < size {
            return Ok(None);
        }
        Ok(Some((
            Frame {
                kind,
                payload: buf[3..size].to_vec(),
            },
            size,
        )))
    }
}

/// Read one frame from an async stream (cuts by size; several or partial packages per read are
/// fine). `Ok(None)` on a clean EOF between packages.
pub async fn read_frame<R: tokio::io::AsyncRead + Unpin>(
    r: &mut R,
) -> Result<Option<Frame>, FrameReadError> {
    use tokio::io::AsyncReadExt;
    let mut hdr = [0u8; 3];
    let mut got = 0;
    while got < 3 {
        let n = r.read(&mut hdr[got..]).await.map_err(FrameReadError::Io)?;
        if n == 0 {
            if got == 0 {
                return Ok(None);
            }
            return Err(FrameReadError::Protocol(UrError::malformed(
                P,
                "connection closed inside a package header",
            )));
        }
        got += n;
    }
    let size = usize::from(u16::from_be_bytes([hdr[0], hdr[1]]));
    if size < 3 {
        return Err(FrameReadError::Protocol(UrError::malformed(
            P,
            format!("package size {size} is smaller than its 3-byte header"),
        )));
    }
    let kind = PackageType::from_byte(hdr[2]).map_err(FrameReadError::Protocol)?;
    let mut payload = vec![0; size - 3];
    r.read_exact(&mut payload).await.map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            FrameReadError::Protocol(UrError::malformed(P, "connection closed inside a package"))
        } else {
            FrameReadError::Io(e)
        }
    })?;
    Ok(Some(Frame { kind, payload }))
}

/// Why reading a frame failed.
#[derive(Debug)]
pub enum FrameReadError {
    /// Transport error.
    Io(std::io::Error),
    /// Bad bytes.
    Protocol(UrError),
}
