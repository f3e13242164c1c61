//! `handeye calibrate` and `handeye check`: one calibration run on the configured robot and
//! camera (see `handeye::run`). This is where the concrete drivers are chosen from the
//! configuration; the run itself only knows the hal traits.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::Context;
use handeye::camera::{ExecCamera, FileCamera};
use handeye::config::{CameraBackend, Config};
use handeye::model::RobotModel;
use handeye::record::Trigger;
use handeye::run::{Outcome, Progress, Recorder, RunMode, RunRecord, RunRequest, Stage};
use handeye::store::{Store, HISTORY_FILE};
use handeye_gige::{ControlConfig, GigeCamera, GvcpClient};
use handeye_hal::DepthCamera;
use handeye_ur::{Ports, UrConfig, UrRobot};
use nalgebra::Isometry3;
use tokio_util::sync::CancellationToken;

use super::args::resolve_robot;

/// Arguments of `calibrate`.
#[derive(Debug, clap::Args)]
pub(crate) struct CalibrateArgs {
    /// The cell's configuration (see config/handeye.example.toml).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// Print the run record as one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Preflight and plan only: print the targets and the checked paths, move nothing.
    #[arg(long)]
    dry_run: bool,
}

/// Arguments of `check`.
#[derive(Debug, clap::Args)]
pub(crate) struct CheckArgs {
    /// The cell's configuration (see config/handeye.example.toml).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// Print the run record as one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

pub(crate) async fn calibrate(
    args: CalibrateArgs,
    shutdown: CancellationToken,
) -> anyhow::Result<ExitCode> {
    let cfg = Config::load(&args.config)?;
    let req = RunRequest {
        mode: RunMode::Calibrate,
        dry_run: args.dry_run,
        run_id: None,
        program_handover: false,
    };
    finish(execute(&cfg, req, &shutdown, args.json).await?, args.json)
}

pub(crate) async fn check(
    args: CheckArgs,
    shutdown: CancellationToken,
) -> anyhow::Result<ExitCode> {
    let cfg = Config::load(&args.config)?;
    let req = RunRequest {
        mode: RunMode::Check,
        dry_run: false,
        run_id: None,
        program_handover: false,
    };
    finish(execute(&cfg, req, &shutdown, args.json).await?, args.json)
}

fn finish(record: RunRecord, json: bool) -> anyhow::Result<ExitCode> {
    if json {
        println!("{}", serde_json::to_string_pretty(&record)?);
    } else {
        print!("{}", summary(&record));
    }
    Ok(ExitCode::from(record.exit_code()))
}

/// The robot model the configuration names.
pub(crate) fn load_model(cfg: &Config) -> anyhow::Result<Arc<RobotModel>> {
    let path = match &cfg.robot.urdf {
        Some(p) => p.clone(),
        None => resolve_robot(cfg.robot.model.name()).map_err(anyhow::Error::msg)?,
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
        calibration.dh().map_err(anyhow::Error::msg)?;
    }
    Ok(Arc::new(model))
}

/// Connects the configured robot and camera and runs once, recorded like the daemon's runs
/// (trigger `cli`): in the history, so `handeye history`, the page and the next check see what
/// the controller now holds. Connection failures are errors; everything after that is in the
/// record.
pub(crate) async fn execute(
    cfg: &Config,
    req: RunRequest,
    shutdown: &CancellationToken,
    quiet: bool,
) -> anyhow::Result<RunRecord> {
    let model = load_model(cfg)?;
    let robot = connect_robot(cfg).await?;
    let camera = AnyCamera::connect(cfg).await?;
    let recorder = recorder(cfg).await;
    let progress = Terminal::new(quiet);
    let record = recorder
        .run(&robot, &camera, &model, cfg, req, shutdown, &progress)
        .await;
    progress.done();
    Ok(record)
}

/// The recorder of a command's run: the history in the storage directory (opened beside a
/// running daemon), or the run's files only when the history cannot be opened (said why).
async fn recorder(cfg: &Config) -> Recorder {
    let path = cfg.storage.dir.join(HISTORY_FILE);
    let opened = tokio::task::spawn_blocking(move || Store::open(&path))
        .await
        .map_err(anyhow::Error::from)
        .and_then(|r| r.map_err(anyhow::Error::from));
    match opened {
        Ok(store) => Recorder::new(Arc::new(store), Trigger::Cli),
        Err(e) => {
            tracing::warn!("this run is not recorded in the history: {e:#}");
            Recorder::files_only()
        }
    }
}

/// The configured camera, whichever backend: one concrete type for the generic run.
#[derive(Debug, Clone)]
pub(crate) enum AnyCamera {
    /// GigE Vision.
    Gige(GigeCamera),
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
                AnyCamera::Gige(camera)
            }
            CameraBackend::Exec { command, timeout } => {
                AnyCamera::Exec(ExecCamera::new(command.clone(), *timeout)?)
            }
            CameraBackend::File { paths } => AnyCamera::File(FileCamera::new(paths.clone())?),
        })
    }
}

