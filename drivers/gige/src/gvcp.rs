//! GVCP (GigE Vision Control Protocol) codec: commands and acknowledges, both directions.
//!
//! Everything is big-endian. Parsers never panic: short, oversized or inconsistent packets are
//! [`GigeError::Malformed`]; error statuses map to [`GigeError::DeviceStatus`] via [`check_status`].

use crate::error::{GigeError, Result};

/// UDP port of the GVCP server on every device.
pub const GVCP_PORT: u16 = 3956;
/// First byte of every command.
pub const KEY: u8 = 0x42;
/// Flag: the device must acknowledge.
pub const FLAG_ACK_REQUIRED: u8 = 0x01;
/// Flag on DISCOVERY: the device may answer with a broadcast.
pub const FLAG_BROADCAST_ACK: u8 = 0x10;
/// Flag on PACKETRESEND: 64-bit block id / 32-bit packet id layout.
pub const FLAG_EXTENDED_ID: u8 = 0x10;
/// Largest GVCP datagram (576-byte IP datagram minus IP and UDP headers).
pub const MAX_PACKET: usize = 548;
/// Largest READMEM/WRITEMEM data block.
pub const MAX_MEM_BLOCK: usize = 536;
/// Largest READREG address count.
pub const MAX_READREG: usize = 135;
/// Largest WRITEREG pair count.
pub const MAX_WRITEREG: usize = 67;

/// Command codes (the ack code is the command code + 1).
pub mod code {
    /// DISCOVERY.
    pub const DISCOVERY: u16 = 0x0002;
    /// FORCEIP.
    pub const FORCEIP: u16 = 0x0004;
    /// PACKETRESEND (no ack).
    pub const PACKETRESEND: u16 = 0x0040;
    /// READREG.
    pub const READREG: u16 = 0x0080;
    /// WRITEREG.
    pub const WRITEREG: u16 = 0x0082;
    /// READMEM.
    pub const READMEM: u16 = 0x0084;
    /// WRITEMEM.
    pub const WRITEMEM: u16 = 0x0086;
    /// PENDING_ACK (ack only).
    pub const PENDING_ACK: u16 = 0x0089;
}

/// Bootstrap register addresses used by the driver and the simulator.
pub mod reg {
    /// GigE Vision version.
    pub const VERSION: u32 = 0x0000;
    /// Device mode (endianness, class).
    pub const DEVICE_MODE: u32 = 0x0004;
    /// MAC high (low 16 bits).
    pub const MAC_HIGH: u32 = 0x0008;
    /// MAC low.
    pub const MAC_LOW: u32 = 0x000C;
    /// Supported IP configuration.
    pub const SUPPORTED_IP_CONFIG: u32 = 0x0010;
    /// Current IP configuration.
    pub const CURRENT_IP_CONFIG: u32 = 0x0014;
    /// Current IP address.
    pub const CURRENT_IP: u32 = 0x0024;
    /// Current subnet mask.
    pub const SUBNET_MASK: u32 = 0x0034;
    /// Default gateway.
    pub const GATEWAY: u32 = 0x0044;
    /// Manufacturer name (32 bytes).
    pub const MANUFACTURER: u32 = 0x0048;
    /// Model name (32 bytes).
    pub const MODEL: u32 = 0x0068;
    /// Device version (32 bytes).
    pub const DEVICE_VERSION: u32 = 0x0088;
    /// Manufacturer info (48 bytes).
    pub const MANUFACTURER_INFO: u32 = 0x00A8;
    /// Serial number (16 bytes).
    pub const SERIAL: u32 = 0x00D8;
    /// User-defined name (16 bytes).
    pub const USER_NAME: u32 = 0x00E8;
    /// First XML URL (512 bytes).
    pub const FIRST_URL: u32 = 0x0200;
    /// Second XML URL (512 bytes).
    pub const SECOND_URL: u32 = 0x0400;
    /// Number of network interfaces.
    pub const NUM_INTERFACES: u32 = 0x0600;
    /// Link speed of interface 0 (Mb/s).
    pub const LINK_SPEED: u32 = 0x0670;
    /// Number of message channels.
    pub const NUM_MESSAGE_CHANNELS: u32 = 0x0900;
    /// Number of stream channels.
    pub const NUM_STREAM_CHANNELS: u32 = 0x0904;
    /// GVSP capability.
    pub const GVSP_CAPABILITY: u32 = 0x092C;
    /// GVCP capability.
    pub const GVCP_CAPABILITY: u32 = 0x0934;
    /// Heartbeat timeout (ms).
    pub const HEARTBEAT_TIMEOUT: u32 = 0x0938;
    /// Timestamp tick frequency, high word.
    pub const TICK_FREQ_HIGH: u32 = 0x093C;
    /// Timestamp tick frequency, low word.
    pub const TICK_FREQ_LOW: u32 = 0x0940;
    /// Timestamp control.
    pub const TIMESTAMP_CONTROL: u32 = 0x0944;
    /// Latched timestamp, high word.
    pub const TIMESTAMP_HIGH: u32 = 0x0948;
    /// Latched timestamp, low word.
    pub const TIMESTAMP_LOW: u32 = 0x094C;
    /// GVCP configuration.
    pub const GVCP_CONFIG: u32 = 0x0954;
    /// GVSP configuration (extended ids).
    pub const GVSP_CONFIG: u32 = 0x0960;
    /// Control channel privilege.
    pub const CCP: u32 = 0x0A00;
    /// Stream channel 0 port.
    pub const SCP0: u32 = 0x0D00;
    /// Stream channel 0 packet size.
    pub const SCPS0: u32 = 0x0D04;
    /// Stream channel 0 packet delay.
    pub const SCPD0: u32 = 0x0D08;
    /// Stream channel 0 destination address.
    pub const SCDA0: u32 = 0x0D18;
    /// Stream channel 0 source port.
    pub const SCSP0: u32 = 0x0D1C;
    /// Stream channel 0 capability.
    pub const SCC0: u32 = 0x0D20;
    /// Stream channel 0 configuration.
    pub const SCCFG0: u32 = 0x0D24;
}

