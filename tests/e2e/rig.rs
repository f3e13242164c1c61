//! The whole simulated rig over real protocols: `handeye sim robot` (UR dashboard, RTDE,
//! script), `handeye sim camera --robot` (GigE Vision, following the robot over RTDE), and the
//! CLI clients against them.

use std::f64::consts::FRAC_PI_2;
use std::path::Path;
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Vector3};

use handeye::model::RobotModel;
use handeye::plan::{ViewConstraints, ViewPlanner};
use handeye::sim::Intrinsics;

use crate::support::{
    csv, iso, pose_arg, pose_error, run, secs, shared, sim_robot, Daemon, Output, TempDir,
};

/// Where `handeye sim robot` starts.
const INITIAL_Q: [f64; 6] = [0.0, -FRAC_PI_2, FRAC_PI_2, -FRAC_PI_2, -FRAC_PI_2, 0.0];

/// A view of the base for `mount`, the one of a few candidates nearest the initial pose (short
/// move).
fn view_near_start(model: &RobotModel, mount: Isometry3<f64>, seed: u64) -> Vec<f64> {
    let planner = ViewPlanner::new(
        model,
        mount,
        Intrinsics::compact_1280x960(),
        ViewConstraints::default(),
    );
    let reach = |q: &[f64]| {
        q.iter()
            .zip(INITIAL_Q)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    };
    planner
        .generate(6, seed)
        .expect("views of the base")
        .into_iter()
        .min_by(|a, b| reach(a).total_cmp(&reach(b)))
        .expect("at least one view")
}

fn move_robot(ip: &str, q: &[f64]) -> Output {
    run(
        &[
            "robot",
            "--host",
            ip,
            "move",
            "--joints",
            &csv(q),
            "--speed",
            "1.0",
            "--accel",
            "2.0",
            "--move-timeout-s",
            "30",
        ],
        secs(40),
    )
}

fn status_joints(ip: &str) -> Vec<f64> {
    let out = run(&["robot", "--host", ip, "status", "--json"], secs(15)).success();
    serde_json::from_value(out.json()["joint_positions_rad"].clone())
        .unwrap_or_else(|e| panic!("joint_positions_rad ({e}):\n{out}"))
}

/// A simulated camera following the robot at `robot_ip`, ready to stream.
fn sim_camera(dir: &TempDir, ip: &str, robot_ip: &str, mount: &str, size: (u32, u32)) -> Daemon {
    let (w, h) = (size.0.to_string(), size.1.to_string());
    let mut cam = Daemon::start(
        dir,
        &format!("sim-camera-{ip}"),
        &[
            "sim", "camera", "--bind", ip, "--robot", robot_ip, "--mount", mount, "--width", &w,
            "--height", &h,
        ],
    );
    cam.wait_for_log("simulated GigE Vision 3D camera on", secs(30));
    cam
}

fn capture(ip: &str, out: &Path, timeout_ms: u32) -> Output {
    run(
        &[
            "camera",
            "capture",
            "--gige",
            ip,
            "--frames",
            "1",
            "--out",
            &out.to_string_lossy(),
            "--json",
            "--frame-timeout-ms",
            &timeout_ms.to_string(),
        ],
        secs(30),
    )
}

