//! Runs that reach the arm: accepted and written back, stopped by a protective stop, a dropped
//! connection or a silent camera, a check measuring drift, a scan without the robot.

use super::*;

#[tokio::test]
async fn an_accepted_run_writes_back_and_returns_to_the_start() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("accepted");
    let cfg = test_config(&storage.0, f.view);
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    assert_eq!(
        robot.read_int_register(SEQUENCE_INT).await.expect("read"),
        0
    );

    let t = Instant::now();
    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    eprintln!("accepted run: {:.0} ms", t.elapsed().as_secs_f64() * 1e3);
    assert_eq!(record.outcome, Outcome::Accepted, "{:?}", record.reasons);
    assert_eq!(record.failed_stage, None);
    assert_eq!(record.exit_code(), 0);

    // The result is the true mount.
    let est = estimate(&record);
    let (mm, deg) = pose_difference(&f.mount, &est);
    eprintln!("accepted run: error {mm:.3} mm {deg:.4} deg");
    assert!(
        mm < crate::bench::PASS_TRANSLATION_MM && deg < crate::bench::PASS_ROTATION_DEG,
        "error {mm:.3} mm {deg:.4} deg"
    );

    // The record's `ur_pose` is the result, the same array a `UrPose` serializes to.
    let result = record.result.as_ref().expect("a result");
    let ur = UrPose::from(result.ur_pose);
    assert!(ur.approx_eq(&UrPose::from(&est), 1e-9, 1e-9), "{ur}");
    assert_eq!(
        serde_json::to_value(result).expect("json")["ur_pose"],
        serde_json::to_value(ur).expect("json")
    );

    // Written back: the TCP and the registers hold the result, the sequence went 0 -> 1.
    assert!(close(&robot.tcp(), &est, 1e-9), "TCP {:?}", robot.tcp());
    let p = UrPose::from(&est).values();
    for (k, want) in p.iter().enumerate() {
        let got = robot
            .read_double_register(DOUBLE_START + k as u32)
            .await
            .expect("read");
        assert!((got - want).abs() < 1e-9, "register {k}: {got} vs {want}");
    }
    assert_eq!(
        robot.read_int_register(SEQUENCE_INT).await.expect("read"),
        1
    );
    let targets: Vec<&str> = record.written.iter().map(|w| w.target.name()).collect();
    assert_eq!(targets, ["tcp", "registers", "files"]);

    // To the view and back, nothing else.
    assert_eq!(robot.moves(), vec![f.view.to_vec(), HOME.to_vec()]);
    assert!(record.returned_to_start);
    assert_eq!(camera.captures(), 1);

    // Posed by the controller's kinematics.
    let preflight = record.preflight.as_ref().expect("preflight recorded");
    assert_eq!(preflight.kinematics.source, KinematicsOrigin::Controller);
    assert_eq!(preflight.kinematics.dh, Some(f.dh));
    assert_eq!(preflight.start_joints, HOME.to_vec());

    // The files: current result, the run's record, the capture description and the raw scan.
    let dir = &storage.0;
    assert!(dir.join(CURRENT_DIR).join("result.json").is_file());
    let run_dir = dir.join(RUNS_DIR).join(&record.run_id);
    // The record reads back as the typed record (`handeye history`, the page).
    let text = std::fs::read_to_string(run_dir.join("record.json")).expect("record.json");
    let back: RunRecord = serde_json::from_str(&text).expect("a record reads back");
    assert_eq!(
        (back.run_id.as_str(), back.outcome, back.written.len()),
        (record.run_id.as_str(), record.outcome, record.written.len())
    );
    assert_eq!(
        back.preflight.map(|p| p.kinematics.source),
        Some(KinematicsOrigin::Controller)
    );
    let capture = PathBuf::from(record.capture_file.as_ref().expect("capture file kept"));
    assert!(capture.is_file(), "{}", capture.display());
    assert!(capture.starts_with(&run_dir));
    let frame = record.captures[0].frames[0]
        .path
        .as_ref()
        .expect("raw frame kept");
    assert!(
        frame.ends_with(".ply") && Path::new(frame).is_file(),
        "{frame}"
    );

    let t = record.timings_ms;
    for (name, ms) in t.stages().into_iter().chain([("total", t.total)]) {
        assert!(ms.is_finite() && ms >= 0.0, "timing {name} = {ms}");
    }
    assert!(t.total >= t.register && t.settle >= 10.0, "{t:?}");

    // A second calibration on the same cell: the sequence goes 1 -> 2.
    let again = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    assert_eq!(again.outcome, Outcome::Accepted, "{:?}", again.reasons);
    assert_ne!(again.run_id, record.run_id);
    assert_eq!(
        robot.read_int_register(SEQUENCE_INT).await.expect("read"),
        2
    );
    assert_eq!(robot.moves().len(), 4);
}

#[tokio::test]
async fn a_protective_stop_at_the_first_move_aborts_without_writing_or_moving_again() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("pstop");
    let cfg = test_config(&storage.0, f.view);
    let robot = calibrated_robot(f);
    robot.protective_stop_at_move(0);
    let camera = FakeCamera::new(vec![f.scan.clone()]);

    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    assert_eq!(record.outcome, Outcome::Aborted, "{:?}", record.reasons);
    assert_eq!(record.failed_stage, Some(Stage::Move));
    assert!(
        reasons(&record).contains("protective stop"),
        "{:?}",
        record.reasons
    );
    assert_nothing_written(&record, &robot, &storage.0).await;
    // Never auto-resume: the one refused move and nothing after it.
    assert_eq!(robot.moves(), vec![f.view.to_vec()]);
    assert!(!record.returned_to_start);
    assert_eq!(camera.captures(), 0);
    assert_eq!(record.exit_code(), 2);
}

