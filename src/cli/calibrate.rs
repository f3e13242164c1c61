//! `handeye calibrate` and `handeye check`: one calibration run on the configured robot and
//! camera (see `handeye::run`), connected through [`super::wiring`]; the run itself only knows
//! the hal traits.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use handeye::config::Config;
use handeye::daemon::arm::ArmClaim;
use handeye::daemon::lock::{DaemonLock, LockError};
use handeye::record::Trigger;
use handeye::run::{Outcome, Progress, Recorder, RunMode, RunRecord, RunRequest, Stage};
use nalgebra::Isometry3;
use tokio_util::sync::CancellationToken;

use super::wiring::{connect_robot, history_path, load_model, AnyCamera, Registers};

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
    /// The camera was remounted on purpose: accept a result that moved beyond
    /// `gate.max_change_translation_mm` / `max_change_rotation_deg` from the previous
    /// calibration (every other check of the gate still applies). The record and the history
    /// say who accepted it and how far it moved.
    #[arg(long)]
    accept_change: bool,
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
        dry_run: args.dry_run,
        accept_change: args.accept_change.then(cli_user),
        ..RunRequest::new(RunMode::Calibrate)
    };
    // A dry run moves nothing: it may run beside the daemon.
    let _arm = if args.dry_run {
        None
    } else {
        Some(hold_the_arm(&cfg, req.mode.name(), |holder| {
            through_the_daemon(&cfg, &args.config, &req, holder)
        })?)
    };
    finish(execute(&cfg, req, &shutdown, args.json).await?, args.json)
}

/// What a command that moves the arm holds while it runs: the cell's lock (`None` when it
/// could not be taken for another reason than a holder, see [`hold_the_arm`]) and the arm's
/// claim ([`ArmClaim`]). Dropped at the end of the run.
#[derive(Debug)]
pub(crate) struct ArmHold {
    _storage: Option<DaemonLock>,
    _arm: ArmClaim,
}

/// Takes the cell's lock (`<storage.dir>/daemon.lock`, [`DaemonLock`]) for `command`
/// (`calibrate`, `check`, `robot`) that moves the arm, then the arm's claim ([`ArmClaim`]: a
/// daemon or a command on another storage that holds the arm), before anything is connected:
/// one process moves an arm, and a daemon that runs keeps its state (the drift alarm, the
/// reference the next check compares with) in step only with the runs it makes itself. Beside
/// a running daemon the command is refused with `beside_daemon(holder)`, which names the way
/// out. The cell's lock is left out when it cannot be taken for another reason (a full or
/// read-only storage; a run's own preflight says what) and no daemon answers on its control
/// socket; the arm's claim never is.
pub(crate) fn hold_the_arm(
    cfg: &Config,
    command: &str,
    beside_daemon: impl FnOnce(&str) -> String,
) -> anyhow::Result<ArmHold> {
    let storage = &cfg.storage.dir;
    storage_owner(cfg)?;
    let lock = match DaemonLock::acquire_for(storage, command) {
        Ok(lock) => Some(lock),
        Err(LockError::Held { holder, .. }) => return Err(anyhow::anyhow!(beside_daemon(&holder))),
        Err(LockError::HeldByRun {
            command, holder, ..
        }) => anyhow::bail!(
            "another `handeye {command}` run ({holder}) moves this cell's arm (storage {}): one \
             at a time; run this again once it has ended",
            storage.display()
        ),
        Err(e) => {
            if handeye::daemon::control::request(storage, "status").is_ok() {
                let holder = format!(
                    "answering on {}",
                    handeye::daemon::control::socket_path(storage).display()
                );
                return Err(anyhow::anyhow!(beside_daemon(&holder)));
            }
            tracing::warn!("{e}; no daemon answers on {}", storage.display());
            None
        }
    };
    Ok(ArmHold {
        _storage: lock,
        _arm: ArmClaim::take(cfg.robot.host, cfg.robot.ports.dashboard)?,
    })
}

/// Stops a command that writes the storage (its lock, history and run folder) before it
/// connects anything when another user owns the storage: one user owns it
/// ([`handeye::storage::owner`]), and the message names this command under `sudo -u <owner>`.
pub(crate) fn storage_owner(cfg: &Config) -> anyhow::Result<()> {
    handeye::storage::owner::check_owner(
        &cfg.storage.dir,
        &handeye::storage::owner::this_command_line(),
    )?;
    Ok(())
}

