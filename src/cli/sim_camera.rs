//! `handeye sim camera`: a simulated GigE Vision 3D camera on a given address.

use std::process::ExitCode;

use std::sync::Arc;

use nalgebra::Isometry3;

use handeye::model::RobotModel;
use handeye::plan::{ViewConstraints, ViewPlanner};
use handeye::sim::{simulate_scan, Intrinsics, Placement, ScanRequest, SimSettings};
use handeye_gige::sim::{FrameSource, SceneSource, SimCamera, SimOptions, SourceError};
use handeye_gige::GvcpClient;

use super::args::{parse_pose, resolve_robot};

/// The camera mount used when none is given: 8 cm off the tool axis, tilted 15° towards it.
const DEFAULT_MOUNT: &str = "0,-0.08,0.04,-0.26,0,0";

/// Frames rendered by the scan simulator: the robot at fixed joints seen from a camera on its
/// flange, new sensor noise every frame.
struct RobotScene {
    model: Arc<RobotModel>,
    joints: Vec<f64>,
    mount: Isometry3<f64>,
    intrinsics: Intrinsics,
    settings: SimSettings,
    frame: u64,
}

impl FrameSource for RobotScene {
    fn next_frame(&mut self) -> Result<handeye_hal::PointCloud, SourceError> {
        self.frame += 1;
        let req = ScanRequest {
            model: &self.model,
            joints: self.joints.clone(),
            placement: Placement::EyeInHand {
                flange_from_camera: self.mount,
            },
            intrinsics: self.intrinsics,
            noise: self.settings.noise,
            cell: self.settings.cell,
            kinematic_error: self.settings.kinematic_error,
            seed: self.frame,
        };
        Ok(simulate_scan(&req)?.cloud)
    }

    fn size(&self) -> (u32, u32) {
        (self.intrinsics.width, self.intrinsics.height)
    }

    fn intrinsics(&self) -> (f64, f64, f64) {
        (self.intrinsics.fx, self.intrinsics.cx, self.intrinsics.cy)
    }
}

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Address to serve GVCP on, `IP` or `IP:PORT` (default port 3956).
    #[arg(long, value_name = "ADDR")]
    bind: String,
    /// Follow this robot over RTDE and render the robot from the camera mount.
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
    #[arg(long, default_value_t = 640)]
    width: u32,
    /// Sensor height in pixels.
    #[arg(long, default_value_t = 480)]
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
    /// Serial number to report.
    #[arg(long, default_value = "SIM0001")]
    serial: String,
}

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    if args.robot.is_some() {
        anyhow::bail!(
            "--robot (following a live robot over RTDE) is not available yet; without it the camera renders the {} at a fixed view",
            args.model
        );
    }
    if !(0.0..1.0).contains(&args.loss) {
        anyhow::bail!("--loss must be in [0, 1)");
    }
    let bind = GvcpClient::parse_address(&args.bind)?;
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
            .map_err(anyhow::Error::msg)?;
        let model = Arc::new(RobotModel::load(
            &resolve_robot(&args.model).map_err(anyhow::Error::msg)?,
        )?);
        let intrinsics = Intrinsics::from_fov(args.width, args.height, 60f64.to_radians());
        let planner = ViewPlanner::new(&model, mount, intrinsics, ViewConstraints::default());
        let joints = planner.generate(1, 1)?.remove(0);
        let scene = format!("{} at joints {:?} rad", model.name(), joints);
        let source = RobotScene {
            model,
            joints,
            mount,
            intrinsics,
            settings: SimSettings::default(),
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
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?
        .block_on(tokio::signal::ctrl_c())?;
    let s = cam.stats();
    eprintln!(
        "served {} frames, dropped {} packets, resent {}",
        s.frames, s.dropped_packets, s.resent_packets
    );
    Ok(ExitCode::SUCCESS)
}
