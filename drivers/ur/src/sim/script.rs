//! Primary (30001) and secondary (30002) servers, the script receiver shared with 30003, and
//! starting URScript programs (and ur_rtde's control script) on their own threads; what a
//! running program sees is [`super::program`].

use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::broadcast::error::RecvError;

use super::program::{SimHost, STOPPED};
use super::state::{RUNTIME_PLAYING, RUNTIME_STOPPED};
use super::urscript::{self, Program, RuntimeError};
use super::{rtde_control, Shared};
use crate::primary;

/// Largest program text accepted (ur_rtde's control script is ~42 kB).
const MAX_PROGRAM: usize = 1 << 20;

pub(crate) async fn serve_primary(listener: TcpListener, shared: Arc<Shared>, primary: bool) {
    let what = if primary { "primary" } else { "secondary" };
    super::accept_loop(listener, shared, what, move |sock, shared| async move {
        connection(sock, &shared, primary).await
    })
    .await;
}

fn state_package(shared: &Shared) -> Vec<u8> {
    let s = shared.lock();
    let m = primary::RobotModeData {
        timestamp_us: (s.timestamp() * 1e6) as u64,
        power_on: s.robot_mode != super::RobotModeCode::PowerOff,
        emergency_stopped: s.safety_mode == super::SafetyModeCode::RobotEmergencyStop,
        protective_stopped: s.safety_mode == super::SafetyModeCode::ProtectiveStop,
        program_running: s.runtime_state == RUNTIME_PLAYING,
        program_paused: s.runtime_state == super::state::RUNTIME_PAUSED,
        robot_mode: s.robot_mode as i8,
        target_speed_fraction: s.speed_slider,
    };
    primary::encode_robot_state(&s.primary_state(m, shared.config.model))
}

async fn connection(
    sock: TcpStream,
    shared: &Arc<Shared>,
    is_primary: bool,
) -> std::io::Result<()> {
    let (mut r, mut w) = sock.into_split();
    // Subscribed before the first package goes out: a client that has read it misses no
    // robot message published afterwards.
    let mut messages = shared.messages.subscribe();
    let opened_remote = shared.lock().remote_control;
    let (maj, min, bug, build) = shared.version();
    w.write_all(&primary::encode_version(
        shared.timestamp_us(),
        maj as u8,
        min as u8,
        bug as i32,
        build as i32,
    ))
    .await?;
    w.write_all(&state_package(shared)).await?;
    // The stream is written by its own task, so a client that never reads (a script sender)
    // still has its programs read and run: once its buffers are full, only its stream stalls.
    let (reply_tx, mut replies) = tokio::sync::mpsc::channel::<Vec<u8>>(16);
    let stream_shared = shared.clone();
    let writer = tokio::spawn(async move {
        let shared = stream_shared;
        let mut tick = tokio::time::interval(Duration::from_millis(100));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        loop {
            let pkg = tokio::select! {
                _ = tick.tick() => state_package(&shared),
                Some(reply) = replies.recv() => reply,
                m = messages.recv(), if is_primary => match m {
                    Ok(m) => m,
                    Err(RecvError::Lagged(_)) => continue,
                    Err(RecvError::Closed) => return,
                },
            };
            if w.write_all(&pkg).await.is_err() {
                return;
            }
        }
    });
    let _writer = super::AbortOnDrop(writer);
    let mut rx = ScriptReceiver::default();
    let mut buf = vec![0u8; 8192];
    loop {
        let n = r.read(&mut buf).await?;
        if n == 0 {
            return Ok(());
        }
        for reply in rx.feed(&buf[..n], shared, opened_remote) {
            // A reader too slow to take its own error replies loses them, never the program.
            if is_primary {
                let _ = reply_tx.try_send(reply);
            }
        }
        if rx.overflowed {
            // Let the writer send the reason before the connection closes.
            tokio::time::sleep(Duration::from_millis(50)).await;
            return Ok(());
        }
    }
}

/// Cuts a text stream into programs: `def`/`sec` … `end`, or single lines.
#[derive(Debug, Default)]
pub(crate) struct ScriptReceiver {
    pending: Vec<u8>,
    program: Option<String>,
    pub(crate) overflowed: bool,
}

