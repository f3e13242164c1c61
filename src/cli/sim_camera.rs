//! `handeye sim camera`: a simulated GigE Vision 3D camera on a given address.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::Context as _;
use handeye::model::RobotModel;
use handeye::plan::{ViewConstraints, ViewPlanner};
use handeye::sim::{Intrinsics, KinematicError, SimSettings};
use handeye_gige::sim::{FrameSource, SceneSource, SimCamera, SimOptions};
use handeye_gige::GvcpClient;
use handeye_hal::limits;
use handeye_hal::ur_dh::PhysicalArm;
use tokio_util::sync::CancellationToken;

use super::args::{parse_pose, resolve_robot};
use super::scene::{
    parse_robot_addr, LiveJoints, RobotScene, SceneJoints, SceneMount, DEFAULT_MOUNT,
};

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Address to serve GVCP on, `IP` or `IP:PORT` (default port 3956).
    #[arg(long, value_name = "ADDR")]
    bind: String,
    /// Follow this UR controller over RTDE (`IP` or `IP:PORT`, default port 30004; e.g. a
    /// `handeye sim robot`) and render the robot at the joints it measures, seen from the
    /// camera mount. Without it the robot stands still at a generated view of its base.
    #[arg(long, value_name = "ROBOT_ADDR")]
    robot: Option<String>,
    /// Robot model of the rendered scene.
    #[arg(long, default_value = "ur5e")]
    model: String,
    /// Camera mount `flange_from_camera` as `x,y,z,rx,ry,rz` (m, rotation vector rad)
    /// [default: 0,-0.08,0.04,-0.26,0,0].
    #[arg(long, value_name = "POSE", allow_hyphen_values = true)]
    mount: Option<String>,
    /// Sensor width in pixels.
    #[arg(long, default_value_t = DEFAULT_WIDTH)]
    width: u32,
    /// Sensor height in pixels.
    #[arg(long, default_value_t = DEFAULT_HEIGHT)]
    height: u32,
    /// Frames per second while acquiring.
    #[arg(long, default_value_t = 10.0)]
    frame_rate: f64,
    /// Fraction of stream packets to drop (the camera resends them on request).
    #[arg(long, default_value_t = 0.0)]
    loss: f64,
    /// Serve the built-in plane + sphere test pattern instead of the robot.
    #[arg(long)]
    test_pattern: bool,
    /// TOML file with `[noise]`, `[cell]` and `[kinematic_error]` tables (see
    /// config/simulator.example.toml). Default: realistic noise and cell; kinematic error only
    /// without `--robot` (a followed robot's measured joints are rendered on the nominal model).
    #[arg(long)]
    settings: Option<PathBuf>,
    /// A perfect sensor in empty space: no noise, no cell, no kinematic error.
    #[arg(long, conflicts_with = "settings")]
    ideal: bool,
    /// Serial number to report.
    #[arg(long, default_value = "SIM0001")]
    serial: String,
    /// Render the physical arm with this seed, the one `handeye sim robot
    /// --factory-calibration SEED` drives.
    #[arg(long, value_name = "SEED")]
    factory_calibration: Option<u64>,
    /// Read the mount from this file (`x,y,z,rx,ry,rz`) whenever it changes: a simulator-only
    /// way to move the camera on its bracket while running (drift tests).
    #[arg(long, value_name = "FILE")]
    mount_file: Option<PathBuf>,
}

/// Frame rates the simulated camera serves, frames per second.
const MIN_FRAME_RATE_HZ: f64 = 0.01;
const MAX_FRAME_RATE_HZ: f64 = 120.0;
/// Sensor sizes the simulated camera renders, pixels per side.
pub(crate) const MIN_PIXELS: u32 = 16;
/// The simulated camera's size unless `--width`/`--height` say otherwise, for `sim camera`
/// and `sim rig` alike: the `compact` preset's 1280×960, what the demo and the benchmarks use.
pub(crate) const DEFAULT_WIDTH: u32 = 1280;
/// See [`DEFAULT_WIDTH`].
pub(crate) const DEFAULT_HEIGHT: u32 = 960;
/// See [`MIN_PIXELS`].
pub(crate) const MAX_PIXELS: u32 = 8192;

/// Serves until `shutdown` is cancelled (Ctrl-C or SIGTERM), then stops the camera and prints
/// what it served.
pub(crate) async fn run(args: Args, shutdown: CancellationToken) -> anyhow::Result<ExitCode> {
    // Loading meshes, planning the view and binding sockets block: keep them off the workers.
    let cam = tokio::task::spawn_blocking(move || start(args))
        .await
        .context("the simulator start-up thread failed")??;
    shutdown.cancelled().await;
    let s = cam.stats();
    // Dropping joins the camera's threads.
    tokio::task::spawn_blocking(move || drop(cam))
        .await
        .context("stopping the simulated camera")?;
    eprintln!(
        "served {} frames, dropped {} packets, resent {}",
        s.frames, s.dropped_packets, s.resent_packets
    );
    Ok(ExitCode::SUCCESS)
}

