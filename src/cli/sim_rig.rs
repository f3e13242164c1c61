//! `handeye sim rig`: the whole simulated cell in one process — a UR controller simulator
//! (dashboard, primary/secondary, real-time, RTDE) and a simulated GigE Vision 3D camera on its
//! flange that renders the arm at the joints the controller reports over RTDE. Clients talk
//! to both over the real protocols. The ground truth (the camera mount, the arm's calibrated
//! kinematics) goes to a file for tests, never to the solver.

use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::Context;
use handeye::frames::to_row_major;
use handeye::model::RobotModel;
use handeye::sim::{Intrinsics, SimSettings};
use handeye_gige::sim::{SimCamera, SimOptions};
use handeye_gige::GvcpClient;

use handeye_hal::ur_dh::{DhParams, UrModel};
use handeye_hal::UrPose;
use handeye_sim_scene::{MAX_PIXELS, MIN_PIXELS};
use handeye_ur::sim::{SimConfig, SimHandle, Simulator};
use handeye_ur::Ports;
use nalgebra::Isometry3;
use rand::SeedableRng;
use tokio_util::sync::CancellationToken;

use super::args::{parse_pose, resolve_robot};
use handeye_sim_scene::{LiveJoints, RobotScene, SceneJoints, SceneMount, DEFAULT_MOUNT};

/// Everything that defines a rig.
#[derive(Debug, Clone)]
pub(crate) struct RigOptions {
    /// The arm.
    pub(crate) model: UrModel,
    /// True `flange_from_camera`.
    pub(crate) mount: Isometry3<f64>,
    /// Seed of the arm's factory calibration (`None`: nominal DH).
    pub(crate) factory_calibration: Option<u64>,
    /// The arm's serial number (`None`: the simulator's for the seed).
    pub(crate) serial: Option<String>,
    /// Address of the controller's ports.
    pub(crate) robot_bind: IpAddr,
    /// The controller's ports (standard, or 0s for ephemeral ones).
    pub(crate) robot_ports: Ports,
    /// GVCP address of the camera (port 0: any free port).
    pub(crate) camera_bind: SocketAddr,
    /// The camera's sensor and lens.
    pub(crate) intrinsics: Intrinsics,
    /// Noise and cell of the rendered scans.
    pub(crate) settings: SimSettings,
    /// Simulator-only: re-read the mount from this file when it changes.
    pub(crate) mount_file: Option<PathBuf>,
    /// The vendor habits the camera imitates (`--imitate`).
    pub(crate) habits: handeye_gige::sim::VendorHabits,
    /// Fault flags and start state of the controller.
    pub(crate) robot: RobotFaults,
}

/// The controller's start state and fault injection.
#[derive(Debug, Clone, Default)]
pub(crate) struct RobotFaults {
    /// Start powered off (POWER_OFF) instead of running.
    pub(crate) powered_off: bool,
    /// Start in local control.
    pub(crate) local_control: bool,
    /// Protective stop when the first move reaches this fraction of its path.
    pub(crate) protective_stop_during_move: Option<f64>,
}

/// A running rig; dropping it stops both simulators.
pub(crate) struct Rig {
    /// The controller simulator (fault injection, state).
    pub(crate) robot: SimHandle,
    /// The camera simulator (serving until dropped).
    _camera: SimCamera,
    /// The camera's GVCP address.
    pub(crate) camera_addr: SocketAddr,
    /// What the rig simulates (the truth).
    pub(crate) options: RigOptions,
    /// The arm's true (calibrated) DH parameters, as the controller reports them.
    pub(crate) controller_dh: DhParams,
    /// The camera's RTDE follower, stopped before the controller goes away.
    live: LiveJoints,
}

impl Drop for Rig {
    fn drop(&mut self) {
        self.live.stop();
    }
}

impl std::fmt::Debug for Rig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Rig")
            .field("camera_addr", &self.camera_addr)
            .field("options", &self.options)
            .finish_non_exhaustive()
    }
}