/// GVCP capability bits (register 0x0934).
pub mod cap {
    /// PACKETRESEND supported.
    pub const PACKET_RESEND: u32 = 0x0000_0004;
    /// WRITEMEM supported.
    pub const WRITEMEM: u32 = 0x0000_0002;
    /// Several registers per READREG/WRITEREG.
    pub const CONCATENATION: u32 = 0x0000_0001;
    /// PENDING_ACK supported.
    pub const PENDING_ACK: u32 = 0x0000_0020;
    /// Serial number register supported.
    pub const SERIAL_NUMBER: u32 = 0x4000_0000;
    /// User-defined name supported.
    pub const USER_NAME: u32 = 0x8000_0000;
    /// Heartbeat can be disabled.
    pub const HEARTBEAT_DISABLE: u32 = 0x2000_0000;
}

/// Control channel privilege bits.
pub mod ccp {
    /// Exclusive access.
    pub const EXCLUSIVE: u32 = 0x1;
    /// Control access.
    pub const CONTROL: u32 = 0x2;
}

/// The payload of a command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CommandKind {
    /// Find devices.
    Discovery,
    /// Read 32-bit registers.
    ReadReg(Vec<u32>),
    /// Write 32-bit registers (address, value).
    WriteReg(Vec<(u32, u32)>),
    /// Read a block of memory.
    ReadMem {
        /// Start address (4-aligned).
        address: u32,
        /// Byte count (multiple of 4, at most 536).
        count: u16,
    },
    /// Write a block of memory.
    WriteMem {
        /// Start address (4-aligned).
        address: u32,
        /// Data (multiple of 4 bytes, at most 536).
        data: Vec<u8>,
    },
    /// Ask the device to send GVSP packets again.
    PacketResend {
        /// Stream channel index.
        channel: u16,
        /// Block id (16-bit in standard mode).
        block_id: u64,
        /// First packet id.
        first: u32,
        /// Last packet id.
        last: u32,
        /// 64-bit block id / 32-bit packet id layout.
        extended: bool,
    },
    /// Any other command, kept raw.
    Other {
        /// Command code.
        code: u16,
        /// Payload bytes.
        payload: Vec<u8>,
    },
}

