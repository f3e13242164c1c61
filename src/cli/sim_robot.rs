//! `handeye sim robot`: a simulated UR controller on the standard ports (29999, 30001–30004) of
//! one address, until Ctrl-C or SIGTERM.

use std::net::IpAddr;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use handeye_hal::limits;
use handeye_hal::ur_dh::UrModel;
use handeye_ur::sim::{SimConfig, Simulator};
use tokio_util::sync::CancellationToken;

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Arm model (ur3, ur5, ur10 are CB3: 125 Hz, no remote/local; the rest e-Series: 500 Hz).
    #[arg(long, default_value = "ur5e")]
    model: UrModel,
    /// Address to serve on; use distinct 127.0.0.x to run several simulators side by side.
    #[arg(long, default_value = "127.0.0.1")]
    bind: IpAddr,
    /// Start powered on with brakes released (default: POWER_OFF, like a booted controller).
    #[arg(long)]
    powered: bool,
    /// Start in local control (e-Series): scripts and state-changing dashboard commands refused.
    #[arg(long)]
    local_control: bool,
    /// Hold input registers 0–23 (and bits 0–63) as an active fieldbus adapter does (IN_USE).
    #[arg(long)]
    fieldbus: bool,
    /// Hold this RTDE input field as a fieldbus/other client would (repeatable).
    #[arg(long = "hold", value_name = "FIELD")]
    hold: Vec<String>,
    /// Trigger a protective stop when the next move reaches this fraction of its path (0–1).
    #[arg(long, value_name = "FRACTION")]
    protective_stop_during_move: Option<f64>,
    /// Delay every reply by this many milliseconds.
    #[arg(long, default_value_t = 0)]
    latency_ms: u64,
    /// Close every client connection at this interval, seconds.
    #[arg(long, value_name = "SECONDS")]
    drop_connections_every_s: Option<f64>,
    /// Refuse RTDE protocol version 2 (an old controller; clients must fall back to 1).
    #[arg(long)]
    rtde_v1_only: bool,
    /// Seconds after a protective stop before `unlock protective stop` is accepted.
    #[arg(long, default_value_t = 5.0)]
    unlock_delay_s: f64,
    /// Simulate a physical arm, as built: every joint off by a deterministic pseudo-random
    /// error of factory-calibration size (0.3 mm, 0.3 mrad 1σ) drawn from SEED; the controller
    /// publishes the arm's exact DH in the primary KinematicsInfo (its nearly parallel joints
    /// 2–4 give d of hundreds of metres, as a real one's) and computes every pose from it;
    /// every link's housing sits off its frame by the same sizes, which only a camera
    /// following this controller (`sim camera --robot`) shows (default: an exactly nominal
    /// arm).
    #[arg(long, value_name = "SEED")]
    factory_calibration: Option<u64>,
    /// The arm's serial number, as dashboard `get serial number` answers it (default: one in
    /// a real controller's 11-digit shape, from the model and the factory-calibration seed).
    #[arg(long, value_name = "SERIAL", value_parser = parse_serial)]
    serial: Option<String>,
}

/// A `--serial` as a controller could answer it: 1–32 letters and digits.
pub(crate) fn parse_serial(s: &str) -> Result<String, String> {
    match handeye_ur::dashboard::parse_serial_number(s) {
        Ok(Some(serial)) if serial == s => Ok(serial),
        _ => Err(format!(
            "`{}` is no serial number: expected 1–32 letters and digits, e.g. 20205500001",
            limits::Quoted(s)
        )),
    }
}

/// Longest simulated reply delay (`--latency-ms`), milliseconds.
const MAX_LATENCY_MS: u64 = 60_000;
/// Shortest interval between dropped connections (`--drop-connections-every-s`), seconds: a
/// client needs some time connected to do anything.
const MIN_DROP_INTERVAL_S: f64 = 0.01;
/// Longest fault timing (`--drop-connections-every-s`, `--unlock-delay-s`), seconds (a day).
const MAX_FAULT_DELAY_S: f64 = 86_400.0;

/// Serves until `shutdown` is cancelled (Ctrl-C or SIGTERM), then stops the simulator.
pub(crate) async fn run(args: Args, shutdown: CancellationToken) -> anyhow::Result<ExitCode> {
    let mut c = SimConfig::new(args.model, args.bind);
    c.start_running = args.powered;
    c.remote_control = !args.local_control;
    if args.fieldbus {
        c = c.with_fieldbus_lower_range();
    }
    for f in &args.hold {
        anyhow::ensure!(
            handeye_ur::rtde::is_input_field(f),
            "`{}` is not an RTDE input field",
            limits::Quoted(f)
        );
    }
    c.fieldbus_held.extend(args.hold);
    if let Some(f) = args.protective_stop_during_move {
        anyhow::ensure!(
            (0.0..=1.0).contains(&f),
            "--protective-stop-during-move must be within 0–1"
        );
        c.protective_stop_during_move = Some(f);
    }
    anyhow::ensure!(
        args.latency_ms <= MAX_LATENCY_MS,
        "--latency-ms = {}: expected 0 to {MAX_LATENCY_MS} ms (a reply later than that is no reply)",
        args.latency_ms
    );
    c.latency = Duration::from_millis(args.latency_ms);
    if let Some(s) = args.drop_connections_every_s {
        c.drop_connections_every = Some(
            limits::duration_from_secs(
                "--drop-connections-every-s",
                s,
                MIN_DROP_INTERVAL_S,
                MAX_FAULT_DELAY_S,
            )
            .map_err(anyhow::Error::msg)?,
        );
    }
    c.rtde_v2 = !args.rtde_v1_only;
    c.unlock_delay = limits::duration_from_secs(
        "--unlock-delay-s",
        args.unlock_delay_s,
        0.0,
        MAX_FAULT_DELAY_S,
    )
    .map_err(anyhow::Error::msg)?;
    if let Some(seed) = args.factory_calibration {
        c = c.factory_calibrated(seed);
        if let Some(arm) = &c.arm {
            let d = arm.controller_dh();
            tracing::info!(
                seed,
                theta_rad = ?d.theta,
                a_m = ?d.a,
                d_m = ?d.d,
                alpha_rad = ?d.alpha,
                "factory-calibrated {} arm: every joint off by a small error; the controller \
                 publishes its exact DH",
                c.model
            );
        }
    }
    if let Some(serial) = args.serial {
        c.serial = serial;
    }
    let arm = match args.factory_calibration {
        Some(seed) => format!(" (factory-calibrated arm, seed {seed})"),
        None => String::new(),
    };
    let model = c.model;
    let bind = c.bind;
    let serial = c.serial.clone();
    let sim = Simulator::start(c)
        .await
        .with_context(|| format!("starting the simulator on {bind}"))?;
    let p = sim.ports();
    eprintln!(
        "simulated {model}{arm}, serial {serial}, on {bind}: dashboard {}, primary {}, secondary {}, real-time {}, RTDE {} (Ctrl-C to stop)",
        p.dashboard, p.primary, p.secondary, p.realtime, p.rtde
    );
    shutdown.cancelled().await;
    drop(sim);
    eprintln!("simulator stopped");
    Ok(ExitCode::SUCCESS)
}
