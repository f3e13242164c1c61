//! The robot rendered by the scan simulator as a camera on its flange sees it, at fixed
//! joints or following a (simulated) controller over RTDE.

use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use handeye_calib::model::RobotModel;
use handeye_calib::sim::{simulate_scan, Intrinsics, Placement, ScanRequest, SimSettings};
use handeye_gige::sim::{FrameSource, SourceError};
use handeye_hal::ur_dh::PhysicalArm;
use handeye_hal::UrPose;
use handeye_ur::client::{RtdeClient, RtdeConfig};
use nalgebra::Isometry3;
use tokio_util::sync::CancellationToken;

use crate::pose::{check_mount, parse_pose};

/// The camera mount used when none is given: 8 cm off the tool axis, tilted 15° towards it.
pub const DEFAULT_MOUNT: &str = "0,-0.08,0.04,-0.26,0,0";

/// Frames rendered by the scan simulator: the robot seen from a camera on its flange, at fixed
/// joints or at the joints a live robot measures, new sensor noise every frame.
pub struct RobotScene {
    /// The rendered robot.
    pub model: Arc<RobotModel>,
    /// Its joints, fixed or followed.
    pub joints: SceneJoints,
    /// The camera on its flange (`flange_from_camera`).
    pub mount: SceneMount,
    /// The camera's sensor and lens.
    pub intrinsics: Intrinsics,
    /// Sensor noise, the cell around the robot, kinematic error.
    pub settings: SimSettings,
    /// The physical arm when the controller is factory calibrated (the arm the UR simulator
    /// drives); `None`: the nominal URDF (plus `settings.kinematic_error`).
    pub arm: Option<PhysicalArm>,
    /// Frames rendered so far (the seed of each frame's noise).
    pub frame: u64,
}

/// A scene that follows a robot stops its RTDE follower when it goes away (a GenTL producer
/// unloaded by its consumer leaves no thread or connection behind).
impl Drop for RobotScene {
    fn drop(&mut self) {
        if let SceneJoints::Live(live) = &self.joints {
            live.stop();
        }
    }
}

impl std::fmt::Debug for RobotScene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RobotScene")
            .field("model", &self.model.name())
            .field("joints", &self.joints)
            .field("mount", &self.mount)
            .field("frame", &self.frame)
            .finish_non_exhaustive()
    }
}

/// The camera mount (`flange_from_camera`): fixed, or read from a file whenever the file
/// changes (a simulator-only way for tests to move the camera on its bracket).
#[derive(Debug)]
pub struct SceneMount {
    current: Isometry3<f64>,
    file: Option<(PathBuf, Option<SystemTime>)>,
}

impl SceneMount {
    /// A mount that never changes.
    pub fn fixed(mount: Isometry3<f64>) -> Self {
        Self {
            current: mount,
            file: None,
        }
    }

    /// A mount read from `path` (`x,y,z,rx,ry,rz`, m and rad) whenever its modification time
    /// changes; `initial` until the file exists and parses.
    pub fn watched(initial: Isometry3<f64>, path: PathBuf) -> Self {
        Self {
            current: initial,
            file: Some((path, None)),
        }
    }

    /// The mount now.
    pub fn get(&mut self) -> Isometry3<f64> {
        if let Some((path, seen)) = &mut self.file {
            let modified = std::fs::metadata(&*path).and_then(|m| m.modified()).ok();
            if modified.is_some() && modified != *seen {
                *seen = modified;
                // Never a FIFO (the read would stall the streaming thread), never a huge file;
                // a mount within reach of the flange.
                match read_mount_file(path) {
                    Ok(m) => {
                        eprintln!(
                            "sim camera: mount is now {} (from {})",
                            UrPose::from(&m),
                            path.display()
                        );
                        self.current = m;
                    }
                    Err(e) => eprintln!("sim camera: ignoring {}: {e}", path.display()),
                }
            }
        }
        self.current
    }
}

/// Largest mount file read (one `x,y,z,rx,ry,rz` line).
const MAX_MOUNT_FILE_BYTES: u64 = 4096;

/// The mount (`flange_from_camera`) a mount file holds (`x,y,z,rx,ry,rz`, m and rad): never a
/// FIFO (the read would stall the streaming thread), never a huge file, a mount within reach
/// of the flange.
pub fn read_mount_file(path: &std::path::Path) -> Result<Isometry3<f64>, String> {
    handeye_hal::limits::read_text_file(path, MAX_MOUNT_FILE_BYTES)
        .map_err(|e| e.to_string())
        .and_then(|t| parse_pose(&t))
        .and_then(|m| check_mount("the mount file's pose", &m).map(|()| m))
}