impl DepthCamera for AnyCamera {
    async fn info(&self) -> Result<handeye_hal::CameraInfo, handeye_hal::HalError> {
        match self {
            AnyCamera::Gige(c) => c.info().await,
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
            AnyCamera::Exec(c) => c.capture(settings).await,
            AnyCamera::File(c) => c.capture(settings).await,
        }
    }
}

/// Connects RTDE, dashboard and primary of the configured controller.
pub(crate) async fn connect_robot(cfg: &Config) -> anyhow::Result<UrRobot> {
    let p = cfg.robot.ports;
    let mut ur = UrConfig::new(cfg.robot.host);
    ur.ports = Ports {
        dashboard: p.dashboard,
        primary: p.primary,
        secondary: p.secondary,
        realtime: p.realtime,
        rtde: p.rtde,
    };
    ur.max_joint_speed_rad_s = cfg.robot.limits.max_joint_speed_rad_s;
    ur.max_joint_accel_rad_s2 = cfg.robot.limits.max_joint_accel_rad_s2;
    // Claim exactly the RTDE input registers the configuration writes (and the pendant
    // handshake's), no others: they stay free for the cell's own clients.
    #[allow(clippy::reversed_empty_ranges)]
    {
        ur.registers = 1..=0;
        ur.int_registers = 1..=0;
    }
    let mut ints: Vec<u32> = Vec::new();
    if let Some(map) = cfg.write_back.registers {
        ur.registers = map.double_start..=map.double_start + 5;
        ints.push(map.sequence_int);
    }
    if let Some(p) = cfg.daemon.pendant {
        ints.extend([p.request_register, p.status_register]);
    }
    if let (Some(lo), Some(hi)) = (ints.iter().min(), ints.iter().max()) {
        ur.int_registers = *lo..=*hi;
    }
    UrRobot::connect(ur)
        .await
        .with_context(|| format!("connecting to the UR controller at {}", cfg.robot.host))
}

/// Progress on the terminal: one updating line on a TTY, plain lines otherwise (stderr).
pub(crate) struct Terminal {
    quiet: bool,
    tty: bool,
    started: Instant,
    last: Mutex<Option<Stage>>,
}

impl Terminal {
    pub(crate) fn new(quiet: bool) -> Self {
        Self {
            quiet,
            tty: std::io::stderr().is_terminal(),
            started: Instant::now(),
            last: Mutex::new(None),
        }
    }

    fn done(&self) {
        if self.tty && !self.quiet {
            eprintln!();
        }
    }
}

impl Progress for Terminal {
    fn stage(&self, stage: Stage, detail: &str) {
        if self.quiet {
            return;
        }
        let t = self.started.elapsed().as_secs_f64();
        if let Ok(mut last) = self.last.lock() {
            *last = Some(stage);
        }
        if self.tty {
            eprint!("\r\x1b[2K[{t:6.1} s] {:<10} {detail}", stage.name());
        } else {
            eprintln!("[{t:6.1} s] {:<10} {detail}", stage.name());
        }
    }
}

