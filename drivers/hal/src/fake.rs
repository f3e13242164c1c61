//! Trait-level fakes for tests of code that only needs a [`Robot`] or a [`DepthCamera`]
//! (feature `fake`). Protocol-level simulators live in the drivers; these exist for logic
//! that no protocol can exercise cheaply (e.g. "protective stop on the third move").

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};

use nalgebra::Isometry3;

use crate::ur_dh::{DhParams, UrModel};
use crate::{
    CameraInfo, CaptureSettings, ControllerIdentity, ControllerKinematics, DepthCamera, HalError,
    MotionLimits, PointCloud, Robot, RobotMode, RobotStatus, SafetyMode,
};

#[derive(Debug)]
struct RobotState {
    status: RobotStatus,
    q: Vec<f64>,
    tcp: Isometry3<f64>,
    moves: Vec<Vec<f64>>,
    protective_stop_at_move: Option<usize>,
    reconnect_at_move: Option<usize>,
    link_generation: u64,
    registers: HashMap<u32, f64>,
    int_registers: HashMap<u32, i32>,
    output_int_registers: HashMap<u32, i32>,
    /// Every TCP set, in order.
    tcp_history: Vec<Isometry3<f64>>,
    after_set_tcp: Option<Hook>,
    /// Register reads (writes) time out, as over a link that is down.
    fail_register_reads: bool,
    fail_register_writes: bool,
}

/// What a register access over a link that is down ends in.
fn register_timeout(what: String) -> HalError {
    HalError::Timeout {
        what,
        timeout: std::time::Duration::from_millis(500),
    }
}

/// A test's action run after a call (e.g. fill the disk once the controller took the TCP).
#[derive(Clone)]
struct Hook(Arc<dyn Fn() + Send + Sync>);

impl std::fmt::Debug for Hook {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Hook")
    }
}

/// A UR arm that moves instantly, records every commanded move and can be told to
/// protective-stop on the N-th move (0-based).
///
/// Kinematics: the model's nominal DH, and [`Robot::kinematics`] is `None` (a controller that
/// publishes none); [`FakeRobot::with_kinematics`] gives it a calibrated arm instead. Registers
/// (double and int) read 0 until written; the TCP offset is identity until set; the speed
/// slider is at 1.
#[derive(Debug, Clone)]
pub struct FakeRobot {
    model: UrModel,
    kinematics: Option<ControllerKinematics>,
    /// Serial and software version [`Robot::identity`] reports (model and checksum come from
    /// the model and the kinematics).
    serial: Option<String>,
    software_version: Option<String>,
    state: Arc<Mutex<RobotState>>,
}

impl FakeRobot {
    /// A powered, running arm in remote control at joint angles `q`.
    pub fn new(model: UrModel, q: [f64; 6]) -> Self {
        let status = RobotStatus {
            robot_mode: RobotMode::Running,
            safety_mode: SafetyMode::Normal,
            remote_control: true,
            program_running: false,
            speed_fraction: 1.0,
        };
        let state = RobotState {
            status,
            q: q.to_vec(),
            tcp: Isometry3::identity(),
            moves: Vec::new(),
            protective_stop_at_move: None,
            reconnect_at_move: None,
            link_generation: 0,
            registers: HashMap::new(),
            int_registers: HashMap::new(),
            output_int_registers: HashMap::new(),
            tcp_history: Vec::new(),
            after_set_tcp: None,
            fail_register_reads: false,
            fail_register_writes: false,
        };
        Self {
            model,
            kinematics: None,
            serial: None,
            software_version: None,
            state: Arc::new(Mutex::new(state)),
        }
    }

    /// This arm as a controller that publishes `kinematics`: [`Robot::kinematics`] returns
    /// them and [`Robot::flange_pose`] is the forward kinematics of `kinematics.dh` (the
    /// controller reports poses of its calibrated arm), not of the nominal model.
    pub fn with_kinematics(mut self, kinematics: ControllerKinematics) -> Self {
        self.kinematics = Some(kinematics);
        self
    }

    /// This arm with a serial number and a software version, as a controller reports them
    /// ([`Robot::identity`]; without: `None`, an old controller that does not tell).
    pub fn with_serial(mut self, serial: &str, software_version: &str) -> Self {
        self.serial = Some(serial.to_string());
        self.software_version = Some(software_version.to_string());
        self
    }

    /// The DH set this arm's reported poses use.
    pub fn dh(&self) -> DhParams {
        self.kinematics.map_or_else(|| self.model.dh(), |k| k.dh)
    }

