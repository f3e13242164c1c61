//! Driver wiring, in one place: the concrete robot and camera the configuration names (the
//! binary is the only code that names `handeye-ur`, `handeye-gige` and `handeye-gentl`), the robot model, and
//! the history file. `calibrate`, `check`, `demo` and `daemon` all connect through here.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use handeye::camera::{ExecCamera, FileCamera};
use handeye::config::{CameraBackend, Config};
use handeye::guard::{Cell, MotionGuard};
use handeye::model::RobotModel;
use handeye::store::HISTORY_FILE;
use handeye_gentl::{GentlCamera, GentlOptions};
use handeye_gige::{ControlConfig, GigeCamera, GvcpClient};
use handeye_hal::DepthCamera;
use handeye_ur::{Ports, UrConfig, UrRobot};

use super::args::resolve_robot;

/// The history database of a configuration (`<storage.dir>/history.sqlite`).
pub(crate) fn history_path(cfg: &Config) -> PathBuf {
    cfg.storage.dir.join(HISTORY_FILE)
}

/// The robot model the configuration names.
pub(crate) fn load_model(cfg: &Config) -> anyhow::Result<Arc<RobotModel>> {
    let path = match &cfg.robot.urdf {
        Some(p) => p.clone(),
        None => resolve_robot(cfg.robot.model.name())
            .map_err(anyhow::Error::msg)
            .with_context(|| format!("robot.model in {}", cfg.origin))?,
    };
    let model = RobotModel::load(&path)
        .with_context(|| format!("loading the robot model {}", path.display()))?;
    anyhow::ensure!(
        model.dof() == 6,
        "{} has {} joints; a UR arm has 6",
        path.display(),
        model.dof()
    );
    // The run poses the model by the file when the controller tells no kinematics; a file that
    // cannot serve is refused now, not at the first run.
    if let Some(file) = &cfg.robot.calibration {
        let calibration = handeye::model::UrCalibration::load(file)
            .with_context(|| format!("robot.calibration in {}", cfg.origin))?;
        calibration
            .dh(&cfg.robot.model.dh())
            .map_err(anyhow::Error::msg)?;
    }
    Ok(Arc::new(model))
}

/// The configured camera, whichever backend: one concrete type for the generic run.
#[derive(Debug, Clone)]
pub(crate) enum AnyCamera {
    /// GigE Vision.
    Gige(GigeCamera),
    /// A vendor's GenTL producer.
    Gentl(GentlCamera),
    /// A vendor SDK through a command.
    Exec(ExecCamera),
    /// Recorded files.
    File(FileCamera),
}

impl AnyCamera {
    /// Connects the camera `cfg.camera` names.
    pub(crate) async fn connect(cfg: &Config) -> anyhow::Result<AnyCamera> {
        Ok(match &cfg.camera.backend {
            CameraBackend::Gige { address } => {
                let addr = GvcpClient::parse_address(address)?;
                let camera = tokio::task::spawn_blocking(move || {
                    GigeCamera::connect(addr, ControlConfig::default())
                })
                .await?
                .with_context(|| format!("connecting to the GigE Vision camera at {addr}"))?;
                let mut camera = camera;
                camera.options.trigger = cfg.camera.trigger;
                camera.options.settings = cfg.camera.settings.clone();
                AnyCamera::Gige(camera)
            }
            CameraBackend::Gentl {
                producer,
                device,
                call_timeout,
            } => {
                let producer = handeye_gentl::resolve_producer(producer.as_deref())?;
                let options = GentlOptions {
                    device: device.clone(),
                    trigger: cfg.camera.trigger,
                    call_timeout: *call_timeout,
                    settings: cfg.camera.settings.clone(),
                    ..GentlOptions::default()
                };
                AnyCamera::Gentl(connect_gentl(&producer, options).await?)
            }
            CameraBackend::Exec { command, timeout } => {
                AnyCamera::Exec(ExecCamera::new(command.clone(), *timeout)?)
            }
            CameraBackend::File { paths } => AnyCamera::File(FileCamera::new(paths.clone())?),
        })
    }
}

