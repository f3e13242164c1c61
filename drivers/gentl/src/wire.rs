//! The pipe protocol between [`GentlCamera`](crate::GentlCamera) and its host process (the
//! `handeye gentl-host` child that loads the producer, see [`crate::host`]).
//!
//! A message is a frame: one tag byte, a little-endian u32 length, then that many bytes. The
//! requests and small replies are JSON; point clouds are binary (width, height, flags, then
//! f32 coordinates, intensities and confidences, little-endian). The host announces every
//! producer call that may block ([`Message::Begin`] with the call's budget, then
//! [`Message::End`]), so the camera side can abandon it past its deadline and say which call
//! it was.

use std::io::{Read, Write};
use std::time::Duration;

use handeye_hal::nalgebra::Point3;
use handeye_hal::{CameraInfo, PointCloud, Trigger};

use crate::camera::{GentlStats, InterfaceDevices};

/// Largest frame accepted, bytes: a 2^20 x 2^20 cloud cannot be sent, a 64 MP one with
/// intensity and confidence can (20 bytes a point).
pub(crate) const MAX_FRAME: u64 = 2 << 30;

/// What the camera side asks the host.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) enum Request {
    /// List the producer's interfaces and devices, then end.
    List {
        producer: String,
        call_timeout_ms: u64,
    },
    /// Load the producer and open the device; the host then serves [`Request::Info`] and
    /// [`Request::Capture`] until its input closes.
    Open {
        producer: String,
        device: Option<String>,
        confidence: bool,
        trigger: Trigger,
        settings: handeye_hal::CameraSettings,
        call_timeout_ms: u64,
    },
    /// The device's identity and size.
    Info,
    /// The features a user would set (`camera probe --gentl --device`).
    Features,
    /// Capture frames.
    Capture {
        frames: u32,
        frame_timeout_ms: u64,
        exposure_us: Option<u64>,
    },
}

/// What the host answers (JSON part).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) enum Answer {
    Listed(Vec<InterfaceDevices>),
    Opened,
    Info(CameraInfo),
    Features(Vec<handeye_gige::genicam::FeatureState>),
    /// The clouds follow as [`Tag::Cloud`] frames, this many.
    Captured {
        clouds: u32,
        stats: GentlStats,
    },
    Failed(Failure),
}

/// An error of the host, as the camera side reports it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Failure {
    /// The error's text.
    pub(crate) message: String,
    /// How the daemon classes it.
    pub(crate) class: FailureClass,
}

/// The [`handeye_hal::HalError`] an error of the host becomes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FailureClass {
    /// No frame in time: `HalError::Timeout` after this long.
    FrameTimeout {
        /// The frame timeout, milliseconds.
        timeout_ms: u64,
    },
    /// The producer failed a call: `HalError::Connection`.
    Connection,
    /// Anything else: `HalError::Protocol`.
    Protocol,
}

/// A frame's kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub(crate) enum Tag {
    /// A [`Request`] (camera side to host).
    Request = 1,
    /// A producer call begins: JSON `[name, budget_ms]`.
    Begin = 2,
    /// The call announced last returned.
    End = 3,
    /// An [`Answer`].
    Answer = 4,
    /// One point cloud (binary).
    Cloud = 5,
}

impl Tag {
    fn from_u8(b: u8) -> Option<Self> {
        Some(match b {
            1 => Self::Request,
            2 => Self::Begin,
            3 => Self::End,
            4 => Self::Answer,
            5 => Self::Cloud,
            _ => return None,
        })
    }
}

/// One decoded frame from the host.
#[derive(Debug)]
pub(crate) enum Message {
    Begin { call: String, budget: Duration },
    End,
    Answer(Answer),
    Cloud(PointCloud),
}

/// Write one frame.
pub(crate) fn write_frame(w: &mut impl Write, tag: Tag, body: &[u8]) -> std::io::Result<()> {
    let len = u32::try_from(body.len())
        .map_err(|_| std::io::Error::other(format!("a frame of {} bytes", body.len())))?;
    let mut head = [0u8; 5];
    head[0] = tag as u8;
    head[1..].copy_from_slice(&len.to_le_bytes());
    w.write_all(&head)?;
    w.write_all(body)?;
    w.flush()
}

/// Read one frame: its tag and bytes; `Ok(None)` at the end of input.
pub(crate) fn read_frame(r: &mut impl Read) -> std::io::Result<Option<(Tag, Vec<u8>)>> {
    let mut head = [0u8; 5];
    match r.read_exact(&mut head) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
        Err(e) => return Err(e),
    }
    let tag = Tag::from_u8(head[0]).ok_or_else(|| bad(format!("frame tag {}", head[0])))?;
    let len = u32::from_le_bytes([head[1], head[2], head[3], head[4]]);
    if u64::from(len) > MAX_FRAME {
        return Err(bad(format!("a frame of {len} bytes")));
    }
    let mut body = Vec::new();
    r.take(u64::from(len)).read_to_end(&mut body)?;
    if body.len() != len as usize {
        return Err(bad("a frame cut short".into()));
    }
    Ok(Some((tag, body)))
}

fn bad(detail: String) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, detail)
}