    fn lock(&self) -> MutexGuard<'_, RobotState> {
        // A panic in another test thread must not hide this fake's state.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Make the move with this 0-based index end in a protective stop (arm stays where it was).
    pub fn protective_stop_at_move(&self, index: usize) {
        self.lock().protective_stop_at_move = Some(index);
    }

    /// Make the connection drop and come back during the move with this 0-based index: the
    /// move succeeds (the driver reconnected) and [`Robot::link_generation`] goes up by one.
    pub fn reconnect_at_move(&self, index: usize) {
        self.lock().reconnect_at_move = Some(index);
    }

    /// Make the connection drop and come back now: [`Robot::link_generation`] goes up by one.
    pub fn reconnect(&self) {
        self.lock().link_generation += 1;
    }

    /// Make every register read time out (`true`), as over a link that is down, or answer
    /// again (`false`).
    pub fn fail_register_reads(&self, fail: bool) {
        self.lock().fail_register_reads = fail;
    }

    /// Make every register write time out (`true`), or be taken again (`false`).
    pub fn fail_register_writes(&self, fail: bool) {
        self.lock().fail_register_writes = fail;
    }

    /// Set an integer output register, as a program on the controller would.
    pub fn set_output_int_register(&self, index: u32, value: i32) {
        self.lock().output_int_registers.insert(index, value);
    }

    /// Replace the reported status (e.g. remote control off).
    pub fn set_status(&self, status: RobotStatus) {
        self.lock().status = status;
    }

    /// Every move commanded so far, in order, including refused ones.
    pub fn moves(&self) -> Vec<Vec<f64>> {
        self.lock().moves.clone()
    }

    /// The TCP last set (`flange_from_tcp`).
    pub fn tcp(&self) -> Isometry3<f64> {
        self.lock().tcp
    }

    /// Every TCP set so far, in order.
    pub fn tcp_history(&self) -> Vec<Isometry3<f64>> {
        self.lock().tcp_history.clone()
    }

    /// Run `action` after every [`Robot::set_tcp`] (once the TCP is taken), e.g. to fill the
    /// disk at that point of a run.
    pub fn after_set_tcp(&self, action: impl Fn() + Send + Sync + 'static) {
        self.lock().after_set_tcp = Some(Hook(Arc::new(action)));
    }
}

impl Robot for FakeRobot {
    async fn status(&self) -> Result<RobotStatus, HalError> {
        Ok(self.lock().status.clone())
    }

    async fn joint_positions(&self) -> Result<Vec<f64>, HalError> {
        Ok(self.lock().q.clone())
    }

    async fn flange_pose(&self) -> Result<Isometry3<f64>, HalError> {
        let q = self.lock().q.clone();
        let q: [f64; 6] = q
            .try_into()
            .map_err(|_| HalError::InvalidArgument("fake robot needs 6 joints".into()))?;
        Ok(self.dh().forward(&q))
    }

    async fn move_joints(&self, q: &[f64], _limits: MotionLimits) -> Result<(), HalError> {
        let mut s = self.lock();
        if q.len() != 6 {
            return Err(HalError::InvalidArgument(format!(
                "expected 6 joint angles, got {}",
                q.len()
            )));
        }
        let index = s.moves.len();
        s.moves.push(q.to_vec());
        if !s.status.remote_control {
            return Err(HalError::NotInRemoteControl);
        }
        if !s.status.can_move() {
            return Err(HalError::NotReady {
                state: format!("{:?}/{:?}", s.status.robot_mode, s.status.safety_mode),
            });
        }
        if s.protective_stop_at_move == Some(index) {
            s.status.safety_mode = SafetyMode::ProtectiveStop;
            return Err(HalError::ProtectiveStop {
                during: format!("move {index}"),
            });
        }
        if s.reconnect_at_move == Some(index) {
            s.link_generation += 1;
        }
        s.q = q.to_vec();
        Ok(())
    }

    fn link_generation(&self) -> u64 {
        self.lock().link_generation
    }

    async fn power_on(&self) -> Result<(), HalError> {
        let mut st = self.lock();
        if matches!(
            st.status.safety_mode,
            crate::SafetyMode::RobotEmergencyStop | crate::SafetyMode::SystemEmergencyStop
        ) {
            return Err(HalError::Refused {
                device: "fake robot".into(),
                request: "power on".into(),
                reason: "an emergency stop is active".into(),
            });
        }
        st.status.robot_mode = crate::RobotMode::Running;
        Ok(())
    }

    async fn stop(&self) -> Result<(), HalError> {
        Ok(())
    }

    async fn set_tcp(&self, flange_from_tcp: &Isometry3<f64>) -> Result<(), HalError> {
        let hook = {
            let mut s = self.lock();
            s.tcp = *flange_from_tcp;
            s.tcp_history.push(*flange_from_tcp);
            s.after_set_tcp.clone()
        };
        if let Some(Hook(action)) = hook {
            action();
        }
        Ok(())
    }

