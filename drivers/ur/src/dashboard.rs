//! Dashboard client (port 29999): one line per command, one line per reply, parsed strictly,
//! every exchange under a timeout.

use std::net::SocketAddr;
use std::time::Duration;

use handeye_hal::{RobotMode, SafetyMode};
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};

use crate::UrError;

/// The banner every dashboard server sends on connect.
pub const BANNER: &str = "Connected: Universal Robots Dashboard Server";
const MAX_REPLY: u64 = 4096;

/// A connected dashboard client.
#[derive(Debug)]
pub struct DashboardClient {
    addr: SocketAddr,
    r: BufReader<OwnedReadHalf>,
    w: OwnedWriteHalf,
    timeout: Duration,
}

/// Parse `Robotmode: NAME`.
pub fn parse_robot_mode(reply: &str) -> Result<RobotMode, UrError> {
    let name = reply.strip_prefix("Robotmode: ").ok_or_else(|| {
        UrError::malformed(
            "dashboard",
            format!("expected `Robotmode: <MODE>`, got `{reply}`"),
        )
    })?;
    robot_mode_from_name(name)
        .ok_or_else(|| UrError::malformed("dashboard", format!("unknown robot mode `{name}`")))
}

/// Robot mode from its dashboard name.
pub fn robot_mode_from_name(name: &str) -> Option<RobotMode> {
    Some(match name {
        "NO_CONTROLLER" => RobotMode::NoController,
        "DISCONNECTED" => RobotMode::Disconnected,
        "CONFIRM_SAFETY" => RobotMode::ConfirmSafety,
        "BOOTING" => RobotMode::Booting,
        "POWER_OFF" => RobotMode::PowerOff,
        "POWER_ON" => RobotMode::PowerOn,
        "IDLE" => RobotMode::Idle,
        "BACKDRIVE" => RobotMode::Backdrive,
        "RUNNING" => RobotMode::Running,
        "UPDATING_FIRMWARE" => RobotMode::UpdatingFirmware,
        _ => return None,
    })
}

/// Robot mode from its RTDE code.
pub fn robot_mode_from_code(code: i32) -> Option<RobotMode> {
    Some(match code {
        -1 => RobotMode::NoController,
        0 => RobotMode::Disconnected,
        1 => RobotMode::ConfirmSafety,
        2 => RobotMode::Booting,
        3 => RobotMode::PowerOff,
        4 => RobotMode::PowerOn,
        5 => RobotMode::Idle,
        6 => RobotMode::Backdrive,
        7 => RobotMode::Running,
        8 => RobotMode::UpdatingFirmware,
        _ => return None,
    })
}

/// Safety mode from its dashboard name.
pub fn safety_mode_from_name(name: &str) -> Option<SafetyMode> {
    Some(match name {
        "NORMAL" => SafetyMode::Normal,
        "REDUCED" => SafetyMode::Reduced,
        "PROTECTIVE_STOP" => SafetyMode::ProtectiveStop,
        "RECOVERY" => SafetyMode::Recovery,
        "SAFEGUARD_STOP" => SafetyMode::SafeguardStop,
        "SYSTEM_EMERGENCY_STOP" => SafetyMode::SystemEmergencyStop,
        "ROBOT_EMERGENCY_STOP" => SafetyMode::RobotEmergencyStop,
        "VIOLATION" => SafetyMode::Violation,
        "FAULT" => SafetyMode::Fault,
        "VALIDATE_JOINT_ID" => SafetyMode::ValidateJointId,
        "UNDEFINED_SAFETY_MODE" => SafetyMode::Undefined,
        "AUTOMATIC_MODE_SAFEGUARD_STOP" => SafetyMode::AutomaticModeSafeguardStop,
        "SYSTEM_THREE_POSITION_ENABLING_STOP" => SafetyMode::SystemThreePositionEnablingStop,
        _ => return None,
    })
}

/// Safety mode from its RTDE code (unknown newer codes map to `Undefined`).
pub fn safety_mode_from_code(code: i32) -> SafetyMode {
    match code {
        1 => SafetyMode::Normal,
        2 => SafetyMode::Reduced,
        3 => SafetyMode::ProtectiveStop,
        4 => SafetyMode::Recovery,
        5 => SafetyMode::SafeguardStop,
        6 => SafetyMode::SystemEmergencyStop,
        7 => SafetyMode::RobotEmergencyStop,
        8 => SafetyMode::Violation,
        9 => SafetyMode::Fault,
        10 => SafetyMode::ValidateJointId,
        12 => SafetyMode::AutomaticModeSafeguardStop,
        13 => SafetyMode::SystemThreePositionEnablingStop,
        _ => SafetyMode::Undefined,
    }
}