#[tokio::test]
async fn a_connection_that_drops_and_comes_back_mid_run_aborts_without_writing() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("relink");
    let cfg = test_config(&storage.0, f.view);
    let robot = calibrated_robot(f);
    // The driver reconnects during the move: the move itself reports success.
    robot.reconnect_at_move(0);
    let camera = FakeCamera::new(vec![f.scan.clone()]);

    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    assert_eq!(record.outcome, Outcome::Aborted, "{:?}", record.reasons);
    assert_eq!(record.failed_stage, Some(Stage::Move));
    assert!(
        reasons(&record).contains("connection to the robot dropped"),
        "{:?}",
        record.reasons
    );
    assert_eq!(camera.captures(), 0, "no capture on a link that dropped");
    assert_nothing_written(&record, &robot, &storage.0).await;
}

#[tokio::test]
async fn a_camera_that_stops_answering_fails_the_capture_and_the_arm_returns() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("camera");
    let cfg = test_config(&storage.0, f.view);
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    camera.stop_answering_after(0);

    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    assert_eq!(record.outcome, Outcome::Error, "{:?}", record.reasons);
    assert_eq!(record.failed_stage, Some(Stage::Capture));
    let why = reasons(&record);
    assert!(
        why.contains("camera failed") && why.contains("check the camera"),
        "{why}"
    );
    assert_nothing_written(&record, &robot, &storage.0).await;
    assert!(record.result.is_none());
    // The arm itself is fine: it goes back where it started.
    assert_eq!(robot.moves(), vec![f.view.to_vec(), HOME.to_vec()]);
    assert!(record.returned_to_start);
}

#[tokio::test]
async fn a_check_reports_drift_and_writes_nothing() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("check");
    let mut cfg = test_config(&storage.0, f.view);
    let robot = calibrated_robot(f);
    let calibrated = calibrate_accepted(&robot, f, &cfg).await;
    let tcp = robot.tcp();
    let current = std::fs::read(storage.0.join(CURRENT_DIR).join("result.json")).expect("current");

    // Later: the same view, other sensor noise.
    let camera = FakeCamera::new(vec![f.rescan.clone()]);
    let check = start(&robot, &camera, f, &cfg, RunMode::Check, false).await;
    assert_eq!(check.outcome, Outcome::Accepted, "{:?}", check.reasons);
    let drift = check.drift.as_ref().expect("a drift record");
    eprintln!(
        "check drift {:.4} mm {:.5} deg",
        drift.translation_mm, drift.rotation_deg
    );
    assert!(
        drift.reference.contains(&calibrated.run_id),
        "{}",
        drift.reference
    );
    assert!(drift.translation_mm < 0.3, "{drift:?}");
    assert!(!drift.drifted, "{drift:?}");
    assert_eq!(check.exit_code(), 0);
    // Nothing written: TCP, sequence and the current calibration unchanged.
    assert!(check.written.is_empty(), "{:?}", check.written);
    assert_eq!(robot.tcp(), tcp);
    assert_eq!(
        robot.read_int_register(SEQUENCE_INT).await.expect("read"),
        1
    );
    let after = std::fs::read(storage.0.join(CURRENT_DIR).join("result.json")).expect("current");
    assert_eq!(after, current, "a check replaced the current calibration");
    assert!(check.returned_to_start);

    // The same measurement against a threshold no real result meets: drifted, exit code 1.
    cfg.check.max_drift_translation_mm = 1e-6;
    let strict = start(&robot, &camera, f, &cfg, RunMode::Check, false).await;
    assert_eq!(strict.outcome, Outcome::Accepted, "{:?}", strict.reasons);
    let drift = strict.drift.as_ref().expect("a drift record");
    assert!(drift.drifted, "{drift:?}");
    assert_eq!(strict.exit_code(), 1);
    assert!(strict.written.is_empty());
    assert_eq!(
        robot.read_int_register(SEQUENCE_INT).await.expect("read"),
        1
    );
}

#[tokio::test]
async fn a_scan_without_the_robot_writes_nothing_and_the_arm_returns() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("no-robot");
    let cfg = test_config(&storage.0, f.view);
    let robot = calibrated_robot(f);
    // A wall 0.6 m in front of the camera, nothing else.
    let wall: Vec<Point3<f32>> = (0..160)
        .flat_map(|i| (0..120).map(move |j| (i, j)))
        .map(|(i, j)| Point3::new(-0.4 + 0.005 * i as f32, -0.3 + 0.005 * j as f32, 0.6))
        .collect();
    let camera = FakeCamera::new(vec![PointCloud::from_points(wall)]);

    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    eprintln!(
        "a scan of a wall: {} at {:?}: {:?}",
        record.outcome, record.failed_stage, record.reasons
    );
    assert_eq!(record.outcome, Outcome::Error, "{:?}", record.reasons);
    assert_eq!(record.failed_stage, Some(Stage::Register));
    assert_eq!(record.exit_code(), 2);
    assert_nothing_written(&record, &robot, &storage.0).await;
    assert_eq!(robot.moves(), vec![f.view.to_vec(), HOME.to_vec()]);
    assert!(record.returned_to_start);
}
