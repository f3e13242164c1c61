//! Running the `handeye` binary as child processes: every wait has a deadline, long-running
//! simulators are killed on drop, and their logs go to files shown when a test fails.

use std::io::Read;
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Vector3};

/// The `handeye` binary under test.
pub(crate) const BIN: &str = env!("CARGO_BIN_EXE_handeye");

/// `../shared` beside the repository, or `None` (after printing SKIP) when it is absent.
/// Panics instead when env `CI` is set: CI must run every scenario.
pub(crate) fn shared(test: &str) -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    if dir.join("robots").is_dir() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{test}: ../shared/robots is missing (CI is set, so this is a failure)"
    );
    skip(&format!(
        "SKIP {test}: ../shared/robots not found beside the repository"
    ));
    None
}

/// Prints a SKIP line where the person running the tests sees it: straight to the process's
/// stderr, which the test harness does not capture (it captures `eprintln!`, shown only for
/// failing tests, so a passing skip would be silent).
pub(crate) fn skip(line: &str) {
    let line = line.strip_prefix("SKIP ").unwrap_or(line);
    let (test, reason) = line.split_once(": ").unwrap_or(("e2e", line));
    // Counted in the registry .ci/run prints after the tests (handeye::skips).
    handeye::skips::record(test, reason);
}

/// A directory removed on drop.
pub(crate) struct TempDir(PathBuf);

impl TempDir {
    /// A fresh directory named after the test.
    pub(crate) fn new(test: &str) -> Self {
        let p = std::env::temp_dir().join(format!("handeye-e2e-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).expect("create temp dir");
        Self(p)
    }

    /// A path inside it.
    pub(crate) fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A finished command.
#[derive(Debug)]
pub(crate) struct Output {
    /// The command line, for messages.
    pub(crate) cmdline: String,
    /// How it ended.
    pub(crate) status: ExitStatus,
    /// Its stdout.
    pub(crate) stdout: String,
    /// Its stderr.
    pub(crate) stderr: String,
}

impl Output {
    /// Exit code (-1 when killed by a signal).
    pub(crate) fn code(&self) -> i32 {
        self.status.code().unwrap_or(-1)
    }

    /// Panics with the whole output unless the exit code is 0.
    pub(crate) fn success(self) -> Self {
        assert!(self.status.success(), "{self}");
        self
    }

    /// stdout parsed as JSON.
    pub(crate) fn json(&self) -> serde_json::Value {
        serde_json::from_str(&self.stdout)
            .unwrap_or_else(|e| panic!("stdout is not JSON ({e}):\n{self}"))
    }
}

impl std::fmt::Display for Output {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "`{}` exited with {}\n--- stdout\n{}\n--- stderr\n{}",
            self.cmdline, self.status, self.stdout, self.stderr
        )
    }
}

fn command(args: &[&str]) -> Command {
    let mut c = Command::new(BIN);
    c.args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env(
            "HANDEYE_ROBOTS",
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/robots"),
        )
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null());
    c
}

fn cmdline(args: &[&str]) -> String {
    format!("handeye {}", args.join(" "))
}

/// `handeye history list --json` for the cell `config`: its runs, newest first.
pub(crate) fn history(config: &Path) -> serde_json::Value {
    let out = run(
        &[
            "history",
            "--config",
            config.to_str().expect("utf-8"),
            "list",
            "--json",
        ],
        secs(20),
    )
    .success();
    out.json()
}

/// Runs `handeye ARGS` to completion; kills it and panics after `limit`.
pub(crate) fn run(args: &[&str], limit: Duration) -> Output {
    run_env(args, &[], limit)
}

/// [`run`] with more environment variables.
pub(crate) fn run_env(args: &[&str], env: &[(&str, &str)], limit: Duration) -> Output {
    let mut child = command(args)
        .envs(env.iter().copied())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn handeye");
    let drain = |r: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut s = String::new();
            if let Some(mut r) = r {
                let _ = r.read_to_string(&mut s);
            }
            s
        })
    };
    let out = drain(
        child
            .stdout
            .take()
            .map(|r| Box::new(r) as Box<dyn Read + Send>),
    );
    let err = drain(
        child
            .stderr
            .take()
            .map(|r| Box::new(r) as Box<dyn Read + Send>),
    );
    let deadline = Instant::now() + limit;
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "`{}` did not finish within {limit:?}; killed",
                cmdline(args)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Output {
        cmdline: cmdline(args),
        status,
        stdout: out.join().unwrap_or_default(),
        stderr: err.join().unwrap_or_default(),
    }
}

/// A long-running `handeye` (a simulator), killed on drop; stderr goes to a log file.
pub(crate) struct Daemon {
    child: Child,
    log: PathBuf,
    name: String,
}