/// Parse `URSoftware 5.11.1.108318 (…)` into its four numbers.
pub fn parse_polyscope_version(reply: &str) -> Result<[u32; 4], UrError> {
    let bad = || {
        UrError::malformed(
            "dashboard",
            format!("expected `URSoftware <a.b.c.d> (<date>)`, got `{reply}`"),
        )
    };
    let v = reply
        .strip_prefix("URSoftware ")
        .ok_or_else(bad)?
        .split_whitespace()
        .next()
        .ok_or_else(bad)?;
    let parts: Vec<u32> = v
        .split('.')
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map_err(|_| bad())?;
    <[u32; 4]>::try_from(parts).map_err(|_| bad())
}

/// A reply that says the controller does not know the command (older software).
fn is_unknown_command(reply: &str) -> bool {
    reply.starts_with("could not understand")
}

/// Parse the reply to `get serial number` (e.g. `20205500001`): `None` when the controller
/// does not know the command (older software); an error for anything but one word of
/// letters and digits.
pub fn parse_serial_number(reply: &str) -> Result<Option<String>, UrError> {
    if is_unknown_command(reply) {
        return Ok(None);
    }
    let s = reply.trim();
    if !s.is_empty() && s.len() <= 32 && s.bytes().all(|b| b.is_ascii_alphanumeric()) {
        Ok(Some(s.to_string()))
    } else {
        Err(UrError::malformed(
            "dashboard",
            format!("expected a serial number, got `{reply}`"),
        ))
    }
}

/// Parse the reply to `get robot model` (e.g. `UR5`; some versions add the `e`): `None` when
/// the controller does not know the command; an error unless it is `UR` and a number, with an
/// optional `e`.
pub fn parse_robot_model(reply: &str) -> Result<Option<String>, UrError> {
    if is_unknown_command(reply) {
        return Ok(None);
    }
    let s = reply.trim();
    let family = s
        .strip_prefix("UR")
        .map(|rest| rest.trim_end_matches(['e', 'E']));
    match family {
        Some(n) if !n.is_empty() && n.len() <= 3 && n.bytes().all(|b| b.is_ascii_digit()) => {
            Ok(Some(s.to_string()))
        }
        _ => Err(UrError::malformed(
            "dashboard",
            format!("expected a robot model such as `UR5`, got `{reply}`"),
        )),
    }
}

impl DashboardClient {
    /// Connect and check the banner (within `timeout`).
    pub async fn connect(addr: SocketAddr, timeout: Duration) -> Result<Self, UrError> {
        let sock =
            crate::connect_within(addr, timeout, || format!("dashboard connect to {addr}")).await?;
        let (r, w) = sock.into_split();
        let mut c = Self {
            addr,
            r: BufReader::new(r),
            w,
            timeout,
        };
        let banner = c.read_line("dashboard banner").await?;
        if banner != BANNER {
            return Err(UrError::malformed(
                "dashboard",
                format!("unexpected banner `{banner}` (is this port 29999 of a UR controller?)"),
            ));
        }
        Ok(c)
    }

    async fn read_line(&mut self, what: &str) -> Result<String, UrError> {
        let mut buf = Vec::new();
        let mut limited = (&mut self.r).take(MAX_REPLY);
        let n = tokio::time::timeout(self.timeout, limited.read_until(b'\n', &mut buf))
            .await
            .map_err(|_| UrError::Timeout {
                what: what.to_string(),
                after: self.timeout,
            })?
            .map_err(|source| UrError::Io {
                peer: self.addr.to_string(),
                source,
            })?;
        if n == 0 {
            return Err(UrError::Io {
                peer: self.addr.to_string(),
                source: std::io::Error::new(
                    std::io::ErrorKind::UnexpectedEof,
                    "dashboard closed the connection",
                ),
            });
        }
        if buf.last() != Some(&b'\n') {
            return Err(UrError::malformed(
                "dashboard",
                "reply line too long or cut off",
            ));
        }
        let s = String::from_utf8(buf)
            .map_err(|_| UrError::malformed("dashboard", "reply is not text"))?;
        Ok(s.trim_end_matches(['\n', '\r']).to_string())
    }

