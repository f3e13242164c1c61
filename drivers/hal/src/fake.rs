//! Trait-level fakes for tests of code that only needs a [`Robot`] or a [`DepthCamera`]
//! (feature `fake`). Protocol-level simulators live in the drivers; these exist for logic
//! that no protocol can exercise cheaply (e.g. "protective stop on the third move").

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};

use nalgebra::Isometry3;

use crate::ur_dh::UrModel;
use crate::{
    CameraInfo, CaptureSettings, DepthCamera, HalError, MotionLimits, PointCloud, Robot, RobotMode,
    RobotStatus, SafetyMode,
};

#[derive(Debug)]
struct RobotState {
    status: RobotStatus,
    q: Vec<f64>,
    tcp: Isometry3<f64>,
    moves: Vec<Vec<f64>>,
    protective_stop_at_move: Option<usize>,
    registers: HashMap<u32, f64>,
}

/// A UR arm that moves instantly, records every commanded move and can be told to
/// protective-stop on the N-th move (0-based). Kinematics: the model's nominal DH.
#[derive(Debug, Clone)]
pub struct FakeRobot {
    model: UrModel,
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
        };
        let state = RobotState {
            status,
            q: q.to_vec(),
            tcp: Isometry3::identity(),
            moves: Vec::new(),
            protective_stop_at_move: None,
            registers: HashMap::new(),
        };
        Self { model, state: Arc::new(Mutex::new(state)) }
    }

    fn lock(&self) -> MutexGuard<'_, RobotState> {
        // A panic in another test thread must not hide this fake's state.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Make the move with this 0-based index end in a protective stop (arm stays where it was).
    pub fn protective_stop_at_move(&self, index: usize) {
        self.lock().protective_stop_at_move = Some(index);
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
        Ok(self.model.dh().forward(&q))
    }

    async fn move_joints(&self, q: &[f64], _limits: MotionLimits) -> Result<(), HalError> {
        let mut s = self.lock();
        if q.len() != 6 {
            return Err(HalError::InvalidArgument(format!("expected 6 joint angles, got {}", q.len())));
        }
        let index = s.moves.len();
        s.moves.push(q.to_vec());
        if !s.status.remote_control {
            return Err(HalError::NotInRemoteControl);
        }
        if !s.status.can_move() {
            return Err(HalError::NotReady { state: format!("{:?}/{:?}", s.status.robot_mode, s.status.safety_mode) });
        }
        if s.protective_stop_at_move == Some(index) {
            s.status.safety_mode = SafetyMode::ProtectiveStop;
            return Err(HalError::ProtectiveStop { during: format!("move {index}") });
        }
        s.q = q.to_vec();
        Ok(())
    }

    async fn stop(&self) -> Result<(), HalError> {
        Ok(())
    }

    async fn set_tcp(&self, flange_from_tcp: &Isometry3<f64>) -> Result<(), HalError> {
        self.lock().tcp = *flange_from_tcp;
        Ok(())
    }

    async fn write_double_register(&self, index: u32, value: f64) -> Result<(), HalError> {
        self.lock().registers.insert(index, value);
        Ok(())
    }

    async fn read_double_register(&self, index: u32) -> Result<f64, HalError> {
        Ok(self.lock().registers.get(&index).copied().unwrap_or(0.0))
    }
}

/// A camera that replays the given clouds in a loop.
#[derive(Debug, Clone)]
pub struct FakeCamera {
    clouds: Arc<Vec<PointCloud>>,
    next: Arc<Mutex<usize>>,
}

impl FakeCamera {
    /// Replays `clouds` in order, wrapping around. Fails to capture if `clouds` is empty.
    pub fn new(clouds: Vec<PointCloud>) -> Self {
        Self { clouds: Arc::new(clouds), next: Arc::new(Mutex::new(0)) }
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
            return Err(HalError::InvalidArgument("FakeCamera has no clouds to replay".into()));
        }
        let mut next = self.next.lock().unwrap_or_else(|e| e.into_inner());
        let out = (0..settings.frames)
            .map(|_| {
                let c = self.clouds[*next % self.clouds.len()].clone();
                *next += 1;
                c
            })
            .collect();
        Ok(out)
    }
}
