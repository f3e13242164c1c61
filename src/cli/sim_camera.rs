//! `handeye sim camera`: a simulated GigE Vision 3D camera on a given address.

use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use nalgebra::Isometry3;

use handeye::model::RobotModel;
use handeye::plan::{ViewConstraints, ViewPlanner};
use handeye::sim::{
    simulate_scan, Intrinsics, KinematicError, Placement, ScanRequest, SimSettings,
};
use handeye_gige::sim::{FrameSource, SceneSource, SimCamera, SimOptions, SourceError};
use handeye_gige::GvcpClient;
use handeye_ur::client::{RtdeClient, RtdeConfig};

use super::args::{parse_pose, resolve_robot};

/// The camera mount used when none is given: 8 cm off the tool axis, tilted 15° towards it.
const DEFAULT_MOUNT: &str = "0,-0.08,0.04,-0.26,0,0";

/// Frames rendered by the scan simulator: the robot seen from a camera on its flange, at fixed
/// joints or at the joints a live robot measures, new sensor noise every frame.
struct RobotScene {
    model: Arc<RobotModel>,
    joints: SceneJoints,
    mount: Isometry3<f64>,
    intrinsics: Intrinsics,
    settings: SimSettings,
    frame: u64,
}

/// Where the rendered robot's joints come from.
enum SceneJoints {
    /// A generated view that looks at the base.
    Fixed(Vec<f64>),
    /// The latest `actual_q` of a robot followed over RTDE.
    Live(LiveJoints),
}

/// The joints a robot reports over RTDE, kept up to date by a follower thread
/// ([`follow_robot`]) and read by the camera's streaming thread.
#[derive(Clone)]
struct LiveJoints {
    /// Controller address, for messages.
    robot: SocketAddr,
    state: Arc<Mutex<FollowState>>,
}

/// What the follower thread last saw.
#[derive(Debug, Default)]
struct FollowState {
    /// Latest measured joints (rad, URDF order) and when they arrived.
    joints: Option<(Vec<f64>, Instant)>,
    /// Why there are no current joints (connection refused, lost, …), for the frame error.
    problem: Option<String>,
}

/// Joints older than this are not rendered: the link to the robot is considered lost.
const MAX_JOINT_AGE: Duration = Duration::from_millis(500);
/// RTDE output rate asked of the controller (valid on CB3 and e-Series).
const FOLLOW_HZ: f64 = 25.0;
/// No sample for this long: drop the RTDE client and connect again from scratch.
const RECONNECT_AFTER: Duration = Duration::from_secs(5);

impl LiveJoints {
    /// The joints to render now, or why there are none.
    fn current(&self) -> Result<Vec<f64>, String> {
        let st = self
            .state
            .lock()
            .map_err(|_| "robot follower thread panicked".to_string())?;
        match &st.joints {
            Some((q, at)) if at.elapsed() <= MAX_JOINT_AGE => Ok(q.clone()),
            Some((_, at)) => Err(format!(
                "{} (last joints {:.1} s old; not rendering a stale pose)",
                st.problem
                    .as_deref()
                    .unwrap_or("no recent joint data from the robot"),
                at.elapsed().as_secs_f64(),
            )),
            None => Err(st
                .problem
                .clone()
                .unwrap_or_else(|| format!("no joint data from the robot at {} yet", self.robot))),
        }
    }

    fn set(&self, f: impl FnOnce(&mut FollowState)) {
        if let Ok(mut st) = self.state.lock() {
            f(&mut st);
        }
    }

    /// Records a problem; prints it when it differs from the previous one.
    fn problem(&self, msg: String) {
        let mut changed = false;
        self.set(|st| {
            changed = st.problem.as_deref() != Some(msg.as_str());
            st.problem = Some(msg.clone());
        });
        if changed {
            eprintln!("sim camera: {msg}");
        }
    }
}

