//! `handeye demo`: the product's job on the simulated rig, end to end over the real protocols.
//! A UR controller simulator (factory-calibrated arm) and a simulated GigE Vision 3D camera at
//! an unknown, random mount on its flange start in this process on free loopback ports; then
//! one `calibrate` run talks to them through RTDE/dashboard/URScript and GVCP/GVSP exactly as
//! to a real cell — preflight, plan, move, capture, register, solve, gate, write-back, return —
//! and the result is compared with the ground truth.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::process::ExitCode;

use handeye::bench::{PASS_ROTATION_DEG, PASS_TRANSLATION_MM};
use handeye::config::{self, RobotPorts, ViewTargets};
use handeye::run::{pose_difference, Outcome, RunMode, RunRequest};
use handeye::sim::{Intrinsics, SimSettings};
use handeye_hal::ur_dh::UrModel;
use handeye_hal::UrPose;
use handeye_ur::Ports;
use nalgebra::{Isometry3, Vector3};
use rand::{Rng, SeedableRng};
use tokio_util::sync::CancellationToken;

use super::calibrate::{describe_pose, execute, summary};
use super::sim_rig::{Rig, RigOptions, RobotFaults};

/// Calibrate a simulated UR with a wrist camera through the real protocols.
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct Args {
    /// Robot model.
    #[arg(long, default_value = "ur5e")]
    robot: UrModel,
    /// Camera preset: `compact` (1280×960) or `zivid2-m60` (2448×2048), structured light;
    /// `realsense-d435` (1280×720), active stereo; `helios2` (640×480), time of flight.
    #[arg(long, default_value = "compact")]
    camera: String,
    /// Seed of the mount, the arm's factory calibration, the view and the sensor noise
    /// (default: from the clock, printed).
    #[arg(long)]
    seed: Option<u64>,
    /// Where the run keeps its record, captures and result files (default: a fresh folder
    /// under the system's temporary directory, removed when the demo passes, kept and printed
    /// when it fails).
    #[arg(long, value_name = "DIR")]
    storage: Option<PathBuf>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Benchmark: run N demos (seeds SEED, SEED+1, …; a new rig, mount and arm each) and print
    /// one line per run and the median / p95 of the time, the run's overhead and the error.
    #[arg(long, value_name = "N", conflicts_with = "json")]
    runs: Option<usize>,
}

pub(crate) async fn run(args: Args, shutdown: CancellationToken) -> anyhow::Result<ExitCode> {
    let seed = args.seed.unwrap_or_else(|| {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(1, |d| d.as_secs())
    });
    match args.runs {
        Some(n) => benchmark(&args, seed, n, &shutdown).await,
        None => once(&args, seed, &shutdown).await.map(|o| o.exit),
    }
}

/// What one demo measured.
struct DemoOutcome {
    exit: ExitCode,
    passed: bool,
    total_ms: f64,
    overhead_ms: f64,
    error: Option<(f64, f64)>,
}