impl CommandKind {
    /// Command code on the wire.
    pub fn code(&self) -> u16 {
        match self {
            Self::Discovery => code::DISCOVERY,
            Self::ReadReg(_) => code::READREG,
            Self::WriteReg(_) => code::WRITEREG,
            Self::ReadMem { .. } => code::READMEM,
            Self::WriteMem { .. } => code::WRITEMEM,
            Self::PacketResend { .. } => code::PACKETRESEND,
            Self::Other { code, .. } => *code,
        }
    }

    /// Short human description for error messages.
    pub fn describe(&self) -> String {
        match self {
            Self::Discovery => "DISCOVERY".into(),
            Self::ReadReg(a) => format!("READREG {}", hex_list(a.iter().copied())),
            Self::WriteReg(p) => format!("WRITEREG {}", hex_list(p.iter().map(|(a, _)| *a))),
            Self::ReadMem { address, count } => format!("READMEM 0x{address:08x} ({count} bytes)"),
            Self::WriteMem { address, data } => {
                format!("WRITEMEM 0x{address:08x} ({} bytes)", data.len())
            }
            Self::PacketResend {
                block_id,
                first,
                last,
                ..
            } => {
                format!("PACKETRESEND block {block_id} packets {first}..={last}")
            }
            Self::Other { code, .. } => format!("command 0x{code:04x}"),
        }
    }
}

