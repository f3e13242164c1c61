use std::net::{IpAddr, Ipv4Addr};
use std::path::{Path, PathBuf};
use std::time::Duration;

use handeye_hal::ur_dh::UrModel;
use handeye_hal::{CaptureSettings, MotionLimits};

use super::*;
use crate::calib::{GateThresholds, Mount};

const MINIMAL: &str = r#"
[robot]
model = "ur5e"
host = "192.168.56.101"

[camera]
backend = "gige"
address = "192.168.1.50"

[mount]
prior = [0.0, -0.08, 0.04, -0.26, 0.0, 0.0]
"#;

fn parse(text: &str) -> Result<Config, ConfigError> {
    Config::from_toml(text, "cell.toml", Path::new("/etc/handeye"))
}

/// Parses `text`, expects an error, and checks it names `key` and `line` in its message.
fn refused(text: &str, key: &str, line: usize) -> ConfigError {
    let err = parse(text).expect_err("refused");
    let msg = err.to_string();
    assert_eq!(err.key(), Some(key), "{msg}");
    assert_eq!(err.line(), Some(line), "{msg}");
    assert!(msg.contains(key), "message names the key: {msg}");
    assert!(
        msg.starts_with(&format!("cell.toml:{line}")),
        "message names file and line: {msg}"
    );
    err
}

/// MINIMAL with `extra` appended to its `[table]` (inserted right after the header).
fn with(table: &str, extra: &str) -> String {
    let header = format!("[{table}]\n");
    if MINIMAL.contains(&header) {
        MINIMAL.replacen(&header, &format!("{header}{extra}\n"), 1)
    } else {
        format!("{MINIMAL}\n{header}{extra}\n")
    }
}

fn line_of(text: &str, needle: &str) -> usize {
    let at = text.find(needle).expect("needle");
    text[..at].matches('\n').count() + 1
}

#[test]
fn every_example_file_loads() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
    let mut loaded = Vec::new();
    for entry in std::fs::read_dir(&dir).expect("config dir") {
        let path = entry.expect("entry").path();
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default();
        // The scan simulator's settings are a different file format (crate::sim::SimSettings).
        if !name.ends_with(".example.toml") || name == "simulator.example.toml" {
            continue;
        }
        let c = Config::load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(c.origin, path.display().to_string());
        assert!(c.storage.dir.is_absolute(), "{name}: storage.dir resolved");
        // Runnable from the checkout (a simulator on loopback): its runs' data stays outside
        // it (issue 38: `calibrate --config config/sim-rig.example.toml` left an untracked
        // folder in config/).
        if c.robot.host.is_loopback() {
            assert!(
                !c.storage.dir.starts_with(&dir),
                "{name}: storage.dir {} is inside the checkout",
                c.storage.dir.display()
            );
        }
        loaded.push(name.to_string());
    }
    loaded.sort();
    for expected in [
        "eye-to-hand.example.toml",
        "handeye.example.toml",
        "sim-rig.example.toml",
        "sim-rig-daemon.example.toml",
        "ur-zivid-exec.example.toml",
    ] {
        assert!(loaded.iter().any(|l| l == expected), "{expected} loaded");
    }
}

/// Fuzz target `config` (hal::fuzz): mutations of every example configuration (and of the
/// eye-to-hand one) — values replaced by extreme numbers, nesting tokens, lines dropped and
/// doubled, keys spliced from another file — validate or are refused with a message naming
/// the file; an error's line, when it has one, is a line of the file.
#[test]
fn fuzz_config() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
    let seeds = [
        "handeye.example.toml",
        "eye-to-hand.example.toml",
        "sim-rig-daemon.example.toml",
        "ur-zivid-exec.example.toml",
    ]
    .iter()
    .map(|n| std::fs::read(dir.join(n)).expect("example"))
    .collect();
    handeye_hal::fuzz::Target::new("config", seeds).run(|b| {
        let text = String::from_utf8_lossy(b);
        match Config::from_toml(&text, "fuzz.toml", &dir) {
            Ok(_) => Ok(()),
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.contains("fuzz.toml"), "{msg}");
                if let Some(line) = e.line() {
                    assert!(
                        line >= 1 && line <= text.lines().count() + 1,
                        "line {line}: {msg}"
                    );
                }
                Err(msg)
            }
        }
    });
}

#[test]
fn the_sim_rig_example_is_sim_rig() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim-rig.example.toml");
    let file = Config::load(&path).expect("loads");
    let code = sim_rig(
        IpAddr::V4(Ipv4Addr::LOCALHOST),
        RobotPorts::UR_STANDARD,
        "127.0.0.2".to_string(),
        file.storage.dir.clone(),
    );
    assert_eq!(
        Config {
            origin: code.origin.clone(),
            ..file
        },
        code
    );
}

