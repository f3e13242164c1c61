//! `handeye`: the command-line tool and (later) daemon. Parses arguments, sets up tracing and
//! dispatches to the subcommands in `cli/`. The binary (this file and `cli/`) is the only
//! place that names concrete drivers; the build checks it (`[features]` in Cargo.toml).

use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};
use tokio_util::sync::CancellationToken;

mod cli;

/// Tests measure the largest allocation a parser makes (the fuzz targets' memory bound).
#[cfg(test)]
#[global_allocator]
static ALLOC: handeye_hal::fuzz::TrackingAlloc = handeye_hal::fuzz::TrackingAlloc;

/// Target-free hand-eye calibration for Universal Robots arms with a 3D camera.
#[derive(Debug, Parser)]
#[command(name = "handeye", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Calibrate a simulated UR5e with a wrist camera at a random mount, through the real
    /// protocols (an in-process rig), and compare with the ground truth (no hardware needed).
    Demo(cli::demo::Args),
    /// Run one calibration on the configured cell: preflight, plan, move, capture, register,
    /// solve, gate, write back, return.
    Calibrate(cli::calibrate::CalibrateArgs),
    /// Measure the camera pose the same way and compare it with the current calibration
    /// (never writes back). Exit 0 within thresholds, 1 drifted, 2 error.
    Check(cli::calibrate::CheckArgs),
    /// Render a simulated 3D scan of a robot (PLY + ground-truth JSON).
    SimulateScan(cli::simulate_scan::Args),
    /// Calibrate from recorded scans and joint angles.
    Solve(cli::solve::Args),
    /// Run the accuracy/speed benchmark on simulated scans.
    Bench(cli::bench::Args),
    /// The recorded runs (`<storage.dir>/history.sqlite`): list, show one, export (read-only).
    History(cli::history::Args),
    /// Talk to a UR controller (commissioning).
    Robot(cli::robot::Args),
    /// Talk to a GigE Vision 3D camera.
    Camera(cli::camera::Args),
    /// The service: owns the robot and camera, runs calibrations and checks when asked (at
    /// startup, on a schedule, from the HTTP API), records every run in the history.
    Daemon(cli::daemon::Args),
    /// Ask the running daemon what it is doing: state, current run and stage, last run, last
    /// calibration, drift alarm, connections. Exit 2 when no daemon answers.
    Status(cli::status::Args),
    /// Ask the running daemon to cancel the run in progress (the arm is stopped) and every
    /// queued one; sends the API token. Exit 0 when one was cancelled or none was running.
    Cancel(cli::cancel::Args),
    /// The configuration's reference: every key with its unit, default and range.
    Config(cli::config::Args),
    /// Run protocol simulators (a UR controller, a GigE Vision 3D camera).
    #[command(subcommand)]
    Sim(SimCommand),
    /// The process that loads a GenTL producer for the `gentl` camera (started by handeye
    /// itself, speaking a pipe protocol on stdin/stdout; see handeye_gentl::host).
    #[command(name = "gentl-host", hide = true)]
    GentlHost,
}

#[derive(Debug, Subcommand)]
enum SimCommand {
    /// Simulated UR controller on the standard ports (29999, 30001-30004).
    Robot(cli::sim_robot::Args),
    /// Simulated GigE Vision 3D camera.
    Camera(cli::sim_camera::Args),
    /// The whole simulated cell: a UR controller and a GigE Vision 3D camera on its flange
    /// that renders the arm at the joints the controller reports.
    Rig(cli::sim_rig::Args),
}