impl Rig {
    /// Starts the controller, then the camera following it over RTDE.
    pub(crate) async fn start(opts: RigOptions) -> anyhow::Result<Rig> {
        let path = resolve_robot(opts.model.name()).map_err(anyhow::Error::msg)?;
        let model = Arc::new(RobotModel::load(&path)?);
        let mut c = SimConfig::new(opts.model, opts.robot_bind);
        c.ports = opts.robot_ports;
        c.start_running = !opts.robot.powered_off;
        c.remote_control = !opts.robot.local_control;
        c.protective_stop_during_move = opts.robot.protective_stop_during_move;
        if let Some(seed) = opts.factory_calibration {
            c = c.factory_calibrated(seed);
        }
        if let Some(serial) = &opts.serial {
            c.serial = serial.clone();
        }
        let robot = Simulator::start(c)
            .await
            .with_context(|| format!("starting the UR simulator on {}", opts.robot_bind))?;
        let controller_dh = robot.dh();
        let rtde = SocketAddr::new(opts.robot_bind, robot.ports().rtde);
        let intrinsics = opts.intrinsics;
        let live = LiveJoints::follow(rtde)?;
        let scene = RobotScene {
            model,
            joints: SceneJoints::Live(live.clone()),
            mount: match &opts.mount_file {
                Some(p) => SceneMount::watched(opts.mount, p.clone()),
                None => SceneMount::fixed(opts.mount),
            },
            intrinsics,
            settings: SimSettings {
                // The arm's kinematic error is the controller's calibration, rendered exactly;
                // its joint readings are off as a real arm's are (the arm stands at its physical
                // joints, the controller reports the joints it reads).
                kinematic_error: opts.settings.kinematic_error.readings_only(),
                ..opts.settings
            },
            arm: robot.arm(),
            frame: 0,
        };
        let camera = SimCamera::spawn(
            opts.camera_bind,
            Box::new(scene),
            SimOptions {
                serial: "SIMRIG01".into(),
                habits: opts.habits.clone(),
                ..SimOptions::default()
            },
        )
        .with_context(|| format!("starting the simulated camera on {}", opts.camera_bind))?;
        let camera_addr = camera.addr();
        Ok(Rig {
            robot,
            _camera: camera,
            camera_addr,
            options: opts,
            controller_dh,
            live,
        })
    }

    /// The ground truth as JSON: `flange_from_camera` (4×4 and UR pose), the arm's DH and
    /// serial number.
    pub(crate) fn truth(&self) -> serde_json::Value {
        serde_json::json!({
            "flange_from_camera": to_row_major(&self.options.mount),
            "flange_from_camera_ur": UrPose::from(&self.options.mount).to_string(),
            "model": self.options.model.name(),
            "factory_calibration_seed": self.options.factory_calibration,
            "controller_dh": self.controller_dh,
            "serial": self.robot.serial(),
            "robot": {
                "host": self.robot.ip().to_string(),
                "ports": ports_json(self.robot.ports()),
            },
            "camera": self.camera_addr.to_string(),
        })
    }
}

fn ports_json(p: Ports) -> serde_json::Value {
    serde_json::json!({
        "dashboard": p.dashboard, "primary": p.primary, "secondary": p.secondary,
        "realtime": p.realtime, "rtde": p.rtde,
    })
}

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Arm model.
    #[arg(long, default_value = "ur5e")]
    model: UrModel,
    /// Camera mount `flange_from_camera` as `x,y,z,rx,ry,rz` (m, rotation vector rad)
    /// [default: 0,-0.08,0.04,-0.26,0,0].
    #[arg(
        long,
        value_name = "POSE",
        allow_hyphen_values = true,
        conflicts_with = "random_mount"
    )]
    mount: Option<String>,
    /// A random wrist-camera mount drawn from SEED (as the benchmark draws them).
    #[arg(long, value_name = "SEED")]
    random_mount: Option<u64>,
    /// Address of the controller's standard ports (29999, 30001–30004).
    #[arg(long, default_value = "127.0.0.1", value_name = "ADDR")]
    robot_bind: IpAddr,
    /// GVCP address of the camera, `IP` or `IP:PORT` (default port 3956).
    #[arg(long, default_value = "127.0.0.2", value_name = "ADDR")]
    camera_bind: String,
    /// The physical arm's seed: its joints are off as a real arm's are, and the controller
    /// publishes its exact DH.
    #[arg(long, default_value_t = 1, value_name = "SEED")]
    factory_calibration: u64,
    /// An arm exactly at its nominal DH (no factory calibration).
    #[arg(long)]
    nominal_kinematics: bool,
    /// The arm's serial number, as dashboard `get serial number` answers it (default: one in
    /// a real controller's 11-digit shape, from the model and the factory-calibration seed).
    #[arg(long, value_name = "SERIAL", value_parser = super::sim_robot::parse_serial)]
    serial: Option<String>,
    /// Sensor width, pixels.
    #[arg(long, default_value_t = handeye_sim_scene::DEFAULT_WIDTH)]
    width: u32,
    /// Sensor height, pixels.
    #[arg(long, default_value_t = handeye_sim_scene::DEFAULT_HEIGHT)]
    height: u32,
    /// Write the ground truth (mount, the arm's DH, addresses) to this JSON file, at start (the
    /// mount: `--mount-file`'s when it holds one, else `--mount`).
    #[arg(long, value_name = "FILE")]
    truth: Option<PathBuf>,
    /// Simulator-only: re-read the mount from this file (`x,y,z,rx,ry,rz`) when it changes.
    #[arg(long, value_name = "FILE")]
    mount_file: Option<PathBuf>,
    /// Start the arm powered off.
    #[arg(long)]
    powered_off: bool,
    /// Start in local control.
    #[arg(long)]
    local_control: bool,
    /// Protective stop when the first move reaches this fraction of its path (0–1).
    #[arg(long, value_name = "FRACTION")]
    protective_stop_during_move: Option<f64>,
    /// A perfect sensor in empty space: no noise, no cell.
    #[arg(long)]
    ideal: bool,
    /// The camera describes itself and streams as this vendor's does (photoneo, lucid, sick,
    /// blaze); default: by SFNC's letter.
    #[arg(long, value_name = "VENDOR", value_parser = handeye_sim_scene::parse_imitation)]
    imitate: Option<String>,
}

