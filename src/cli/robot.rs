//! `handeye robot`: commissioning commands for a UR controller (status, move, set-tcp,
//! registers). Moves need remote control and are capped in speed.

use std::net::IpAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::Context;
use handeye::config::Config;
use handeye::guard::{Cell, MotionGuard};
use handeye::model::RobotModel;
use handeye_hal::ur_dh::UrModel;
use handeye_hal::ur_limits;
use handeye_hal::{limits, ControllerIdentity, MotionLimits, Robot};
use handeye_ur::{UrConfig, UrPose, UrRobot};

use super::args::resolve_robot;
use super::emit;
use super::wiring::load_model;
use nalgebra::Isometry3;
use tokio_util::sync::CancellationToken;

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Controller address (e.g. 192.168.56.101, or 127.0.0.1 for `handeye sim robot`);
    /// overrides the configuration's `robot.host`. Default: `robot.host` with `--config`,
    /// else 127.0.0.1.
    #[arg(long, global = true)]
    host: Option<IpAddr>,
    /// The cell's configuration: the controller it names (`robot.host`, `robot.ports`, speed
    /// caps); `move` checks the path against its robot model, camera mount, floor clearance
    /// and obstacles and caps the speed at its limits; `status` says whether its current
    /// calibration was made on this arm.
    #[arg(long, global = true, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Limit for each request to the controller (connect, dashboard, RTDE setup, script
    /// read-back), seconds (0.1–600). A move's own limit is `move --move-timeout-s`.
    #[arg(long, global = true, default_value_t = 3.0)]
    timeout_s: f64,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Who the controller is (model, serial, software, kinematics checksum), robot mode,
    /// safety mode, remote control, program state, joints, flange and TCP poses.
    Status {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Joint move (`movej`); returns when the arm has arrived; Ctrl-C stops the arm.
    Move {
        /// Six joint angles, comma-separated (base, shoulder, elbow, wrist 1, 2, 3).
        #[arg(
            long,
            value_delimiter = ',',
            allow_hyphen_values = true,
            required = true
        )]
        joints: Vec<f64>,
        /// Joint angles are in degrees instead of radians.
        #[arg(long)]
        deg: bool,
        /// Joint speed cap, rad/s.
        #[arg(long, default_value_t = 0.25)]
        speed: f64,
        /// Joint acceleration, rad/s².
        #[arg(long, default_value_t = 0.5)]
        accel: f64,
        /// Give up on the move (and stop the arm) after this many seconds (1–3600). Not the
        /// same as `--timeout-s`, the limit for each request to the controller.
        #[arg(long, default_value_t = 60.0)]
        move_timeout_s: f64,
    },
    /// Set the runtime TCP (flange → TCP, UR pose `x,y,z,rx,ry,rz` in m and rad) and read it back.
    SetTcp {
        /// `x,y,z,rx,ry,rz` or `p[x,y,z,rx,ry,rz]`.
        #[arg(long, allow_hyphen_values = true)]
        pose: UrPose,
    },
    /// Which robot models this program finds, and where: the folders it looks in (in order),
    /// then every UR model with its URDF or `missing`. Connects nothing. Exit 1 when the
    /// configured `robot.model` (with `--config`) has no file, or no folder of models is found.
    Models,
    /// Read or write RTDE double registers 24–47.
    Registers {
        /// Write `INDEX=VALUE` (repeatable) before reading.
        #[arg(long = "set", value_name = "INDEX=VALUE")]
        set: Vec<String>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
}