    async fn write_double_register(&self, index: u32, value: f64) -> Result<(), HalError> {
        self.lock().registers.insert(index, value);
        Ok(())
    }

    async fn read_double_register(&self, index: u32) -> Result<f64, HalError> {
        Ok(self.lock().registers.get(&index).copied().unwrap_or(0.0))
    }

    async fn write_int_register(&self, index: u32, value: i32) -> Result<(), HalError> {
        let mut s = self.lock();
        if s.fail_register_writes {
            return Err(register_timeout(format!(
                "input_int_register_{index} write"
            )));
        }
        s.int_registers.insert(index, value);
        Ok(())
    }

    async fn read_int_register(&self, index: u32) -> Result<i32, HalError> {
        Ok(self.lock().int_registers.get(&index).copied().unwrap_or(0))
    }

    async fn read_output_int_register(&self, index: u32) -> Result<i32, HalError> {
        let s = self.lock();
        if s.fail_register_reads {
            return Err(register_timeout(format!(
                "output_int_register_{index} read"
            )));
        }
        Ok(s.output_int_registers.get(&index).copied().unwrap_or(0))
    }

    async fn tcp_offset(&self) -> Result<Isometry3<f64>, HalError> {
        Ok(self.lock().tcp)
    }

    async fn kinematics(&self) -> Result<Option<ControllerKinematics>, HalError> {
        Ok(self.kinematics)
    }

    async fn identity(&self) -> Result<ControllerIdentity, HalError> {
        Ok(ControllerIdentity {
            serial: self.serial.clone(),
            model: Some(self.model.controller_name()),
            software_version: self.software_version.clone(),
            kinematics_checksum: self.kinematics.map(|k| k.checksum),
        })
    }
}

#[derive(Debug, Default)]
struct CameraState {
    /// Index of the next cloud to replay (before wrapping).
    next: usize,
    /// Successful `capture` calls so far.
    captures: usize,
    /// After this many successful captures every call times out.
    answer_limit: Option<usize>,
}

/// A camera that replays the given clouds in a loop. Clones share the replay position.
#[derive(Debug, Clone)]
pub struct FakeCamera {
    clouds: Arc<Vec<PointCloud>>,
    state: Arc<Mutex<CameraState>>,
}

impl FakeCamera {
    /// Replays `clouds` in order, wrapping around. Fails to capture if `clouds` is empty.
    pub fn new(clouds: Vec<PointCloud>) -> Self {
        Self {
            clouds: Arc::new(clouds),
            state: Arc::new(Mutex::new(CameraState::default())),
        }
    }

    /// A camera that stops answering: after `captures` more successful `capture` calls in total
    /// (counted from the first call, not from now), every further call fails at once with
    /// `HalError::Timeout { what: "capture", timeout: settings.frame_timeout }` and replays
    /// nothing. `0` makes the very next call fail.
    pub fn stop_answering_after(&self, captures: usize) {
        self.lock().answer_limit = Some(captures);
    }

    /// Successful `capture` calls so far.
    pub fn captures(&self) -> usize {
        self.lock().captures
    }

    fn lock(&self) -> MutexGuard<'_, CameraState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl DepthCamera for FakeCamera {
    async fn info(&self) -> Result<CameraInfo, HalError> {
        let first = self.clouds.first();
        Ok(CameraInfo {
            vendor: "handeye".into(),
            model: "FakeCamera".into(),
            serial: "0".into(),
            firmware: env!("CARGO_PKG_VERSION").into(),
            width: first.map_or(0, |c| c.width),
            height: first.map_or(0, |c| c.height),
            pixel_formats: vec!["Coord3D_ABC32f".into()],
        })
    }

