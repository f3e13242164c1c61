//! [`UrRobot`]: the [`handeye_hal::Robot`] implementation over RTDE + dashboard + primary.

use std::future::Future;
use std::net::{IpAddr, SocketAddr};
use std::ops::RangeInclusive;
use std::sync::Arc;
use std::time::{Duration, Instant};

use handeye_hal::ur_dh::UrModel;
use handeye_hal::ur_limits::{self, within_pose_bound, UrLimits};
use handeye_hal::{
    ControllerIdentity, ControllerKinematics, HalError, MotionLimits, Robot, RobotMode,
    RobotStatus, SafetyMode,
};
use nalgebra::Isometry3;
use tokio::sync::Mutex;

use super::checks::{
    check_can_move, check_kinematics, int_field, joints_field, pose_field, speed_fraction_field,
    speeds_field, MoveWatch, MAX_POSE_DISTANCE_M, MAX_TCP_OFFSET_M, RUNTIME_PLAYING,
};
use super::rtde_client::{RtdeClient, RtdeConfig, Sample};
use super::script::ScriptClient;
use crate::dashboard::{robot_mode_from_code, safety_mode_from_code, DashboardClient};
use crate::rtde::Value;
use crate::{Ports, UrError, UrPose};

/// How to reach and drive one controller.
#[derive(Debug, Clone)]
pub struct UrConfig {
    /// Controller address.
    pub host: IpAddr,
    /// Ports (standard unless testing against a simulator on ephemeral ports).
    pub ports: Ports,
    /// RTDE output frequency; `None` = 125 Hz CB3 / 500 Hz e-Series.
    pub rtde_frequency: Option<f64>,
    /// Hard cap on joint speed for every move, rad/s (the configured safety cap; default
    /// [`ur_limits::DRIVER_SPEED_CAP_RAD_S`]). The arm model's own limits cap it further.
    pub max_joint_speed_rad_s: f64,
    /// Hard cap on joint acceleration, rad/s² (default
    /// [`ur_limits::DRIVER_ACCEL_CAP_RAD_S2`]).
    pub max_joint_accel_rad_s2: f64,
    /// Double registers this client writes and reads (`input_double_register_N`, and
    /// `output_double_register_N` from a pendant program; upper range 24–47 by default: 0–23
    /// belong to fieldbus adapters). An empty range (e.g. `1..=0`) claims none, leaving
    /// them to other RTDE clients.
    pub registers: RangeInclusive<u32>,
    /// Int registers this client writes and reads (`input_int_register_N`,
    /// `output_int_register_N`); 24–31 by default. Narrower than the doubles because every
    /// register adds fields to the one RTDE output recipe, whose name list is limited to
    /// 2048 bytes; `connect` refuses a combination that does not fit.
    pub int_registers: RangeInclusive<u32>,
    /// Limit for each request/reply exchange.
    pub timeout: Duration,
    /// Longest pause between RTDE reconnection attempts.
    pub max_backoff: Duration,
}

impl UrConfig {
    /// Defaults for a controller at `host`.
    pub fn new(host: IpAddr) -> Self {
        Self {
            host,
            ports: Ports::STANDARD,
            rtde_frequency: None,
            max_joint_speed_rad_s: ur_limits::DRIVER_SPEED_CAP_RAD_S,
            max_joint_accel_rad_s2: ur_limits::DRIVER_ACCEL_CAP_RAD_S2,
            registers: 24..=47,
            int_registers: 24..=31,
            timeout: Duration::from_secs(3),
            max_backoff: Duration::from_secs(5),
        }
    }

    /// This configuration claiming no RTDE input register (double or int): for a client that
    /// only reads and moves, beside another (a running daemon, a fieldbus) that holds them.
    #[allow(clippy::reversed_empty_ranges)]
    pub fn without_registers(mut self) -> Self {
        self.registers = 1..=0;
        self.int_registers = 1..=0;
        self
    }
}

/// Joint-space arrival tolerance, rad.
const ARRIVED_RAD: f64 = 1e-3;
/// A sample older than this means the link is down.
const STALE: Duration = Duration::from_millis(1000);

