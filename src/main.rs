//! `handeye`: the command-line tool and (later) daemon. Parses arguments, sets up tracing and
//! dispatches to the subcommands in `cli/`; this is the only place that names concrete drivers.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

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
    /// Simulate a scan of a UR5e from a random camera mount, calibrate from it and compare
    /// with the ground truth (no hardware needed).
    Demo(cli::demo::Args),
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
        Command::Demo(a) => cli::demo::run(a),
        Command::SimulateScan(a) => cli::simulate_scan::run(a),
        Command::Solve(a) => cli::solve::run(a),
        Command::Bench(a) => cli::bench::run(a),
        Command::Robot(a) => cli::robot::run(a),
        Command::Camera(a) => cli::camera::run(a),
        Command::Sim(SimCommand::Robot(a)) => cli::sim_robot::run(a),
        Command::Sim(SimCommand::Camera(a)) => cli::sim_camera::run(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
