//! Script client: sends URScript programs to the primary interface (30001) on a fresh
//! connection and watches that connection's robot messages for the outcome.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use crate::primary::{self, PrimaryPackage};
use crate::UrError;

/// Sends programs to one controller.
#[derive(Debug, Clone)]
pub struct ScriptClient {
    addr: SocketAddr,
    timeout: Duration,
}

/// What the controller said about a program.
#[derive(Debug, Clone, PartialEq)]
pub enum ScriptOutcome {
    /// `PROGRAM_XXX_STARTED` seen (def programs).
    Started,
    /// No error within the wait (sec programs).
    NoError,
}

impl ScriptClient {
    /// Client for the primary interface at `addr`.
    pub fn new(addr: SocketAddr, timeout: Duration) -> Self {
        Self { addr, timeout }
    }

    /// Read the version message the controller sends first.
    pub async fn version(&self) -> Result<(u8, u8, i32, i32), UrError> {
        let (_sock, first, _) = self.open().await?;
        match first {
            PrimaryPackage::Version {
                major,
                minor,
                bugfix,
                build,
            } => Ok((major, minor, bugfix, build)),
            other => Err(UrError::malformed(
                "primary",
                format!("expected the version message first, got {other:?}"),
            )),
        }
    }

    /// Read the controller's kinematics (ROBOT_STATE sub-package 5) from a fresh primary
    /// connection: the first KinematicsInfo that arrives within the timeout, or `Ok(None)` if
    /// none does (a controller too old to send it). Connection errors are returned.
    pub async fn kinematics(&self) -> Result<Option<primary::KinematicsInfo>, UrError> {
        let deadline = Instant::now() + self.timeout;
        let (mut sock, first, mut buf) = self.open().await?;
        if let PrimaryPackage::RobotState {
            kinematics: Some(k),
            ..
        } = first
        {
            return Ok(Some(k));
        }
        loop {
            while let Some((p, n)) = primary::split(&buf)? {
                buf.drain(..n);
                if let PrimaryPackage::RobotState {
                    kinematics: Some(k),
                    ..
                } = p
                {
                    return Ok(Some(k));
                }
            }
            match read_some(&mut sock, &mut buf, deadline, self.addr, self.timeout).await {
                Ok(()) => {}
                Err(UrError::Timeout { .. }) => return Ok(None),
                Err(e) => return Err(e),
            }
        }
    }

    /// Connect and read the first package; also returns the bytes read after it.
    async fn open(&self) -> Result<(TcpStream, PrimaryPackage, Vec<u8>), UrError> {
        let mut sock = crate::connect_within(self.addr, self.timeout, || {
            format!("connect to {}", self.addr)
        })
        .await?;
        let mut buf = Vec::new();
        let deadline = Instant::now() + self.timeout;
        let first = loop {
            if let Some((p, n)) = primary::split(&buf)? {
                buf.drain(..n);
                break p;
            }
            read_some(&mut sock, &mut buf, deadline, self.addr, self.timeout).await?;
        };
        Ok((sock, first, buf))
    }

    /// Send `program`. For a `def` program named `name`, wait until the controller reports it
    /// started; for anything else, wait `settle` for an error. Compile/runtime errors and
    /// refusals (C210 local control) are returned.
    pub async fn send(
        &self,
        program: &str,
        name: Option<&str>,
        settle: Duration,
    ) -> Result<ScriptOutcome, UrError> {
        let (mut sock, _, mut buf) = self.open().await?;
        sock.write_all(program.as_bytes())
            .await
            .map_err(|source| UrError::Io {
                peer: self.addr.to_string(),
                source,
            })?;
        let deadline = Instant::now() + if name.is_some() { self.timeout } else { settle };
        loop {
            while let Some((p, n)) = primary::split(&buf)? {
                buf.drain(..n);
                match p {
                    PrimaryPackage::Key { title, text, .. }
                        if title == "PROGRAM_XXX_STARTED" && Some(text.as_str()) == name =>
                    {
                        return Ok(ScriptOutcome::Started);
                    }
                    PrimaryPackage::ErrorCode {
                        code: 210, text, ..
                    } => {
                        return Err(UrError::Refused {
                            device: "primary",
                            request: first_line(program),
                            reason: format!("C210 {text}; enable Remote Control on the pendant"),
                        })
                    }
                    PrimaryPackage::ErrorCode { text, .. }
                    | PrimaryPackage::RuntimeException { text, .. } => {
                        return Err(UrError::Refused {
                            device: "primary",
                            request: first_line(program),
                            reason: text,
                        });
                    }
                    _ => {}
                }
            }
            if Instant::now() >= deadline {
                return match name {
                    Some(n) => Err(UrError::Timeout {
                        what: format!("start of program `{n}`"),
                        after: self.timeout,
                    }),
                    None => Ok(ScriptOutcome::NoError),
                };
            }
            match read_some(&mut sock, &mut buf, deadline, self.addr, self.timeout).await {
                Ok(()) => {}
                Err(UrError::Timeout { .. }) if name.is_none() => {
                    return Ok(ScriptOutcome::NoError)
                }
                Err(e) => return Err(e),
            }
        }
    }
}

fn first_line(p: &str) -> String {
    p.lines().next().unwrap_or("").to_string()
}

async fn read_some(
    sock: &mut TcpStream,
    buf: &mut Vec<u8>,
    deadline: Instant,
    addr: SocketAddr,
    timeout: Duration,
) -> Result<(), UrError> {
    let mut chunk = [0u8; 4096];
    let left = deadline.saturating_duration_since(Instant::now());
    let n = tokio::time::timeout(left, sock.read(&mut chunk))
        .await
        .map_err(|_| UrError::Timeout {
            what: format!("primary interface {addr}"),
            after: timeout,
        })?
        .map_err(|source| UrError::Io {
            peer: addr.to_string(),
            source,
        })?;
    if n == 0 {
        return Err(UrError::Io {
            peer: addr.to_string(),
            source: std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "primary interface closed",
            ),
        });
    }
    buf.extend_from_slice(&chunk[..n]);
    if buf.len() > primary::MAX_PACKAGE {
        return Err(UrError::malformed("primary", "package larger than 1 MiB"));
    }
    Ok(())
}