fn hex_list(it: impl Iterator<Item = u32>) -> String {
    it.map(|a| format!("0x{a:08x}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// A GVCP command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Command {
    /// Header flags (`FLAG_*`).
    pub flags: u8,
    /// Request id (non-zero), echoed in the ack.
    pub req_id: u16,
    /// What is asked.
    pub kind: CommandKind,
}

fn be16(b: &[u8], off: usize) -> u16 {
    u16::from_be_bytes([b[off], b[off + 1]])
}

fn be32(b: &[u8], off: usize) -> u32 {
    u32::from_be_bytes([b[off], b[off + 1], b[off + 2], b[off + 3]])
}

fn be64(b: &[u8], off: usize) -> u64 {
    (u64::from(be32(b, off)) << 32) | u64::from(be32(b, off + 4))
}

impl Command {
    /// Serialize to wire bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut p = Vec::new();
        match &self.kind {
            CommandKind::Discovery => {}
            CommandKind::ReadReg(addrs) => {
                for a in addrs {
                    p.extend_from_slice(&a.to_be_bytes());
                }
            }
            CommandKind::WriteReg(pairs) => {
                for (a, v) in pairs {
                    p.extend_from_slice(&a.to_be_bytes());
                    p.extend_from_slice(&v.to_be_bytes());
                }
            }
            CommandKind::ReadMem { address, count } => {
                p.extend_from_slice(&address.to_be_bytes());
                p.extend_from_slice(&[0, 0]);
                p.extend_from_slice(&count.to_be_bytes());
            }
            CommandKind::WriteMem { address, data } => {
                p.extend_from_slice(&address.to_be_bytes());
                p.extend_from_slice(data);
            }
            CommandKind::PacketResend {
                channel,
                block_id,
                first,
                last,
                extended,
            } => {
                p.extend_from_slice(&channel.to_be_bytes());
                if *extended {
                    p.extend_from_slice(&[0, 0]);
                    p.extend_from_slice(&first.to_be_bytes());
                    p.extend_from_slice(&last.to_be_bytes());
                    p.extend_from_slice(&block_id.to_be_bytes());
                } else {
                    p.extend_from_slice(&(*block_id as u16).to_be_bytes());
                    p.extend_from_slice(&(first & 0x00FF_FFFF).to_be_bytes());
                    p.extend_from_slice(&(last & 0x00FF_FFFF).to_be_bytes());
                }
            }
            CommandKind::Other { payload, .. } => p.extend_from_slice(payload),
        }
        let mut flags = self.flags;
        if let CommandKind::PacketResend { extended: true, .. } = self.kind {
            flags |= FLAG_EXTENDED_ID;
        }
        let mut out = Vec::with_capacity(8 + p.len());
        out.push(KEY);
        out.push(flags);
        out.extend_from_slice(&self.kind.code().to_be_bytes());
        out.extend_from_slice(&(p.len() as u16).to_be_bytes());
        out.extend_from_slice(&self.req_id.to_be_bytes());
        out.extend_from_slice(&p);
        out
    }

    /// Parse a command (device side).
    pub fn decode(b: &[u8]) -> Result<Self> {
        const W: &str = "GVCP command";
        if b.len() < 8 {
            return Err(GigeError::malformed(
                W,
                format!("{} bytes, header needs 8", b.len()),
            ));
        }
        if b[0] != KEY {
            return Err(GigeError::malformed(
                W,
                format!("key 0x{:02x}, expected 0x42", b[0]),
            ));
        }
        let flags = b[1];
        let cmd = be16(b, 2);
        let len = usize::from(be16(b, 4));
        let req_id = be16(b, 6);
        let p = &b[8..];
        if p.len() < len {
            return Err(GigeError::malformed(
                W,
                format!(
                    "length field says {len} payload bytes, packet has {}",
                    p.len()
                ),
            ));
        }
        let p = &p[..len];
        let need_multiple = |n: usize| -> Result<()> {
            if len % n != 0 {
                Err(GigeError::malformed(
                    W,
                    format!("payload length {len} is not a multiple of {n}"),
                ))
            } else {
                Ok(())
            }
        };
        let kind = match cmd {
            code::DISCOVERY => CommandKind::Discovery,
            code::READREG => {
                need_multiple(4)?;
                if len == 0 || len / 4 > MAX_READREG {
                    return Err(GigeError::malformed(
                        W,
                        format!("READREG with {} addresses", len / 4),
                    ));
                }
                CommandKind::ReadReg(p.chunks_exact(4).map(|c| be32(c, 0)).collect())
            }
            code::WRITEREG => {
                need_multiple(8)?;
                if len == 0 || len / 8 > MAX_WRITEREG {
                    return Err(GigeError::malformed(
                        W,
                        format!("WRITEREG with {} pairs", len / 8),
                    ));
                }
                CommandKind::WriteReg(
                    p.chunks_exact(8)
                        .map(|c| (be32(c, 0), be32(c, 4)))
                        .collect(),
                )
            }
            code::READMEM => {
                if len != 8 {
                    return Err(GigeError::malformed(
                        W,
                        format!("READMEM payload {len} bytes, expected 8"),
                    ));
                }
                CommandKind::ReadMem {
                    address: be32(p, 0),
                    count: be16(p, 6),
                }
            }
            code::WRITEMEM => {
                if len < 4 {
                    return Err(GigeError::malformed(W, "WRITEMEM without address"));
                }
                CommandKind::WriteMem {
                    address: be32(p, 0),
                    data: p[4..].to_vec(),
                }
            }
            code::PACKETRESEND => {
                if flags & FLAG_EXTENDED_ID != 0 {
                    if len != 20 {
                        return Err(GigeError::malformed(
                            W,
                            format!("extended PACKETRESEND payload {len} bytes, expected 20"),
                        ));
                    }
                    CommandKind::PacketResend {
                        channel: be16(p, 0),
                        first: be32(p, 4),
                        last: be32(p, 8),
                        block_id: be64(p, 12),
                        extended: true,
                    }
                } else {
                    if len != 12 {
                        return Err(GigeError::malformed(
                            W,
                            format!("PACKETRESEND payload {len} bytes, expected 12"),
                        ));
                    }
                    CommandKind::PacketResend {
                        channel: be16(p, 0),
                        block_id: u64::from(be16(p, 2)),
                        first: be32(p, 4) & 0x00FF_FFFF,
                        last: be32(p, 8) & 0x00FF_FFFF,
                        extended: false,
                    }
                }
            }
            code => CommandKind::Other {
                code,
                payload: p.to_vec(),
            },
        };
        Ok(Self {
            flags,
            req_id,
            kind,
        })
    }
}

/// A GVCP acknowledge.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ack {
    /// Status code (0 = success).
    pub status: u16,
    /// Ack code (command code + 1, or PENDING_ACK).
    pub ack_code: u16,
    /// Echo of the command's request id.
    pub ack_id: u16,
    /// Payload bytes.
    pub payload: Vec<u8>,
}