/// The refusal of a run beside the running daemon (`holder`: `pid 1234`): what to ask the
/// daemon instead (the page's button, the HTTP route), or how to run the command after all.
fn through_the_daemon(cfg: &Config, config: &Path, req: &RunRequest, holder: &str) -> String {
    let (button, route) = match (req.mode, &req.accept_change) {
        (RunMode::Calibrate, Some(_)) => ("Accept remount", "/api/calibrate/accept-change"),
        (RunMode::Calibrate, None) => ("Calibrate", "/api/calibrate"),
        (RunMode::Check, _) => ("Check", "/api/check"),
    };
    let api = super::status::reachable(cfg.daemon.listen);
    // The packaged unit hands the daemon /etc/handeye/token (LoadCredential=) when the
    // configuration names no file.
    let token = cfg
        .daemon
        .token_file
        .as_deref()
        .unwrap_or(Path::new("/etc/handeye/token"));
    let flag = if req.accept_change.is_some() {
        " --accept-change"
    } else {
        ""
    };
    format!(
        "handeye daemon ({holder}) runs this cell (storage {storage}) and moves its arm: this \
         command does not move it beside the daemon, and the daemon would not learn of its \
         result (its drift alarm, the calibration its checks compare with). Ask the daemon for \
         the run: the \
         {button} button on its page (http://{api}/), or POST {route} with the API token \
         (`curl -X POST -H \"Authorization: Bearer $(cat {token})\" http://{api}{route}`), \
         then `handeye status --config {cfg}`; or stop the daemon (`systemctl stop handeye`), \
         run `handeye {mode} --config {cfg}{flag}` again and start the daemon again",
        storage = cfg.storage.dir.display(),
        cfg = config.display(),
        token = token.display(),
        mode = req.mode,
    )
}

/// Who runs this command, for the record of an accepted change: `cli (user alice)` (the user
/// behind `sudo` when there is one).
fn cli_user() -> String {
    let name = ["SUDO_USER", "USER", "LOGNAME"]
        .iter()
        .find_map(|v| std::env::var(v).ok().filter(|s| !s.trim().is_empty()));
    match name {
        Some(n) => format!("cli (user {})", n.trim()),
        // SAFETY: getuid has no preconditions and cannot fail.
        None => format!("cli (uid {})", unsafe { libc::getuid() }),
    }
}

pub(crate) async fn check(
    args: CheckArgs,
    shutdown: CancellationToken,
) -> anyhow::Result<ExitCode> {
    let cfg = Config::load(&args.config)?;
    let req = RunRequest::new(RunMode::Check);
    let _arm = hold_the_arm(&cfg, req.mode.name(), |holder| {
        through_the_daemon(&cfg, &args.config, &req, holder)
    })?;
    finish(execute(&cfg, req, &shutdown, args.json).await?, args.json)
}

fn finish(record: RunRecord, json: bool) -> anyhow::Result<ExitCode> {
    if json {
        // The record, with the word every view uses for it (`drifted`, `within limits`, …).
        let mut doc = serde_json::to_value(&record)?;
        doc["verdict"] = record.verdict().into();
        println!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        print!("{}", summary(&record));
    }
    Ok(ExitCode::from(record.exit_code()))
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
    storage_owner(cfg)?;
    let model = load_model(cfg)?;
    // A dry run writes nothing: it claims no register (it runs beside a daemon that does).
    let registers = if req.dry_run {
        Registers::None
    } else {
        Registers::Configured
    };
    let robot = connect_robot(cfg, &model, registers).await?;
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
    let path = history_path(cfg);
    let opened = tokio::task::spawn_blocking(move || handeye::run::open_history(&path))
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
    let mut s = format!("handeye {} — run {}: {}\n", r.mode, r.run_id, r.verdict());
    for reason in &r.reasons {
        s += &format!("  - {reason}\n");
    }
    for w in &r.warnings {
        s += &format!("  warning: {w}\n");
    }
    if let Some(p) = &r.preflight {
        if let Some(c) = &p.controller {
            s += &format!("  controller: {c}\n");
        }
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
            "  view {}: joints {:.3?} rad; path checked at {} configurations (step ≤ {:.3} rad){}\n",
            i + 1,
            v.joints,
            v.path.samples,
            v.path.max_step_rad,
            match (&v.distance_to_base_m, &v.not_seeing_base) {
                (Some(d), _) => format!("; base at {d:.2} m"),
                (None, Some(why)) => format!("; the camera at the mount prior would not see the base: {why}"),
                (None, None) => String::new(),
            }
        );
    }
    if let Some(f) = &r.forecast {
        let sigma = match (
            f.uncertainty_translation_mm,
            f.uncertainty_rotation_deg,
            &f.uncertainty_note,
        ) {
            (Some(t), Some(d), _) => {
                format!("1σ about {t:.2} mm / {d:.3}° (the views simulated at the mount prior)")
            }
            (_, _, Some(note)) => format!("no σ: {note}"),
            _ => "no σ".to_string(),
        };
        s += &format!(
            "  forecast: {sigma}; the run about {:.0} s (moves {:.1} s at the configured caps)\n",
            f.run_s, f.moves_s
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
            "  uncertainty (1σ): {:.3} mm, {:.4}°{}\n",
            res.uncertainty.translation_mm,
            res.uncertainty.rotation_deg,
            res.uncertainty.workspace_note()
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
