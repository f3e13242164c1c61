//! UR controller simulator: dashboard (29999), primary/secondary (30001/30002), real-time
//! (30003) and RTDE (30004) servers over one simulated arm, with fault injection.
//!
//! Start it with [`Simulator::start`]; the returned [`SimHandle`] injects faults and inspects
//! state, and stops every server when dropped or on [`SimHandle::shutdown`]. Memory is bounded:
//! no queue or log grows with run time (robot messages go through a fixed-size broadcast ring,
//! per-connection buffers are capped).

mod control;
mod dashboard;
pub mod fault_proxy;
mod motion;
mod program;
mod realtime;
mod rtde_control;
mod rtde_server;
mod script;
mod state;
mod urscript;

use std::collections::HashSet;
use std::f64::consts::FRAC_PI_2;
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use handeye_hal::ur_dh::{DhParams, PhysicalArm, UrModel};
use handeye_hal::ControllerKinematics;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{broadcast, watch};

use crate::{Ports, UrError};
pub(crate) use state::State;
pub use state::{RobotModeCode, SafetyModeCode};

/// How to start a simulator.
#[derive(Debug, Clone)]
pub struct SimConfig {
    /// Arm model (kinematics from [`UrModel::dh`], CB3 vs e-Series behaviour).
    pub model: UrModel,
    /// Address to bind every port on (loopback in tests: `127.0.0.x`).
    pub bind: IpAddr,
    /// Ports; [`Ports::STANDARD`] for real clients, or 0s for ephemeral ports in parallel tests.
    pub ports: Ports,
    /// The physical arm (its joints' small errors, as a real arm is built); `None` = exactly
    /// nominal. The controller computes the arm's exact standard DH
    /// ([`PhysicalArm::controller_dh`]: with a real arm's nearly parallel joints 2–4, `d` of
    /// hundreds of metres), publishes it in the primary KinematicsInfo and uses it for every
    /// pose, forward and inverse kinematics.
    pub arm: Option<PhysicalArm>,
    /// Start powered with brakes released (RUNNING) instead of POWER_OFF.
    pub start_running: bool,
    /// Start in remote control (e-Series); CB3 is always remote.
    pub remote_control: bool,
    /// Input fields held by a fieldbus adapter (answer `IN_USE`).
    pub fieldbus_held: Vec<String>,
    /// Protective stop when the next move reaches this fraction of its path (0..1).
    pub protective_stop_during_move: Option<f64>,
    /// Delay before each request's reply (dashboard commands, RTDE setup packages); streaming
    /// is not delayed.
    pub latency: Duration,
    /// Close every client connection at this interval.
    pub drop_connections_every: Option<Duration>,
    /// How long after a protective stop `unlock protective stop` is refused (real: 5 s).
    pub unlock_delay: Duration,
    /// Whether the RTDE server accepts protocol version 2 (false: an old controller, v1 only).
    pub rtde_v2: bool,
    /// Initial joint angles, rad.
    pub initial_q: [f64; 6],
    /// The arm's serial number (dashboard `get serial number`); [`SimConfig::new`] and
    /// [`SimConfig::factory_calibrated`] give one of [`serial_number`]'s.
    pub serial: String,
}

/// A serial number in a real controller's shape (11 digits: year of manufacture, a two-digit
/// model code, a five-digit sequence number, e.g. `20205500001` for a UR5e) for the
/// simulated arm `model` with sequence `seed % 99999 + 1`. The model codes are the
/// simulator's own, not UR's.
pub fn serial_number(model: UrModel, seed: u64) -> String {
    let year = if model.is_cb3() { 2016 } else { 2020 };
    let code = match model {
        UrModel::Ur3 => 30,
        UrModel::Ur5 => 50,
        UrModel::Ur10 => 60,
        UrModel::Ur3e => 35,
        UrModel::Ur5e => 55,
        UrModel::Ur7e => 75,
        UrModel::Ur10e => 65,
        UrModel::Ur12e => 12,
        UrModel::Ur16e => 16,
        UrModel::Ur15 => 15,
        UrModel::Ur20 => 20,
        UrModel::Ur30 => 31,
    };
    format!("{year}{code:02}{:05}", seed % 99_999 + 1)
}