fn matrix_lines(m: &[[f64; 4]; 4], indent: &str) -> String {
    m.iter()
        .map(|r| {
            format!(
                "{indent}[{:>10.6} {:>10.6} {:>10.6} {:>10.6}]\n",
                r[0], r[1], r[2], r[3]
            )
        })
        .collect()
}

/// A pose in UR units (mm, rotation vector rad) and as 4×4, labelled.
pub(crate) fn describe_pose(name: &str, t: &Isometry3<f64>) -> String {
    let p = t.translation.vector * 1e3;
    let r = t.rotation.scaled_axis();
    format!(
        "  {name}: x {:.3} mm, y {:.3} mm, z {:.3} mm, rotation vector [{:.6}, {:.6}, {:.6}] rad\n{}",
        p.x,
        p.y,
        p.z,
        r.x,
        r.y,
        r.z,
        matrix_lines(&handeye::frames::to_row_major(t), "    ")
    )
}

/// The text summary of a run record.
pub(crate) fn summary(r: &RunRecord) -> String {
    let mut s = format!("handeye {} — run {}: {}\n", r.mode, r.run_id, r.outcome);
    for reason in &r.reasons {
        s += &format!("  - {reason}\n");
    }
    if let Some(p) = &r.preflight {
        s += &format!(
            "  robot: {:?}, {:?}, speed slider {:.0}%, kinematics: {}{}\n",
            p.status.robot_mode,
            p.status.safety_mode,
            p.status.speed_fraction * 100.0,
            p.kinematics.source,
            p.kinematics
                .note
                .as_ref()
                .map_or(String::new(), |n| format!(" ({n})"))
        );
        s += &format!(
            "  camera: {} {} ({})\n",
            p.camera.vendor, p.camera.model, p.camera.serial
        );
    }
    for (i, v) in r.views.iter().enumerate() {
        s += &format!(
            "  view {i}: joints {:.3?} rad; path checked at {} configurations (step ≤ {:.3} rad){}\n",
            v.joints,
            v.path.samples,
            v.path.max_step_rad,
            v.distance_to_base_m
                .map_or(String::new(), |d| format!("; base at {d:.2} m"))
        );
    }
    if let Some(res) = &r.result {
        if let Some(t) = res
            .flange_from_camera
            .as_ref()
            .and_then(handeye::frames::from_row_major)
        {
            s += &describe_pose("flange_from_camera (camera in tool0)", &t);
            s += &describe_pose("camera_from_flange (tool0 in camera)", &t.inverse());
        } else if let Some(t) = handeye::frames::from_row_major(&res.base_from_camera) {
            s += &describe_pose("base_from_camera (camera in the controller's base)", &t);
            s += &describe_pose("camera_from_base", &t.inverse());
        }
        s += &format!(
            "  uncertainty (1σ): {:.3} mm, {:.4}°\n",
            res.uncertainty.translation_mm, res.uncertainty.rotation_deg
        );
    }
    if let Some(d) = &r.drift {
        s += &format!(
            "  drift from {}: {:.3} mm, {:.4}° (max {:.3} mm, {:.4}°): {}\n",
            d.reference,
            d.translation_mm,
            d.rotation_deg,
            d.max_translation_mm,
            d.max_rotation_deg,
            if d.drifted { "DRIFTED" } else { "within" }
        );
    }
    for w in &r.written {
        s += &format!("  written ({}): {}\n", w.target, w.detail);
    }
    if r.outcome != Outcome::Accepted && r.outcome != Outcome::Planned {
        s += "  nothing was written back\n";
    }
    let t = &r.timings_ms;
    s += &format!(
        "  time: {:.0} ms (preflight {:.0}, plan {:.0}, moves {:.0}, settle {:.0}, capture {:.0}, register {:.0}, solve {:.1}, write-back {:.0}, return {:.0}); overhead {:.0} ms\n",
        t.total, t.preflight, t.plan, t.moves, t.settle, t.capture, t.register, t.solve, t.write_back, t.return_move, t.overhead()
    );
    if let Some(f) = &r.capture_file {
        s += &format!("  raw capture: {f} (replay with `handeye solve --capture {f}`)\n");
    }
    s
}