/// `n` demos in a row; a summary of their times and errors.
async fn benchmark(
    args: &Args,
    seed: u64,
    n: usize,
    shutdown: &CancellationToken,
) -> anyhow::Result<ExitCode> {
    anyhow::ensure!((1..=1000).contains(&n), "--runs must be 1..=1000");
    let mut outs = Vec::new();
    let started = std::time::Instant::now();
    for k in 0..n as u64 {
        if shutdown.is_cancelled() {
            break;
        }
        let quiet = Args {
            json: true,
            storage: None,
            ..args.clone()
        };
        let o = once(&quiet, seed + k, shutdown).await?;
        let (mm, deg) = o.error.unwrap_or((f64::NAN, f64::NAN));
        eprintln!(
            "seed {:>4}: {} total {:>6.0} ms, overhead {:>4.0} ms, error {mm:.3} mm / {deg:.4}°",
            seed + k,
            if o.passed { "passed" } else { "FAILED" },
            o.total_ms,
            o.overhead_ms
        );
        outs.push(o);
    }
    let stat = |f: &dyn Fn(&DemoOutcome) -> f64| {
        let mut v: Vec<f64> = outs.iter().map(f).filter(|x| x.is_finite()).collect();
        v.sort_by(f64::total_cmp);
        let at = |q: f64| {
            v.get(((v.len() as f64 - 1.0) * q).round() as usize)
                .copied()
        };
        (at(0.5).unwrap_or(f64::NAN), at(0.95).unwrap_or(f64::NAN))
    };
    let passed = outs.iter().filter(|o| o.passed).count();
    let (t50, t95) = stat(&|o| o.total_ms);
    let (o50, o95) = stat(&|o| o.overhead_ms);
    let (e50, e95) = stat(&|o| o.error.map_or(f64::NAN, |e| e.0));
    let (r50, r95) = stat(&|o| o.error.map_or(f64::NAN, |e| e.1));
    println!(
        "{} demo runs ({}, {}): {passed} passed; start to finish median {t50:.0} ms, p95 {t95:.0} ms; \
         run overhead (all but motion, settling and camera capture) median {o50:.0} ms, p95 {o95:.0} ms; \
         error median {e50:.3} mm / {r50:.4}°, p95 {e95:.3} mm / {r95:.4}°; wall {:.1} s",
        outs.len(),
        args.robot,
        args.camera,
        started.elapsed().as_secs_f64()
    );
    Ok(if passed == outs.len() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

/// One demo: rig, calibrate, compare.
async fn once(args: &Args, seed: u64, shutdown: &CancellationToken) -> anyhow::Result<DemoOutcome> {
    let started = std::time::Instant::now();
    let intrinsics = Intrinsics::preset_or_error(&args.camera).map_err(anyhow::Error::msg)?;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mount = handeye::bench::random_mount(&mut rng);
    // What the bracket's drawing says: the truth off by a few millimetres and degrees.
    let prior = mount
        * Isometry3::new(
            Vector3::from_fn(|_, _| rng.random_range(-0.005..0.005)),
            Vector3::from_fn(|_, _| rng.random_range(-2f64..2.0).to_radians()),
        );
    let loopback = IpAddr::V4(Ipv4Addr::LOCALHOST);
    let rig = Rig::start(RigOptions {
        model: args.robot,
        mount,
        factory_calibration: Some(seed),
        serial: None,
        robot_bind: loopback,
        // Ephemeral ports: two demos at once never clash.
        robot_ports: Ports {
            dashboard: 0,
            primary: 0,
            secondary: 0,
            realtime: 0,
            rtde: 0,
        },
        camera_bind: SocketAddr::new(loopback, 0),
        intrinsics,
        settings: SimSettings::for_camera(&args.camera),
        mount_file: None,
        habits: Default::default(),
        robot: RobotFaults::default(),
    })
    .await?;
    let p = rig.robot.ports();
    let storage = args.storage.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("handeye-demo-{}-{seed}", std::process::id()))
    });
    let mut cfg = config::sim_rig(
        loopback,
        RobotPorts {
            dashboard: p.dashboard,
            primary: p.primary,
            secondary: p.secondary,
            realtime: p.realtime,
            rtde: p.rtde,
        },
        rig.camera_addr.to_string(),
        storage.clone(),
    );
    cfg.origin = format!("<demo, seed {seed}>");
    cfg.robot.model = args.robot;
    cfg.mount.prior = Some(prior);
    if let ViewTargets::Auto { seed: s, .. } = &mut cfg.views.targets {
        *s = seed;
    }
    if !args.json {
        println!(
            "handeye demo — simulated {} (factory-calibrated arm) with a wrist camera ({}), seed {seed}",
            args.robot, args.camera
        );
        println!(
            "  rig: UR controller on {loopback} (RTDE port {}, dashboard {}), GigE Vision camera on {}",
            p.rtde, p.dashboard, rig.camera_addr
        );
        println!(
            "  true flange_from_camera (unknown to the solver): {}",
            UrPose::from(&mount)
        );
        println!(
            "  mount prior (the bracket's drawing):           {}",
            UrPose::from(&prior)
        );
    }
    let req = RunRequest::new(RunMode::Calibrate);
    let record = execute(&cfg, req, shutdown, args.json).await?;
    let estimate = record
        .result
        .as_ref()
        .and_then(|r| r.flange_from_camera.as_ref())
        .and_then(handeye::frames::from_row_major);
    let error = estimate.map(|e| pose_difference(&mount, &e));
    let tcp_on_controller: Isometry3<f64> = rig.robot.tcp_offset().into();
    let written_back = !record.written.is_empty();
    let passed = record.outcome == Outcome::Accepted
        && error.is_some_and(|(mm, deg)| mm <= PASS_TRANSLATION_MM && deg <= PASS_ROTATION_DEG);
    if args.runs.is_some() {
        // Benchmark: the caller prints one line per run.
    } else if args.json {
        let doc = serde_json::json!({
            "seed": seed,
            "robot": args.robot.name(),
            "outcome": record.outcome,
            "flange_from_camera": record.result.as_ref().and_then(|r| r.flange_from_camera),
            "ground_truth": handeye::frames::to_row_major(&mount),
            "error": error.map(|(mm, deg)| serde_json::json!({
                "translation_mm": mm,
                "rotation_deg": deg,
            })),
            "timings_ms": record.timings_ms,
            "overhead_ms": record.timings_ms.overhead(),
            "written_back": written_back,
            "written": record.written,
            "tcp_on_controller": handeye::frames::to_row_major(&tcp_on_controller),
            "passed": passed,
            "record": record,
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        print!("{}", summary(&record));
        print!(
            "{}",
            describe_pose("ground truth flange_from_camera", &mount)
        );
        if let Some((mm, deg)) = error {
            println!(
                "  error vs ground truth: {mm:.3} mm, {deg:.4}° (pass: accepted and ≤ {PASS_TRANSLATION_MM} mm / {PASS_ROTATION_DEG}°)"
            );
        }
        println!(
            "  TCP now active on the controller: {}",
            UrPose::from(&tcp_on_controller)
        );
        if args.storage.is_none() && passed {
            println!("  files: removed (a passing demo keeps them with --storage DIR)");
        } else {
            println!("  files: {}", storage.display());
        }
        println!("  demo {}", if passed { "PASSED" } else { "FAILED" });
    }
    drop(rig);
    if args.storage.is_none() && passed {
        // A passing demo leaves nothing behind in the temporary directory (a failing one keeps
        // its files to look at).
        if let Err(e) = std::fs::remove_dir_all(&storage) {
            tracing::warn!("cannot remove {}: {e}", storage.display());
        }
    }
    let exit = if passed {
        ExitCode::SUCCESS
    } else if record.outcome == Outcome::Rejected || record.outcome == Outcome::Accepted {
        ExitCode::from(1)
    } else {
        ExitCode::from(2)
    };
    Ok(DemoOutcome {
        exit,
        passed,
        total_ms: started.elapsed().as_secs_f64() * 1e3,
        overhead_ms: record.timings_ms.overhead(),
        error,
    })
}