impl SimConfig {
    /// Defaults for `model` on `bind` with the standard ports: powered off, remote control on.
    pub fn new(model: UrModel, bind: IpAddr) -> Self {
        Self {
            model,
            bind,
            ports: Ports::STANDARD,
            arm: None,
            start_running: false,
            remote_control: true,
            fieldbus_held: Vec::new(),
            protective_stop_during_move: None,
            latency: Duration::ZERO,
            drop_connections_every: None,
            unlock_delay: Duration::from_secs(5),
            rtde_v2: true,
            initial_q: [0.0, -FRAC_PI_2, FRAC_PI_2, -FRAC_PI_2, -FRAC_PI_2, 0.0],
            serial: serial_number(model, 0),
        }
    }

    /// Every port 0 (the OS picks; read them from [`SimHandle::ports`]).
    pub fn ephemeral(mut self) -> Self {
        self.ports = Ports {
            dashboard: 0,
            primary: 0,
            secondary: 0,
            realtime: 0,
            rtde: 0,
        };
        self
    }

    /// A factory-calibrated arm: [`SimConfig::arm`] becomes a deterministic pseudo-random
    /// physical arm with joint errors of the size a UR factory calibration finds (1σ 0.3 mm and
    /// 0.3 mrad per joint and axis; [`PhysicalArm::factory`]); the same `seed` gives the same
    /// arm. The controller publishes its exact DH, with calibration status "linearised".
    /// The serial number becomes [`serial_number`]`(model, seed)`: another seed is another arm.
    pub fn factory_calibrated(mut self, seed: u64) -> Self {
        self.arm = Some(PhysicalArm::factory(self.model, seed));
        self.serial = serial_number(self.model, seed);
        self
    }

    /// Hold the lower register range (int/double 0–23, bits 0–63) as a fieldbus adapter would.
    pub fn with_fieldbus_lower_range(mut self) -> Self {
        for i in 0..24 {
            self.fieldbus_held.push(format!("input_int_register_{i}"));
            self.fieldbus_held
                .push(format!("input_double_register_{i}"));
        }
        self.fieldbus_held.push("input_bit_registers0_to_31".into());
        self.fieldbus_held
            .push("input_bit_registers32_to_63".into());
        self
    }
}

/// Shared between the servers, the physics task and the script threads.
pub(crate) struct Shared {
    pub(crate) state: Mutex<State>,
    pub(crate) config: SimConfig,
    /// Robot messages for 30001 clients (bounded ring: slow readers skip).
    pub(crate) messages: broadcast::Sender<Vec<u8>>,
    /// Bumped to close every connection.
    pub(crate) drop_gen: watch::Sender<u64>,
    pub(crate) fieldbus: HashSet<String>,
}

impl std::fmt::Debug for Shared {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Shared")
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl Shared {
    pub(crate) fn lock(&self) -> MutexGuard<'_, State> {
        // A panic inside a lock holder is a bug; keep serving with the state as it was.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub(crate) fn publish(&self, pkg: Vec<u8>) {
        // No receivers is fine.
        let _ = self.messages.send(pkg);
    }

    pub(crate) fn timestamp_us(&self) -> u64 {
        (self.lock().timestamp() * 1e6) as u64
    }

    pub(crate) fn version(&self) -> (u32, u32, u32, u32) {
        self.software().0
    }

    /// The software version and its build date as `PolyScope version` shows it.
    pub(crate) fn software(&self) -> ((u32, u32, u32, u32), &'static str) {
        if self.config.model.is_cb3() {
            ((3, 15, 7, 106331), "Sep 06 2021")
        } else {
            ((5, 11, 1, 108318), "Mar 22 2021")
        }
    }
}