#[test]
fn the_full_example_documents_the_defaults() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/handeye.example.toml");
    let c = Config::load(&path).expect("loads");
    assert_eq!(c.robot.limits, defaults::motion_limits());
    assert_eq!(c.robot.ports, defaults::ROBOT_PORTS);
    assert_eq!(c.gate, defaults::gate());
    assert_eq!(c.camera.settle, Duration::from_secs_f64(defaults::SETTLE_S));
    assert_eq!(
        c.check.max_drift_translation_mm,
        defaults::MAX_DRIFT_TRANSLATION_MM
    );
    assert_eq!(
        c.check.max_drift_rotation_deg,
        defaults::MAX_DRIFT_ROTATION_DEG
    );
    assert_eq!(c.views.floor_clearance_m, defaults::FLOOR_CLEARANCE_M);
    // One frame (no gain of more has been measured) and no active obstacle: the example's
    // box is commented out, a placeholder the cell does not have.
    assert_eq!(c.camera.capture.frames, 1);
    assert!(c.views.obstacles.is_empty());
    assert_eq!(
        c.write_back.registers,
        Some(RegisterMap {
            double_start: 24,
            sequence_int: 24
        })
    );
    assert!(matches!(c.views.targets, ViewTargets::Joints(ref j) if j.len() == 1));
}

#[test]
fn defaults_fill_a_minimal_file() {
    let c = parse(MINIMAL).expect("minimal config");
    assert_eq!(c.robot.model, UrModel::Ur5e);
    assert_eq!(c.robot.urdf, None);
    assert_eq!(c.robot.ports, RobotPorts::UR_STANDARD);
    assert_eq!(c.robot.limits, MotionLimits::default());
    assert!(!c.robot.allow_power_on);
    assert_eq!(c.robot.kinematics, KinematicsSource::Controller);
    assert_eq!(c.camera.capture, CaptureSettings::default());
    assert_eq!(c.camera.settle, Duration::from_millis(500));
    assert_eq!(c.mount.mount, Mount::EyeInHand);
    assert_eq!(c.mount.max_camera_flange_distance_m, Some(0.3));
    let prior = c.mount.prior.expect("prior");
    assert!((prior.translation.vector.y + 0.08).abs() < 1e-12);
    assert!((prior.rotation.scaled_axis().x + 0.26).abs() < 1e-12);
    assert_eq!(
        c.views.targets,
        ViewTargets::Auto {
            count: 3,
            min_distance_m: 0.4,
            max_distance_m: 0.8,
            seed: 1
        }
    );
    assert!(c.views.obstacles.is_empty());
    assert!(c.views.return_to_start);
    assert_eq!(c.gate, GateThresholds::default());
    assert!(c.write_back.tcp);
    assert!(c.write_back.files);
    assert_eq!(c.write_back.registers, None);
    assert_eq!(c.storage.dir, PathBuf::from("/etc/handeye/handeye-data"));
    assert!(c.storage.keep_captures);
}

#[test]
fn values_are_taken_and_paths_resolved_against_the_config_directory() {
    let text = r#"
[robot]
model = "UR10e"
host = "::1"
urdf = "robots/ur10e.urdf"
max_joint_speed_rad_s = 3.15
move_timeout_s = 5
kinematics = "nominal"
allow_power_on = true
[robot.ports]
rtde = 40004
[camera]
backend = "exec"
command = ["python3", "{config_dir}/zivid_capture.py", "{out}"]
exposure_us = 2500
[views]
mode = "joints"
joints = [[0, -1.57, 0, -1.57, 0, 0]]
[gate]
max_rmse_mm = 3
[storage]
dir = "/abs/data"
"#;
    let c = Config::from_toml(text, "t.toml", Path::new("/cfg")).expect("valid");
    assert_eq!(c.robot.model, UrModel::Ur10e);
    assert_eq!(c.robot.host, "::1".parse::<IpAddr>().expect("ip"));
    assert_eq!(c.robot.urdf, Some(PathBuf::from("/cfg/robots/ur10e.urdf")));
    assert_eq!(c.robot.limits.max_joint_speed_rad_s, 3.15);
    assert_eq!(c.robot.limits.timeout, Duration::from_secs(5));
    assert_eq!(c.robot.kinematics, KinematicsSource::Nominal);
    assert!(c.robot.allow_power_on);
    assert_eq!(c.robot.ports.rtde, 40004);
    assert_eq!(c.robot.ports.dashboard, 29999);
    assert_eq!(
        c.camera.backend,
        CameraBackend::Exec {
            command: vec![
                "python3".into(),
                "/cfg/zivid_capture.py".into(),
                "{out}".into()
            ],
            timeout: Duration::from_secs(30)
        }
    );
    assert_eq!(c.camera.capture.exposure, Some(Duration::from_micros(2500)));
    assert_eq!(c.gate.max_rmse_mm, 3.0);
    assert_eq!(c.gate.min_coverage, GateThresholds::default().min_coverage);
    assert_eq!(c.storage.dir, PathBuf::from("/abs/data"));

    let files = "[robot]\nmodel = \"ur5e\"\nhost = \"10.0.0.1\"\n[camera]\nbackend = \"file\"\nfiles = [\"a.ply\", \"/b.pcd\"]\n[views]\nmode = \"joints\"\njoints = [[0, -1.57, 0, -1.57, 0, 0]]\n";
    let c = Config::from_toml(files, "t.toml", Path::new("cfg")).expect("valid");
    assert_eq!(
        c.camera.backend,
        CameraBackend::File {
            paths: vec![PathBuf::from("cfg/a.ply"), PathBuf::from("/b.pcd")]
        }
    );
}