/// Runs an async subcommand on the binary's one tokio runtime with its one shutdown signal
/// (mini-redis): Ctrl-C or SIGTERM cancels the token, and each command decides what that
/// means (a move stops the arm, a run is aborted and recorded, a simulator stops and reports).
/// This is the only place that builds a runtime for a command or installs signal handlers
/// (the `sim camera` RTDE follower keeps a private runtime on its own thread).
///
/// Blocking work (registration, GigE Vision I/O, mesh loading) goes to `spawn_blocking`; when
/// the command returns early (interrupted), such work still running is abandoned after
/// [`BLOCKING_GRACE`] instead of holding the process open.
fn with_runtime<F, Fut>(command: F) -> anyhow::Result<ExitCode>
where
    F: FnOnce(CancellationToken) -> Fut,
    Fut: std::future::Future<Output = anyhow::Result<ExitCode>>,
{
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let shutdown = CancellationToken::new();
    let signal = shutdown.clone();
    rt.spawn(async move {
        shutdown_signal().await;
        tracing::warn!("shutdown requested: stopping");
        signal.cancel();
    });
    let result = rt.block_on(command(shutdown));
    rt.shutdown_timeout(BLOCKING_GRACE);
    result
}

/// How long blocking tasks may still run after the command has returned: a signal ends every
/// command within a second (issue 46: `camera xml` parsing a large description).
const BLOCKING_GRACE: Duration = Duration::from_millis(500);

/// Resolves on Ctrl-C or SIGTERM (systemd's stop). A signal we cannot listen for keeps its
/// default action (the process ends without a clean stop), so say so.
async fn shutdown_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    () = ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(e) => {
                tracing::warn!("cannot listen for SIGTERM ({e}); it ends the process at once");
                ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    ctrl_c().await;
}

/// Resolves on Ctrl-C; never, if its handler cannot be installed.
async fn ctrl_c() {
    if let Err(e) = tokio::signal::ctrl_c().await {
        tracing::warn!("cannot listen for Ctrl-C ({e}); it ends the process at once");
        std::future::pending::<()>().await;
    }
}

/// The log filter without `RUST_LOG`: the daemon's journal tells the story of its runs (one
/// line per start and outcome, skipped checks, connection changes: `info`); the other
/// commands print their own results and log only warnings.
fn default_filter(command: &Command) -> &'static str {
    match command {
        Command::Daemon(_) => "warn,handeye=info",
        _ => "warn",
    }
}

/// Log targets of dependencies that log, at ERROR, every error they also return to us: the
/// GenApi interpreter (a camera that dies mid-run printed `ERROR cameleon_genapi: …` beside our
/// own message, which already says what failed and what to do). Silenced unless `RUST_LOG`
/// names them.
const DUPLICATE_ERROR_TARGETS: [&str; 1] = ["cameleon_genapi"];

/// The filter: `RUST_LOG` if set, else `default`; either way without
/// [`DUPLICATE_ERROR_TARGETS`] unless `RUST_LOG` names them.
fn log_filter(rust_log: Option<&str>, default: &str) -> tracing_subscriber::EnvFilter {
    let mut directives = rust_log.unwrap_or(default).to_string();
    for target in DUPLICATE_ERROR_TARGETS {
        if !directives.contains(target) {
            directives.push_str(&format!(",{target}=off"));
        }
    }
    tracing_subscriber::EnvFilter::try_new(&directives)
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default))
}

