//! Dashboard server (29999): the real banner, exact replies, and the state changes behind them.

use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};

use super::state::{RobotModeCode, SafetyModeCode, RUNTIME_PAUSED, RUNTIME_PLAYING};
use super::Shared;

/// Longest command line accepted; longer lines close the connection.
const MAX_LINE: usize = 4096;

/// How long the simulated arm takes from `power on` to IDLE (a real one: a few seconds).
const POWER_ON_TIME: Duration = Duration::from_millis(1500);
/// How long its brakes take to release (a real arm: a second or two, audibly).
const BRAKE_RELEASE_TIME: Duration = Duration::from_millis(1000);

pub(crate) async fn serve(listener: TcpListener, shared: Arc<Shared>) {
    super::accept_loop(listener, shared, "dashboard", |sock, shared| async move {
        connection(sock, &shared).await
    })
    .await;
}

async fn connection(sock: TcpStream, shared: &Shared) -> std::io::Result<()> {
    let (r, mut w) = sock.into_split();
    let mut r = BufReader::new(r);
    w.write_all(b"Connected: Universal Robots Dashboard Server\n")
        .await?;
    let mut line = Vec::new();
    loop {
        line.clear();
        let n = (&mut r)
            .take(MAX_LINE as u64 + 1)
            .read_until(b'\n', &mut line)
            .await?;
        if n == 0 {
            return Ok(());
        }
        if line.len() > MAX_LINE {
            w.write_all(b"could not understand: command too long\n")
                .await?;
            return Ok(());
        }
        let cmd = String::from_utf8_lossy(&line).trim().to_string();
        let (reply, close) = handle(shared, &cmd);
        let latency = shared.lock().latency;
        if !latency.is_zero() {
            tokio::time::sleep(latency).await;
        }
        w.write_all(reply.as_bytes()).await?;
        w.write_all(b"\n").await?;
        if close {
            return Ok(());
        }
    }
}