impl Ack {
    /// Serialize to wire bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(8 + self.payload.len());
        out.extend_from_slice(&self.status.to_be_bytes());
        out.extend_from_slice(&self.ack_code.to_be_bytes());
        out.extend_from_slice(&(self.payload.len() as u16).to_be_bytes());
        out.extend_from_slice(&self.ack_id.to_be_bytes());
        out.extend_from_slice(&self.payload);
        out
    }

    /// Parse an ack (host side). Does not interpret the status.
    pub fn decode(b: &[u8]) -> Result<Self> {
        const W: &str = "GVCP ack";
        if b.len() < 8 {
            return Err(GigeError::malformed(
                W,
                format!("{} bytes, header needs 8", b.len()),
            ));
        }
        let len = usize::from(be16(b, 4));
        if b.len() - 8 < len {
            return Err(GigeError::malformed(
                W,
                format!(
                    "length field says {len} payload bytes, packet has {}",
                    b.len() - 8
                ),
            ));
        }
        Ok(Self {
            status: be16(b, 0),
            ack_code: be16(b, 2),
            ack_id: be16(b, 6),
            payload: b[8..8 + len].to_vec(),
        })
    }

    /// Values of a READREG ack for `n` registers.
    pub fn readreg_values(&self, n: usize) -> Result<Vec<u32>> {
        if n.checked_mul(4) != Some(self.payload.len()) {
            return Err(GigeError::malformed(
                "READREG ack",
                format!("{} bytes for {n} registers", self.payload.len()),
            ));
        }
        Ok(self.payload.chunks_exact(4).map(|c| be32(c, 0)).collect())
    }

    /// Data of a READMEM ack, checked against the request.
    pub fn readmem_data(&self, address: u32, count: usize) -> Result<&[u8]> {
        const W: &str = "READMEM ack";
        if self.payload.len().checked_sub(4) != Some(count) {
            return Err(GigeError::malformed(
                W,
                format!(
                    "{} bytes, expected address + {count} data bytes",
                    self.payload.len()
                ),
            ));
        }
        let got = be32(&self.payload, 0);
        if got != address {
            return Err(GigeError::malformed(
                W,
                format!("address 0x{got:08x}, asked 0x{address:08x}"),
            ));
        }
        Ok(&self.payload[4..])
    }

    /// Milliseconds announced by a PENDING_ACK.
    pub fn pending_ms(&self) -> Result<u16> {
        if self.payload.len() < 4 {
            return Err(GigeError::malformed(
                "PENDING_ACK",
                "payload shorter than 4 bytes",
            ));
        }
        Ok(be16(&self.payload, 2))
    }
}

/// Name and operator hint of a status code.
pub fn status_name(status: u16) -> (&'static str, &'static str) {
    match status {
        0x0000 => ("SUCCESS", "no action needed"),
        0x0100 => ("PACKET_RESEND", "no action needed"),
        0x8001 => (
            "NOT_IMPLEMENTED",
            "the camera does not support this command",
        ),
        0x8002 => (
            "INVALID_PARAMETER",
            "the value is out of range for the camera",
        ),
        0x8003 => (
            "INVALID_ADDRESS",
            "the register does not exist; check the camera's GenICam XML",
        ),
        0x8004 => (
            "WRITE_PROTECT",
            "the register is read-only (or locked while streaming)",
        ),
        0x8005 => (
            "BAD_ALIGNMENT",
            "addresses and sizes must be multiples of 4",
        ),
        0x8006 => (
            "ACCESS_DENIED",
            "another application controls the camera; close it",
        ),
        0x8007 => ("BUSY", "the camera is busy; retry later"),
        0x8008 => (
            "LOCAL_PROBLEM",
            "camera-internal problem; power-cycle the camera",
        ),
        0x8009 => ("MSG_MISMATCH", "protocol mismatch"),
        0x800A => ("INVALID_PROTOCOL", "protocol mismatch"),
        0x800B => ("NO_MSG", "no message"),
        0x800C => (
            "PACKET_UNAVAILABLE",
            "the packet is gone from the camera's memory",
        ),
        0x800D => (
            "DATA_OVERRUN",
            "the camera's buffer overflowed; lower the frame rate or raise packet delay",
        ),
        0x800E => ("INVALID_HEADER", "the camera rejected the packet header"),
        0x800F => ("WRONG_CONFIG", "wrong configuration"),
        0x8010 => ("PACKET_NOT_YET_AVAILABLE", "retry later"),
        0x8011 => (
            "PACKET_AND_PREV_REMOVED_FROM_MEMORY",
            "the packets are gone from the camera's memory",
        ),
        0x8012 => (
            "PACKET_REMOVED_FROM_MEMORY",
            "the packet is gone from the camera's memory",
        ),
        0x8013 => ("NO_REF_TIME", "no PTP reference time"),
        0x8014 => ("PACKET_TEMPORARILY_UNAVAILABLE", "retry later"),
        0x8015 => ("OVERFLOW", "camera queue overflow"),
        0x8016 => ("ACTION_LATE", "the action time is in the past"),
        0x8017 => (
            "LEADER_TRAILER_OVERFLOW",
            "leader/trailer too large for the packet size",
        ),
        0x8FFF => ("ERROR", "generic camera error; check the camera's log"),
        _ => (
            "UNKNOWN_STATUS",
            "unknown status code; check the camera's documentation",
        ),
    }
}