/// A running simulator. Dropping it stops every server.
#[derive(Debug)]
pub struct SimHandle {
    shared: Arc<Shared>,
    ports: Ports,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

/// Starts simulators.
#[derive(Debug)]
pub struct Simulator;

impl Simulator {
    /// Bind every port and start serving. Must be called inside a tokio runtime.
    pub async fn start(config: SimConfig) -> Result<SimHandle, UrError> {
        let bind = |port: u16| {
            let addr = SocketAddr::new(config.bind, port);
            async move {
                let l = TcpListener::bind(addr)
                    .await
                    .map_err(|source| UrError::Io {
                        peer: addr.to_string(),
                        source,
                    })?;
                Ok::<_, UrError>(l)
            }
        };
        let p = config.ports;
        let (ld, lp, ls, lr, lt) = (
            bind(p.dashboard).await?,
            bind(p.primary).await?,
            bind(p.secondary).await?,
            bind(p.realtime).await?,
            bind(p.rtde).await?,
        );
        let port = |l: &TcpListener| l.local_addr().map(|a| a.port()).unwrap_or(0);
        let ports = Ports {
            dashboard: port(&ld),
            primary: port(&lp),
            secondary: port(&ls),
            realtime: port(&lr),
            rtde: port(&lt),
        };
        let (messages, _) = broadcast::channel(64);
        let (drop_gen, _) = watch::channel(0);
        let shared = Arc::new(Shared {
            state: Mutex::new(State::new(&config)),
            fieldbus: config.fieldbus_held.iter().cloned().collect(),
            config,
            messages,
            drop_gen,
        });
        let mut tasks = vec![
            tokio::spawn(dashboard::serve(ld, shared.clone())),
            tokio::spawn(script::serve_primary(lp, shared.clone(), true)),
            tokio::spawn(script::serve_primary(ls, shared.clone(), false)),
            tokio::spawn(realtime::serve(lr, shared.clone())),
            tokio::spawn(rtde_server::serve(lt, shared.clone())),
            tokio::spawn(control::run(shared.clone())),
        ];
        if let Some(every) = shared.config.drop_connections_every {
            let s = shared.clone();
            tasks.push(tokio::spawn(async move {
                let mut t = tokio::time::interval(every);
                t.tick().await;
                loop {
                    t.tick().await;
                    s.drop_gen.send_modify(|g| *g += 1);
                }
            }));
        }
        Ok(SimHandle {
            shared,
            ports,
            tasks,
        })
    }
}

impl SimHandle {
    /// The ports actually bound.
    pub fn ports(&self) -> Ports {
        self.ports
    }

    /// The bind address.
    pub fn ip(&self) -> IpAddr {
        self.shared.config.bind
    }

    /// Stop serving (also done on drop).
    pub fn shutdown(&mut self) {
        for t in self.tasks.drain(..) {
            t.abort();
        }
        self.shared.drop_gen.send_modify(|g| *g += 1);
        self.shared.lock().stop_program(None);
    }

    /// Power on and release brakes (as an operator on the pendant).
    pub fn power_on_and_release(&self) {
        let mut s = self.shared.lock();
        s.robot_mode = RobotModeCode::Running;
    }

    /// Trigger a protective stop now (as if the arm hit something).
    pub fn protective_stop(&self) {
        self.shared.lock().protective_stop();
    }

    /// Protective stop when the next move reaches `fraction` of its path.
    pub fn protective_stop_during_next_move(&self, fraction: f64) {
        self.shared.lock().pstop_at_fraction = Some(fraction.clamp(0.0, 1.0));
    }

    /// Emergency stop pressed (true) or released (false; the arm stays powered off).
    pub fn emergency_stop(&self, pressed: bool) {
        self.shared.lock().emergency_stop(pressed);
    }

    /// Switch remote control on/off (local control stops any running program, like the pendant).
    pub fn set_remote_control(&self, on: bool) {
        let mut s = self.shared.lock();
        s.remote_control = on || self.shared.config.model.is_cb3();
        if !s.remote_control {
            s.stop_program(Some("remote control switched off"));
        }
    }

    /// Close every client connection now (clients must reconnect).
    pub fn drop_connections(&self) {
        self.shared.drop_gen.send_modify(|g| *g += 1);
    }

    /// Change the reply latency.
    pub fn set_latency(&self, latency: Duration) {
        self.shared.lock().latency = latency;
    }

    /// Current joint angles, rad.
    pub fn joint_positions(&self) -> [f64; 6] {
        self.shared.lock().q
    }

    /// Active TCP offset `flange_from_tcp` as a UR pose.
    pub fn tcp_offset(&self) -> crate::UrPose {
        self.shared.lock().tcp
    }

    /// `actual_TCP_pose` (`base_from_tcp`).
    pub fn tcp_pose(&self) -> crate::UrPose {
        self.shared.lock().tcp_pose()
    }

    /// Robot mode.
    pub fn robot_mode(&self) -> RobotModeCode {
        self.shared.lock().robot_mode
    }

