//! `handeye`: the command-line tool and (later) daemon. Parses arguments, sets up tracing and
//! dispatches to the subcommands in `cli/`; this is the only place that names concrete drivers.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use tokio_util::sync::CancellationToken;

mod cli;

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
    /// Talk to a UR controller (commissioning).
    Robot(cli::robot::Args),
    /// Talk to a GigE Vision 3D camera.
    Camera(cli::camera::Args),
    /// Run protocol simulators (a UR controller, a GigE Vision 3D camera).
    #[command(subcommand)]
    Sim(SimCommand),
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

/// Runs `command` on the binary's one tokio runtime with one shutdown signal: Ctrl-C or
/// SIGTERM cancels the token (a running move is stopped, the run aborted and recorded).
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
    rt.block_on(command(shutdown))
}

/// Ctrl-C or SIGTERM.
async fn shutdown_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::SimulateScan(a) => cli::simulate_scan::run(a),
        Command::Solve(a) => cli::solve::run(a),
        Command::Bench(a) => cli::bench::run(a),
        Command::Robot(a) => cli::robot::run(a),
        Command::Camera(a) => cli::camera::run(a),
        Command::Sim(SimCommand::Robot(a)) => cli::sim_robot::run(a),
        Command::Sim(SimCommand::Camera(a)) => cli::sim_camera::run(a),
        Command::Demo(a) => with_runtime(|shutdown| cli::demo::run(a, shutdown)),
        Command::Calibrate(a) => with_runtime(|shutdown| cli::calibrate::calibrate(a, shutdown)),
        Command::Check(a) => with_runtime(|shutdown| cli::calibrate::check(a, shutdown)),
        Command::Sim(SimCommand::Rig(a)) => with_runtime(|shutdown| cli::sim_rig::run(a, shutdown)),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