impl Daemon {
    /// Starts `handeye ARGS` with its stderr in `dir/<name>.log`.
    pub(crate) fn start(dir: &TempDir, name: &str, args: &[&str]) -> Self {
        Self::spawn(dir, name, command(args))
    }

    /// Like [`Self::start`], with more environment variables.
    pub(crate) fn start_env(
        dir: &TempDir,
        name: &str,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        let mut c = command(args);
        c.envs(env.iter().copied());
        Self::spawn(dir, name, c)
    }

    /// Like [`Self::start`], without `RUST_LOG`: the log as a journal shows it by default.
    pub(crate) fn start_with_default_log(dir: &TempDir, name: &str, args: &[&str]) -> Self {
        let mut c = command(args);
        c.env_remove("RUST_LOG");
        Self::spawn(dir, name, c)
    }

    fn spawn(dir: &TempDir, name: &str, mut command: Command) -> Self {
        let log = dir.join(&format!("{name}.log"));
        let file = std::fs::File::create(&log).expect("log file");
        let child = command
            .stdout(Stdio::null())
            .stderr(file)
            .spawn()
            .expect("spawn handeye");
        Self {
            child,
            log,
            name: name.to_string(),
        }
    }

    /// Its process id.
    pub(crate) fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Its log so far.
    pub(crate) fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Waits until the log contains `needle`; panics (with the log) if it exits or `limit`
    /// passes first.
    pub(crate) fn wait_for_log(&mut self, needle: &str, limit: Duration) {
        let deadline = Instant::now() + limit;
        loop {
            if self.log().contains(needle) {
                return;
            }
            if let Ok(Some(s)) = self.child.try_wait() {
                panic!(
                    "{} exited ({s}) before logging `{needle}`:\n{}",
                    self.name,
                    self.log()
                );
            }
            assert!(
                Instant::now() < deadline,
                "{} did not log `{needle}` within {limit:?}:\n{}",
                self.name,
                self.log()
            );
            std::thread::sleep(Duration::from_millis(30));
        }
    }

    /// Waits until a TCP port accepts connections.
    pub(crate) fn wait_for_port(&mut self, addr: SocketAddr, limit: Duration) {
        let deadline = Instant::now() + limit;
        loop {
            if TcpStream::connect_timeout(&addr, Duration::from_millis(200)).is_ok() {
                return;
            }
            if let Ok(Some(s)) = self.child.try_wait() {
                panic!(
                    "{} exited ({s}) before listening on {addr}:\n{}",
                    self.name,
                    self.log()
                );
            }
            assert!(
                Instant::now() < deadline,
                "{} not listening on {addr} within {limit:?}:\n{}",
                self.name,
                self.log()
            );
            std::thread::sleep(Duration::from_millis(30));
        }
    }

    /// Sends `signal` (e.g. `libc::SIGTERM`, `libc::SIGKILL`) to it.
    pub(crate) fn signal(&self, signal: i32) {
        let pid = i32::try_from(self.child.id()).expect("pid fits in i32");
        // SAFETY: kill(2) on our own child's pid has no memory effects.
        let r = unsafe { libc::kill(pid, signal) };
        assert_eq!(r, 0, "kill({pid}, {signal}) failed");
    }

    /// Waits until it exits; panics (with the log) if that takes longer than `limit`.
    pub(crate) fn wait_exit(&mut self, limit: Duration) -> ExitStatus {
        let deadline = Instant::now() + limit;
        loop {
            if let Ok(Some(s)) = self.child.try_wait() {
                return s;
            }
            assert!(
                Instant::now() < deadline,
                "{} still running {limit:?} after it was told to stop:\n{}",
                self.name,
                self.log()
            );
            std::thread::sleep(Duration::from_millis(30));
        }
    }

    /// Kills it now and waits for it to end.
    pub(crate) fn stop(mut self) -> String {
        self.kill();
        self.log()
    }

    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        self.kill();
    }
}

/// A simulated UR controller on `ip` (standard ports), powered and ready to move.
pub(crate) fn sim_robot(dir: &TempDir, ip: &str, extra: &[&str]) -> Daemon {
    let mut args = vec!["sim", "robot", "--model", "ur5e", "--bind", ip];
    args.extend_from_slice(extra);
    let mut d = Daemon::start(dir, &format!("sim-robot-{ip}"), &args);
    let addr = SocketAddr::new(ip.parse().expect("ip"), 30004);
    d.wait_for_port(addr, Duration::from_secs(10));
    d
}