/// Where the rendered robot's joints come from.
#[derive(Debug)]
pub enum SceneJoints {
    /// A generated view that looks at the base.
    Fixed(Vec<f64>),
    /// The latest `actual_q` of a robot followed over RTDE.
    Live(LiveJoints),
}

/// The joints a robot reports over RTDE, kept up to date by a follower thread
/// (`follow_robot`) and read by the camera's streaming thread.
#[derive(Clone)]
pub struct LiveJoints {
    /// Controller address, for messages.
    robot: SocketAddr,
    state: Arc<Mutex<FollowState>>,
    /// Ends the follower thread.
    stop: CancellationToken,
    /// The follower thread, joined by [`LiveJoints::stop`].
    thread: Arc<Mutex<Option<std::thread::JoinHandle<()>>>>,
}

impl std::fmt::Debug for LiveJoints {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveJoints")
            .field("robot", &self.robot)
            .finish_non_exhaustive()
    }
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
    /// Joints of the robot at `robot`, kept fresh by a follower thread started here.
    pub fn follow(robot: SocketAddr) -> std::io::Result<Self> {
        let live = LiveJoints {
            robot,
            state: Arc::new(Mutex::new(FollowState::default())),
            stop: CancellationToken::new(),
            thread: Arc::new(Mutex::new(None)),
        };
        let follower = live.clone();
        let handle = std::thread::Builder::new()
            .name("rtde-follow".into())
            .spawn(move || follow_robot(follower))?;
        if let Ok(mut t) = live.thread.lock() {
            *t = Some(handle);
        }
        Ok(live)
    }

    /// Stops following: the follower thread closes its RTDE connection and ends (joined).
    pub fn stop(&self) {
        self.stop.cancel();
        let handle = self.thread.lock().ok().and_then(|mut t| t.take());
        if let Some(h) = handle {
            if h.join().is_err() {
                eprintln!("sim camera: the RTDE follower thread panicked");
            }
        }
    }

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
    let stop = live.stop.clone();
    rt.block_on(async move {
        tokio::select! {
            _ = stop.cancelled() => {}
            _ = follow_loop(live) => {}
        }
    });
}

/// The follower's connect / receive / reconnect loop; never returns.
async fn follow_loop(live: LiveJoints) {
    {
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
    }
}

/// `ADDR` or `ADDR:PORT` of a UR controller's RTDE interface (default port 30004).
pub fn parse_robot_addr(s: &str) -> anyhow::Result<SocketAddr> {
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
            flange_from_camera: self.mount.get(),
        };
        let mut req = ScanRequest::new(
            &self.model,
            joints,
            placement,
            self.intrinsics,
            &self.settings,
            self.frame,
        );
        if let Some(arm) = self.arm {
            req = req.with_arm(arm);
        }
        Ok(simulate_scan(&req)?.cloud)
    }

    fn size(&self) -> (u32, u32) {
        (self.intrinsics.width, self.intrinsics.height)
    }

    fn intrinsics(&self) -> (f64, f64, f64) {
        (self.intrinsics.fx, self.intrinsics.cx, self.intrinsics.cy)
    }
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

    /// Issue 16: a mount file that is a FIFO does not stall the camera (it is not read), one
    /// with a pose across the cell is ignored, a good one is taken.
    #[cfg(unix)]
    #[test]
    fn issue_16_mount_file_is_read_only_when_plausible() {
        let dir = std::env::temp_dir().join(format!("handeye-scene-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let initial = Isometry3::translation(0.0, -0.08, 0.04);
        let fifo = dir.join("mount.fifo");
        let _ = std::fs::remove_file(&fifo);
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .expect("mkfifo");
        assert!(made.success());
        let mut m = SceneMount::watched(initial, fifo.clone());
        let t = Instant::now();
        assert_eq!(m.get(), initial);
        assert!(t.elapsed() < Duration::from_secs(1), "{:?}", t.elapsed());
        let file = dir.join("mount.txt");
        std::fs::write(&file, "1e6,0,0,0,0,0").expect("write");
        let mut m = SceneMount::watched(initial, file.clone());
        assert_eq!(
            m.get(),
            initial,
            "a mount 1000 km from the flange is ignored"
        );
        std::fs::write(&file, "0.01,-0.07,0.05,0,0,0.1").expect("write");
        let mut m = SceneMount::watched(initial, file);
        assert!((m.get().translation.vector.x - 0.01).abs() < 1e-12);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn live_joints_are_fresh_or_the_frame_fails_with_the_reason() {
        let live = LiveJoints {
            robot: "127.0.0.1:30004".parse().expect("addr"),
            state: Arc::new(Mutex::new(FollowState::default())),
            stop: CancellationToken::new(),
            thread: Arc::new(Mutex::new(None)),
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