/// One command → (reply, close connection afterwards).
pub(crate) fn handle(shared: &Shared, cmd: &str) -> (String, bool) {
    let cb3 = shared.config.model.is_cb3();
    let (maj, min, bug, build) = shared.version();
    let lower = cmd.to_ascii_lowercase();
    let arg = |prefix: &str| {
        cmd.get(prefix.len()..)
            .map(str::trim)
            .unwrap_or("")
            .to_string()
    };
    let mut s = shared.lock();
    let remote = s.remote_control;
    const LOCAL: &str = "Command is not allowed due to the robot being in local control. Switch to remote control on the teach pendant";
    let needs_remote = [
        "power on",
        "power off",
        "brake release",
        "load ",
        "play",
        "stop",
        "pause",
        "unlock protective stop",
        "close safety popup",
        "restart safety",
        "shutdown",
    ];
    if !remote
        && needs_remote
            .iter()
            .any(|c| lower == c.trim() || (c.ends_with(' ') && lower.starts_with(c)))
    {
        return (
            match lower.as_str() {
                "play" | "stop" | "pause" => format!("Failed to execute: {lower}"),
                _ => LOCAL.to_string(),
            },
            false,
        );
    }
    let program_state_name = |st: u32| match st {
        RUNTIME_PLAYING => "PLAYING",
        RUNTIME_PAUSED => "PAUSED",
        _ => "STOPPED",
    };
    let reply = match lower.as_str() {
        "robotmode" => format!("Robotmode: {}", s.robot_mode.name()),
        "safetymode" => format!("Safetymode: {}", s.safety_mode.name()),
        "safetystatus" if !cb3 => format!("Safetystatus: {}", s.safety_mode.name()),
        "is in remote control" if !cb3 => remote.to_string(),
        "power on" => {
            if s.robot_mode == RobotModeCode::PowerOff
                && s.safety_mode != SafetyModeCode::RobotEmergencyStop
            {
                s.robot_mode = RobotModeCode::PowerOn;
                s.mode_change = Some((RobotModeCode::Idle, Instant::now() + POWER_ON_TIME));
            }
            "Powering on".into()
        }
        "power off" => {
            s.stop_program(Some("power off"));
            s.mode_change = None;
            s.motion = None;
            s.qd = [0.0; 6];
            s.robot_mode = RobotModeCode::PowerOff;
            "Powering off".into()
        }
        "brake release" => {
            // From POWER_ON the controller first finishes powering on; either way the arm
            // runs once the brakes are off.
            let ready = match s.mode_change {
                Some((RobotModeCode::Idle, at)) => Some(at),
                _ if s.robot_mode == RobotModeCode::Idle => Some(Instant::now()),
                _ => None,
            };
            if let Some(at) = ready {
                s.mode_change = Some((RobotModeCode::Running, at + BRAKE_RELEASE_TIME));
            }
            "Brake releasing".into()
        }
        "play" => {
            if s.loaded_program.is_some() && s.can_move().is_ok() {
                s.program_gen += 1;
                s.runtime_state = RUNTIME_PLAYING;
                s.dashboard_playing = RUNTIME_PLAYING;
                "Starting program".into()
            } else {
                "Failed to execute: play".into()
            }
        }
        "pause" => {
            if s.dashboard_playing == RUNTIME_PLAYING {
                s.runtime_state = RUNTIME_PAUSED;
                s.dashboard_playing = RUNTIME_PAUSED;
                s.stop_motion(10.0);
                "Pausing program".into()
            } else {
                "Failed to execute: pause".into()
            }
        }
        "stop" => {
            s.stop_program(Some("stopped from the dashboard"));
            "Stopped".into()
        }
        "programstate" => {
            let name = s
                .loaded_program
                .as_deref()
                .map(base_name)
                .unwrap_or("<unnamed>")
                .to_string();
            format!("{} {}", program_state_name(s.dashboard_playing), name)
        }
        "running" => format!("Program running: {}", s.runtime_state == RUNTIME_PLAYING),
        "get loaded program" => match &s.loaded_program {
            Some(p) => format!("Loaded program: {p}"),
            None => "No program loaded".into(),
        },
        "polyscopeversion" => format!(
            "URSoftware {maj}.{min}.{bug}.{build} ({})",
            shared.software().1
        ),
        "version" if !cb3 => format!("{maj}.{min}.{bug}.{build}"),
        "quit" => return ("Disconnected".into(), true),
        "shutdown" => {
            s.stop_program(Some("shutdown"));
            s.robot_mode = RobotModeCode::PowerOff;
            return ("Shutting down".into(), true);
        }
        "unlock protective stop" => {
            let delay = shared.config.unlock_delay;
            match (s.safety_mode, s.pstop_since) {
                (SafetyModeCode::ProtectiveStop, Some(t)) if Instant::now() - t < delay => {
                    "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of protective stop before unlocking".into()
                }
                (SafetyModeCode::ProtectiveStop, _) => {
                    s.safety_mode = SafetyModeCode::Normal;
                    s.pstop_since = None;
                    "Protective stop releasing".into()
                }
                _ => "Protective stop releasing".into(),
            }
        }
        "close safety popup" => "closing safety popup".into(),
        "close popup" => "closing popup".into(),
        "restart safety" => {
            s.stop_program(Some("restart safety"));
            s.safety_mode = SafetyModeCode::Normal;
            s.pstop_since = None;
            s.robot_mode = RobotModeCode::PowerOff;
            "Restarting safety".into()
        }
        "isprogramsaved" => {
            let name = s
                .loaded_program
                .as_deref()
                .map(base_name)
                .unwrap_or("<unnamed>")
                .to_string();
            format!("true {name}")
        }
        "get serial number" => shared.config.serial.clone(),
        "get robot model" => shared.config.model.controller_name(),
        "get operational mode" if !cb3 => s.operational_mode.unwrap_or("NONE").into(),
        "clear operational mode" if !cb3 => {
            let prev = s.operational_mode.take().unwrap_or("NONE");
            format!(
                "No longer controlling the operational mode. Current operational mode: '{prev}'."
            )
        }
        _ if lower.starts_with("load installation ") => {
            format!("Loading installation: {}", arg("load installation "))
        }
        _ if lower.starts_with("load ") => {
            let file = arg("load ");
            if file.ends_with(".urp") && !file.contains('\0') {
                s.stop_program(None);
                let full = if file.starts_with('/') {
                    file.clone()
                } else {
                    format!("/programs/{file}")
                };
                s.loaded_program = Some(full);
                format!("Loading program: {file}")
            } else {
                format!("File not found: {file}")
            }
        }
        _ if lower.starts_with("popup ") => "showing popup".into(),
        _ if lower.starts_with("addtolog") => {
            let msg = arg("addToLog");
            if msg.is_empty() {
                "No log message to add".into()
            } else {
                s.push_log(msg);
                "Added log message".into()
            }
        }
        _ if lower.starts_with("set operational mode ") && !cb3 => {
            let m = arg("set operational mode ").to_ascii_uppercase();
            match m.as_str() {
                "MANUAL" => s.operational_mode = Some("MANUAL"),
                "AUTOMATIC" => s.operational_mode = Some("AUTOMATIC"),
                _ => return (format!("Failed setting operational mode: {m}"), false),
            }
            format!("Operational mode {m} is set")
        }
        _ => format!("could not understand: '{cmd}'"),
    };
    (reply, false)
}

fn base_name(path: &str) -> &str {
    path.rsplit('/').next().unwrap_or(path)
}