    /// Safety mode.
    pub fn safety_mode(&self) -> SafetyModeCode {
        self.shared.lock().safety_mode
    }

    /// Whether a program is running (runtime_state PLAYING).
    pub fn program_running(&self) -> bool {
        self.shared.lock().runtime_state == state::RUNTIME_PLAYING
    }

    /// Value of `input_double_register_i` as the controller holds it.
    pub fn input_double_register(&self, i: usize) -> f64 {
        self.shared
            .lock()
            .in_double
            .get(i)
            .copied()
            .unwrap_or(f64::NAN)
    }

    /// Value of `input_int_register_i`.
    pub fn input_int_register(&self, i: usize) -> i32 {
        self.shared.lock().in_int.get(i).copied().unwrap_or(0)
    }

    /// Set an output double register (as a pendant program would).
    pub fn set_output_double_register(&self, i: usize, v: f64) {
        if let Some(r) = self.shared.lock().out_double.get_mut(i) {
            *r = v;
        }
    }

    /// Set an output int register (as a pendant program would).
    pub fn set_output_int_register(&self, i: usize, v: i32) {
        if let Some(r) = self.shared.lock().out_int.get_mut(i) {
            *r = v;
        }
    }

    /// The last few robot messages as text (bounded), e.g. runtime exceptions of scripts.
    pub fn recent_log(&self) -> Vec<String> {
        self.shared.lock().log.iter().cloned().collect()
    }

    /// The kinematics the controller computes with: the physical arm's exact DH, or the
    /// nominal set.
    pub fn dh(&self) -> DhParams {
        self.shared.lock().dh
    }

    /// The arm's serial number (dashboard `get serial number`).
    pub fn serial(&self) -> &str {
        &self.shared.config.serial
    }

    /// The physical arm this controller drives (`None`: exactly nominal), for a simulated
    /// camera that must see the same arm.
    pub fn arm(&self) -> Option<PhysicalArm> {
        self.shared.config.arm
    }

    /// The kinematics this controller publishes (primary KinematicsInfo): [`SimHandle::dh`],
    /// its checksums, calibrated.
    pub fn kinematics(&self) -> ControllerKinematics {
        self.shared
            .lock()
            .kinematics_info()
            .to_controller_kinematics()
    }

    /// Move the speed slider (as an operator on the pendant), clamped to 0–1; RTDE
    /// `target_speed_fraction` and the primary robot mode data follow.
    pub fn set_speed_slider(&self, fraction: f64) {
        if fraction.is_finite() {
            self.shared.lock().speed_slider = fraction.clamp(0.0, 1.0);
        }
    }

    /// The speed slider, 0–1.
    pub fn speed_slider(&self) -> f64 {
        self.shared.lock().speed_slider
    }
}

impl Drop for SimHandle {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Accepts connections on `listener` until the task is aborted, serving each with `handle`
/// until it ends or the simulator drops every connection (fault injection). A failed `accept`
/// (e.g. out of file descriptors) is logged and retried after a pause, never spun on.
pub(crate) async fn accept_loop<F, Fut, E>(
    listener: TcpListener,
    shared: Arc<Shared>,
    what: &'static str,
    handle: F,
) where
    F: Fn(TcpStream, Arc<Shared>) -> Fut,
    Fut: std::future::Future<Output = Result<(), E>> + Send + 'static,
    E: std::fmt::Display,
{
    loop {
        let sock = match listener.accept().await {
            Ok((sock, _)) => sock,
            Err(e) => {
                tracing::warn!("{what}: accept failed: {e}; retrying");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let mut drop_rx = shared.drop_gen.subscribe();
        let connection = handle(sock, shared.clone());
        tokio::spawn(async move {
            tokio::select! {
                r = connection => {
                    if let Err(e) = r {
                        tracing::debug!("{what} connection closed: {e}");
                    }
                }
                _ = dropped(&mut drop_rx) => {}
            }
        });
    }
}

/// Aborts a connection's helper task (its stream writer) when the connection ends.
pub(crate) struct AbortOnDrop(pub(crate) tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// Wait for the next drop signal (used by every connection task).
pub(crate) async fn dropped(rx: &mut watch::Receiver<u64>) {
    if rx.changed().await.is_err() {
        std::future::pending::<()>().await;
    }
}