/// Follows the robot at `live.robot` over RTDE (`actual_q`) until the process ends: connects,
/// stores every sample, and on a refused or lost connection records why and connects again
/// (backoff 0.2–2 s). Runs its own single-threaded runtime; call from a dedicated thread.
fn follow_robot(live: LiveJoints) {
    let rt = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            live.problem(format!("cannot start the RTDE follower: {e}"));
            return;
        }
    };
    rt.block_on(async move {
        let mut backoff = Duration::from_millis(200);
        loop {
            let cfg = RtdeConfig {
                addr: live.robot,
                frequency: Some(FOLLOW_HZ),
                outputs: vec!["actual_q".into()],
                inputs: vec![],
                timeout: Duration::from_secs(2),
                max_backoff: Duration::from_secs(1),
            };
            let client = match RtdeClient::connect(cfg).await {
                Ok(c) => c,
                Err(e) => {
                    live.problem(format!(
                        "cannot follow the robot over RTDE at {}: {e}; retrying",
                        live.robot
                    ));
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(Duration::from_secs(2));
                    continue;
                }
            };
            backoff = Duration::from_millis(200);
            eprintln!(
                "sim camera: following the robot at {} over RTDE ({FOLLOW_HZ} Hz actual_q)",
                live.robot
            );
            let mut last = Instant::now();
            let mut quiet_since: Option<Instant> = None;
            loop {
                match client.next_sample(last, MAX_JOINT_AGE).await {
                    Ok(s) => {
                        last = s.received;
                        quiet_since = None;
                        let Some(q) = s.vec6("actual_q") else {
                            live.problem("RTDE sample without actual_q".into());
                            continue;
                        };
                        let was_down = live
                            .state
                            .lock()
                            .map(|st| st.problem.is_some())
                            .unwrap_or(false);
                        live.set(|st| {
                            st.joints = Some((q.to_vec(), s.received));
                            st.problem = None;
                        });
                        if was_down {
                            eprintln!("sim camera: receiving joints from {}", live.robot);
                        }
                    }
                    Err(e) => {
                        live.problem(format!(
                            "lost the robot's RTDE stream at {}: {e}; reconnecting",
                            live.robot
                        ));
                        let since = *quiet_since.get_or_insert_with(Instant::now);
                        if since.elapsed() >= RECONNECT_AFTER {
                            break;
                        }
                        // The client reconnects by itself; a closed client returns at once.
                        tokio::time::sleep(Duration::from_millis(100)).await;
                    }
                }
            }
        }
    });
}

/// `ADDR` or `ADDR:PORT` of a UR controller's RTDE interface (default port 30004).
fn parse_robot_addr(s: &str) -> anyhow::Result<SocketAddr> {
    if let Ok(a) = s.parse::<SocketAddr>() {
        return Ok(a);
    }
    let ip: IpAddr = s.parse().map_err(|_| {
        anyhow::anyhow!(
            "--robot `{s}` is not an IP address or IP:PORT (the RTDE port, default 30004)"
        )
    })?;
    Ok(SocketAddr::new(ip, handeye_ur::Ports::STANDARD.rtde))
}

impl FrameSource for RobotScene {
    fn next_frame(&mut self) -> Result<handeye_hal::PointCloud, SourceError> {
        self.frame += 1;
        let joints = match &self.joints {
            SceneJoints::Fixed(q) => q.clone(),
            SceneJoints::Live(live) => live.current()?,
        };
        let placement = Placement::EyeInHand {
            flange_from_camera: self.mount,
        };
        let req = ScanRequest::new(
            &self.model,
            joints,
            placement,
            self.intrinsics,
            &self.settings,
            self.frame,
        );
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
}

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    if !(0.0..1.0).contains(&args.loss) {
        anyhow::bail!("--loss must be in [0, 1)");
    }
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
            .map_err(anyhow::Error::msg)?;
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
                let live = LiveJoints {
                    robot: addr,
                    state: Arc::new(Mutex::new(FollowState::default())),
                };
                let follower = live.clone();
                std::thread::Builder::new()
                    .name("rtde-follow".into())
                    .spawn(move || follow_robot(follower))?;
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
        let source = RobotScene {
            model,
            joints,
            mount,
            intrinsics,
            settings,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robot_addresses_default_to_the_rtde_port() {
        let a = parse_robot_addr("127.0.0.110").expect("ip");
        assert_eq!(a, "127.0.0.110:30004".parse().expect("addr"));
        let a = parse_robot_addr("127.0.0.110:40004").expect("ip:port");
        assert_eq!(a.port(), 40004);
        let e = parse_robot_addr("robot.local").expect_err("not an ip");
        assert!(e.to_string().contains("robot.local"), "{e}");
    }

    #[test]
    fn live_joints_are_fresh_or_the_frame_fails_with_the_reason() {
        let live = LiveJoints {
            robot: "127.0.0.1:30004".parse().expect("addr"),
            state: Arc::new(Mutex::new(FollowState::default())),
        };
        let e = live.current().expect_err("nothing yet");
        assert!(e.contains("127.0.0.1:30004"), "{e}");
        live.problem("cannot follow the robot over RTDE at 127.0.0.1:30004: refused".into());
        assert!(live.current().expect_err("refused").contains("refused"));

        let q = vec![0.1, -1.0, 1.0, -1.5, -1.5, 0.0];
        live.set(|st| {
            st.joints = Some((q.clone(), Instant::now()));
            st.problem = None;
        });
        assert_eq!(live.current().expect("fresh"), q);

        let old = Instant::now()
            .checked_sub(MAX_JOINT_AGE * 2)
            .expect("clock far enough from its origin");
        live.set(|st| st.joints = Some((q.clone(), old)));
        live.problem("lost the robot's RTDE stream at 127.0.0.1:30004: closed".into());
        let e = live.current().expect_err("stale");
        assert!(e.contains("lost") && e.contains("stale"), "{e}");
    }
}
