//! The exec camera against stand-in commands (`sh` scripts): success, failure, timeout,
//! garbage, nothing written, cancellation.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use nalgebra::Point3;

use super::*;
use crate::camera::PrivateDir;
use crate::cloud::{write_ply, PlyEncoding};

/// `sh -c SCRIPT sh {out} {frame}`: the script sees the output path as `$1`, the frame as `$2`.
fn sh(script: &str, timeout: Duration) -> ExecCamera {
    let argv = ["sh", "-c", script, "sh", "{out}", "{frame}"]
        .map(String::from)
        .to_vec();
    ExecCamera::new(argv, timeout).expect("camera")
}

fn frames(n: u32) -> CaptureSettings {
    CaptureSettings {
        frames: n,
        ..CaptureSettings::default()
    }
}

/// Whether a process is still running (a zombie waiting for init to reap it is not).
fn is_running(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        // The state follows the parenthesised command name.
        Ok(stat) => stat
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().next())
            .is_some_and(|state| state != "Z" && state != "X"),
        Err(_) => false,
    }
}

/// Reads a pid the stand-in wrote, waiting briefly for the file.
fn read_pid(path: &Path) -> u32 {
    for _ in 0..200 {
        if let Ok(s) = std::fs::read_to_string(path) {
            if let Ok(pid) = s.trim().parse() {
                return pid;
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    panic!(
        "the stand-in command never wrote its pid to {}",
        path.display()
    );
}

/// Waits (bounded) until `pid` no longer runs; returns whether it stopped.
fn stops(pid: u32) -> bool {
    for _ in 0..500 {
        if !is_running(pid) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    false
}

const PLY_SCRIPT: &str = r#"
[ "$HANDEYE_OUTPUT" = "$1" ] || { echo "HANDEYE_OUTPUT differs from {out}" >&2; exit 9; }
[ "$HANDEYE_FRAME" = "$2" ] || { echo "HANDEYE_FRAME differs from {frame}" >&2; exit 9; }
[ "$HANDEYE_EXPOSURE_US" = "6500" ] || { echo "no exposure" >&2; exit 9; }
printf 'ply\nformat ascii 1.0\ncomment unit mm\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n' > "$1"
printf '10 20 %d\nnan nan nan\n' "$(( ($2 + 1) * 1000 ))" >> "$1"
echo "captured frame $2" >&2
"#;

#[tokio::test]
async fn runs_once_per_frame_and_reads_each_output() {
    let log_dir = PrivateDir::new("test-exec").expect("temp dir");
    let log = log_dir.path().join("dirs.log");
    // Also record where the output went and that directory's mode.
    let script = format!(
        "{PLY_SCRIPT}\nd=$(dirname \"$1\"); echo \"$d $(stat -c %a \"$d\")\" >> '{}'",
        log.display()
    );
    let cam = sh(&script, Duration::from_secs(10));
    let settings = CaptureSettings {
        frames: 3,
        exposure: Some(Duration::from_micros(6500)),
        ..CaptureSettings::default()
    };
    let clouds = cam.capture(&settings).await.expect("capture");
    assert_eq!(clouds.len(), 3);
    for (i, c) in clouds.iter().enumerate() {
        // Millimetres in the file (`comment unit mm`), metres here; frame i wrote z = i + 1 m.
        assert_eq!(c.points.len(), 2);
        assert!((c.points[0] - Point3::new(0.01, 0.02, i as f32 + 1.0)).norm() < 1e-6);
        assert!(c.points[1].x.is_nan());
    }
    let lines = std::fs::read_to_string(&log).expect("log");
    let lines: Vec<&str> = lines.lines().collect();
    assert_eq!(lines.len(), 3, "one invocation per frame: {lines:?}");
    let (dir, mode) = lines[0].split_once(' ').expect("dir and mode");
    assert!(
        lines.iter().all(|l| l.starts_with(dir)),
        "one directory per capture"
    );
    assert_eq!(mode, "700", "private temp dir");
    assert!(
        !Path::new(dir).exists(),
        "temp dir {dir} removed after the capture"
    );

    let info = cam.info().await.expect("info");
    assert_eq!((info.vendor.as_str(), info.model.as_str()), ("exec", "sh"));
}

#[tokio::test]
async fn passes_an_organized_binary_cloud_through() {
    let dir = PrivateDir::new("test-exec").expect("temp dir");
    let src = dir.path().join("recorded.ply");
    let points: Vec<Point3<f32>> = (0..12)
        .map(|i| Point3::new(i as f32 * 0.01, 0.0, 0.8))
        .collect();
    let cloud = PointCloud {
        width: 4,
        height: 3,
        points,
        intensity: None,
        confidence: None,
    };
    write_ply(&src, &cloud, PlyEncoding::BinaryLittleEndian).expect("write");
    let argv = vec![
        "cp".to_owned(),
        src.display().to_string(),
        "{out}".to_owned(),
    ];
    let cam = ExecCamera::new(argv, Duration::from_secs(10)).expect("camera");
    let clouds = cam.capture_frames(&frames(1)).await.expect("capture");
    assert_eq!(clouds, vec![cloud]);
}

#[tokio::test]
async fn non_zero_exit_names_the_code_and_quotes_stderr() {
    let cam = sh(
        "echo 'Connecting to camera' >&2; echo 'zivid: no camera with serial 2020C0DE' >&2; exit 3",
        Duration::from_secs(10),
    );
    let err = cam.capture_frames(&frames(2)).await.expect_err("fails");
    match &err {
        CameraError::Exit {
            code,
            frame,
            stderr,
            ..
        } => {
            assert_eq!(*code, Some(3));
            assert_eq!(*frame, 0);
            assert!(
                stderr.contains("no camera with serial 2020C0DE"),
                "{stderr}"
            );
        }
        other => panic!("unexpected {other:?}"),
    }
    let msg = err.to_string();
    assert!(msg.contains("exit code 3"), "{msg}");
    assert!(msg.contains("no camera with serial 2020C0DE"), "{msg}");
    assert!(msg.contains("sh -c"), "names the command: {msg}");
}

#[tokio::test]
async fn timeout_kills_the_process_group() {
    let dir = PrivateDir::new("test-exec").expect("temp dir");
    let pid_file = dir.path().join("sleeper.pid");
    // The sleeper is a grandchild: only a process-group kill ends it.
    let script = format!(
        "sleep 30 & echo $! > '{}'; echo 'waiting for the camera' >&2; wait",
        pid_file.display()
    );
    let cam = sh(&script, Duration::from_millis(1500));
    let started = Instant::now();
    let err = cam.capture_frames(&frames(1)).await.expect_err("times out");
    let elapsed = started.elapsed();
    match &err {
        CameraError::Timeout {
            timeout, stderr, ..
        } => {
            assert_eq!(*timeout, Duration::from_millis(1500));
            assert!(stderr.contains("waiting for the camera"), "{stderr}");
        }
        other => panic!("unexpected {other:?}"),
    }
    // Not a speed check: the sleeper would have kept us 30 s had it not been killed.
    assert!(elapsed < Duration::from_secs(20), "{elapsed:?}");
    let pid = read_pid(&pid_file);
    assert!(stops(pid), "the command's child {pid} still runs");
    assert!(err.to_string().contains("was killed"), "{err}");
}

#[tokio::test]
async fn garbage_output_is_a_parse_error() {
    let cam = sh(
        "echo 'this is not a point cloud' > \"$1\"",
        Duration::from_secs(10),
    );
    let err = cam.capture_frames(&frames(1)).await.expect_err("garbage");
    assert!(
        matches!(
            &err,
            CameraError::BadOutput {
                source: crate::cloud::CloudError::NoMagic { .. },
                ..
            }
        ),
        "{err:?}"
    );
    let chain = format!("{:#}", anyhow::Error::new(HalError::from(err)));
    assert!(chain.starts_with("exec camera failed: "), "{chain}");
    assert!(chain.contains("not a point-cloud file"), "{chain}");

    // A PLY header that promises more than the file holds.
    let cam = sh(
        "printf 'ply\\nformat binary_little_endian 1.0\\nelement vertex 1000\\nproperty float x\\nproperty float y\\nproperty float z\\nend_header\\n' > \"$1\"",
        Duration::from_secs(10),
    );
    let err = cam.capture_frames(&frames(1)).await.expect_err("short");
    assert!(matches!(&err, CameraError::BadOutput { .. }), "{err:?}");
}

#[tokio::test]
async fn writing_nothing_is_an_error() {
    let cam = sh("echo 'saved' >&2; exit 0", Duration::from_secs(10));
    let err = cam.capture_frames(&frames(1)).await.expect_err("nothing");
    match &err {
        CameraError::NoOutput { stderr, path, .. } => {
            assert!(stderr.contains("saved"));
            assert!(path.ends_with("frame_0.ply"));
        }
        other => panic!("unexpected {other:?}"),
    }
    assert!(err.to_string().contains("HANDEYE_OUTPUT"), "{err}");
}

#[tokio::test]
async fn a_background_process_holding_stderr_does_not_hang_the_capture() {
    // The command exits at once but leaves a process holding its stderr for 3 s.
    let script = format!("(sleep 3 &) ; {PLY_SCRIPT}");
    let cam = sh(&script, Duration::from_secs(10));
    let settings = CaptureSettings {
        frames: 1,
        exposure: Some(Duration::from_micros(6500)),
        ..CaptureSettings::default()
    };
    let clouds = cam.capture_frames(&settings).await.expect("capture");
    assert_eq!(clouds.len(), 1);
}

#[tokio::test]
async fn dropping_the_capture_kills_the_command() {
    let dir = PrivateDir::new("test-exec").expect("temp dir");
    let pid_file = dir.path().join("sleeper.pid");
    let script = format!("echo $$ > '{}'; exec sleep 30", pid_file.display());
    let cam = sh(&script, Duration::from_secs(60));
    let settings = frames(1);
    let capture = cam.capture_frames(&settings);
    let pid = tokio::select! {
        _ = capture => panic!("the capture cannot finish"),
        pid = tokio::task::spawn_blocking(move || read_pid(&pid_file)) => pid.expect("pid"),
    };
    // `capture` was dropped by select!.
    assert!(
        stops(pid),
        "the command {pid} still runs after its capture was dropped"
    );
}

#[tokio::test]
async fn missing_program_and_bad_configs_are_clear_errors() {
    let cam = ExecCamera::new(
        vec!["/nonexistent/zivid_capture".to_owned()],
        Duration::from_secs(1),
    )
    .expect("camera");
    let err = cam.capture_frames(&frames(1)).await.expect_err("missing");
    assert!(matches!(err, CameraError::Spawn { .. }), "{err:?}");
    assert!(
        err.to_string().contains("/nonexistent/zivid_capture"),
        "{err}"
    );

    assert!(matches!(
        ExecCamera::new(Vec::new(), Duration::from_secs(1)),
        Err(CameraError::EmptyCommand)
    ));
    assert!(matches!(
        ExecCamera::new(vec!["true".to_owned()], Duration::ZERO),
        Err(CameraError::ZeroTimeout)
    ));
    // Zero frames: nothing runs (the program does not even exist).
    assert!(cam
        .capture_frames(&frames(0))
        .await
        .expect("zero")
        .is_empty());
}

#[test]
fn placeholders_are_replaced_everywhere_in_an_argument() {
    let out = Path::new("/tmp/x/frame_2.ply");
    assert_eq!(
        substitute("--out={out}", out, 2),
        OsString::from("--out=/tmp/x/frame_2.ply")
    );
    assert_eq!(
        substitute("{out}.{frame}.{out}", out, 7),
        OsString::from("/tmp/x/frame_2.ply.7./tmp/x/frame_2.ply")
    );
    assert_eq!(substitute("plain", out, 0), OsString::from("plain"));
}

/// `config/zivid_capture.py` cannot run here (no Zivid SDK, no camera); at least it must be
/// valid Python.
#[test]
fn zivid_example_script_is_valid_python() {
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/zivid_capture.py");
    assert!(script.exists(), "{} is missing", script.display());
    let python = std::env::var_os("HANDEYE_PYTHON").unwrap_or_else(|| "python3".into());
    let status = Command::new(&python)
        .args([
            "-c",
            "import sys; compile(open(sys.argv[1]).read(), sys.argv[1], 'exec')",
        ])
        .arg(&script)
        .status();
    match status {
        Ok(s) => assert!(s.success(), "{} does not compile", script.display()),
        Err(e) => {
            assert!(
                std::env::var_os("CI").is_none(),
                "python3 is needed in CI to check the Zivid script: {e}"
            );
            crate::skips::record(
                "camera::exec::tests (the Zivid script)",
                &format!("cannot run {python:?} ({e})"),
            );
        }
    }
}