    async fn capture(&self, settings: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
        if self.clouds.is_empty() {
            return Err(HalError::InvalidArgument(
                "FakeCamera has no clouds to replay".into(),
            ));
        }
        let mut s = self.lock();
        if s.answer_limit.is_some_and(|limit| s.captures >= limit) {
            return Err(HalError::Timeout {
                what: "capture".into(),
                timeout: settings.frame_timeout,
            });
        }
        s.captures += 1;
        let out = (0..settings.frames)
            .map(|_| {
                let c = self.clouds[s.next % self.clouds.len()].clone();
                s.next += 1;
                c
            })
            .collect();
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use std::future::Future;
    use std::task::{Context, Poll, Waker};
    use std::time::Duration;

    use nalgebra::{Point3, Translation3};

    use super::*;

    /// The fakes never wait, so their futures are ready on the first poll.
    fn ready<T>(f: impl Future<Output = T>) -> T {
        let mut f = std::pin::pin!(f);
        match f.as_mut().poll(&mut Context::from_waker(Waker::noop())) {
            Poll::Ready(v) => v,
            Poll::Pending => panic!("fake futures never wait"),
        }
    }

    const Q: [f64; 6] = [0.1, -1.2, 1.3, -1.6, -1.5, 0.2];

    #[test]
    fn nominal_by_default_and_with_kinematics_reports_the_calibrated_arm() {
        let plain = FakeRobot::new(UrModel::Ur5e, Q);
        assert_eq!(ready(plain.kinematics()).expect("ok"), None);
        let nominal = UrModel::Ur5e.dh().forward(&Q);
        let flange = ready(plain.flange_pose()).expect("pose");
        assert!((flange.translation.vector - nominal.translation.vector).norm() < 1e-12);

        let k = ControllerKinematics {
            dh: crate::ur_dh::PhysicalArm::factory(UrModel::Ur5e, 7).controller_dh(),
            checksum: [1, 2, 3, 4, 5, 6],
            calibrated: true,
        };
        let robot = FakeRobot::new(UrModel::Ur5e, Q).with_kinematics(k);
        assert_eq!(ready(robot.kinematics()).expect("ok"), Some(k));
        let flange = ready(robot.flange_pose()).expect("pose");
        let truth = k.dh.forward(&Q);
        assert!((flange.translation.vector - truth.translation.vector).norm() < 1e-12);
        assert!(flange.rotation.angle_to(&truth.rotation) < 1e-12);
        assert!((flange.translation.vector - nominal.translation.vector).norm() > 1e-5);
        // A move changes the pose the calibrated arm reports.
        let q2 = [0.3, -1.0, 1.0, -1.5, -1.5, 0.0];
        ready(robot.move_joints(&q2, MotionLimits::default())).expect("move");
        let moved = ready(robot.flange_pose()).expect("pose");
        assert!((moved.translation.vector - k.dh.forward(&q2).translation.vector).norm() < 1e-12);
    }

    #[test]
    fn registers_tcp_and_speed_fraction() {
        let robot = FakeRobot::new(UrModel::Ur5e, Q);
        assert_eq!(ready(robot.read_int_register(24)).expect("read"), 0);
        ready(robot.write_int_register(24, -7)).expect("write");
        assert_eq!(ready(robot.read_int_register(24)).expect("read"), -7);
        ready(robot.write_double_register(24, 0.5)).expect("write");
        assert_eq!(ready(robot.read_int_register(24)).expect("read"), -7);
        assert_eq!(ready(robot.read_double_register(24)).expect("read"), 0.5);
        assert_eq!(ready(robot.status()).expect("status").speed_fraction, 1.0);
        assert_eq!(
            ready(robot.tcp_offset()).expect("tcp"),
            Isometry3::identity()
        );
        let tcp = Isometry3::from_parts(Translation3::new(0.0, 0.01, 0.12), Default::default());
        ready(robot.set_tcp(&tcp)).expect("set");
        assert_eq!(ready(robot.tcp_offset()).expect("tcp"), tcp);
        assert_eq!(robot.tcp(), tcp);
    }

    #[test]
    fn camera_stops_answering_after_n_captures() {
        let clouds = (0..3)
            .map(|i| PointCloud::from_points(vec![Point3::new(i as f32, 0.0, 1.0)]))
            .collect::<Vec<_>>();
        let cam = FakeCamera::new(clouds.clone());
        cam.stop_answering_after(2);
        let settings = CaptureSettings {
            frames: 2,
            frame_timeout: Duration::from_millis(250),
            exposure: None,
        };
        let first = ready(cam.capture(&settings)).expect("1st");
        assert_eq!(first, vec![clouds[0].clone(), clouds[1].clone()]);
        let second = ready(cam.clone().capture(&settings)).expect("2nd (clones share)");
        assert_eq!(second, vec![clouds[2].clone(), clouds[0].clone()]);
        for _ in 0..3 {
            match ready(cam.capture(&settings)) {
                Err(HalError::Timeout { what, timeout }) => {
                    assert_eq!(what, "capture");
                    assert_eq!(timeout, Duration::from_millis(250));
                }
                other => panic!("expected a timeout, got {other:?}"),
            }
        }
        assert_eq!(cam.captures(), 2);
        let silent = FakeCamera::new(clouds);
        silent.stop_answering_after(0);
        assert!(matches!(
            ready(silent.capture(&settings)),
            Err(HalError::Timeout { .. })
        ));
    }
}