fn init_tracing(default: &str) {
    use std::io::IsTerminal as _;
    let rust_log = std::env::var("RUST_LOG").ok();
    tracing_subscriber::fmt()
        .with_env_filter(log_filter(rust_log.as_deref(), default))
        .with_writer(std::io::stderr)
        // Colour codes only for a person at a terminal, never into a log file or journal.
        .with_ansi(std::io::stderr().is_terminal())
        .init();
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            // Help and version go to stdout as clap writes them; a usage error echoes the bad
            // token, bounded and escaped (exit 2).
            if e.use_stderr() {
                let message = handeye_hal::limits::sanitize_message(&e.render().to_string());
                eprint!("{message}");
                // `solve --json` promises one JSON object on stdout, also for a usage error.
                let argv: Vec<String> = std::env::args().skip(1).collect();
                if argv.first().is_some_and(|c| c == "solve") && argv.iter().any(|a| a == "--json")
                {
                    let first = message.lines().next().unwrap_or("");
                    println!(
                        "{}",
                        serde_json::json!({
                            "status": "error",
                            "outcome": "error",
                            "error": first.trim_start_matches("error: "),
                        })
                    );
                }
            } else {
                print!("{}", e.render());
            }
            return ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(2));
        }
    };
    init_tracing(default_filter(&cli.command));
    let result = match cli.command {
        // Synchronous: computation on the calling thread and rayon, no I/O to wait for. They
        // run without a runtime, so Ctrl-C ends them the default way, at once.
        Command::SimulateScan(a) => cli::simulate_scan::run(a),
        Command::Solve(a) => cli::solve::run(a),
        Command::Bench(a) => cli::bench::run(a),
        Command::History(a) => cli::history::run(a),
        Command::Status(a) => cli::status::run(a),
        Command::Cancel(a) => cli::cancel::run(a),
        Command::Config(a) => cli::config::run(a),
        // Asynchronous: talk to devices or serve them; stop on the shutdown token.
        Command::Demo(a) => with_runtime(|shutdown| cli::demo::run(a, shutdown)),
        Command::Daemon(a) => with_runtime(|shutdown| cli::daemon::run(a, shutdown)),
        Command::Calibrate(a) => with_runtime(|shutdown| cli::calibrate::calibrate(a, shutdown)),
        Command::Check(a) => with_runtime(|shutdown| cli::calibrate::check(a, shutdown)),
        Command::Robot(a) => with_runtime(|shutdown| cli::robot::run(a, shutdown)),
        Command::Camera(a) => with_runtime(|shutdown| cli::camera::run(a, shutdown)),
        Command::Sim(SimCommand::Robot(a)) => {
            with_runtime(|shutdown| cli::sim_robot::run(a, shutdown))
        }
        Command::Sim(SimCommand::Camera(a)) => {
            with_runtime(|shutdown| cli::sim_camera::run(a, shutdown))
        }
        Command::Sim(SimCommand::Rig(a)) => with_runtime(|shutdown| cli::sim_rig::run(a, shutdown)),
        // Its own exit code: it ends when its input closes.
        Command::GentlHost => return handeye_gentl::host::serve(),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", cli::args::error_text(&e));
            ExitCode::from(2)
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use super::*;

    /// What a subscriber with `filter` prints for one error of ours and one of the GenApi
    /// interpreter's.
    fn logged(filter: tracing_subscriber::EnvFilter) -> String {
        let buf = Arc::new(Mutex::new(Vec::<u8>::new()));
        let sink = Arc::clone(&buf);
        let subscriber = tracing_subscriber::fmt()
            .with_env_filter(filter)
            .with_ansi(false)
            .with_writer(move || Sink(Arc::clone(&sink)))
            .finish();
        tracing::subscriber::with_default(subscriber, || {
            tracing::error!(target: "cameleon_genapi", "device error: timeout");
            tracing::warn!(target: "handeye", "the camera does not answer");
        });
        let bytes = buf.lock().expect("log").clone();
        String::from_utf8(bytes).expect("text")
    }

    struct Sink(Arc<Mutex<Vec<u8>>>);

    impl std::io::Write for Sink {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().expect("log").extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    /// The GenTL camera starts this binary as its host under the name the driver uses.
    #[test]
    fn the_gentl_host_subcommand_is_the_drivers() {
        let cli = Cli::try_parse_from(["handeye", handeye_gentl::HOST_SUBCOMMAND]).expect("parse");
        assert!(matches!(cli.command, Command::GentlHost));
    }

    /// Issue 38: the GenApi interpreter's own ERROR lines (duplicates of the errors it returns
    /// to us) are not printed beside ours, also with a RUST_LOG that does not name it; a
    /// RUST_LOG that names it shows them.
    #[test]
    fn dependency_error_lines_are_left_to_our_messages() {
        for rust_log in [None, Some("warn"), Some("debug")] {
            let text = logged(log_filter(rust_log, "warn"));
            assert!(
                text.contains("the camera does not answer"),
                "{rust_log:?}: {text}"
            );
            assert!(!text.contains("cameleon_genapi"), "{rust_log:?}: {text}");
        }
        let text = logged(log_filter(Some("warn,cameleon_genapi=error"), "warn"));
        assert!(text.contains("device error"), "{text}");
    }
}