const BASE_OUTPUTS: &[&str] = &[
    "timestamp",
    "actual_q",
    "actual_qd",
    "target_q",
    "actual_TCP_pose",
    "tcp_offset",
    "robot_mode",
    "safety_mode",
    "runtime_state",
    "robot_status_bits",
    "safety_status_bits",
    "target_speed_fraction",
];

#[derive(Debug)]
struct Inner {
    cfg: UrConfig,
    rtde: RtdeClient,
    dashboard: Mutex<Option<DashboardClient>>,
    script: ScriptClient,
    /// Read from the primary interface on connect; `Err` (what was wrong) when the
    /// controller published values no arm has, and then read again at the next ask (a
    /// transient fault does not refuse every later run).
    kinematics: Mutex<Result<Option<ControllerKinematics>, String>>,
    /// The limits of the arm the kinematics are a calibration of (the hal's UR limits
    /// table); without kinematics, the most conservative of every model's.
    limits: UrLimits,
}

/// The limits of the arm whose kinematics are `k`: its model's from the hal's table (the
/// nearest model whose nominal kinematics `k` calibrates), else, unknown, the slowest speed and
/// the lowest acceleration of every model.
fn arm_limits(k: Option<&ControllerKinematics>) -> UrLimits {
    if let Some((model, _)) = k.and_then(|k| UrModel::matching(&k.dh).into_iter().next()) {
        return model.limits();
    }
    UrModel::ALL
        .into_iter()
        .map(UrModel::limits)
        .reduce(|a, b| UrLimits {
            joint_speed_rad_s: std::array::from_fn(|i| {
                a.joint_speed_rad_s[i].min(b.joint_speed_rad_s[i])
            }),
            joint_accel_rad_s2: a.joint_accel_rad_s2.min(b.joint_accel_rad_s2),
            joint_position_rad: a.joint_position_rad.min(b.joint_position_rad),
        })
        .unwrap_or_else(|| UrModel::Ur5e.limits())
}

/// A Universal Robots controller (CB3 or e-Series). Cheap to clone; one RTDE connection.
#[derive(Debug, Clone)]
pub struct UrRobot {
    inner: Arc<Inner>,
}

impl UrRobot {
    /// Connect RTDE (output recipe + one input recipe per double register, then one per int
    /// register), check the dashboard and read the controller's kinematics from the primary
    /// interface (a controller that sends none within `cfg.timeout` is logged, not an error).
    pub async fn connect(cfg: UrConfig) -> Result<Self, UrError> {
        // An empty range claims no register of that kind: other RTDE clients keep them.
        for (what, r) in [("double", &cfg.registers), ("int", &cfg.int_registers)] {
            if !r.is_empty() && *r.end() > 47 {
                return Err(UrError::InvalidArgument(format!(
                    "{what} register range {r:?} must lie within 0..=47"
                )));
            }
        }
        if !(cfg.max_joint_speed_rad_s > 0.0 && cfg.max_joint_accel_rad_s2 > 0.0) {
            return Err(UrError::InvalidArgument(
                "speed and acceleration caps must be positive".into(),
            ));
        }
        let mut outputs: Vec<String> = BASE_OUTPUTS.iter().map(|s| s.to_string()).collect();
        for i in cfg.registers.clone() {
            outputs.push(format!("input_double_register_{i}"));
            outputs.push(format!("output_double_register_{i}"));
        }
        for i in cfg.int_registers.clone() {
            outputs.push(format!("input_int_register_{i}"));
            outputs.push(format!("output_int_register_{i}"));
        }
        let inputs = cfg
            .registers
            .clone()
            .map(|i| vec![format!("input_double_register_{i}")])
            .chain(
                cfg.int_registers
                    .clone()
                    .map(|i| vec![format!("input_int_register_{i}")]),
            )
            .collect();
        let rtde = RtdeClient::connect(RtdeConfig {
            addr: SocketAddr::new(cfg.host, cfg.ports.rtde),
            frequency: cfg.rtde_frequency,
            outputs,
            inputs,
            timeout: cfg.timeout,
            max_backoff: cfg.max_backoff,
        })
        .await?;
        let dash =
            DashboardClient::connect(SocketAddr::new(cfg.host, cfg.ports.dashboard), cfg.timeout)
                .await?;
        let script = ScriptClient::new(SocketAddr::new(cfg.host, cfg.ports.primary), cfg.timeout);
        let kinematics = read_kinematics(&script).await;
        let robot = Self {
            inner: Arc::new(Inner {
                cfg,
                rtde,
                dashboard: Mutex::new(Some(dash)),
                script,
                limits: arm_limits(kinematics.as_ref().ok().and_then(Option::as_ref)),
                kinematics: Mutex::new(kinematics),
            }),
        };
        robot.sample().await?;
        Ok(robot)
    }