impl ScriptReceiver {
    /// Feed bytes; returns packages to send back on this connection (errors for this client).
    pub(crate) fn feed(
        &mut self,
        bytes: &[u8],
        shared: &Arc<Shared>,
        opened_remote: bool,
    ) -> Vec<Vec<u8>> {
        let mut replies = Vec::new();
        self.pending.extend_from_slice(bytes);
        if self.pending.len() + self.program.as_ref().map_or(0, String::len) > MAX_PROGRAM {
            self.overflowed = true;
            replies.push(primary::encode_error_code(
                shared.timestamp_us(),
                0,
                3,
                "script too long (over 1 MiB); connection closed",
            ));
            return replies;
        }
        while let Some(pos) = self.pending.iter().position(|b| *b == b'\n') {
            let line: Vec<u8> = self.pending.drain(..=pos).collect();
            let line = String::from_utf8_lossy(&line).trim_end().to_string();
            let complete = match &mut self.program {
                Some(p) => {
                    p.push_str(&line);
                    p.push('\n');
                    (line == "end").then(|| self.program.take().unwrap_or_default())
                }
                None if line.starts_with("def ") || line.starts_with("sec ") => {
                    self.program = Some(format!("{line}\n"));
                    None
                }
                None if line.trim().is_empty() => None,
                None => Some(line),
            };
            if let Some(text) = complete {
                replies.extend(submit(shared, &text, opened_remote));
            }
        }
        replies
    }
}

/// Compile and start a program; returns packages for the sender only.
pub(crate) fn submit(shared: &Arc<Shared>, text: &str, opened_remote: bool) -> Vec<Vec<u8>> {
    let ts = shared.timestamp_us();
    if !shared.lock().remote_control || !opened_remote {
        return vec![primary::encode_error_code(
            ts,
            210,
            3,
            "C210: socket is read-only: the robot is in local control (switch to remote control and reconnect)",
        )];
    }
    if let Some(control) = rtde_control::recognise(text) {
        match control {
            Ok(c) => start_program(shared, "rtde_control".into(), false, move |host| {
                rtde_control::run(&c, host)
            }),
            Err(e) => {
                let msg = format!("compile error: {}", e.message);
                shared.lock().push_log(format!("line {}: {msg}", e.line));
                shared.publish(primary::encode_runtime_exception(
                    ts,
                    e.line as i32,
                    0,
                    &msg,
                ));
            }
        }
        return Vec::new();
    }
    let prog = match urscript::parse_program(text) {
        Ok(p) => p,
        Err(e) => {
            let msg = format!("compile error: {}", e.message);
            tracing::warn!(line = e.line, "URScript program refused: {msg}");
            shared.lock().push_log(format!("line {}: {msg}", e.line));
            let pkg = primary::encode_runtime_exception(ts, e.line as i32, 0, &msg);
            shared.publish(pkg);
            return Vec::new();
        }
    };
    start(shared, prog);
    Vec::new()
}

fn start(shared: &Arc<Shared>, prog: Program) {
    let name = prog.name.clone();
    let secondary = prog.secondary;
    start_program(shared, name, secondary, move |host| {
        urscript::run(&prog, host)
    });
}

/// Start a program on its own thread: a primary program needs an arm that can move, stops the
/// one running, sets the runtime state PLAYING and announces PROGRAM_XXX_STARTED on the primary
/// stream; when `body` returns, a runtime error is published as a runtime exception, the state
/// returns to STOPPED and PROGRAM_XXX_STOPPED is announced. A secondary program runs beside.
pub(crate) fn start_program<F>(shared: &Arc<Shared>, name: String, secondary: bool, body: F)
where
    F: FnOnce(&mut SimHost<'_>) -> Result<(), RuntimeError> + Send + 'static,
{
    let ts = shared.timestamp_us();
    let gen = {
        let mut s = shared.lock();
        if secondary {
            s.program_gen
        } else {
            if let Err(why) = s.can_move() {
                drop(s);
                let msg = format!("program {name} not started: {why}");
                shared.lock().push_log(msg.clone());
                shared.publish(primary::encode_error_code(ts, 0, 3, &msg));
                return;
            }
            s.stop_program(None);
            s.runtime_state = RUNTIME_PLAYING;
            s.program_name = Some(name.clone());
            s.program_gen
        }
    };
    if !secondary {
        shared.publish(primary::encode_key(ts, 0, "PROGRAM_XXX_STARTED", &name));
    }
    let shared = shared.clone();
    let spawned = std::thread::Builder::new()
        .name(format!("urscript-{name}"))
        .spawn(move || {
            let mut host = SimHost::new(&shared, gen, secondary);
            let result = body(&mut host);
            let ts = shared.timestamp_us();
            if let Err(e) = result {
                if e.message != STOPPED {
                    tracing::warn!(
                        line = e.line,
                        "URScript runtime error in `{name}`: {}",
                        e.message
                    );
                    shared
                        .lock()
                        .push_log(format!("line {}: {}", e.line, e.message));
                    shared.publish(primary::encode_runtime_exception(
                        ts,
                        e.line as i32,
                        0,
                        &e.message,
                    ));
                }
            }
            if !secondary {
                let mut s = shared.lock();
                if s.program_gen == gen {
                    s.runtime_state = RUNTIME_STOPPED;
                    s.program_name = None;
                }
                drop(s);
                shared.publish(primary::encode_key(ts, 0, "PROGRAM_XXX_STOPPED", &name));
            }
        });
    if let Err(e) = spawned {
        tracing::warn!("cannot start a script thread: {e}");
    }
}