/// The camera behind a GenTL producer (its host process started, the device open).
pub(crate) async fn connect_gentl(
    producer: &std::path::Path,
    options: GentlOptions,
) -> anyhow::Result<GentlCamera> {
    GentlCamera::connect(producer, options)
        .await
        .with_context(|| {
            format!(
                "opening the camera through the GenTL producer {}",
                producer.display()
            )
        })
}

impl DepthCamera for AnyCamera {
    async fn info(&self) -> Result<handeye_hal::CameraInfo, handeye_hal::HalError> {
        match self {
            AnyCamera::Gige(c) => c.info().await,
            AnyCamera::Gentl(c) => c.info().await,
            AnyCamera::Exec(c) => c.info().await,
            AnyCamera::File(c) => c.info().await,
        }
    }

    async fn capture(
        &self,
        settings: &handeye_hal::CaptureSettings,
    ) -> Result<Vec<handeye_hal::PointCloud>, handeye_hal::HalError> {
        match self {
            AnyCamera::Gige(c) => c.capture(settings).await,
            AnyCamera::Gentl(c) => c.capture(settings).await,
            AnyCamera::Exec(c) => c.capture(settings).await,
            AnyCamera::File(c) => c.capture(settings).await,
        }
    }

    fn link_generation(&self) -> u64 {
        match self {
            AnyCamera::Gige(c) => c.link_generation(),
            AnyCamera::Gentl(c) => c.link_generation(),
            AnyCamera::Exec(c) => c.link_generation(),
            AnyCamera::File(c) => c.link_generation(),
        }
    }
}

/// The configured controller (`[robot]`: host, ports, speed and acceleration caps), claiming
/// no RTDE input register.
pub(crate) fn ur_config(cfg: &Config) -> UrConfig {
    let p = cfg.robot.ports;
    let mut ur = UrConfig::new(cfg.robot.host).without_registers();
    ur.ports = Ports {
        dashboard: p.dashboard,
        primary: p.primary,
        secondary: p.secondary,
        realtime: p.realtime,
        rtde: p.rtde,
    };
    ur.max_joint_speed_rad_s = cfg.robot.limits.max_joint_speed_rad_s;
    ur.max_joint_accel_rad_s2 = cfg.robot.limits.max_joint_accel_rad_s2;
    ur
}

/// Which RTDE input registers a connection claims.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Registers {
    /// Those the configuration writes (write-back, the pendant handshake): a run that writes.
    Configured,
    /// None: a dry run, read-only, beside a daemon that holds them.
    None,
}

/// Connects RTDE, dashboard and primary of the configured controller, every move guarded in
/// the configured cell (joint limits, floor, self-collision, obstacles, speed caps).
pub(crate) async fn connect_robot(
    cfg: &Config,
    model: &Arc<RobotModel>,
    registers: Registers,
) -> anyhow::Result<MotionGuard<UrRobot>> {
    // Claim exactly the RTDE input registers the configuration writes (and the pendant
    // handshake's), no others: they stay free for the cell's own clients.
    let mut ur = ur_config(cfg);
    let mut ints: Vec<u32> = Vec::new();
    if let (Some(map), Registers::Configured) = (cfg.write_back.registers, registers) {
        ur.registers = map.double_start..=map.double_start + 5;
        ints.push(map.sequence_int);
    }
    if let (Some(p), Registers::Configured) = (cfg.daemon.pendant, registers) {
        ints.extend([p.request_register, p.status_register]);
    }
    if let (Some(lo), Some(hi)) = (ints.iter().min(), ints.iter().max()) {
        ur.int_registers = *lo..=*hi;
    }
    let robot = UrRobot::connect(ur)
        .await
        .with_context(|| format!("connecting to the UR controller at {}", cfg.robot.host))?;
    Ok(MotionGuard::new(
        robot,
        Cell::from_config(Arc::clone(model), cfg),
    ))
}