/// Builds the frame source and starts serving (blocking).
fn start(args: Args) -> anyhow::Result<SimCamera> {
    if !(0.0..1.0).contains(&args.loss) {
        anyhow::bail!("--loss must be in [0, 1)");
    }
    limits::check_range(
        "--frame-rate",
        args.frame_rate,
        MIN_FRAME_RATE_HZ,
        MAX_FRAME_RATE_HZ,
        "frames/s",
        "",
    )
    .map_err(anyhow::Error::msg)?;
    anyhow::ensure!(
        (MIN_PIXELS..=MAX_PIXELS).contains(&args.width)
            && (MIN_PIXELS..=MAX_PIXELS).contains(&args.height),
        "--width {} --height {}: each must be {MIN_PIXELS}–{MAX_PIXELS} pixels",
        args.width,
        args.height
    );
    let bind = GvcpClient::parse_address(&args.bind)?;
    let robot = args.robot.as_deref().map(parse_robot_addr).transpose()?;
    if robot.is_some() && args.test_pattern {
        anyhow::bail!("--robot and --test-pattern exclude each other");
    }
    let opts = SimOptions {
        loss_ratio: args.loss,
        frame_rate: args.frame_rate,
        serial: args.serial,
        ..SimOptions::default()
    };
    let (source, scene): (Box<dyn FrameSource>, String) = if args.test_pattern {
        (
            Box::new(SceneSource::new(args.width, args.height)),
            "built-in plane + sphere test scene".into(),
        )
    } else {
        let mount = parse_pose(args.mount.as_deref().unwrap_or(DEFAULT_MOUNT))
            .map_err(|e| anyhow::anyhow!("--mount: {e}"))?;
        super::args::check_mount("--mount", &mount).map_err(anyhow::Error::msg)?;
        let model = Arc::new(RobotModel::load(
            &resolve_robot(&args.model).map_err(anyhow::Error::msg)?,
        )?);
        let settings = match (&args.settings, args.ideal) {
            (_, true) => SimSettings::ideal(),
            (Some(path), false) => SimSettings::load(path)?,
            (None, false) if robot.is_some() => SimSettings {
                kinematic_error: KinematicError::none(),
                ..SimSettings::default()
            },
            (None, false) => SimSettings::default(),
        };
        let intrinsics = Intrinsics::from_fov(args.width, args.height, 60f64.to_radians());
        let (joints, scene) = match robot {
            Some(addr) => {
                anyhow::ensure!(
                    model.dof() == 6,
                    "--model {} has {} joints; a UR controller reports 6",
                    args.model,
                    model.dof()
                );
                let live = LiveJoints::follow(addr)?;
                (
                    SceneJoints::Live(live),
                    format!("{} following the robot at {addr} over RTDE", model.name()),
                )
            }
            None => {
                let planner =
                    ViewPlanner::new(&model, mount, intrinsics, ViewConstraints::default());
                let joints = planner.generate(1, 1)?.remove(0);
                let scene = format!("{} at joints {:?} rad", model.name(), joints);
                (SceneJoints::Fixed(joints), scene)
            }
        };
        let arm = match args.factory_calibration {
            Some(seed) => Some(factory_arm(&model, seed)?),
            None => None,
        };
        let source = RobotScene {
            model,
            joints,
            mount: match args.mount_file {
                Some(path) => SceneMount::watched(mount, path),
                None => SceneMount::fixed(mount),
            },
            intrinsics,
            settings,
            arm,
            frame: 0,
        };
        (Box::new(source), scene)
    };
    let cam = SimCamera::spawn(bind, source, opts)?;
    eprintln!(
        "simulated GigE Vision 3D camera on {} ({}x{}, {scene}); Ctrl-C to stop",
        cam.addr(),
        args.width,
        args.height
    );
    Ok(cam)
}

/// The physical arm of a factory-calibrated `model` as the UR simulator started with
/// `--factory-calibration seed` drives it.
pub(crate) fn factory_arm(model: &RobotModel, seed: u64) -> anyhow::Result<PhysicalArm> {
    let ur = model.ur_model().ok_or_else(|| {
        anyhow::anyhow!(
            "--factory-calibration needs a UR model; {} is not one",
            model.name()
        )
    })?;
    Ok(PhysicalArm::factory(ur, seed))
}
