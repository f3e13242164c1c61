//! Subcommands of the `handeye` binary. Each module has an `Args` (clap) and a `run`.
//! `run` returns the process exit code: 0 success, 1 a completed run whose result was rejected,
//! 2 an error (bad input, unreachable device, …).

pub(crate) mod args;
pub(crate) mod bench;
pub(crate) mod calibrate;
pub(crate) mod camera;
pub(crate) mod cancel;
pub(crate) mod config;
pub(crate) mod daemon;
pub(crate) mod demo;
pub(crate) mod history;
pub(crate) mod robot;
pub(crate) mod sim_camera;
pub(crate) mod sim_rig;
pub(crate) mod sim_robot;
pub(crate) mod simulate_scan;
pub(crate) mod solve;
pub(crate) mod status;
pub(crate) mod wiring;

/// Print to stdout; a closed pipe (`| head`) is not an error: the reader has what it wanted.
pub(crate) fn emit(text: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => Ok(r?),
    }
}