/// Turn a non-success status into an error.
pub fn check_status(status: u16, command: &CommandKind) -> Result<()> {
    if status == 0 {
        return Ok(());
    }
    let (name, hint) = status_name(status);
    Err(GigeError::DeviceStatus {
        command: command.describe(),
        status,
        name,
        hint,
    })
}

/// What a DISCOVERY ack tells about a device.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct DiscoveryInfo {
    /// GigE Vision version (major, minor).
    pub version: (u16, u16),
    /// MAC address.
    pub mac: [u8; 6],
    /// Current IPv4 address.
    pub ip: std::net::Ipv4Addr,
    /// Subnet mask.
    pub subnet: std::net::Ipv4Addr,
    /// Manufacturer.
    pub manufacturer: String,
    /// Model.
    pub model: String,
    /// Device version.
    pub device_version: String,
    /// Manufacturer info.
    pub manufacturer_info: String,
    /// Serial number.
    pub serial: String,
    /// User-defined name.
    pub user_name: String,
}

/// A NUL-terminated string field.
pub fn c_string(b: &[u8]) -> String {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    String::from_utf8_lossy(&b[..end]).trim().to_owned()
}

impl DiscoveryInfo {
    /// Parse the 248-byte discovery ack payload (bootstrap registers 0x00–0xF7).
    pub fn parse(p: &[u8]) -> Result<Self> {
        if p.len() < 0xF8 {
            return Err(GigeError::malformed(
                "DISCOVERY ack",
                format!("{} payload bytes, expected 248", p.len()),
            ));
        }
        let ip = |o: usize| std::net::Ipv4Addr::new(p[o], p[o + 1], p[o + 2], p[o + 3]);
        let v = be32(p, 0);
        Ok(Self {
            version: ((v >> 16) as u16, v as u16),
            mac: [p[10], p[11], p[12], p[13], p[14], p[15]],
            ip: ip(0x24),
            subnet: ip(0x34),
            manufacturer: c_string(&p[0x48..0x68]),
            model: c_string(&p[0x68..0x88]),
            device_version: c_string(&p[0x88..0xA8]),
            manufacturer_info: c_string(&p[0xA8..0xD8]),
            serial: c_string(&p[0xD8..0xE8]),
            user_name: c_string(&p[0xE8..0xF8]),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples() -> Vec<Command> {
        let k = [
            CommandKind::Discovery,
            CommandKind::ReadReg(vec![0x0A00, 0x0934]),
            CommandKind::WriteReg(vec![(0x0A00, 2)]),
            CommandKind::ReadMem {
                address: 0x200,
                count: 512,
            },
            CommandKind::WriteMem {
                address: 0xA000,
                data: vec![1, 2, 3, 4],
            },
            CommandKind::PacketResend {
                channel: 0,
                block_id: 7,
                first: 3,
                last: 9,
                extended: false,
            },
            CommandKind::PacketResend {
                channel: 0,
                block_id: 1 << 40,
                first: 3,
                last: 9,
                extended: true,
            },
        ];
        k.into_iter()
            .enumerate()
            .map(|(i, kind)| Command {
                flags: FLAG_ACK_REQUIRED,
                req_id: i as u16 + 1,
                kind,
            })
            .collect()
    }

    #[test]
    fn commands_round_trip() {
        for c in samples() {
            let mut d = Command::decode(&c.encode()).expect("decode");
            if matches!(d.kind, CommandKind::PacketResend { extended: true, .. }) {
                d.flags &= !FLAG_EXTENDED_ID;
            }
            assert_eq!(d, c);
        }
    }

    #[test]
    fn wrong_key_and_short_packets_are_clear_errors() {
        let mut b = samples()[1].encode();
        b[0] = 0x43;
        let e = Command::decode(&b).expect_err("wrong key");
        assert!(e.to_string().contains("key 0x43"), "{e}");
        let e = Command::decode(&b[..5]).expect_err("short");
        assert!(e.to_string().contains("header needs 8"), "{e}");
        let e = Ack::decode(&[0, 0, 0, 0x81, 0x10, 0, 0, 1]).expect_err("absurd length");
        assert!(e.to_string().contains("length field"), "{e}");
    }

    #[test]
    fn status_codes_match_the_standard_table() {
        assert_eq!(status_name(0x8006).0, "ACCESS_DENIED");
        assert_eq!(status_name(0x800C).0, "PACKET_UNAVAILABLE");
        assert_eq!(status_name(0x8012).0, "PACKET_REMOVED_FROM_MEMORY");
        let e =
            check_status(0x8004, &CommandKind::WriteReg(vec![(0xA000, 1)])).expect_err("status");
        assert!(e.to_string().contains("WRITE_PROTECT"), "{e}");
        assert!(e.to_string().contains("0x0000a000"), "{e}");
    }

    /// Valid commands (every kind) and acknowledges, the seeds of the GVCP fuzz target.
    fn gvcp_seeds() -> Vec<Vec<u8>> {
        let mut seeds: Vec<Vec<u8>> = samples().iter().map(Command::encode).collect();
        seeds.push(
            Ack {
                status: 0,
                ack_code: 3,
                ack_id: 1,
                payload: vec![0; 248],
            }
            .encode(),
        );
        seeds.push(
            Ack {
                status: 0,
                ack_code: 0x85,
                ack_id: 1,
                payload: vec![0; 12],
            }
            .encode(),
        );
        seeds
    }

    /// Fuzz target `gvcp` (hal::fuzz): mutated commands and acknowledges decode as one or the
    /// other or are refused with a message; what a decoded acknowledge yields for any count
    /// the caller may ask is bounded.
    #[test]
    fn fuzz_gvcp() {
        handeye_hal::fuzz::Target::new("gvcp", gvcp_seeds())
            .allocation_cap(16, 1 << 16)
            .run(|b| {
                let command = Command::decode(b);
                match Ack::decode(b) {
                    Ok(a) => {
                        for n in [0, 1, 3, MAX_READREG + 1] {
                            let _ = a.readreg_values(n);
                        }
                        let _ = a.readmem_data(0x200, 600);
                        let _ = a.pending_ms();
                        let _ = DiscoveryInfo::parse(&a.payload);
                        Ok(())
                    }
                    Err(e) => command.map(|_| ()).map_err(|_| e.to_string()),
                }
            });
    }

    /// Structure-aware huge counts: the length field and every count/address word at its
    /// largest, and the largest counts a caller may ask an ack for.
    #[test]
    fn gvcp_huge_counts_in_every_word() {
        let seeds = gvcp_seeds();
        for seed in &seeds {
            for off in (0..seed.len().min(64)).step_by(2) {
                for value in [0xFFFFu16, 0x8000, 0x0218] {
                    let mut b = seed.clone();
                    for (i, byte) in value.to_be_bytes().into_iter().enumerate() {
                        if let Some(x) = b.get_mut(off + i) {
                            *x = byte;
                        }
                    }
                    let _ = Command::decode(&b);
                    if let Ok(a) = Ack::decode(&b) {
                        for n in [0, MAX_READREG, MAX_READREG + 1, usize::MAX / 4] {
                            let _ = a.readreg_values(n);
                        }
                        for len in [0, MAX_MEM_BLOCK, MAX_MEM_BLOCK + 1, usize::MAX] {
                            let _ = a.readmem_data(u32::MAX, len);
                        }
                    }
                }
            }
        }
    }
}