    /// Send one command and return the reply line (without newline).
    pub async fn request(&mut self, cmd: &str) -> Result<String, UrError> {
        if cmd.contains('\n') {
            return Err(UrError::InvalidArgument(
                "dashboard commands are single lines".into(),
            ));
        }
        let line = format!("{cmd}\n");
        tokio::time::timeout(self.timeout, self.w.write_all(line.as_bytes()))
            .await
            .map_err(|_| UrError::Timeout {
                what: format!("dashboard `{cmd}`"),
                after: self.timeout,
            })?
            .map_err(|source| UrError::Io {
                peer: self.addr.to_string(),
                source,
            })?;
        self.read_line(&format!("dashboard reply to `{cmd}`")).await
    }

    async fn expect(&mut self, cmd: &str, ok: &str) -> Result<(), UrError> {
        let reply = self.request(cmd).await?;
        if reply == ok {
            Ok(())
        } else {
            Err(UrError::Refused {
                device: "dashboard",
                request: cmd.into(),
                reason: reply,
            })
        }
    }

    /// `robotmode`.
    pub async fn robot_mode(&mut self) -> Result<RobotMode, UrError> {
        let r = self.request("robotmode").await?;
        parse_robot_mode(&r)
    }

    /// `safetystatus` (e-Series) — falls back to `safetymode` on CB3.
    pub async fn safety_status(&mut self) -> Result<SafetyMode, UrError> {
        let r = self.request("safetystatus").await?;
        let name = match r.strip_prefix("Safetystatus: ") {
            Some(n) => n.to_string(),
            None => {
                let r = self.request("safetymode").await?;
                r.strip_prefix("Safetymode: ")
                    .ok_or_else(|| {
                        UrError::malformed(
                            "dashboard",
                            format!("expected `Safetymode: <MODE>`, got `{r}`"),
                        )
                    })?
                    .to_string()
            }
        };
        safety_mode_from_name(&name)
            .ok_or_else(|| UrError::malformed("dashboard", format!("unknown safety mode `{name}`")))
    }

    /// `is in remote control` (e-Series 5.6+); `true` on controllers without the command (CB3).
    pub async fn is_in_remote_control(&mut self) -> Result<bool, UrError> {
        let r = self.request("is in remote control").await?;
        match r.as_str() {
            "true" => Ok(true),
            "false" => Ok(false),
            _ if r.starts_with("could not understand") => Ok(true),
            _ => Err(UrError::malformed(
                "dashboard",
                format!("expected `true`/`false`, got `{r}`"),
            )),
        }
    }

    /// `running`.
    pub async fn program_running(&mut self) -> Result<bool, UrError> {
        let r = self.request("running").await?;
        match r.as_str() {
            "Program running: true" => Ok(true),
            "Program running: false" => Ok(false),
            _ => Err(UrError::malformed(
                "dashboard",
                format!("expected `Program running: true|false`, got `{r}`"),
            )),
        }
    }

    /// `PolyscopeVersion` → `[major, minor, bugfix, build]`.
    pub async fn polyscope_version(&mut self) -> Result<[u32; 4], UrError> {
        let r = self.request("PolyscopeVersion").await?;
        parse_polyscope_version(&r)
    }

    /// `get serial number` (e-Series 5.6+, CB3 3.12+): `None` on older controllers.
    pub async fn serial_number(&mut self) -> Result<Option<String>, UrError> {
        let r = self.request("get serial number").await?;
        parse_serial_number(&r)
    }

    /// `get robot model` (e.g. `UR5`, the family without the e-Series `e` on many
    /// versions): `None` on controllers that do not know the command.
    pub async fn robot_model(&mut self) -> Result<Option<String>, UrError> {
        let r = self.request("get robot model").await?;
        parse_robot_model(&r)
    }

    /// `power on` (needs remote control).
    pub async fn power_on(&mut self) -> Result<(), UrError> {
        self.expect("power on", "Powering on").await
    }

    /// `power off`.
    pub async fn power_off(&mut self) -> Result<(), UrError> {
        self.expect("power off", "Powering off").await
    }

    /// `brake release`.
    pub async fn brake_release(&mut self) -> Result<(), UrError> {
        self.expect("brake release", "Brake releasing").await
    }