    /// The RTDE client (samples, reconnect count).
    pub fn rtde(&self) -> &RtdeClient {
        &self.inner.rtde
    }

    /// Run one dashboard exchange, reconnecting once if the connection was lost.
    pub async fn dashboard<T, F>(&self, f: F) -> Result<T, UrError>
    where
        F: for<'a> Fn(
            &'a mut DashboardClient,
        )
            -> std::pin::Pin<Box<dyn Future<Output = Result<T, UrError>> + Send + 'a>>,
    {
        let mut guard = self.inner.dashboard.lock().await;
        for attempt in 0..2 {
            if guard.is_none() {
                let addr = SocketAddr::new(self.inner.cfg.host, self.inner.cfg.ports.dashboard);
                *guard = Some(DashboardClient::connect(addr, self.inner.cfg.timeout).await?);
            }
            let Some(d) = guard.as_mut() else { continue };
            match f(d).await {
                Err(UrError::Io { .. } | UrError::Timeout { .. }) if attempt == 0 => *guard = None,
                Err(
                    e @ (UrError::Io { .. } | UrError::Timeout { .. } | UrError::Malformed { .. }),
                ) => {
                    *guard = None;
                    return Err(e);
                }
                r => return r,
            }
        }
        Err(UrError::Timeout {
            what: "dashboard".into(),
            after: self.inner.cfg.timeout,
        })
    }

    /// The newest sample if it is fresh (else the next one); a sample of a faulty stream
    /// (the controller's timestamp stands still or went back) is an error.
    async fn sample(&self) -> Result<Arc<Sample>, UrError> {
        if let Some(s) = self.inner.rtde.latest() {
            if s.received.elapsed() < STALE {
                return s.trusted();
            }
        }
        self.inner
            .rtde
            .next_sample(Instant::now() - STALE, STALE.max(self.inner.cfg.timeout))
            .await
    }

    /// Waits for a sample whose controller `timestamp` is later than the newest one's now
    /// (one package period): the stream is live before anything moves. A frozen stream ends
    /// the wait with [`UrError::Stream`] once its timestamp has stood still for
    /// [`super::MAX_FROZEN_TIMESTAMP`]; a recipe without `timestamp` does not wait.
    async fn advancing(&self) -> Result<Arc<Sample>, UrError> {
        let first = self.sample().await?;
        let Some(t0) = first.f64("timestamp") else {
            return Ok(first);
        };
        let mut last = first.received;
        loop {
            let s = self
                .inner
                .rtde
                .next_sample(last, STALE.max(self.inner.cfg.timeout))
                .await?;
            if s.f64("timestamp").is_some_and(|t| t > t0) {
                return Ok(s);
            }
            last = s.received;
        }
    }

    /// Waits until RTDE reports `mode` (or RUNNING, which comes after every other mode on the
    /// way up), at most [`POWER_TIMEOUT`].
    async fn wait_for_mode(&self, mode: RobotMode, what: &str) -> Result<(), HalError> {
        let started = Instant::now();
        loop {
            let s = self.sample().await?;
            let code = s.f64("robot_mode").unwrap_or(-128.0) as i32;
            let now = robot_mode_from_code(code);
            if now == Some(mode) || now == Some(RobotMode::Running) {
                return Ok(());
            }
            if started.elapsed() > POWER_TIMEOUT {
                return Err(HalError::Timeout {
                    what: format!("{what} (the robot mode is {now:?})"),
                    timeout: POWER_TIMEOUT,
                });
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    async fn remote_control(&self) -> Result<bool, UrError> {
        self.dashboard(|d| Box::pin(d.is_in_remote_control())).await
    }

    /// Send a `def` program and wait for the controller to report it started.
    pub async fn run_program(&self, name: &str, body: &str) -> Result<(), UrError> {
        let text = format!("def {name}():\n{body}end\n");
        self.inner
            .script
            .send(&text, Some(name), Duration::ZERO)
            .await
            .map(|_| ())
    }

    /// Send a `sec` program (runs alongside a pendant program, no physical time).
    pub async fn run_secondary(&self, name: &str, body: &str) -> Result<(), UrError> {
        let text = format!("sec {name}():\n{body}end\n");
        self.inner
            .script
            .send(&text, None, Duration::from_millis(100))
            .await
            .map(|_| ())
    }

    /// Joint move; returns when arrived or fails (stopping the arm). `cancel` completing aborts
    /// the move with `Cancelled`.
    pub async fn move_joints_until(
        &self,
        q: &[f64],
        limits: MotionLimits,
        cancel: impl Future<Output = ()>,
    ) -> Result<(), HalError> {
        let q: [f64; 6] = q.try_into().map_err(|_| {
            HalError::InvalidArgument(format!("expected 6 joint angles, got {}", q.len()))
        })?;
        let arm = self.inner.limits;
        if !arm.within_reach(&q) {
            return Err(HalError::InvalidArgument(format!(
                "joint target {q:?} is outside ±{:.4} rad",
                arm.joint_position_rad
            )));
        }
        if !(limits.max_joint_speed_rad_s > 0.0 && limits.max_joint_accel_rad_s2 > 0.0) {
            return Err(HalError::InvalidArgument(
                "speed and acceleration must be positive".into(),
            ));
        }
        // The second layer under the motion guard: the driver's own caps and the arm's limits,
        // from the same table.
        let capped = arm.cap(MotionLimits {
            max_joint_speed_rad_s: limits
                .max_joint_speed_rad_s
                .min(self.inner.cfg.max_joint_speed_rad_s),
            max_joint_accel_rad_s2: limits
                .max_joint_accel_rad_s2
                .min(self.inner.cfg.max_joint_accel_rad_s2),
            timeout: limits.timeout,
        });
        let (v, a) = (capped.max_joint_speed_rad_s, capped.max_joint_accel_rad_s2);
        let during = "joint move";
        let list: Vec<String> = q.iter().map(|x| format!("{x:.9}")).collect();
        let body = format!("  movej([{}], a={a:.6}, v={v:.6})\n", list.join(","));
        let ready = async {
            let st = self.status().await?;
            check_can_move(&st, during)?;
            // The data the move is followed by must be live, not a replay that has not yet
            // stood still for the bound.
            self.advancing().await?;
            Ok::<_, HalError>(MoveWatch::new(&st, during))
        };
        // Corrupt data before the program went out: say that the arm was not moved.
        let watch = ready.await.map_err(HalError::before_move)?;
        let mut guard = StopGuard {
            robot: Some(self.clone()),
        };
        let started = Instant::now();
        self.run_program("handeye_move", &body).await?;
        let deadline = started + limits.timeout;
        let work = async {
            let mut seen_playing = false;
            let mut last = Instant::now();
            loop {
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    return Err(HalError::Timeout {
                        what: during.into(),
                        timeout: limits.timeout,
                    });
                }
                let s = self
                    .inner
                    .rtde
                    .next_sample(last, left.min(STALE))
                    .await
                    .map_err(|e| match e {
                        UrError::Timeout { .. } if Instant::now() >= deadline => {
                            HalError::Timeout {
                                what: during.into(),
                                timeout: limits.timeout,
                            }
                        }
                        other => other.into(),
                    })?;
                last = s.received;
                // Safety mode, runtime state and speed slider, on every sample.
                let playing = watch.check(&s)?;
                let aq = joints_field(&s)?;
                let qd = speeds_field(&s)?;
                seen_playing |= playing;
                let arrived = aq.iter().zip(&q).all(|(x, y)| (x - y).abs() < ARRIVED_RAD)
                    && qd.iter().all(|v| v.abs() < 1e-3);
                if arrived && !playing {
                    return Ok(());
                }
                if !playing
                    && (seen_playing || started.elapsed() > Duration::from_millis(500))
                    && !arrived
                {
                    if !self.remote_control().await? {
                        return Err(HalError::NotInRemoteControl);
                    }
                    return Err(HalError::Refused {
                        device: "UR controller".into(),
                        request: during.into(),
                        reason: "the move program stopped before the arm arrived".into(),
                    });
                }
            }
        };
        let result = tokio::select! {
            r = work => r,
            _ = cancel => Err(HalError::Cancelled { what: during.into() }),
        };
        match &result {
            Ok(()) => guard.disarm(),
            Err(
                HalError::ProtectiveStop { .. }
                | HalError::EmergencyStop { .. }
                | HalError::NotInRemoteControl,
            ) => guard.disarm(),
            Err(_) => {
                guard.disarm();
                let _ = self.stop().await;
            }
        }
        result
    }

    /// Read `output_double_register_N` (what a pendant program wrote).
    pub async fn read_output_double_register(&self, index: u32) -> Result<f64, HalError> {
        self.register("output_double_register_", index).await
    }

    fn check_register(&self, index: u32) -> Result<(), HalError> {
        if self.inner.cfg.registers.contains(&index) {
            Ok(())
        } else {
            Err(HalError::InvalidArgument(format!(
                "double register {index} is outside the configured range {:?}",
                self.inner.cfg.registers
            )))
        }
    }

    fn check_int_register(&self, index: u32) -> Result<(), HalError> {
        if self.inner.cfg.int_registers.contains(&index) {
            Ok(())
        } else {
            Err(HalError::InvalidArgument(format!(
                "int register {index} is outside the configured range {:?}",
                self.inner.cfg.int_registers
            )))
        }
    }

    async fn register(&self, prefix: &str, index: u32) -> Result<f64, HalError> {
        self.check_register(index)?;
        let s = self.sample().await?;
        s.f64(&format!("{prefix}{index}"))
            .ok_or_else(|| HalError::InvalidArgument(format!("{prefix}{index} not in the recipe")))
    }

    async fn int_register(&self, prefix: &str, index: u32) -> Result<i32, HalError> {
        self.check_int_register(index)?;
        let s = self.sample().await?;
        int_field(&s, &format!("{prefix}{index}"))
    }

    /// Write one input register through its input recipe and wait until the controller
    /// reflects `value` in the output stream (within `cfg.timeout`).
    async fn write_confirmed(
        &self,
        recipe: usize,
        name: String,
        value: Value,
        same: impl Fn(&Sample) -> Option<(bool, String)>,
    ) -> Result<(), HalError> {
        let t0 = Instant::now();
        let wrote = match value {
            Value::Double(v) => v.to_string(),
            Value::Int32(v) => v.to_string(),
            other => format!("{other:?}"),
        };
        self.inner.rtde.write(recipe, vec![value]).await?;
        self.read_back(t0, name, wrote, same).await
    }

    /// Waits until an RTDE sample received after `since` satisfies `same` (which returns
    /// whether the sample shows what was written, and what it shows, or `None` when it does
    /// not carry the field); fails with `ReadBackMismatch` after `cfg.timeout`.
    async fn read_back(
        &self,
        since: Instant,
        what: String,
        wrote: String,
        same: impl Fn(&Sample) -> Option<(bool, String)>,
    ) -> Result<(), HalError> {
        let deadline = since + self.inner.cfg.timeout;
        let mut last = since;
        let mut read = String::from("nothing");
        while Instant::now() < deadline {
            let s = self
                .inner
                .rtde
                .next_sample(last, self.inner.cfg.timeout)
                .await?;
            last = s.received;
            if let Some((ok, r)) = same(&s) {
                if ok {
                    return Ok(());
                }
                read = r;
            }
        }
        Err(HalError::ReadBackMismatch { what, wrote, read })
    }

    /// The active TCP offset (`flange_from_tcp`) as the controller reports it.
    pub async fn tcp_offset(&self) -> Result<Isometry3<f64>, HalError> {
        let s = self.sample().await?;
        Ok(pose_field(&s, "tcp_offset", MAX_TCP_OFFSET_M)?.into())
    }

    /// `actual_TCP_pose` (`base_from_tcp`).
    pub async fn tcp_pose(&self) -> Result<Isometry3<f64>, HalError> {
        let s = self.sample().await?;
        Ok(pose_field(&s, "actual_TCP_pose", MAX_POSE_DISTANCE_M)?.into())
    }
}

/// The controller's kinematics from the primary interface; `Ok(None)` (with a warning) when it
/// sends none in time or cannot be reached; `Err` (what is wrong) when it sends values no arm
/// has ([`check_kinematics`]): every run on this connection is refused, as no pose the
/// controller reports can be trusted.
async fn read_kinematics(script: &ScriptClient) -> Result<Option<ControllerKinematics>, String> {
    match script.kinematics().await {
        Ok(Some(k)) => {
            if let Err(why) = check_kinematics(&k) {
                let why = format!(
                    "{why}; the controller or something between it and this PC sends corrupt \
                     data: check the controller's log and the network before calibrating"
                );
                tracing::warn!("{why}");
                return Err(why);
            }
            let k = k.to_controller_kinematics();
            if !k.calibrated {
                tracing::warn!(
                    "the controller says its arm is not factory calibrated (calibration_status)"
                );
            }
            tracing::debug!(dh = ?k.dh, "controller kinematics");
            Ok(Some(k))
        }
        Ok(None) => {
            tracing::warn!(
                "the controller sent no kinematics info on the primary interface; \
                 its calibrated DH parameters are unknown"
            );
            Ok(None)
        }
        Err(e) => {
            tracing::warn!("could not read the controller's kinematics: {e}");
            Ok(None)
        }
    }
}

/// Stops the arm if a move future is dropped (cancelled) before it finished.
struct StopGuard {
    robot: Option<UrRobot>,
}

impl StopGuard {
    fn disarm(&mut self) {
        self.robot = None;
    }
}

impl Drop for StopGuard {
    fn drop(&mut self) {
        if let Some(r) = self.robot.take() {
            if let Ok(h) = tokio::runtime::Handle::try_current() {
                h.spawn(async move {
                    if let Err(e) = r.stop().await {
                        tracing::error!("could not stop the arm after a cancelled move: {e}");
                    }
                });
            }
        }
    }
}

/// Longest a stop may take to bring the arm to a stand (from π rad/s at 2 rad/s²: 1.6 s).
const STOP_TIMEOUT: Duration = Duration::from_secs(10);

/// Longest a power-on or a brake release may take (a real arm: a few seconds each).
const POWER_TIMEOUT: Duration = Duration::from_secs(30);

impl Robot for UrRobot {
    async fn status(&self) -> Result<RobotStatus, HalError> {
        let s = self.sample().await?;
        let code = s.f64("robot_mode").unwrap_or(-128.0) as i32;
        let robot_mode = robot_mode_from_code(code).ok_or_else(|| HalError::Protocol {
            peer: "RTDE".into(),
            detail: format!("unknown robot_mode {code}"),
        })?;
        let safety_mode = safety_mode_from_code(s.f64("safety_mode").unwrap_or(0.0) as i32);
        let remote_control = self.remote_control().await?;
        Ok(RobotStatus {
            robot_mode,
            safety_mode,
            remote_control,
            program_running: s.f64("runtime_state") == Some(RUNTIME_PLAYING),
            speed_fraction: speed_fraction_field(&s)?,
        })
    }

    /// `actual_q`, from a sample whose joint speeds are real too (a sample with corrupt
    /// speeds is corrupt as a whole).
    async fn joint_positions(&self) -> Result<Vec<f64>, HalError> {
        let s = self.sample().await?;
        speeds_field(&s)?;
        Ok(joints_field(&s)?.to_vec())
    }

    async fn flange_pose(&self) -> Result<Isometry3<f64>, HalError> {
        // Both from the same sample: the TCP pose is the flange's through this offset.
        let s = self.sample().await?;
        let tcp = pose_field(&s, "actual_TCP_pose", MAX_POSE_DISTANCE_M)?;
        let off = pose_field(&s, "tcp_offset", MAX_TCP_OFFSET_M)?;
        Ok(Isometry3::from(tcp) * Isometry3::from(off).inverse())
    }

    async fn move_joints(&self, q: &[f64], limits: MotionLimits) -> Result<(), HalError> {
        self.move_joints_until(q, limits, std::future::pending())
            .await
    }

    async fn power_on(&self) -> Result<(), HalError> {
        let st = self.status().await?;
        if matches!(
            st.safety_mode,
            SafetyMode::RobotEmergencyStop | SafetyMode::SystemEmergencyStop
        ) {
            return Err(HalError::Refused {
                device: "UR controller".into(),
                request: "power on".into(),
                reason: "an emergency stop is active; release it on the pendant".into(),
            });
        }
        if st.robot_mode == RobotMode::Running {
            return Ok(());
        }
        if matches!(st.robot_mode, RobotMode::PowerOff) {
            self.dashboard(|d| Box::pin(d.power_on())).await?;
            self.wait_for_mode(RobotMode::Idle, "power on").await?;
        }
        self.dashboard(|d| Box::pin(d.brake_release())).await?;
        self.wait_for_mode(RobotMode::Running, "brake release")
            .await
    }

    /// Sends `stopj` and returns once the arm stands and the stop program has ended (within
    /// `STOP_TIMEOUT`): whatever comes next (the next run's preflight) must not find our own
    /// stop still playing.
    async fn stop(&self) -> Result<(), HalError> {
        let a = self.inner.cfg.max_joint_accel_rad_s2.max(2.0);
        let sent = Instant::now();
        self.run_program("handeye_stop", &format!("  stopj({a:.3})\n"))
            .await?;
        let deadline = sent + STOP_TIMEOUT;
        // Samples from after the controller reported the stop program started.
        let mut last = Instant::now();
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(HalError::Timeout {
                    what: "stopping the arm (stopj)".into(),
                    timeout: STOP_TIMEOUT,
                });
            }
            let s = self.inner.rtde.next_sample(last, left.min(STALE)).await?;
            last = s.received;
            let standing = speeds_field(&s)?.iter().all(|v| v.abs() < 1e-3);
            if standing && s.f64("runtime_state") != Some(RUNTIME_PLAYING) {
                return Ok(());
            }
        }
    }

    async fn set_tcp(&self, flange_from_tcp: &Isometry3<f64>) -> Result<(), HalError> {
        let p = UrPose::from(flange_from_tcp);
        // The TCP this driver would refuse on read is never sent.
        within_pose_bound(&p.0, MAX_TCP_OFFSET_M).map_err(|why| {
            HalError::InvalidArgument(format!(
                "TCP p{:?} (flange → TCP), {why}: the controller would hold no real tool; \
                 nothing was sent (check the calibration or the pose given)",
                p.0
            ))
        })?;
        let body = format!("  set_tcp({})\n", p.to_script());
        let started = Instant::now();
        let readback = self.read_back(started, "TCP offset".into(), format!("{:?}", p.0), |s| {
            s.vec6("tcp_offset").map(|t| {
                let read = UrPose(t);
                (read.approx_eq(&p, 1e-6, 1e-6), format!("{:?}", read.0))
            })
        });
        let send = self.run_secondary("handeye_set_tcp", &body);
        tokio::pin!(readback, send);
        // The read-back is the confirmation: once the controller reports the new TCP the
        // program ran, and waiting out the script's error window is not needed. When the TCP
        // already had that value, only the script's own outcome can tell.
        let unchanged = self
            .tcp_offset()
            .await
            .is_ok_and(|t| UrPose::from(&t).approx_eq(&p, 1e-6, 1e-6));
        if unchanged {
            send.await?;
            return readback.await;
        }
        tokio::select! {
            biased;
            r = &mut send => {
                r?;
                readback.await
            }
            r = &mut readback => r,
        }
    }

    async fn write_double_register(&self, index: u32, value: f64) -> Result<(), HalError> {
        self.check_register(index)?;
        let recipe = (index - self.inner.cfg.registers.start()) as usize;
        let name = format!("input_double_register_{index}");
        let field = name.clone();
        self.write_confirmed(recipe, name, Value::Double(value), move |s| {
            let read = s.f64(&field)?;
            let same = read == value || (read.is_nan() && value.is_nan());
            Some((same, read.to_string()))
        })
        .await
    }

    async fn read_double_register(&self, index: u32) -> Result<f64, HalError> {
        self.register("input_double_register_", index).await
    }

    async fn write_int_register(&self, index: u32, value: i32) -> Result<(), HalError> {
        self.check_int_register(index)?;
        // Int recipes follow the double ones, one per register.
        let recipe = self.inner.cfg.registers.clone().count()
            + (index - self.inner.cfg.int_registers.start()) as usize;
        let name = format!("input_int_register_{index}");
        let field = name.clone();
        self.write_confirmed(recipe, name, Value::Int32(value), move |s| {
            let read = int_field(s, &field).ok()?;
            Some((read == value, read.to_string()))
        })
        .await
    }

    async fn read_int_register(&self, index: u32) -> Result<i32, HalError> {
        self.int_register("input_int_register_", index).await
    }

    async fn read_output_int_register(&self, index: u32) -> Result<i32, HalError> {
        self.int_register("output_int_register_", index).await
    }

    async fn tcp_offset(&self) -> Result<Isometry3<f64>, HalError> {
        UrRobot::tcp_offset(self).await
    }

    /// The kinematics read on connect; a `Protocol` error naming the value when the
    /// controller published kinematics no arm has (read again at each ask until they are
    /// sound; the driver's speed limits stay the conservative ones of an unknown arm).
    async fn kinematics(&self) -> Result<Option<ControllerKinematics>, HalError> {
        let mut cached = self.inner.kinematics.lock().await;
        if cached.is_err() {
            *cached = read_kinematics(&self.inner.script).await;
        }
        cached.clone().map_err(|detail| HalError::Protocol {
            peer: "primary interface".into(),
            detail,
        })
    }

    /// Dashboard `get serial number`, `get robot model` and `PolyScope version`; the
    /// kinematics checksums from the KinematicsInfo read on connect.
    async fn identity(&self) -> Result<ControllerIdentity, HalError> {
        let serial = self.dashboard(|d| Box::pin(d.serial_number())).await?;
        let model = self.dashboard(|d| Box::pin(d.robot_model())).await?;
        let v = self.dashboard(|d| Box::pin(d.polyscope_version())).await?;
        Ok(ControllerIdentity {
            serial,
            model,
            software_version: Some(format!("{}.{}.{}.{}", v[0], v[1], v[2], v[3])),
            kinematics_checksum: self
                .inner
                .kinematics
                .lock()
                .await
                .as_ref()
                .ok()
                .and_then(|k| k.map(|k| k.checksum)),
        })
    }

    /// The RTDE reconnections: each is a new session (recipes set up again), possibly with a
    /// restarted controller.
    fn link_generation(&self) -> u64 {
        self.inner.rtde.reconnects()
    }
}

#[cfg(test)]
mod tests {
    use std::f64::consts::{PI, TAU};

    use super::*;

    #[test]
    fn the_driver_caps_at_the_limits_of_the_arm_its_kinematics_say() {
        let k = |model: UrModel| ControllerKinematics {
            dh: model.dh(),
            checksum: [0; 6],
            calibrated: true,
        };
        assert_eq!(
            arm_limits(Some(&k(UrModel::Ur10e))),
            UrModel::Ur10e.limits()
        );
        assert_eq!(arm_limits(Some(&k(UrModel::Ur3e))), UrModel::Ur3e.limits());
        // Unknown: every joint as slow as the slowest model's.
        let unknown = arm_limits(None);
        assert_eq!(
            unknown.joint_speed_rad_s,
            [TAU / 3.0, TAU / 3.0, PI, PI, PI, PI]
        );
        assert_eq!(
            unknown.joint_accel_rad_s2,
            ur_limits::MAX_JOINT_ACCEL_RAD_S2
        );
    }
}