/// JSON of a value.
pub(crate) fn json<T: serde::Serialize>(v: &T) -> Vec<u8> {
    // Serializing these plain types cannot fail.
    serde_json::to_vec(v).unwrap_or_default()
}

/// Decode a frame from the host.
pub(crate) fn decode_message(tag: Tag, body: &[u8]) -> std::io::Result<Message> {
    fn from_json<T: serde::de::DeserializeOwned>(b: &[u8]) -> std::io::Result<T> {
        serde_json::from_slice(b).map_err(|e| bad(format!("a bad message: {e}")))
    }
    Ok(match tag {
        Tag::Begin => {
            let (call, ms): (String, u64) = from_json(body)?;
            Message::Begin {
                call,
                budget: Duration::from_millis(ms),
            }
        }
        Tag::End => Message::End,
        Tag::Answer => Message::Answer(from_json(body)?),
        Tag::Cloud => Message::Cloud(decode_cloud(body)?),
        Tag::Request => return Err(bad("a request from the host".into())),
    })
}

const HAS_INTENSITY: u8 = 1;
const HAS_CONFIDENCE: u8 = 2;

/// A cloud as bytes.
pub(crate) fn encode_cloud(c: &PointCloud) -> Vec<u8> {
    let n = c.points.len();
    let mut out = Vec::with_capacity(13 + 20 * n);
    out.extend_from_slice(&c.width.to_le_bytes());
    out.extend_from_slice(&c.height.to_le_bytes());
    out.extend_from_slice(&(n as u32).to_le_bytes());
    let mut flags = 0;
    if c.intensity.as_ref().is_some_and(|v| v.len() == n) {
        flags |= HAS_INTENSITY;
    }
    if c.confidence.as_ref().is_some_and(|v| v.len() == n) {
        flags |= HAS_CONFIDENCE;
    }
    out.push(flags);
    for p in &c.points {
        for v in [p.x, p.y, p.z] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    for (flag, plane) in [
        (HAS_INTENSITY, &c.intensity),
        (HAS_CONFIDENCE, &c.confidence),
    ] {
        if flags & flag != 0 {
            for v in plane.iter().flatten() {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    out
}

/// A cloud from bytes.
pub(crate) fn decode_cloud(b: &[u8]) -> std::io::Result<PointCloud> {
    let word = |i: usize| -> std::io::Result<u32> {
        b.get(i..i + 4)
            .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
            .ok_or_else(|| bad("a cloud cut short".into()))
    };
    let (width, height, n) = (word(0)?, word(4)?, word(8)? as usize);
    let flags = *b.get(12).ok_or_else(|| bad("a cloud cut short".into()))?;
    let planes = usize::from(flags & HAS_INTENSITY != 0) + usize::from(flags & HAS_CONFIDENCE != 0);
    if b.len() != 13 + n * 4 * (3 + planes) {
        return Err(bad(format!("{} bytes for a cloud of {n} points", b.len())));
    }
    let f = |i: usize| f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    let points = (0..n)
        .map(|k| {
            let i = 13 + 12 * k;
            Point3::new(f(i), f(i + 4), f(i + 8))
        })
        .collect();
    let mut at = 13 + 12 * n;
    let mut plane = |flag: u8| {
        (flags & flag != 0).then(|| {
            let v = (0..n).map(|k| f(at + 4 * k)).collect();
            at += 4 * n;
            v
        })
    };
    let intensity = plane(HAS_INTENSITY);
    let confidence = plane(HAS_CONFIDENCE);
    Ok(PointCloud {
        width,
        height,
        points,
        intensity,
        confidence,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clouds_and_messages_cross_the_pipe_unchanged() {
        let cloud = PointCloud {
            width: 2,
            height: 1,
            points: vec![
                Point3::new(1.0, f32::NAN, -3.5),
                Point3::new(0.0, 2.0, 1e-3),
            ],
            intensity: None,
            confidence: Some(vec![0.5, 1.0]),
        };
        let mut pipe = Vec::new();
        write_frame(&mut pipe, Tag::Cloud, &encode_cloud(&cloud)).expect("write");
        write_frame(&mut pipe, Tag::Begin, &json(&("EventGetData", 1500u64))).expect("write");
        let mut r = pipe.as_slice();
        let (tag, body) = read_frame(&mut r).expect("read").expect("frame");
        let Message::Cloud(back) = decode_message(tag, &body).expect("cloud") else {
            panic!("a cloud")
        };
        assert!(back.points[0].y.is_nan());
        assert_eq!(
            (back.width, back.points[1], &back.confidence),
            (2, cloud.points[1], &cloud.confidence)
        );
        let (tag, body) = read_frame(&mut r).expect("read").expect("frame");
        let Message::Begin { call, budget } = decode_message(tag, &body).expect("begin") else {
            panic!("begin")
        };
        assert_eq!(
            (call.as_str(), budget),
            ("EventGetData", Duration::from_millis(1500))
        );
        assert!(read_frame(&mut r).expect("eof").is_none());
        // A cut frame is an error, not a hang or a short cloud.
        let mut cut = &pipe[..pipe.len() - 3];
        read_frame(&mut cut).expect("first");
        assert!(read_frame(&mut cut).is_err());
    }
}