/// Comma-separated numbers with full precision.
pub(crate) fn csv(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// `x,y,z,rx,ry,rz` of an isometry (metres, rotation vector).
pub(crate) fn pose_arg(t: &Isometry3<f64>) -> String {
    let p = t.translation.vector;
    let r = t.rotation.scaled_axis();
    csv(&[p.x, p.y, p.z, r.x, r.y, r.z])
}

/// A 4×4 row-major JSON matrix as an isometry.
pub(crate) fn iso(v: &serde_json::Value) -> Isometry3<f64> {
    let m: [[f64; 4]; 4] =
        serde_json::from_value(v.clone()).unwrap_or_else(|e| panic!("not a 4x4 matrix ({e}): {v}"));
    handeye::frames::from_row_major(&m).unwrap_or_else(|| panic!("not a rigid transform: {v}"))
}

/// Translation (mm) and rotation (degrees) between two poses.
pub(crate) fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    (
        (a.translation.vector - b.translation.vector).norm() * 1e3,
        d.rotation.angle().to_degrees(),
    )
}

/// Seconds as a `Duration` (short to write in tests).
pub(crate) fn secs(s: u64) -> Duration {
    Duration::from_secs(s)
}

/// The rig's true camera mount in these tests, ~1 cm and ~3° from the configured prior.
pub(crate) fn true_mount() -> Isometry3<f64> {
    Isometry3::new(
        Vector3::new(0.008, -0.074, 0.047),
        Vector3::new(-0.22, 0.03, 0.02),
    )
}

/// A rig on `robot_ip`/`camera_ip` with the truth in `dir/truth.json` and the mount re-read
/// from `dir/mount.txt`.
pub(crate) fn start_rig(dir: &TempDir, robot_ip: &str, camera_ip: &str, extra: &[&str]) -> Daemon {
    std::fs::write(dir.join("mount.txt"), pose_arg(&true_mount())).expect("mount file");
    let truth = dir.join("truth.json");
    let mount_file = dir.join("mount.txt");
    let mount = pose_arg(&true_mount());
    let mut args = vec![
        "sim",
        "rig",
        "--robot-bind",
        robot_ip,
        "--camera-bind",
        camera_ip,
        "--mount",
        &mount,
        "--truth",
        truth.to_str().expect("utf-8 path"),
        "--mount-file",
        mount_file.to_str().expect("utf-8 path"),
    ];
    args.extend_from_slice(extra);
    let mut d = Daemon::start(dir, &format!("sim-rig-{robot_ip}"), &args);
    d.wait_for_log("simulated rig", secs(30));
    d
}

/// `$REPO/.venv/bin/python` with ur-rtde, or `None` (panics under CI).
pub(crate) fn python() -> Option<PathBuf> {
    let py = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    if py.exists() {
        return Some(py);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{} is missing in CI: run .ci/install.d/ur-rtde.sh",
        py.display()
    );
    skip(&format!(
        "SKIP {} (the ur-rtde part): {} not found",
        std::thread::current().name().unwrap_or("an e2e test"),
        py.display()
    ));
    None
}

pub(crate) fn ur_pose(p: &[f64]) -> Isometry3<f64> {
    Isometry3::new(
        Vector3::new(p[0], p[1], p[2]),
        Vector3::new(p[3], p[4], p[5]),
    )
}

pub(crate) fn joints(ip: &str) -> Vec<f64> {
    let out = run(&["robot", "--host", ip, "status", "--json"], secs(15)).success();
    serde_json::from_value(out.json()["joint_positions_rad"].clone()).expect("joints")
}

pub(crate) fn max_change(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// A configuration (`dir/handeye.toml`) for the rig at `robot_ip`/`camera_ip`: a UR5e at
/// 1 rad/s, the GigE camera (`camera_extra`: more `[camera]` keys), the default mount as the
/// prior, the TCP written back, results in `dir/data`; `tail` (more tables) goes last.
pub(crate) fn rig_config(
    dir: &TempDir,
    robot_ip: &str,
    camera_ip: &str,
    camera_extra: &str,
    tail: &str,
) -> PathBuf {
    let text = format!(
        r#"
[robot]
model = "ur5e"
host = "{robot_ip}"
max_joint_speed_rad_s = 1.0
max_joint_accel_rad_s2 = 2.0

[camera]
backend = "gige"
address = "{camera_ip}"
settle_s = 0.2
{camera_extra}

[mount]
type = "eye-in-hand"
prior = [0.0, -0.08, 0.04, -0.26, 0.0, 0.0]

[write_back]
tcp = true

[storage]
dir = "data"

{tail}
"#
    );
    let path = dir.join("handeye.toml");
    std::fs::write(&path, text).expect("config");
    path
}
