//! `handeye demo`: the product's job on the simulated rig, end to end over the real protocols.
//! A UR controller simulator (factory-calibrated arm) and a simulated GigE Vision 3D camera at
//! an unknown, random mount on its flange start in this process on free loopback ports; then
//! one `calibrate` run talks to them through RTDE/dashboard/URScript and GVCP/GVSP exactly as
//! to a real cell — preflight, plan, move, capture, register, solve, gate, write-back, return —
//! and the result is compared with the ground truth.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use handeye::config::{self, RobotPorts, ViewTargets};
use handeye::run::{pose_difference, Outcome, RunMode, RunRequest};
use handeye::sim::{Intrinsics, SimSettings};
use handeye_hal::ur_dh::UrModel;
use handeye_ur::Ports;
use nalgebra::{Isometry3, Vector3};
use rand::{Rng, SeedableRng};
use tokio_util::sync::CancellationToken;

use super::args::format_pose;
use super::calibrate::{describe_pose, execute, summary};
use super::sim_rig::{Rig, RigOptions, RobotFaults};

/// The demo passes when the result is accepted and this close to the truth, mm.
const PASS_TRANSLATION_MM: f64 = 0.5;
/// The demo passes when the result is accepted and this close to the truth, degrees.
const PASS_ROTATION_DEG: f64 = 0.1;

/// Calibrate a simulated UR with a wrist camera through the real protocols.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Robot model.
    #[arg(long, default_value = "ur5e")]
    robot: UrModel,
    /// Camera preset: `compact` (1280×960) or `zivid2-m60` (2448×2048).
    #[arg(long, default_value = "compact")]
    camera: String,
    /// Seed of the mount, the arm's factory calibration, the view and the sensor noise
    /// (default: from the clock, printed).
    #[arg(long)]
    seed: Option<u64>,
    /// Where the run keeps its record, captures and result files (default: a fresh folder
    /// under the system's temporary directory, printed).
    #[arg(long, value_name = "DIR")]
    storage: Option<PathBuf>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

pub(crate) async fn run(args: Args, shutdown: CancellationToken) -> anyhow::Result<ExitCode> {
    let seed = args.seed.unwrap_or_else(|| {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(1, |d| d.as_secs())
    });
    let intrinsics = Intrinsics::preset(&args.camera).with_context(|| {
        format!(
            "unknown camera preset `{}`; use compact or zivid2-m60",
            args.camera
        )
    })?;
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
        settings: SimSettings::default(),
        mount_file: None,
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
            format_pose(&mount)
        );
        println!(
            "  mount prior (the bracket's drawing):           {}",
            format_pose(&prior)
        );
    }
    let req = RunRequest {
        mode: RunMode::Calibrate,
        dry_run: false,
    };
    let record = execute(&cfg, req, &shutdown, args.json).await?;
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
    if args.json {
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
            format_pose(&tcp_on_controller)
        );
        println!("  files: {}", storage.display());
        println!("  demo {}", if passed { "PASSED" } else { "FAILED" });
    }
    drop(rig);
    Ok(if passed {
        ExitCode::SUCCESS
    } else if record.outcome == Outcome::Rejected || record.outcome == Outcome::Accepted {
        ExitCode::from(1)
    } else {
        ExitCode::from(2)
    })
}