/// Connects and runs one command. `shutdown` (Ctrl-C, SIGTERM) stops a move — the arm is
/// stopped before this returns — and abandons any other command (exit 2, "interrupted").
pub(crate) async fn run(args: Args, shutdown: CancellationToken) -> anyhow::Result<ExitCode> {
    let request_timeout = limits::duration_from_secs(
        "--timeout-s",
        args.timeout_s,
        MIN_REQUEST_TIMEOUT_S,
        MAX_REQUEST_TIMEOUT_S,
    )
    .map_err(anyhow::Error::msg)?;
    // Everything the user gave is checked before anything is connected or moved.
    let config = args.config.as_deref().map(Config::load).transpose()?;
    if matches!(args.command, Command::Models) {
        return models(config.as_ref());
    }
    let checked_move = match &args.command {
        Command::Move {
            joints,
            deg,
            speed,
            accel,
            move_timeout_s,
        } => Some(check_move(joints, *deg, *speed, *accel, *move_timeout_s)?),
        _ => None,
    };
    let mut cfg = match &config {
        Some(c) => super::wiring::ur_config(c),
        None => UrConfig::new(DEFAULT_HOST),
    };
    if let Some(host) = args.host {
        cfg.host = host;
    }
    cfg.timeout = request_timeout;
    // Before anything is sent: which controller this is, and why this one.
    let whence = match (&args.host, &args.config) {
        (Some(_), _) => "--host".to_string(),
        (None, Some(path)) => format!("robot.host in {}", path.display()),
        (None, None) => "the default; give --config FILE or --host".to_string(),
    };
    eprintln!(
        "controller {} (dashboard port {}, RTDE port {}; {whence})",
        cfg.host, cfg.ports.dashboard, cfg.ports.rtde
    );
    let host = cfg.host;
    // A move or a TCP beside the daemon of the configured cell would change what it holds
    // behind its back: one process moves a cell's arm (a `--host` elsewhere is another arm).
    let moves = matches!(args.command, Command::Move { .. } | Command::SetTcp { .. });
    let _arm = match &config {
        Some(c) if moves && c.robot.host == host => {
            Some(super::calibrate::hold_the_arm(c, "robot", |holder| {
                format!(
                    "handeye daemon ({holder}) runs this cell (storage {}) and moves its arm: \
                     stop it (`systemctl stop handeye`) before moving the arm or setting the TCP \
                     by hand, then start it again",
                    c.storage.dir.display()
                )
            })?)
        }
        _ => None,
    };
    // Whatever the configuration: an arm another process holds is not moved by hand.
    let _claim = match moves && _arm.is_none() {
        true => Some(handeye::daemon::arm::ArmClaim::take(
            host,
            cfg.ports.dashboard,
        )?),
        false => None,
    };
    // Only `registers` reads and writes them (24–47 and the int registers 24–31, whatever
    // the configuration writes): the others claim no RTDE input, so they work beside a
    // running daemon (or another client) that holds the registers.
    if matches!(args.command, Command::Registers { .. }) {
        let all = UrConfig::new(host);
        cfg.registers = all.registers;
        cfg.int_registers = all.int_registers;
    } else {
        cfg = cfg.without_registers();
    }
    let robot = tokio::select! {
        r = UrRobot::connect(cfg) => {
            r.with_context(|| format!("connecting to the controller at {host}"))?
        }
        () = shutdown.cancelled() => {
            anyhow::bail!("interrupted while connecting to {host}")
        }
    };
    match args.command {
        Command::Move { .. } => {
            let (q, lim) = checked_move.context("move arguments were checked")?;
            let cell = move_cell(&robot, config.as_ref(), lim).await?;
            let robot = MotionGuard::new(robot, cell);
            // Dropping the move (on `shutdown`) stops the arm; say so to the controller too.
            tokio::select! {
                r = robot.move_joints(&q, lim) => r.context("move")?,
                () = shutdown.cancelled() => {
                    robot.stop().await.context("stopping the arm after the interrupt")?;
                    anyhow::bail!("interrupted: the move was cancelled and the arm stopped");
                }
            }
            emit("arrived\n")?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Status { json } => {
            interruptible(&shutdown, status(&robot, json, config.as_ref())).await
        }
        Command::SetTcp { pose } => interruptible(&shutdown, set_tcp(&robot, pose)).await,
        Command::Registers { set, json } => {
            interruptible(&shutdown, registers(&robot, &set, json)).await
        }
        Command::Models => models(config.as_ref()),
    }
}

/// `handeye robot models`: the folders the models are looked for in (in order, the first
/// that exists is used), then every UR model with its URDF there or `missing`; the
/// configuration's `robot.urdf` is named when it sets one. Exit 1 when the configured model
/// has no file, or (without `--config`) when no folder of models is found.
fn models(config: Option<&Config>) -> anyhow::Result<ExitCode> {
    use handeye_sim_scene::robots_dir_candidates;
    let mut out =
        String::from("robot models are looked for in (the first folder found is used):\n");
    let candidates = robots_dir_candidates();
    let used = candidates.iter().position(|(p, _)| p.is_dir());
    for (i, (path, whence)) in candidates.iter().enumerate() {
        let state = match (used, path.is_dir()) {
            (Some(u), true) if u == i => "used",
            (_, true) => "found, not used",
            (_, false) => "absent",
        };
        out.push_str(&format!("  {} ({whence}): {state}\n", path.display()));
    }
    let dir = used.map(|u| &candidates[u].0);
    let urdfs = dir
        .map(|d| handeye::model::find_urdfs(d))
        .unwrap_or_default();
    let mut missing = Vec::new();
    out.push_str("UR models:\n");
    for m in UrModel::ALL {
        let found = urdfs
            .iter()
            .find(|u| u.file_stem().is_some_and(|s| s == m.name()));
        match found {
            Some(u) => out.push_str(&format!("  {:<6} {}\n", m.name(), u.display())),
            None => {
                out.push_str(&format!("  {:<6} missing\n", m.name()));
                missing.push(m);
            }
        }
    }
    let failed = match config {
        Some(c) => match &c.robot.urdf {
            Some(u) => {
                let there = u.is_file();
                out.push_str(&format!(
                    "{}: robot.model {} from robot.urdf = {} ({})\n",
                    c.origin,
                    c.robot.model.name(),
                    u.display(),
                    if there { "found" } else { "missing" }
                ));
                !there
            }
            None => {
                let gone = missing.contains(&c.robot.model);
                out.push_str(&format!(
                    "{}: robot.model {} ({})\n",
                    c.origin,
                    c.robot.model.name(),
                    if gone {
                        "missing: set robot.urdf to the arm's URDF, with its meshes beside it"
                    } else {
                        "found"
                    }
                ));
                gone
            }
        },
        None => {
            if !missing.is_empty() {
                out.push_str(
                    "a missing model can be given to a cell as robot.urdf (the arm's URDF, with its meshes)\n",
                );
            }
            dir.is_none()
        }
    };
    emit(&out)?;
    Ok(if failed {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

/// The cell a `move` is checked in: the configuration's, else the arm the controller's
/// kinematics say it is (no camera, no obstacles, the default floor clearance) with the
/// move's own caps.
async fn move_cell(
    robot: &UrRobot,
    config: Option<&Config>,
    lim: MotionLimits,
) -> anyhow::Result<Cell> {
    if let Some(cfg) = config {
        return Ok(Cell::from_config(load_model(cfg)?, cfg));
    }
    let kinematics = robot
        .kinematics()
        .await
        .context("reading the controller's kinematics")?
        .context(
            "the controller publishes no kinematics, so the move cannot be checked for \
             collisions; give --config FILE (the cell's configuration names robot.model)",
        )?;
    let (model, _) = UrModel::matching(&kinematics.dh)
        .into_iter()
        .next()
        .context(
            "the controller's kinematics are no UR model's, so the move cannot be checked; \
             give --config FILE naming robot.model",
        )?;
    let path = resolve_robot(model.name()).map_err(anyhow::Error::msg)?;
    let urdf = RobotModel::load(&path)
        .with_context(|| format!("loading the robot model {}", path.display()))?;
    Ok(Cell::bare(Arc::new(urdf), model, lim))
}

/// Runs a request that does not move the arm (nothing to undo when it is abandoned) until it
/// ends or `shutdown` is cancelled.
async fn interruptible(
    shutdown: &CancellationToken,
    request: impl std::future::Future<Output = anyhow::Result<ExitCode>>,
) -> anyhow::Result<ExitCode> {
    shutdown
        .run_until_cancelled(request)
        .await
        .unwrap_or_else(|| Err(anyhow::anyhow!("interrupted")))
}

/// Sets the runtime TCP from a UR pose `x,y,z,rx,ry,rz` and reads it back.
async fn set_tcp(robot: &UrRobot, p: UrPose) -> anyhow::Result<ExitCode> {
    super::args::check_pose_distance(
        "--pose",
        &Isometry3::from(p),
        super::args::MAX_MOUNT_DISTANCE_M,
        "a TCP on a tool at the flange",
    )
    .map_err(anyhow::Error::msg)?;
    robot
        .set_tcp(&Isometry3::from(p))
        .await
        .context("set_tcp")?;
    emit(&format!("TCP set and confirmed: {}\n", p.to_script()))?;
    Ok(ExitCode::SUCCESS)
}

/// The controller without `--host` or `--config`: `handeye sim robot` on this PC.
const DEFAULT_HOST: IpAddr = IpAddr::V4(std::net::Ipv4Addr::LOCALHOST);
/// Shortest and longest limit for one request to the controller (`--timeout-s`), seconds.
const MIN_REQUEST_TIMEOUT_S: f64 = 0.1;
const MAX_REQUEST_TIMEOUT_S: f64 = 600.0;
/// Shortest and longest limit for one move (`move --move-timeout-s`), seconds.
const MIN_MOVE_TIMEOUT_S: f64 = 1.0;
const MAX_MOVE_TIMEOUT_S: f64 = 3600.0;
/// Highest joint speed cap, rad/s (the hal's UR limits table; the arm's own limits cap it
/// further).
const MAX_JOINT_SPEED_RAD_S: f64 = ur_limits::MAX_JOINT_SPEED_CAP_RAD_S;
/// Highest joint acceleration, rad/s² (UR's own limit, from the same table).
const MAX_JOINT_ACCEL_RAD_S2: f64 = ur_limits::MAX_JOINT_ACCEL_RAD_S2;
/// A UR joint turns at most ±2π from zero (radians; a little slack for rounding).
const MAX_JOINT_RAD: f64 = ur_limits::JOINT_POSITION_LIMIT_RAD + 1e-6;

/// `move`'s joints (radians after `--deg`), speed, acceleration and timeout, each checked
/// against its range; errors name the flag and say why.
fn check_move(
    joints: &[f64],
    deg: bool,
    speed: f64,
    accel: f64,
    move_timeout_s: f64,
) -> anyhow::Result<(Vec<f64>, MotionLimits)> {
    anyhow::ensure!(
        joints.len() == 6,
        "--joints needs 6 comma-separated values, got {}",
        joints.len()
    );
    let q: Vec<f64> = if deg {
        joints.iter().map(|d| d.to_radians()).collect()
    } else {
        joints.to_vec()
    };
    for (i, v) in q.iter().enumerate() {
        limits::check_range(
            &format!("--joints value {}", i + 1),
            *v,
            -MAX_JOINT_RAD,
            MAX_JOINT_RAD,
            "rad",
            "a UR joint turns at most ±360°; with --deg the values are degrees",
        )
        .map_err(anyhow::Error::msg)?;
    }
    let positive = |flag: &str, v: f64, max: f64, unit: &str, why: &str| {
        limits::check_range(flag, v, 0.0, max, unit, why)
            .and_then(|v| {
                if v > 0.0 {
                    Ok(v)
                } else {
                    Err(format!("{flag} = 0: must be above 0 {unit}"))
                }
            })
            .map_err(anyhow::Error::msg)
    };
    let speed = positive(
        "--speed",
        speed,
        MAX_JOINT_SPEED_RAD_S,
        "rad/s",
        "a UR joint turns at most π rad/s",
    )?;
    let accel = positive(
        "--accel",
        accel,
        MAX_JOINT_ACCEL_RAD_S2,
        "rad/s²",
        "UR joints accelerate at most 40 rad/s²",
    )?;
    let timeout = limits::duration_from_secs(
        "--move-timeout-s",
        move_timeout_s,
        MIN_MOVE_TIMEOUT_S,
        MAX_MOVE_TIMEOUT_S,
    )
    .map_err(anyhow::Error::msg)?;
    Ok((
        q,
        MotionLimits {
            max_joint_speed_rad_s: speed,
            max_joint_accel_rad_s2: accel,
            timeout,
        },
    ))
}

/// Writes `INDEX=VALUE` pairs, then prints input and output double registers 24–47 and the
/// input integer registers 24–31.
async fn registers(robot: &UrRobot, set: &[String], json: bool) -> anyhow::Result<ExitCode> {
    for s in set {
        let (i, v) = s
            .split_once('=')
            .with_context(|| format!("`{}` is not INDEX=VALUE", limits::Quoted(s)))?;
        let i: u32 = i
            .trim()
            .parse()
            .with_context(|| format!("bad register index in `{}`", limits::Quoted(s)))?;
        let v: f64 = v
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite())
            .with_context(|| {
                format!(
                    "bad value in `{}`: expected a finite number",
                    limits::Quoted(s)
                )
            })?;
        robot
            .write_double_register(i, v)
            .await
            .with_context(|| format!("writing register {i}"))?;
    }
    let mut rows = Vec::new();
    for i in 24..=47 {
        let input = robot.read_double_register(i).await?;
        let output = robot.read_output_double_register(i).await?;
        // The integer registers this client reads (24..=31); `null` beyond.
        let input_int = match robot.read_int_register(i).await {
            Ok(v) => Some(v),
            Err(handeye_hal::HalError::InvalidArgument(_)) => None,
            Err(e) => return Err(e.into()),
        };
        rows.push(
            serde_json::json!({"index": i, "input": input, "output": output, "input_int": input_int}),
        );
    }
    let mut text = String::new();
    if json {
        text = serde_json::to_string_pretty(&rows)? + "\n";
    } else {
        text.push_str("register  input_double  output_double  input_int\n");
        for r in rows {
            text.push_str(&format!(
                "{:>8}  {:>12}  {:>13}  {:>9}\n",
                r["index"].to_string(),
                r["input"].to_string(),
                r["output"].to_string(),
                r["input_int"].to_string()
            ));
        }
    }
    emit(&text)?;
    Ok(ExitCode::SUCCESS)
}

/// Whether the current calibration in `cfg`'s storage was made on the controller `now`: a
/// sentence, and the mismatch (`None` when it matches or cannot be told).
fn calibration_arm(cfg: &Config, now: &ControllerIdentity) -> (String, Option<String>) {
    match handeye::storage::load_current(&cfg.storage.dir, cfg.mount.mount) {
        None => (
            format!("no current calibration in {}", cfg.storage.dir.display()),
            None,
        ),
        Some(current) => match &current.controller {
            None => (
                format!(
                    "{}: made before controllers were recorded, not compared",
                    current.source
                ),
                None,
            ),
            Some(then) => match now.calibration_mismatch(then) {
                Some(m) => (format!("{}: {m}", current.source), Some(m)),
                None => (format!("{}: made on this arm", current.source), None),
            },
        },
    }
}

async fn status(robot: &UrRobot, json: bool, cfg: Option<&Config>) -> anyhow::Result<ExitCode> {
    let st = robot.status().await?;
    let q = robot.joint_positions().await?;
    let flange = UrPose::from(robot.flange_pose().await?);
    let tcp = UrPose::from(robot.tcp_pose().await?);
    let offset = UrPose::from(robot.tcp_offset().await?);
    let v = robot.rtde().version();
    let identity = robot
        .identity()
        .await
        .context("asking the controller who it is")?;
    let calibration = cfg.map(|c| calibration_arm(c, &identity));
    if json {
        let out = serde_json::json!({
            "controller_version": v,
            "controller": identity,
            "calibration": calibration.as_ref().map(|(text, mismatch)| serde_json::json!({
                "text": text,
                "other_arm": mismatch,
            })),
            "status": st,
            "can_move": st.can_move(),
            "joint_positions_rad": q,
            "base_from_flange_ur_pose": flange.0,
            "base_from_tcp_ur_pose": tcp.0,
            "flange_from_tcp_ur_pose": offset.0,
        });
        emit(&(serde_json::to_string_pretty(&out)? + "\n"))?;
    } else {
        use std::fmt::Write as _;
        let mut t = String::new();
        writeln!(t, "controller      {}.{}.{}.{}", v[0], v[1], v[2], v[3])?;
        writeln!(t, "arm             {identity}")?;
        if let Some((text, _)) = &calibration {
            writeln!(t, "calibration     {text}")?;
        }
        writeln!(t, "robot mode      {:?}", st.robot_mode)?;
        writeln!(t, "safety mode     {:?}", st.safety_mode)?;
        writeln!(t, "remote control  {}", st.remote_control)?;
        writeln!(t, "program running {}", st.program_running)?;
        writeln!(t, "can move        {}", st.can_move())?;
        writeln!(t, "joints [rad]    {q:.5?}")?;
        writeln!(t, "flange (base)   {}", flange.to_script())?;
        writeln!(t, "TCP (base)      {}", tcp.to_script())?;
        writeln!(t, "TCP offset      {}", offset.to_script())?;
        emit(&t)?;
    }
    Ok(ExitCode::SUCCESS)
}