#[test]
fn load_resolves_against_the_file_directory_and_names_the_file() {
    let dir = std::env::temp_dir().join(format!("handeye-config-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join("cell.toml");
    std::fs::write(&path, MINIMAL).expect("write");
    let c = Config::load(&path).expect("loads");
    assert_eq!(c.storage.dir, dir.join("handeye-data"));
    std::fs::write(&path, with("robot", "speed = 1")).expect("write");
    let err = Config::load(&path).expect_err("unknown key");
    assert!(
        err.to_string()
            .starts_with(&format!("{}:3:", path.display())),
        "{err}"
    );
    let missing = Config::load(&dir.join("absent.toml")).expect_err("absent");
    assert!(matches!(missing, ConfigError::Read { .. }), "{missing}");
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

#[test]
fn unknown_keys_are_refused_with_key_line_and_allowed_keys() {
    let text = with("robot", "max_speed = 1.0");
    let err = refused(&text, "robot.max_speed", line_of(&text, "max_speed"));
    assert!(matches!(err, ConfigError::UnknownKey { .. }), "{err}");
    assert!(err.to_string().contains("max_joint_speed_rad_s"), "{err}");

    let text = format!("{MINIMAL}\n[robot.ports]\nrtde = 30004\nrdte = 1\n");
    refused(&text, "robot.ports.rdte", line_of(&text, "rdte ="));

    let text = format!("{MINIMAL}\n[viewz]\ncount = 1\n");
    refused(&text, "viewz", line_of(&text, "[viewz]"));

    let text = format!(
        "{MINIMAL}\n[[views.obstacles]]\nname = \"a\"\ncentre_m = [0, 0, 0]\nsize_m = [1, 1, 1]\n[[views.obstacles]]\nname = \"b\"\ncenter_m = [0, 0, 0]\n"
    );
    refused(
        &text,
        "views.obstacles[1].center_m",
        line_of(&text, "center_m"),
    );
}

#[test]
fn wrong_types_are_refused_with_key_and_line() {
    let text = with("robot", "max_joint_speed_rad_s = \"fast\"");
    let err = refused(
        &text,
        "robot.max_joint_speed_rad_s",
        line_of(&text, "max_joint"),
    );
    assert!(matches!(err, ConfigError::WrongType { .. }), "{err}");
    assert!(err.to_string().contains("expected a number"), "{err}");

    let text = with(
        "views",
        "mode = \"joints\"\njoints = [\n  [0, 0, 0, 0, 0, 0],\n  [0, 0, 0, 0, \"x\", 0],\n]",
    );
    refused(&text, "views.joints[1][4]", line_of(&text, "\"x\""));

    let text = with("views", "mode = \"joints\"\njoints = [[0, 0, 0, 0, 0]]");
    let err = refused(&text, "views.joints[0]", line_of(&text, "joints ="));
    assert!(err.to_string().contains("length 6"), "{err}");

    let text = with("mount", "type = \"on-the-arm\"");
    let err = refused(&text, "mount.type", line_of(&text, "type ="));
    assert!(err.to_string().contains("eye-in-hand"), "{err}");

    let text = with("write_back", "tcp = 1");
    refused(&text, "write_back.tcp", line_of(&text, "tcp ="));
}

#[test]
fn missing_required_keys_are_named() {
    let text = MINIMAL.replace("host = \"192.168.56.101\"\n", "");
    let err = refused(&text, "robot.host", line_of(&text, "[robot]"));
    assert!(matches!(err, ConfigError::MissingKey { .. }), "{err}");
    let text = MINIMAL.replace(
        "[camera]\nbackend = \"gige\"\naddress = \"192.168.1.50\"\n",
        "",
    );
    let err = parse(&text).expect_err("no camera");
    assert_eq!(err.key(), Some("camera"), "{err}");
}

#[test]
fn syntax_errors_carry_line_and_column() {
    let text = with("robot", "max_joint_speed_rad_s = ");
    let err = parse(&text).expect_err("syntax");
    let line = line_of(&text, "max_joint");
    assert!(
        matches!(err, ConfigError::Syntax { line: l, .. } if l == line),
        "{err}"
    );
    assert!(
        err.to_string().starts_with(&format!("cell.toml:{line}:")),
        "{err}"
    );
}

#[test]
fn speeds_must_be_finite_positive_and_sane() {
    for (value, what) in [
        ("nan", "a finite number"),
        ("inf", "a finite number"),
        ("-0.5", "0 < value <= 3.15 rad/s"),
        ("0", "0 < value <= 3.15 rad/s"),
        ("100", "0 < value <= 3.15 rad/s"),
    ] {
        let text = with("robot", &format!("max_joint_speed_rad_s = {value}"));
        let err = refused(
            &text,
            "robot.max_joint_speed_rad_s",
            line_of(&text, "max_joint"),
        );
        assert!(matches!(err, ConfigError::Invalid { .. }), "{err}");
        assert!(err.to_string().contains(what), "{value}: {err}");
        assert!(err.to_string().contains("0 < value <= 3.15 rad/s"), "{err}");
    }
    let text = with("camera", "settle_s = -1");
    let err = refused(&text, "camera.settle_s", line_of(&text, "settle_s"));
    assert!(err.to_string().contains("0 <= value <= 60 s"), "{err}");
    let text = with("robot", "move_timeout_s = 1e9");
    refused(
        &text,
        "robot.move_timeout_s",
        line_of(&text, "move_timeout_s"),
    );
    let text = with("camera", "frames = 0");
    refused(&text, "camera.frames", line_of(&text, "frames"));
    let text = with("gate", "min_coverage = 1.5");
    refused(&text, "gate.min_coverage", line_of(&text, "min_coverage"));
    let text = format!("{MINIMAL}\n[robot.ports]\nrtde = 70000\n");
    refused(&text, "robot.ports.rtde", line_of(&text, "rtde"));
    let text = format!(
        "{MINIMAL}\n[[views.obstacles]]\nname = \"table\"\ncentre_m = [0, 0, 0]\nsize_m = [1, -1, 1]\n"
    );
    refused(
        &text,
        "views.obstacles[0].size_m[1]",
        line_of(&text, "size_m"),
    );
    let text = with("views", "mode = \"joints\"\njoints = [[0, 0, 7, 0, 0, 0]]");
    refused(&text, "views.joints[0][2]", line_of(&text, "joints ="));
}

#[test]
fn eye_to_hand_cannot_write_the_tcp() {
    let text = format!(
        "{}\n[write_back]\ntcp = true\n",
        MINIMAL.replace("[mount]\n", "[mount]\ntype = \"eye-to-hand\"\n")
    );
    let err = refused(&text, "write_back.tcp", line_of(&text, "tcp = true"));
    assert!(err.to_string().contains("not a TCP"), "{err}");
    // Without the key, eye-to-hand simply does not write the TCP.
    let text = MINIMAL.replace("[mount]\n", "[mount]\ntype = \"eye-to-hand\"\n");
    let c = parse(&text).expect("valid");
    assert!(!c.write_back.tcp);
    assert_eq!(c.mount.max_camera_flange_distance_m, None);
}

#[test]
fn auto_views_of_an_eye_in_hand_camera_need_a_prior() {
    let text = MINIMAL.replace("prior = [0.0, -0.08, 0.04, -0.26, 0.0, 0.0]\n", "");
    let err = refused(&text, "mount.prior", line_of(&text, "[mount]"));
    let msg = err.to_string();
    assert!(
        msg.contains("mount.prior") && msg.contains("joints"),
        "{msg}"
    );
    // Joint targets need none.
    let text =
        format!("{text}\n[views]\nmode = \"joints\"\njoints = [[0, -1.57, 0, -1.57, 0, 0]]\n");
    parse(&text).expect("joint targets need no prior");
    // A prior farther from the flange than the camera may be is refused.
    let text = MINIMAL.replace("0.0, -0.08, 0.04", "0.0, -0.8, 0.04");
    refused(&text, "mount.prior", line_of(&text, "prior"));
}

#[test]
fn registers_must_fit_the_register_bank() {
    for (double_start, sequence_int, bad) in [
        (43, 0, "write_back.registers.double_start"),
        (-1, 0, "write_back.registers.double_start"),
        (0, 48, "write_back.registers.sequence_int"),
    ] {
        let text = format!(
            "{MINIMAL}\n[write_back.registers]\ndouble_start = {double_start}\nsequence_int = {sequence_int}\n"
        );
        let needle = bad.rsplit('.').next().expect("leaf");
        let err = refused(&text, bad, line_of(&text, needle));
        assert!(err.to_string().contains("expected"), "{err}");
    }
    let text = format!("{MINIMAL}\n[write_back.registers]\ndouble_start = 42\nsequence_int = 47\n");
    let c = parse(&text).expect("valid");
    assert_eq!(
        c.write_back.registers,
        Some(RegisterMap {
            double_start: 42,
            sequence_int: 47
        })
    );
}

#[test]
fn camera_backends_need_their_keys_and_refuse_the_others() {
    let text = MINIMAL.replace(
        "backend = \"gige\"\naddress = \"192.168.1.50\"",
        "backend = \"file\"\nfiles = []",
    );
    let err = refused(&text, "camera.files", line_of(&text, "files"));
    assert!(err.to_string().contains("at least one file"), "{err}");

    let text = MINIMAL.replace("\"192.168.1.50\"", "\"camera.local\"");
    let err = refused(&text, "camera.address", line_of(&text, "address"));
    assert!(err.to_string().contains("IP:PORT"), "{err}");
    let text = MINIMAL.replace("\"192.168.1.50\"", "\"192.168.1.50:3956\"");
    parse(&text).expect("IP:PORT");

    let text = MINIMAL.replace("backend = \"gige\"", "backend = \"exec\"");
    refused(&text, "camera.address", line_of(&text, "address"));
    let text = MINIMAL.replace(
        "backend = \"gige\"\naddress = \"192.168.1.50\"",
        "backend = \"exec\"\ncommand = [\"\"]",
    );
    refused(&text, "camera.command", line_of(&text, "command"));
    let text = MINIMAL.replace("address = \"192.168.1.50\"\n", "");
    refused(&text, "camera.address", line_of(&text, "backend"));

    // GenTL: the producer resolves against the config's directory, both keys are optional
    // (GENICAM_GENTL64_PATH, the first device), and the other backends' keys are refused.
    let gentl = |keys: &str| {
        MINIMAL.replace(
            "backend = \"gige\"\naddress = \"192.168.1.50\"",
            &format!("backend = \"gentl\"\n{keys}"),
        )
    };
    let c = parse(&gentl("producer = \"zivid.cti\"\ndevice = \" 2024A \"")).expect("gentl");
    let CameraBackend::Gentl {
        producer,
        device,
        call_timeout,
    } = c.camera.backend
    else {
        panic!("gentl backend");
    };
    assert!(producer.is_some_and(|p| p.ends_with("zivid.cti") && p.is_absolute()));
    assert_eq!(device.as_deref(), Some("2024A"));
    assert_eq!(call_timeout, std::time::Duration::from_secs(10));
    assert_eq!(
        parse(&gentl("")).expect("defaults").camera.backend,
        CameraBackend::Gentl {
            producer: None,
            device: None,
            call_timeout: std::time::Duration::from_secs(10),
        }
    );
    let c = parse(&gentl("call_timeout_s = 2.5")).expect("call timeout");
    assert!(matches!(
        c.camera.backend,
        CameraBackend::Gentl { call_timeout, .. } if call_timeout == std::time::Duration::from_millis(2500)
    ));
    let text = gentl("call_timeout_s = 0");
    refused(
        &text,
        "camera.call_timeout_s",
        line_of(&text, "call_timeout_s"),
    );
    let text = gentl("address = \"192.168.1.50\"");
    refused(&text, "camera.address", line_of(&text, "address"));
    let text = gentl("device = \" \"");
    refused(&text, "camera.device", line_of(&text, "device"));
    let text = MINIMAL.replace(
        "address = \"192.168.1.50\"",
        "address = \"192.168.1.50\"\ndevice = \"x\"",
    );
    refused(&text, "camera.device", line_of(&text, "device"));
}

#[test]
fn bad_hosts_and_models_are_refused() {
    for host in ["\"robot.local\"", "\"192.168.1.300\"", "\"\""] {
        let text = MINIMAL.replace("\"192.168.56.101\"", host);
        let err = refused(&text, "robot.host", line_of(&text, "host"));
        assert!(err.to_string().contains("IPv4 or IPv6"), "{err}");
    }
    let text = MINIMAL.replace("\"ur5e\"", "\"ur6\"");
    let err = refused(&text, "robot.model", line_of(&text, "model"));
    assert!(err.to_string().contains("ur10e"), "{err}");
}

#[test]
fn view_keys_are_checked_against_the_mode() {
    let text = with("views", "min_distance_m = 0.9\nmax_distance_m = 0.5");
    refused(
        &text,
        "views.min_distance_m",
        line_of(&text, "min_distance_m"),
    );
    let text = with("views", "joints = [[0, 0, 0, 0, 0, 0]]");
    let err = refused(&text, "views.joints", line_of(&text, "joints"));
    assert!(
        err.to_string().contains("mode = \\\"joints\\\"")
            || err.to_string().contains("mode = \"joints\""),
        "{err}"
    );
    let text = with("views", "mode = \"joints\"");
    refused(&text, "views.joints", line_of(&text, "mode ="));
    let text = with(
        "views",
        "mode = \"joints\"\njoints = [[0, 0, 0, 0, 0, 0]]\ncount = 2",
    );
    refused(&text, "views.count", line_of(&text, "count"));
    let text = with("views", "count = 11");
    refused(&text, "views.count", line_of(&text, "count"));
}

#[test]
fn calendar_checks_and_the_busy_policy_are_read_and_checked() {
    let text = with(
        "daemon",
        "check_at = [\"Mon-Fri 06:00\", \"22:30\"]\nwhen_busy = \"queue\"",
    );
    let cfg = parse(&text).expect("valid");
    let shown: Vec<String> = cfg.daemon.check_at.iter().map(|t| t.to_string()).collect();
    assert_eq!(shown, ["Mon,Tue,Wed,Thu,Fri 06:00", "22:30"]);
    assert_eq!(cfg.daemon.when_busy, WhenBusy::Queue);
    let base = parse(MINIMAL).expect("valid");
    assert!(base.daemon.check_at.is_empty());
    assert_eq!(base.daemon.when_busy, WhenBusy::Refuse);

    let text = with("daemon", "check_at = [\"06:00\",\n  \"25:00\"]");
    let e = refused(&text, "daemon.check_at[1]", line_of(&text, "\"25:00\""));
    assert!(e.to_string().contains("HH:MM"), "{e}");
    let text = with("daemon", "when_busy = \"wait\"");
    let e = refused(&text, "daemon.when_busy", line_of(&text, "when_busy"));
    assert!(e.to_string().contains("\"queue\""), "{e}");
}

#[test]
fn the_calibration_file_is_resolved_against_the_config_directory() {
    let cfg = parse(&with("robot", "calibration = \"cal/my_robot.yaml\"")).expect("valid");
    assert_eq!(
        cfg.robot.calibration,
        Some(PathBuf::from("/etc/handeye/cal/my_robot.yaml"))
    );
    assert_eq!(parse(MINIMAL).expect("valid").robot.calibration, None);
}

/// Issue 23: configuration inputs that would crash or hang a reader are clear errors, quickly:
/// 70 000 nested arrays (the key locator recursed past the stack), `/dev/zero` (never ends),
/// a FIFO (blocks forever with no writer).
#[test]
fn issue_23_hostile_config_files_are_refused_quickly() {
    let t0 = std::time::Instant::now();
    let deep = format!(
        "[views]\njoints = {}{}\n",
        "[".repeat(70_000),
        "]".repeat(70_000)
    );
    // On a thread with a small stack, as a worker's: depth must not depend on stack size.
    let refused = std::thread::Builder::new()
        .stack_size(2 << 20)
        .spawn(move || parse(&deep).is_err())
        .expect("thread")
        .join()
        .expect("no stack overflow");
    assert!(refused);
    let e = Config::load(Path::new("/dev/zero"))
        .expect_err("not a regular file")
        .to_string();
    assert!(e.contains("/dev/zero"), "{e}");
    let dir = std::env::temp_dir().join(format!("handeye-config-fifo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let fifo = dir.join("cell.toml");
    let _ = std::fs::remove_file(&fifo);
    let status = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .expect("mkfifo runs");
    assert!(status.success());
    let e = Config::load(&fifo).expect_err("a FIFO").to_string();
    assert!(e.contains("FIFO"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
}

/// Issue 23: a config cannot ask for unbounded work: at most [`super::MAX_VIEW_TARGETS`] joint
/// targets and [`super::MAX_OBSTACLES`] obstacles, each refusal naming the key and the limit.
#[test]
fn issue_23_view_targets_and_obstacles_are_capped() {
    let target = "[0, -1.57, 0, -1.57, 0, 0]";
    let joints = |n: usize| {
        format!(
            "{MINIMAL}\n[views]\nmode = \"joints\"\njoints = [{}]\n",
            vec![target; n].join(", ")
        )
    };
    assert!(parse(&joints(super::MAX_VIEW_TARGETS)).is_ok());
    let e = parse(&joints(100_000)).expect_err("too many targets");
    assert_eq!(e.key(), Some("views.joints"), "{e}");
    assert!(e.to_string().contains("at most 32"), "{e}");
    let obstacles = |n: usize| {
        let one =
            "[[views.obstacles]]\nname = \"box\"\ncentre_m = [1, 1, 0]\nsize_m = [0.1, 0.1, 0.1]\n";
        format!("{MINIMAL}\n{}", one.repeat(n))
    };
    assert!(parse(&obstacles(super::MAX_OBSTACLES)).is_ok());
    let e = parse(&obstacles(super::MAX_OBSTACLES + 1)).expect_err("too many obstacles");
    assert_eq!(e.key(), Some("views.obstacles"), "{e}");
    assert!(e.to_string().contains("at most 256"), "{e}");
}

/// `camera.sensor` names how the camera measures depth, and the run's registration is tuned for
/// it; structured light unless given. An unknown class is refused with the key, its line and
/// the classes there are.
#[test]
fn the_camera_sensor_class_is_read_and_checked() {
    use crate::geometry::SensorClass;
    assert_eq!(
        parse(MINIMAL).expect("minimal").camera.sensor,
        SensorClass::StructuredLight
    );
    let text = with("camera", "sensor = \"active-stereo\"");
    assert_eq!(
        parse(&text).expect("active stereo").camera.sensor,
        SensorClass::ActiveStereo
    );
    let text = with("camera", "sensor = \"lidar\"");
    let err = refused(&text, "camera.sensor", line_of(&text, "sensor"));
    assert!(
        err.to_string().contains("active-stereo") && err.to_string().contains("time-of-flight"),
        "{err}"
    );
}

/// Issue 45: the gate's defaults follow the camera's sensor class (a time-of-flight camera's
/// 1σ limit is 1.3 mm: its wrist scans' error / σ reaches 1.6 at p95, and at 1.5 mm the bench
/// accepted scans 2.2–2.3 mm off), and a `[gate]` key the user sets still wins.
#[test]
fn issue_45_the_gate_defaults_to_the_sensor_class_and_gate_keys_override() {
    use crate::geometry::SensorClass;
    let sl = parse(MINIMAL).expect("minimal");
    assert_eq!(sl.gate.max_uncertainty_translation_mm, 1.5);
    let text = with("camera", "sensor = \"time-of-flight\"");
    let tof = parse(&text).expect("time of flight");
    assert_eq!(
        tof.gate,
        GateThresholds::for_sensor(SensorClass::TimeOfFlight)
    );
    assert_eq!(tof.gate.max_uncertainty_translation_mm, 1.3);
    // Every other threshold is structured light's.
    assert_eq!(
        GateThresholds {
            max_uncertainty_translation_mm: sl.gate.max_uncertainty_translation_mm,
            ..tof.gate
        },
        sl.gate
    );
    let text = format!("{text}\n[gate]\nmax_uncertainty_translation_mm = 2.0\n");
    let own = parse(&text).expect("the user's gate");
    assert_eq!(own.gate.max_uncertainty_translation_mm, 2.0);
    assert_eq!(
        own.gate.max_uncertainty_rotation_deg,
        tof.gate.max_uncertainty_rotation_deg
    );
}

/// Issue 45: a drift check's limits follow the camera's sensor class too: a time-of-flight
/// camera's checks of an unmoved camera spread to 1.20 mm / 0.10°, and at structured light's
/// 0.5 mm / 0.05° 34 of 536 simulated checks raised a false alarm; a `[check]` key the user
/// sets still wins.
#[test]
fn issue_45_drift_limits_default_to_the_sensor_class() {
    use crate::geometry::SensorClass;
    let sl = parse(MINIMAL).expect("minimal");
    assert_eq!(
        (
            sl.check.max_drift_translation_mm,
            sl.check.max_drift_rotation_deg
        ),
        (0.5, 0.05)
    );
    let text = with("camera", "sensor = \"time-of-flight\"");
    let tof = parse(&text).expect("time of flight");
    assert_eq!(
        (
            tof.check.max_drift_translation_mm,
            tof.check.max_drift_rotation_deg
        ),
        defaults::drift_for(SensorClass::TimeOfFlight)
    );
    assert!(tof.check.max_drift_translation_mm > 1.2 && tof.check.max_drift_rotation_deg > 0.10);
    let stereo = parse(&with("camera", "sensor = \"active-stereo\"")).expect("active stereo");
    assert_eq!(
        Some((
            stereo.check.max_drift_translation_mm,
            stereo.check.max_drift_rotation_deg
        )),
        stereo.gate.max_split_half
    );
    let text = format!("{text}\n[check]\nmax_drift_rotation_deg = 0.3\n");
    let own = parse(&text).expect("the user's check");
    assert_eq!(own.check.max_drift_rotation_deg, 0.3);
    assert_eq!(
        own.check.max_drift_translation_mm,
        tof.check.max_drift_translation_mm
    );
}

/// A value with control characters is echoed escaped, never raw into the message (a tab in
/// `daemon.listen` and `daemon.startup`, as the config fuzzer found).
#[test]
fn values_are_echoed_escaped_in_the_errors() {
    // TOML basic strings: `\t` a tab, `\u001b` an escape.
    for (key, value) in [
        ("listen", r#""127.0.0.1:8\t650""#),
        ("startup", r#""check\u001b[2J""#),
    ] {
        let text = format!("{MINIMAL}\n[daemon]\n{key} = {value}\n");
        let msg = parse(&text).expect_err("refused").to_string();
        assert!(msg.contains(&format!("daemon.{key}")), "{msg}");
        assert!(!msg.chars().any(char::is_control), "{msg:?}");
    }
}

/// A value the schema refuses is quoted back safe for a terminal (found by `fuzz_config`: a tab
/// inside an unknown variant name came back raw).
#[test]
fn a_refused_value_is_echoed_without_control_characters() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
    for text in [
        "[robot]\nmodel=\"\"\nhost=\"\"\nkinematics=\"\t\"",
        "[robot]\nmodel=\"ur5e\"\nhost=\"127.0.0.1\"\nkinematics=\"control\\u001b[31mler\"",
    ] {
        let e = Config::from_toml(text, "cell.toml", &dir).expect_err(text);
        let msg = e.to_string();
        assert!(msg.contains("robot.kinematics"), "{msg}");
        assert!(!msg.chars().any(|c| c.is_control()), "{msg:?}");
    }
}

/// Issue 44: `camera.user_set` and `[camera.features]` (in the order written: a map would sort
/// them, and a selector must come before what it selects); the features handeye sets itself
/// and values that are no feature value are refused, naming the key.
#[test]
fn issue_44_camera_features_in_order_and_user_set() {
    use handeye_hal::FeatureValue as V;
    let text = format!(
        "{MINIMAL}\n[camera.features]\nScan3dCoordinateSelector = \"CoordinateC\"\nScan3dInvalidDataValue = 0.5\nDepthMax = 1500\nComponentEnable = true\nAnother = \"x\"\n"
    )
    .replacen("[camera]\n", "[camera]\nuser_set = \"UserSet1\"\n", 1);
    let c = parse(&text).expect("loads").camera.settings;
    assert_eq!(c.user_set.as_deref(), Some("UserSet1"));
    assert_eq!(
        c.features,
        [
            (
                "Scan3dCoordinateSelector".into(),
                V::Text("CoordinateC".into())
            ),
            ("Scan3dInvalidDataValue".into(), V::Float(0.5)),
            ("DepthMax".into(), V::Int(1500)),
            ("ComponentEnable".into(), V::Bool(true)),
            ("Another".into(), V::Text("x".into())),
        ]
    );
    let t = format!("{MINIMAL}\n[camera.features]\nTriggerMode = \"On\"\n");
    let e = refused(&t, "camera.features", line_of(&t, "[camera.features]")).to_string();
    assert!(e.contains("camera.trigger"), "{e}");
    let t = format!("{MINIMAL}\n[camera.features]\nWidth = [1, 2]\n");
    let e = parse(&t).expect_err("an array").to_string();
    assert!(
        e.contains("camera.features.Width") && e.contains("array"),
        "{e}"
    );
    let t = with("camera", "user_set = \" \"");
    refused(&t, "camera.user_set", line_of(&t, "user_set"));
    let t = MINIMAL.replace(
        "backend = \"gige\"\naddress = \"192.168.1.50\"",
        "backend = \"file\"\nfiles = [\"a.ply\"]",
    ) + "\n[camera.features]\nWidth = 3\n";
    let e = parse(&t).expect_err("file backend").to_string();
    assert!(
        e.contains("camera.features is not used with backend = \"file\""),
        "{e}"
    );
}

/// Issue 45 (active stereo): the class's gate holds what a RealSense-class camera can (σ 2.5 mm
/// at the robot base / 0.25°, see-through 12 %, split half 5 mm / 0.5°); a `[gate]` key the user
/// sets still wins, the split half's too; structured light checks no split half unless asked.
#[test]
fn issue_45_active_stereo_gate_defaults_and_the_split_half_keys() {
    use crate::geometry::SensorClass;
    let sl = parse(MINIMAL).expect("minimal");
    assert_eq!(sl.gate.max_split_half, None);
    let text = with("camera", "sensor = \"active-stereo\"");
    let stereo = parse(&text).expect("active stereo");
    assert_eq!(
        stereo.gate,
        GateThresholds::for_sensor(SensorClass::ActiveStereo)
    );
    assert_eq!(
        (
            stereo.gate.max_uncertainty_translation_mm,
            stereo.gate.max_uncertainty_rotation_deg,
            stereo.gate.max_free_space_violations,
            stereo.gate.max_split_half
        ),
        (2.5, 0.25, 0.12, Some((5.0, 0.5)))
    );
    let own = parse(&format!("{text}\n[gate]\nmax_split_half_deg = 1.0\n")).expect("own");
    assert_eq!(own.gate.max_split_half, Some((5.0, 1.0)));
    let asked = parse(&format!("{MINIMAL}\n[gate]\nmax_split_half_mm = 2.0\n")).expect("asked");
    assert_eq!(asked.gate.max_split_half, Some((2.0, 180.0)));
}