#[test]
fn full_rig_over_real_protocols() {
    let Some(shared) = shared("full_rig_over_real_protocols") else {
        return;
    };
    let dir = TempDir::new("rig");
    let urdf = shared.join("robots/ur/ur5e/ur5e.urdf");
    let model = RobotModel::load(&urdf).expect("ur5e loads");
    let mount = Isometry3::new(
        Vector3::new(0.005, -0.08, 0.045),
        Vector3::new(-0.25, 0.03, -0.02),
    );
    let view = view_near_start(&model, mount, 3);

    let robot = sim_robot(&dir, "127.0.0.110", &["--powered"]);
    // Issue 24: a move into the floor (the upper arm 57° below horizontal) is refused by the
    // motion guard before anything moves; the arm model comes from the controller.
    let before = status_joints("127.0.0.110");
    let out = move_robot("127.0.0.110", &[0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
    assert_eq!(out.code(), 2, "{out}\n{}", robot.log());
    assert!(
        out.stderr.contains("the motion guard refused the move")
            && out.stderr.contains("mounting plane")
            && out.stderr.contains("nothing moved"),
        "{out}"
    );
    let after = status_joints("127.0.0.110");
    let moved = before
        .iter()
        .zip(&after)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(moved < 1e-9, "moved {moved} rad");
    let out = move_robot("127.0.0.110", &view);
    assert!(out.status.success(), "{out}\n{}", robot.log());
    let mut camera = sim_camera(
        &dir,
        "127.0.0.111",
        "127.0.0.110",
        &pose_arg(&mount),
        (1280, 960),
    );
    camera.wait_for_log("following the robot", secs(10));

    let ply = dir.join("rig.ply");
    let out = capture("127.0.0.111", &ply, 10_000);
    assert!(out.status.success(), "{out}\n{}", camera.log());
    let doc = out.json();
    assert_eq!(doc["frames"], 1, "{out}");
    assert_eq!(
        (doc["width"].as_u64(), doc["height"].as_u64()),
        (Some(1280), Some(960))
    );
    let valid = doc["valid_points"][0].as_u64().expect("valid_points");
    assert!(
        valid as f64 > 0.3 * 1280.0 * 960.0,
        "only {valid} valid points\n{out}"
    );
    let cloud = handeye::cloud::read_cloud(&ply).expect("rig.ply reads back");
    assert_eq!(cloud.valid_count() as u64, valid);

    let joints = status_joints("127.0.0.110");
    assert_eq!(joints.len(), 6);
    let reach = joints
        .iter()
        .zip(&view)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        reach < 2e-3,
        "the robot is not at the view: {joints:?} vs {view:?}"
    );

    let out = run(
        &[
            "solve",
            "--robot",
            &urdf.to_string_lossy(),
            "--joints",
            &csv(&joints),
            "--scan",
            &ply.to_string_lossy(),
            "--json",
        ],
        secs(60),
    );
    assert_eq!(out.code(), 0, "{out}");
    let doc = out.json();
    assert_eq!(doc["outcome"], "accepted", "{out}");
    let (mm, deg) = pose_error(&iso(&doc["flange_from_camera"]), &mount);
    eprintln!("mount recovered over the simulated rig: {mm:.3} mm / {deg:.4}° from the truth");
    assert!(
        mm < 2.0 && deg < 0.5,
        "mount recovered over the rig is {mm:.3} mm / {deg:.4}° off\n{out}"
    );
}

#[test]
fn sim_camera_reports_a_lost_robot_and_reconnects() {
    if shared("sim_camera_reports_a_lost_robot_and_reconnects").is_none() {
        return;
    }
    let dir = TempDir::new("reconnect");
    let robot = sim_robot(&dir, "127.0.0.113", &["--powered"]);
    let mut camera = sim_camera(
        &dir,
        "127.0.0.114",
        "127.0.0.113",
        "0,-0.08,0.04,-0.26,0,0",
        (320, 240),
    );
    camera.wait_for_log("following the robot", secs(10));
    let ply = dir.join("frame.ply");
    let out = capture("127.0.0.114", &ply, 5_000);
    assert!(out.status.success(), "{out}\n{}", camera.log());

    // Robot gone: no frames (never a stale pose), and the camera says why.
    robot.stop();
    std::thread::sleep(Duration::from_millis(800));
    let out = capture("127.0.0.114", &ply, 1_500);
    assert!(!out.status.success(), "captured without a robot:\n{out}");
    let log = camera.log();
    assert!(
        log.contains("127.0.0.113") && log.contains("not rendering a stale pose"),
        "{log}"
    );

    // Robot back on the same address: the camera reconnects and streams again.
    let _robot = sim_robot(&dir, "127.0.0.113", &["--powered"]);
    let deadline = Instant::now() + secs(15);
    loop {
        let out = capture("127.0.0.114", &ply, 2_000);
        if out.status.success() {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "no frames after the robot came back:\n{out}\n{}",
            camera.log()
        );
    }
}

#[test]
fn sim_robot_refuses_motion_in_local_mode() {
    if shared("sim_robot_refuses_motion_in_local_mode").is_none() {
        return;
    }
    let dir = TempDir::new("local");
    let _robot = sim_robot(&dir, "127.0.0.112", &["--powered", "--local-control"]);
    let mut target = INITIAL_Q;
    target[0] += 0.3;
    let out = move_robot("127.0.0.112", &target);
    assert!(!out.status.success(), "moved in local control:\n{out}");
    assert!(
        out.stderr.to_lowercase().contains("remote control"),
        "the message should say to enable Remote Control:\n{out}"
    );
    let q = status_joints("127.0.0.112");
    let moved = q
        .iter()
        .zip(INITIAL_Q)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(moved < 1e-3, "the arm moved: {q:?}");
}

/// Issue 42 (item 7): `sim rig --truth` tells the mount the camera renders: with a mount file
/// that holds a pose, the file's (it was `--mount`'s, which the camera never used). Addresses
/// 127.0.0.195 (controller) and 127.0.0.196 (camera).
#[test]
fn issue_42_the_truth_is_the_mount_files_mount() {
    let Some(_) = shared("issue_42_the_truth_is_the_mount_files_mount") else {
        return;
    };
    let dir = TempDir::new("truth-mount-file");
    let in_file = Isometry3::new(
        Vector3::new(0.01, -0.07, 0.05),
        Vector3::new(-0.2, 0.05, 0.1),
    );
    let mount_file = dir.join("mount.txt");
    std::fs::write(&mount_file, crate::support::pose_arg(&in_file)).expect("mount file");
    let truth = dir.join("truth.json");
    let mut rig = Daemon::start(
        &dir,
        "rig",
        &[
            "sim",
            "rig",
            "--robot-bind",
            "127.0.0.195",
            "--camera-bind",
            "127.0.0.196",
            "--mount",
            "0,-0.08,0.04,-0.26,0,0",
            "--mount-file",
            mount_file.to_str().expect("utf-8"),
            "--truth",
            truth.to_str().expect("utf-8"),
        ],
    );
    rig.wait_for_log("simulated rig", secs(30));
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&truth).expect("truth")).expect("json");
    let told = crate::support::iso(&doc["flange_from_camera"]);
    let (mm, deg) = crate::support::pose_error(&told, &in_file);
    assert!(
        mm < 1e-3 && deg < 1e-3,
        "the truth is not the file's mount: {doc}"
    );
    rig.stop();
}