    /// `load <program>`.
    pub async fn load(&mut self, program: &str) -> Result<(), UrError> {
        let cmd = format!("load {program}");
        let r = self.request(&cmd).await?;
        if r.starts_with("Loading program:") {
            Ok(())
        } else {
            Err(UrError::Refused {
                device: "dashboard",
                request: cmd,
                reason: r,
            })
        }
    }

    /// `play`.
    pub async fn play(&mut self) -> Result<(), UrError> {
        self.expect("play", "Starting program").await
    }

    /// `pause`.
    pub async fn pause(&mut self) -> Result<(), UrError> {
        self.expect("pause", "Pausing program").await
    }

    /// `stop`.
    pub async fn stop(&mut self) -> Result<(), UrError> {
        self.expect("stop", "Stopped").await
    }

    /// `unlock protective stop` (only ever on an explicit operator request).
    pub async fn unlock_protective_stop(&mut self) -> Result<(), UrError> {
        self.expect("unlock protective stop", "Protective stop releasing")
            .await
    }

    /// `quit`: the server answers `Disconnected` and closes.
    pub async fn quit(mut self) -> Result<(), UrError> {
        self.expect("quit", "Disconnected").await
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strict_reply_parsing() {
        assert_eq!(
            parse_robot_mode("Robotmode: RUNNING").expect("ok"),
            RobotMode::Running
        );
        assert!(parse_robot_mode("robotmode: RUNNING").is_err());
        assert!(parse_robot_mode("Robotmode: SLEEPING").is_err());
        assert_eq!(
            parse_polyscope_version("URSoftware 5.19.0.1210631 (Oct 23 2024)").expect("ok"),
            [5, 19, 0, 1210631]
        );
        assert!(parse_polyscope_version("URSoftware 5.19 (Oct 23 2024)").is_err());
        assert!(parse_polyscope_version("").is_err());
        assert_eq!(
            parse_serial_number("20205500001").expect("ok").as_deref(),
            Some("20205500001")
        );
        assert_eq!(
            parse_serial_number("could not understand: 'get serial number'").expect("old"),
            None
        );
        assert!(parse_serial_number("").is_err());
        assert!(parse_serial_number("2020 5500001").is_err());
        assert_eq!(
            parse_robot_model("UR5").expect("ok").as_deref(),
            Some("UR5")
        );
        assert_eq!(
            parse_robot_model("UR16e").expect("ok").as_deref(),
            Some("UR16e")
        );
        assert_eq!(
            parse_robot_model("could not understand: 'get robot model'").expect("old"),
            None
        );
        for bad in ["", "UR", "UR5x", "KUKA", "Robotmode: RUNNING"] {
            assert!(parse_robot_model(bad).is_err(), "{bad}");
        }
    }

    /// Issue 23 (found by the `dashboard` fuzz target): a control character in a reply was
    /// echoed raw in the error.
    #[test]
    fn issue_23_reply_with_control_character_is_escaped() {
        let msg = parse_robot_mode("\u{11}")
            .expect_err("not a mode")
            .to_string();
        assert!(msg.contains("Robotmode"), "{msg}");
        assert!(!msg.chars().any(char::is_control), "{msg:?}");
    }

    /// Fuzz target `dashboard` (hal::fuzz): mutated replies to `robotmode`,
    /// `PolyscopeVersion`, `get serial number` and `get robot model` parse or are refused with
    /// a message.
    #[test]
    fn fuzz_dashboard_replies() {
        let seeds = vec![
            b"Robotmode: RUNNING".to_vec(),
            b"URSoftware 5.19.0.1210631 (Oct 23 2024)".to_vec(),
            b"20205500001".to_vec(),
            b"UR16e".to_vec(),
        ];
        handeye_hal::fuzz::Target::new("dashboard", seeds).run(|b| {
            let s = String::from_utf8_lossy(b);
            if s.starts_with("URSoftware") {
                parse_polyscope_version(&s)
                    .map(|_| ())
                    .map_err(|e| e.to_string())
            } else if s.starts_with("Robotmode") {
                parse_robot_mode(&s).map(|_| ()).map_err(|e| e.to_string())
            } else if s.starts_with("UR") {
                parse_robot_model(&s).map(|_| ()).map_err(|e| e.to_string())
            } else {
                parse_serial_number(&s)
                    .map(|_| ())
                    .map_err(|e| e.to_string())
            }
        });
    }
}