pub(crate) async fn run(args: Args, shutdown: CancellationToken) -> anyhow::Result<ExitCode> {
    let mount = match (args.random_mount, &args.mount) {
        (Some(seed), _) => {
            handeye::bench::random_mount(&mut rand::rngs::StdRng::seed_from_u64(seed))
        }
        (None, m) => {
            parse_pose(m.as_deref().unwrap_or(DEFAULT_MOUNT)).map_err(anyhow::Error::msg)?
        }
    };
    super::args::check_mount("--mount", &mount).map_err(anyhow::Error::msg)?;
    // A mount file that holds a pose is the mount the camera renders from its first frame (it
    // wins over --mount): the truth starts from it too.
    let mount = match &args.mount_file {
        Some(p) if p.exists() => handeye_sim_scene::read_mount_file(p)
            .map_err(|e| anyhow::anyhow!("--mount-file {}: {e}", p.display()))?,
        _ => mount,
    };
    if let Some(f) = args.protective_stop_during_move {
        anyhow::ensure!(
            (0.0..=1.0).contains(&f),
            "--protective-stop-during-move must be a fraction of the path in [0, 1], got {f}"
        );
    }
    anyhow::ensure!(
        (MIN_PIXELS..=MAX_PIXELS).contains(&args.width)
            && (MIN_PIXELS..=MAX_PIXELS).contains(&args.height),
        "--width and --height must be {MIN_PIXELS}–{MAX_PIXELS} pixels"
    );
    let rig = Rig::start(RigOptions {
        model: args.model,
        mount,
        factory_calibration: (!args.nominal_kinematics).then_some(args.factory_calibration),
        serial: args.serial,
        robot_bind: args.robot_bind,
        robot_ports: Ports::STANDARD,
        camera_bind: GvcpClient::parse_address(&args.camera_bind)?,
        intrinsics: Intrinsics::from_fov(args.width, args.height, 60f64.to_radians()),
        settings: if args.ideal {
            SimSettings::ideal()
        } else {
            SimSettings::default()
        },
        mount_file: args.mount_file,
        habits: handeye_sim_scene::imitation(args.imitate.as_deref()),
        robot: RobotFaults {
            powered_off: args.powered_off,
            local_control: args.local_control,
            protective_stop_during_move: args.protective_stop_during_move,
        },
    })
    .await?;
    if let Some(path) = &args.truth {
        let text = serde_json::to_string_pretty(&rig.truth())?;
        std::fs::write(path, text)
            .with_context(|| format!("writing the ground truth to {}", path.display()))?;
    }
    eprintln!(
        "simulated rig: {} controller on {} (standard ports), GigE Vision 3D camera on {}; Ctrl-C to stop",
        args.model, args.robot_bind, rig.camera_addr
    );
    shutdown.cancelled().await;
    Ok(ExitCode::SUCCESS)
}
