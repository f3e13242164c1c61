//! The whole run over the hal fakes: a factory-calibrated UR5e (`FakeRobot` reporting the
//! forward kinematics of its calibrated DH set) and a camera replaying a simulated scan of the
//! base taken from the configured view, so the scan, the reported flange pose and the
//! controller's kinematics agree as on a real arm. Each test asserts what an operator relies
//! on: what moved, what was written, what the record says and why.

use std::f64::consts::FRAC_PI_2;
use std::future::Future;
use std::net::{IpAddr, Ipv4Addr};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use handeye_hal::fake::{FakeCamera, FakeRobot};
use handeye_hal::ur_dh::{DhParams, PhysicalArm, UrModel};
use handeye_hal::{
    CameraInfo, CaptureSettings, ControllerKinematics, DepthCamera, HalError, PointCloud, Robot,
    RobotMode, RobotStatus, SafetyMode, UrPose,
};
use nalgebra::{Isometry3, Point3, Vector3};
use tokio::sync::Notify;
use tokio_util::sync::CancellationToken;

use super::{
    pose_difference, run, KinematicsOrigin, Outcome, RunMode, RunRecord, RunRequest, Silent, Stage,
};
use crate::config::{self, Config, RobotPorts, ViewTargets};
use crate::frames::from_row_major;
use crate::model::RobotModel;
use crate::plan::{ViewConstraints, ViewPlanner};
use crate::sim::{simulate_scan, Intrinsics, Placement, ScanRequest, SimSettings};
use crate::storage::{CURRENT_DIR, RUNS_DIR};
use crate::testutil::shared_robot;
// The tmpfs of the end-to-end tests (a real full disk), shared with them.
#[path = "../../tests/e2e/small_fs.rs"]
mod small_fs;
use small_fs::SmallFs;

/// Where the fake arm starts: the UR home pose, upright, clear of everything.
const HOME: [f64; 6] = [0.0, -FRAC_PI_2, FRAC_PI_2, -FRAC_PI_2, -FRAC_PI_2, 0.0];
/// `sim_rig`'s register map: doubles 24..29 and the sequence int 24.
const DOUBLE_START: u32 = 24;
const SEQUENCE_INT: u32 = 24;

/// What every test shares, built once per test binary.
struct Fixture {
    model: Arc<RobotModel>,
    /// The true `flange_from_camera`.
    mount: Isometry3<f64>,
    /// The physical arm the scans show.
    arm: PhysicalArm,
    /// The exact DH set its controller publishes (joints 2–4 nearly parallel: hundreds of
    /// metres of `d`).
    dh: DhParams,
    /// A view of the base whose straight joint path from [`HOME`] is free.
    view: [f64; 6],
    /// The scan from `view`.
    scan: PointCloud,
    /// Another scan from `view` with other sensor noise (a later check).
    rescan: PointCloud,
}

fn fixture() -> Option<&'static Fixture> {
    static FIXTURE: OnceLock<Option<Fixture>> = OnceLock::new();
    let f = FIXTURE
        .get_or_init(|| shared_robot("ur/ur5e/ur5e.urdf").map(build_fixture))
        .as_ref();
    if f.is_none() {
        crate::skips::record(
            "run::tests",
            "../shared/robots not found; the run tests need the UR5e model",
        );
    }
    f
}

fn build_fixture(model: Arc<RobotModel>) -> Fixture {
    let mount = Isometry3::new(
        Vector3::new(0.0, -0.08, 0.03),
        Vector3::new(-15f64.to_radians(), 0.0, 0.0),
    );
    let arm = PhysicalArm::factory(UrModel::Ur5e, 3);
    let dh = arm.controller_dh();
    let intrinsics = Intrinsics::compact_1280x960();
    let views = ViewPlanner::new(&model, mount, intrinsics, ViewConstraints::default());
    // The run checks paths with the configured prior as the camera.
    let cfg = test_config(Path::new("unused"), HOME);
    let prior = cfg.mount.prior.expect("sim_rig has a prior");
    let paths = ViewPlanner::new(&model, prior, intrinsics, ViewConstraints::default());
    let free = |a: &[f64], b: &[f64]| matches!(paths.check_path(a, b, 0.02), Ok(Ok(_)));
    let view = (1..=12)
        .filter_map(|seed| views.generate(1, seed).ok()?.into_iter().next())
        .find(|q| free(&HOME, q) && free(q, &HOME))
        .expect("a view of the base reachable from home within 12 planner seeds");
    let view: [f64; 6] = view.try_into().expect("6 joints");
    let scan = |seed: u64| {
        let req = ScanRequest::new(
            &model,
            view.to_vec(),
            Placement::EyeInHand {
                flange_from_camera: mount,
            },
            intrinsics,
            &SimSettings::default(),
            seed,
        )
        .with_arm(arm);
        simulate_scan(&req).expect("scan simulated").cloud
    };
    let (scan, rescan) = (scan(11), scan(12));
    Fixture {
        model,
        mount,
        arm,
        dh,
        view,
        scan,
        rescan,
    }
}

/// The simulated rig's configuration with one fixed view and storage in `storage`.
fn test_config(storage: &Path, view: [f64; 6]) -> Config {
    let mut cfg = config::sim_rig(
        IpAddr::V4(Ipv4Addr::LOCALHOST),
        RobotPorts::UR_STANDARD,
        "127.0.0.1".into(),
        storage.to_path_buf(),
    );
    cfg.views.targets = ViewTargets::Joints(vec![view]);
    cfg.camera.settle = Duration::from_millis(10);
    cfg
}

/// A factory-calibrated UR5e at [`HOME`] whose controller publishes its kinematics.
fn calibrated_robot(f: &Fixture) -> FakeRobot {
    FakeRobot::new(UrModel::Ur5e, HOME).with_kinematics(ControllerKinematics {
        dh: f.dh,
        checksum: [0; 6],
        calibrated: true,
    })
}

/// A fresh storage folder, removed when dropped.
struct Storage(PathBuf);

impl Storage {
    fn new(tag: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("handeye-run-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temporary storage");
        Self(dir)
    }
}

impl Drop for Storage {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

async fn start<R: Robot, C: DepthCamera>(
    robot: &R,
    camera: &C,
    f: &Fixture,
    cfg: &Config,
    mode: RunMode,
    dry_run: bool,
) -> RunRecord {
    let req = RunRequest {
        dry_run,
        ..RunRequest::new(mode)
    };
    run(
        robot,
        camera,
        &f.model,
        cfg,
        req,
        &CancellationToken::new(),
        &Silent,
    )
    .await
}

/// A calibration of `robot` from the fixture's first scan, asserted accepted.
async fn calibrate_accepted<R: Robot>(robot: &R, f: &Fixture, cfg: &Config) -> RunRecord {
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    let record = start(robot, &camera, f, cfg, RunMode::Calibrate, false).await;
    assert_eq!(record.outcome, Outcome::Accepted, "{:?}", record.reasons);
    record
}

/// A calibration that `cancel` stops; its record, and how long after the cancel (the instant
/// `cancelled_at` gives once the canceller has run) the run ended.
async fn calibrate_cancelled<R: Robot, C: DepthCamera>(
    robot: &R,
    camera: &C,
    f: &Fixture,
    cfg: &Config,
    cancel: &CancellationToken,
    cancelled_at: impl Future<Output = Instant>,
) -> (RunRecord, Duration) {
    let req = RunRequest::new(RunMode::Calibrate);
    let record = run(robot, camera, &f.model, cfg, req, cancel, &Silent).await;
    let ended = Instant::now();
    (record, ended.saturating_duration_since(cancelled_at.await))
}

fn estimate(record: &RunRecord) -> Isometry3<f64> {
    let result = record.result.as_ref().expect("a result");
    from_row_major(&result.flange_from_camera.expect("eye-in-hand result")).expect("a rigid pose")
}

fn close(a: &Isometry3<f64>, b: &Isometry3<f64>, tol: f64) -> bool {
    (a.to_homogeneous() - b.to_homogeneous()).norm() < tol
}

/// The run wrote nothing anywhere: no write-back, TCP untouched, registers untouched, no
/// current calibration.
async fn assert_nothing_written(record: &RunRecord, robot: &FakeRobot, storage: &Path) {
    assert!(record.written.is_empty(), "written: {:?}", record.written);
    assert_eq!(robot.tcp(), Isometry3::identity(), "the TCP was changed");
    assert_eq!(
        robot.read_int_register(SEQUENCE_INT).await.expect("read"),
        0,
        "the sequence register was changed"
    );
    for k in 0..6 {
        let v = robot
            .read_double_register(DOUBLE_START + k)
            .await
            .expect("read");
        assert_eq!(v, 0.0, "double register {} was written", DOUBLE_START + k);
    }
    assert!(
        !storage.join(CURRENT_DIR).exists(),
        "a current calibration was written"
    );
}

fn reasons(record: &RunRecord) -> String {
    record.reasons.join(" | ").to_lowercase()
}

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
async fn preflight_refusals_say_what_to_do_and_move_nothing() {
    let Some(f) = fixture() else { return };
    let ready = RobotStatus {
        robot_mode: RobotMode::Running,
        safety_mode: SafetyMode::Normal,
        remote_control: true,
        program_running: false,
        speed_fraction: 1.0,
    };
    let cases = [
        (
            "local control",
            RobotStatus {
                remote_control: false,
                ..ready.clone()
            },
            "enable remote control",
        ),
        (
            "protective stop",
            RobotStatus {
                safety_mode: SafetyMode::ProtectiveStop,
                ..ready.clone()
            },
            "clear it on the pendant",
        ),
        (
            "powered off",
            RobotStatus {
                robot_mode: RobotMode::PowerOff,
                ..ready.clone()
            },
            "power it on",
        ),
        (
            "program running",
            RobotStatus {
                program_running: true,
                ..ready.clone()
            },
            "stop it on the pendant",
        ),
    ];
    for (what, status, advice) in cases {
        let storage = Storage::new(&format!("preflight-{}", what.replace(' ', "-")));
        let cfg = test_config(&storage.0, f.view);
        let robot = calibrated_robot(f);
        robot.set_status(status);
        let camera = FakeCamera::new(vec![f.scan.clone()]);
        let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
        assert_eq!(
            record.outcome,
            Outcome::Error,
            "{what}: {:?}",
            record.reasons
        );
        assert_eq!(record.failed_stage, Some(Stage::Preflight), "{what}");
        assert!(
            reasons(&record).contains(advice),
            "{what}: {:?}",
            record.reasons
        );
        assert!(
            robot.moves().is_empty(),
            "{what}: moved {:?}",
            robot.moves()
        );
        assert_eq!(camera.captures(), 0, "{what}");
        assert!(record.views.is_empty(), "{what}: planned anyway");
        assert_nothing_written(&record, &robot, &storage.0).await;
    }
}

/// Issue 24: a powered-off arm is powered on only when `robot.allow_power_on` says so, and the
/// record says it was.
#[tokio::test]
async fn a_powered_off_arm_is_powered_on_only_when_allowed() {
    let Some(f) = fixture() else { return };
    for allow in [false, true] {
        let storage = Storage::new(&format!("power-on-{allow}"));
        let mut cfg = test_config(&storage.0, f.view);
        cfg.robot.allow_power_on = allow;
        let robot = calibrated_robot(f);
        let mut status = robot.status().await.expect("status");
        status.robot_mode = RobotMode::PowerOff;
        robot.set_status(status);
        let camera = FakeCamera::new(vec![f.scan.clone()]);
        let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
        let preflight = record.preflight.as_ref().expect("preflight recorded");
        if allow {
            assert_eq!(record.outcome, Outcome::Accepted, "{:?}", record.reasons);
            assert!(preflight.powered_on);
            assert_eq!(preflight.status.robot_mode, RobotMode::Running);
        } else {
            assert_eq!(record.outcome, Outcome::Error);
            assert!(!preflight.powered_on);
            assert!(
                reasons(&record).contains("robot.allow_power_on = true"),
                "{:?}",
                record.reasons
            );
            assert!(robot.moves().is_empty());
            assert_eq!(
                robot.status().await.expect("status").robot_mode,
                RobotMode::PowerOff
            );
        }
    }
}

/// Issue 24: a configured model that is not the arm (`model = "ur5"` on a UR5e controller) is
/// refused in preflight, naming both, before anything moves.
#[tokio::test]
async fn a_configured_model_that_is_not_the_arm_is_refused_naming_both() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("wrong-model");
    let mut cfg = test_config(&storage.0, f.view);
    cfg.robot.model = UrModel::Ur5;
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    let why = assert_refused_before_moving(&record, &robot, &storage.0).await;
    assert!(
        why.contains("robot.model is ur5") && why.contains("ur5e") && why.contains("ur7e"),
        "{why}"
    );
}

/// Issue 24: without kinematics from the controller, the model it reports (dashboard `get
/// robot model`: the family) still refuses a configured model of another family, naming both.
#[tokio::test]
async fn a_model_the_controller_does_not_report_is_refused_naming_both() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("reported-model");
    let mut cfg = test_config(&storage.0, f.view);
    cfg.robot.model = UrModel::Ur10e;
    // No kinematics published: only the reported name can tell.
    let robot = FakeRobot::new(UrModel::Ur5e, HOME);
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    let why = assert_refused_before_moving(&record, &robot, &storage.0).await;
    assert!(
        why.contains("robot.model is ur10e but the controller says the arm is a ur5")
            && why.contains("set robot.model = \"ur5\" or \"ur5e\""),
        "{why}"
    );
    // The refused run still records who the controller is.
    let controller = record
        .preflight
        .as_ref()
        .and_then(|p| p.controller.clone())
        .expect("the controller's identity");
    assert_eq!(controller.model.as_deref(), Some("UR5"));
}

/// Issue 24: the run records who the controller is, the current calibration keeps it, and a
/// check on another arm (another serial) or on changed kinematics (another checksum) says
/// the calibration belongs elsewhere; a calibrate on another arm says so and does not let the
/// gate compare with the other arm's result.
#[tokio::test]
async fn a_calibration_made_on_another_arm_is_reported() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("other-arm");
    let cfg = test_config(&storage.0, f.view);
    let arm = |serial: &str, checksum: u32| {
        FakeRobot::new(UrModel::Ur5e, HOME)
            .with_kinematics(ControllerKinematics {
                dh: f.dh,
                checksum: [checksum; 6],
                calibrated: true,
            })
            .with_serial(serial, "5.11.1.108318")
    };
    let calibrated = calibrate_accepted(&arm("20205500001", 7), f, &cfg).await;
    assert!(calibrated.warnings.is_empty(), "{:?}", calibrated.warnings);
    let controller = calibrated
        .preflight
        .as_ref()
        .and_then(|p| p.controller.clone())
        .expect("recorded");
    assert_eq!(controller.serial.as_deref(), Some("20205500001"));
    assert_eq!(
        controller.software_version.as_deref(),
        Some("5.11.1.108318")
    );
    assert_eq!(controller.kinematics_checksum, Some([7; 6]));
    let current =
        crate::storage::load_current(&storage.0, crate::calib::Mount::EyeInHand).expect("current");
    assert_eq!(current.controller, Some(controller));

    let check = |robot: FakeRobot| {
        let cfg = cfg.clone();
        async move {
            let camera = FakeCamera::new(vec![f.rescan.clone()]);
            start(&robot, &camera, f, &cfg, RunMode::Check, false).await
        }
    };
    // The same arm: nothing to say.
    let same = check(arm("20205500001", 7)).await;
    assert_eq!(same.verdict(), "within limits", "{:?}", same.reasons);
    assert!(same.warnings.is_empty(), "{:?}", same.warnings);
    // Another arm: said, and still compared (the verdict is the drift's).
    let other = check(arm("20205500002", 7)).await;
    assert_eq!(other.outcome, Outcome::Accepted, "{:?}", other.reasons);
    assert!(other.drift.is_some());
    assert_eq!(other.warnings.len(), 1, "{:?}", other.warnings);
    assert!(
        other.warnings[0].starts_with(
            "the current calibration was made on arm 20205500001; this controller is \
             20205500002: recalibrate"
        ),
        "{:?}",
        other.warnings
    );
    // The same arm with other kinematics.
    let changed = check(arm("20205500001", 8)).await;
    assert_eq!(changed.warnings.len(), 1, "{:?}", changed.warnings);
    assert!(
        changed.warnings[0].contains("kinematics changed"),
        "{:?}",
        changed.warnings
    );

    // Calibrating the other arm says so, and is accepted.
    let recalibrated = calibrate_accepted(&arm("20205500002", 7), f, &cfg).await;
    assert!(
        recalibrated
            .warnings
            .iter()
            .any(|w| w.contains("this run does")),
        "{:?}",
        recalibrated.warnings
    );
}

/// The run failed its preflight: an error, nothing moved, nothing written. Returns its
/// reasons (lower case).
async fn assert_refused_before_moving(
    record: &RunRecord,
    robot: &FakeRobot,
    storage: &Path,
) -> String {
    assert_eq!(record.outcome, Outcome::Error, "{:?}", record.reasons);
    assert_eq!(record.failed_stage, Some(Stage::Preflight));
    assert!(robot.moves().is_empty(), "moved {:?}", robot.moves());
    assert_nothing_written(record, robot, storage).await;
    reasons(record)
}

#[tokio::test]
async fn a_dry_run_plans_and_moves_nothing() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("dry");
    let cfg = test_config(&storage.0, f.view);
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![f.scan.clone()]);

    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, true).await;
    assert_eq!(record.outcome, Outcome::Planned, "{:?}", record.reasons);
    assert_eq!(record.exit_code(), 0);
    assert_eq!(record.views.len(), 1);
    assert_eq!(record.views[0].joints, f.view.to_vec());
    assert!(
        record.views[0].path.samples > 1,
        "{:?}",
        record.views[0].path
    );
    assert!(robot.moves().is_empty());
    assert_eq!(camera.captures(), 0);
    assert!(record.captures.is_empty() && record.result.is_none());
    assert_nothing_written(&record, &robot, &storage.0).await;
    // Issue 43: the dry run says whether the view sees the base, the σ to expect and the
    // run's time.
    assert!(
        record.views[0].distance_to_base_m.is_some(),
        "{:?}",
        record.views[0]
    );
    assert_eq!(record.views[0].not_seeing_base, None);
    let forecast = record.forecast.as_ref().expect("a forecast");
    let sigma = forecast.uncertainty_translation_mm.expect("a σ");
    assert!(sigma > 0.01 && sigma < 2.0, "{forecast:?}");
    assert!(
        forecast.moves_s > 0.0 && forecast.run_s > forecast.moves_s,
        "{forecast:?}"
    );
}

#[tokio::test]
async fn a_run_cancelled_before_it_starts_moves_nothing() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("cancel-before");
    let cfg = test_config(&storage.0, f.view);
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    let cancel = CancellationToken::new();
    cancel.cancel();
    let req = RunRequest::new(RunMode::Calibrate);
    let record = run(&robot, &camera, &f.model, &cfg, req, &cancel, &Silent).await;
    assert_eq!(record.outcome, Outcome::Aborted, "{:?}", record.reasons);
    assert!(
        reasons(&record).contains("cancelled"),
        "{:?}",
        record.reasons
    );
    assert!(robot.moves().is_empty());
    assert_eq!(camera.captures(), 0);
    assert_nothing_written(&record, &robot, &storage.0).await;
}

/// A camera whose capture never completes; says when a capture started.
struct HangingCamera {
    inner: FakeCamera,
    capturing: Arc<Notify>,
}

impl DepthCamera for HangingCamera {
    async fn info(&self) -> Result<CameraInfo, HalError> {
        self.inner.info().await
    }

    async fn capture(&self, _: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
        self.capturing.notify_one();
        std::future::pending().await
    }
}

#[tokio::test]
async fn a_cancel_during_a_hanging_capture_aborts_at_once_and_stays_put() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("cancel-capture");
    let cfg = test_config(&storage.0, f.view);
    let robot = calibrated_robot(f);
    let capturing = Arc::new(Notify::new());
    let camera = HangingCamera {
        inner: FakeCamera::new(vec![f.scan.clone()]),
        capturing: Arc::clone(&capturing),
    };
    let cancel = CancellationToken::new();
    let canceller = {
        let cancel = cancel.clone();
        tokio::spawn(async move {
            capturing.notified().await;
            tokio::time::sleep(Duration::from_millis(200)).await;
            cancel.cancel();
            Instant::now()
        })
    };
    let (record, took) = calibrate_cancelled(&robot, &camera, f, &cfg, &cancel, async {
        canceller.await.expect("the canceller ran")
    })
    .await;
    assert!(
        took < Duration::from_secs(2),
        "the run ended {took:?} after the cancel"
    );
    assert_eq!(record.outcome, Outcome::Aborted, "{:?}", record.reasons);
    assert_eq!(record.failed_stage, Some(Stage::Capture));
    // The failed stage's own time is in the record (the summary showed 0 ms): it hung 200 ms.
    assert!(
        record.timings_ms.capture >= 150.0,
        "{:?}",
        record.timings_ms
    );
    assert!(
        reasons(&record).contains("cancelled"),
        "{:?}",
        record.reasons
    );
    assert_nothing_written(&record, &robot, &storage.0).await;
    // Stopped where it is: no return move after a cancel.
    assert_eq!(robot.moves(), vec![f.view.to_vec()]);
    assert!(!record.returned_to_start);
}

/// Issue 23: planning among very many obstacles is long; a cancel (the API's, SIGTERM's)
/// stops it at once, the record says it was cancelled while planning, and nothing moves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancel_during_a_long_plan_stops_it_at_once() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("cancel-plan");
    let mut cfg = test_config(&storage.0, f.view);
    cfg.views.obstacles = (0..200_000)
        .map(|i| crate::config::Obstacle {
            name: format!("box {i}"),
            centre_m: [10.0 + (i % 100) as f64, 10.0, 0.0],
            size_m: [0.1; 3],
        })
        .collect();
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    let cancel = CancellationToken::new();
    let canceller = {
        let cancel = cancel.clone();
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(500));
            cancel.cancel();
            Instant::now()
        })
    };
    let (record, took) = calibrate_cancelled(&robot, &camera, f, &cfg, &cancel, async {
        canceller.join().expect("the canceller ran")
    })
    .await;
    assert!(
        took < Duration::from_secs(2),
        "the run ended {took:?} after the cancel"
    );
    assert_eq!(record.outcome, Outcome::Aborted, "{:?}", record.reasons);
    assert_eq!(
        record.failed_stage,
        Some(Stage::Plan),
        "{:?}",
        record.reasons
    );
    assert!(
        reasons(&record).contains("cancelled"),
        "{:?}",
        record.reasons
    );
    assert!(robot.moves().is_empty(), "moved {:?}", robot.moves());
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

#[tokio::test]
async fn an_obstacle_on_the_path_stops_the_plan_before_any_move() {
    let Some(f) = fixture() else { return };
    let storage = Storage::new("obstacle");
    let mut cfg = test_config(&storage.0, f.view);
    // A fixture where the flange will be at the view (controller `base` frame).
    let flange = UrModel::Ur5e.dh().forward(&f.view).translation.vector;
    cfg.views.obstacles = vec![config::Obstacle {
        name: "tool changer".into(),
        centre_m: [flange.x, flange.y, flange.z],
        size_m: [0.15, 0.15, 0.15],
    }];
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![f.scan.clone()]);

    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    assert_eq!(record.outcome, Outcome::Error, "{:?}", record.reasons);
    assert_eq!(record.failed_stage, Some(Stage::Plan));
    assert!(
        reasons(&record).contains("`tool changer`"),
        "{:?}",
        record.reasons
    );
    assert!(robot.moves().is_empty(), "moved {:?}", robot.moves());
    assert_eq!(camera.captures(), 0);
    assert_nothing_written(&record, &robot, &storage.0).await;
}

/// The eye-to-hand cell: a camera fixed 1.2 m from the base, above and beside it, and the arm
/// posed where the camera sees the base and the first links.
struct EyeToHandCell {
    /// The true camera pose in the model root (`world` = `base_link` for the UR5e URDF).
    model_from_camera: Isometry3<f64>,
    /// The same in the controller's `base` frame: what the run must find.
    base_from_camera: Isometry3<f64>,
    /// The joint target the camera sees the arm at; reachable from [`HOME`] on a free path.
    view: [f64; 6],
    /// The fixed camera's scan with the arm at `view`.
    scan: PointCloud,
}

fn eye_to_hand_cell() -> Option<(&'static Fixture, &'static EyeToHandCell)> {
    static CELL: OnceLock<EyeToHandCell> = OnceLock::new();
    let f = fixture()?;
    Some((f, CELL.get_or_init(|| build_eye_to_hand_cell(f))))
}

fn build_eye_to_hand_cell(f: &Fixture) -> EyeToHandCell {
    let model_from_camera = crate::sim::look_at(
        &Point3::new(0.75, -0.65, 0.7),
        &Point3::new(0.0, 0.0, 0.2),
        &-Vector3::z(),
    );
    let distance = model_from_camera.translation.vector.norm();
    assert!(
        (1.0..=1.3).contains(&distance),
        "the camera is {distance:.2} m from the base"
    );
    // The truth in the controller's `base` frame, both ways: the URDF's own `base` link and the
    // fixed UR convention (the model root is `base_link`).
    let base_from_model = crate::calib::pipeline::fixed_frame(&f.model, "base")
        .expect("the UR5e URDF has a `base` link")
        .inverse();
    let base_from_camera = crate::frames::ur_base_from_base_link() * model_from_camera;
    assert!(
        close(
            &(base_from_model * model_from_camera),
            &base_from_camera,
            1e-9
        ),
        "the URDF's `base` is not base_link turned by π"
    );

    // The arm turned away from the camera's line of sight, upper arm raised, so that the base
    // and the shoulder are in full view; the straight joint path from home is free.
    let view = [0.6, -1.75, 1.45, -1.3, -1.57, 0.0];
    let paths = ViewPlanner::new(
        &f.model,
        Isometry3::identity(),
        Intrinsics::compact_1280x960(),
        ViewConstraints::default(),
    );
    for (a, b) in [(&HOME, &view), (&view, &HOME)] {
        assert!(
            matches!(paths.check_path(a, b, 0.02), Ok(Ok(_))),
            "the path {a:?} -> {b:?} is not free: {:?}",
            paths.check_path(a, b, 0.02)
        );
    }

    let req = ScanRequest::new(
        &f.model,
        view.to_vec(),
        Placement::EyeToHand { model_from_camera },
        Intrinsics::compact_1280x960(),
        &SimSettings::default(),
        21,
    )
    .with_arm(f.arm);
    let sim = simulate_scan(&req).expect("scan simulated");
    // Enough of the robot in view: measured points on its links, the base among them.
    let mut on_links = std::collections::BTreeMap::<&str, usize>::new();
    for (p, &label) in sim.cloud.points.iter().zip(&sim.labels) {
        if label == u32::MAX || !p.x.is_finite() {
            continue;
        }
        if let Some(link) = sim.objects[label as usize].strip_prefix("link:") {
            *on_links.entry(link).or_default() += 1;
        }
    }
    let robot_points: usize = on_links.values().sum();
    eprintln!(
        "eye-to-hand scan: {robot_points} robot points of {} valid: {on_links:?}",
        sim.cloud.valid_count()
    );
    assert!(robot_points > 20_000, "{on_links:?}");
    for link in ["base_link_inertia", "shoulder_link", "upper_arm_link"] {
        assert!(
            on_links.get(link).copied().unwrap_or(0) > 1_000,
            "{link} barely visible: {on_links:?}"
        );
    }
    EyeToHandCell {
        model_from_camera,
        base_from_camera,
        view,
        scan: sim.cloud,
    }
}

/// The rig's configuration for a camera fixed in the cell: no prior, no flange distance, no
/// TCP write-back (a fixed camera is never a TCP), registers and files on.
fn eye_to_hand_config(storage: &Path, targets: ViewTargets) -> Config {
    let mut cfg = test_config(storage, HOME);
    cfg.mount.mount = crate::calib::Mount::EyeToHand;
    cfg.mount.prior = None;
    cfg.mount.max_camera_flange_distance_m = None;
    cfg.write_back.tcp = false;
    assert!(cfg.write_back.registers.is_some() && cfg.write_back.files);
    cfg.views.targets = targets;
    cfg
}

#[tokio::test]
async fn an_eye_to_hand_run_finds_the_fixed_camera_in_the_base_frame_and_sets_no_tcp() {
    let Some((f, cell)) = eye_to_hand_cell() else {
        return;
    };
    let storage = Storage::new("eye-to-hand");
    let cfg = eye_to_hand_config(&storage.0, ViewTargets::Joints(vec![cell.view]));
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![cell.scan.clone()]);

    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    assert_eq!(record.outcome, Outcome::Accepted, "{:?}", record.reasons);
    assert_eq!(record.failed_stage, None);
    assert_eq!(record.exit_code(), 0);

    // The fixed camera in the controller's `base` frame, not on the flange.
    let result = record.result.as_ref().expect("a result");
    assert_eq!(result.mount, crate::calib::Mount::EyeToHand);
    assert!(
        result.flange_from_camera.is_none(),
        "{:?}",
        result.flange_from_camera
    );
    let est = from_row_major(&result.base_from_camera).expect("a rigid pose");
    let (mm, deg) = pose_difference(&cell.base_from_camera, &est);
    eprintln!("eye-to-hand run: base_from_camera error {mm:.3} mm {deg:.4} deg");
    assert!(mm < 1.0 && deg < 0.2, "error {mm:.3} mm {deg:.4} deg");
    // Not the model-root pose by mistake (they differ by π about z).
    let (mm_root, _) = pose_difference(&cell.model_from_camera, &est);
    assert!(mm_root > 100.0, "the result is in the model root frame");
    let ur = UrPose::from(result.ur_pose);
    assert!(ur.approx_eq(&UrPose::from(&est), 1e-9, 1e-9), "{ur}");

    // Written: registers and files; never a TCP.
    let targets: Vec<&str> = record.written.iter().map(|w| w.target.name()).collect();
    assert_eq!(targets, ["registers", "files"]);
    assert_eq!(robot.tcp(), Isometry3::identity(), "the TCP was changed");
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
    assert!(storage.0.join(CURRENT_DIR).join("result.json").is_file());
    let current = crate::storage::load_current(&storage.0, crate::calib::Mount::EyeToHand)
        .expect("current")
        .pose;
    assert!(close(&current, &est, 1e-9), "current {current:?}");

    // To the view and back.
    assert_eq!(robot.moves(), vec![cell.view.to_vec(), HOME.to_vec()]);
    assert!(record.returned_to_start);
    assert_eq!(camera.captures(), 1);
}

#[tokio::test]
async fn an_automatic_eye_to_hand_run_measures_where_the_arm_stands() {
    let Some((f, cell)) = eye_to_hand_cell() else {
        return;
    };
    let storage = Storage::new("eye-to-hand-auto");
    let cfg = eye_to_hand_config(
        &storage.0,
        ViewTargets::Auto {
            count: 3,
            min_distance_m: 0.3,
            max_distance_m: 0.8,
            seed: 7,
        },
    );
    // The arm already stands where the fixed camera sees it.
    let robot = FakeRobot::new(UrModel::Ur5e, cell.view).with_kinematics(ControllerKinematics {
        dh: f.dh,
        checksum: [0; 6],
        calibrated: true,
    });
    let camera = FakeCamera::new(vec![cell.scan.clone()]);

    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    assert_eq!(record.outcome, Outcome::Accepted, "{:?}", record.reasons);
    assert_eq!(record.views.len(), 1, "{:?}", record.views);
    assert_eq!(record.views[0].joints, cell.view.to_vec());
    assert_eq!(record.captures.len(), 1);
    assert_eq!(record.captures[0].joints, cell.view.to_vec());
    // The arm never leaves where it stands: no move is commanded at all.
    assert!(robot.moves().is_empty(), "moved {:?}", robot.moves());
    assert!(!record.returned_to_start);
    let est = from_row_major(&record.result.as_ref().expect("a result").base_from_camera)
        .expect("a rigid pose");
    let (mm, deg) = pose_difference(&cell.base_from_camera, &est);
    eprintln!("automatic eye-to-hand run: error {mm:.3} mm {deg:.4} deg");
    assert!(mm < 1.0 && deg < 0.2, "error {mm:.3} mm {deg:.4} deg");
    assert_eq!(robot.tcp(), Isometry3::identity());
    assert_eq!(camera.captures(), 1);
}

#[tokio::test]
async fn without_the_controller_s_kinematics_the_calibration_file_poses_the_model() {
    let Some(f) = fixture() else { return };
    // The controller's kinematics are not used (as with a controller that publishes none):
    // the model is posed by the nominal URDF, or by the arm's ur_calibration file.
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    let error = |record: &RunRecord| {
        let est = estimate(record);
        let d = est.inverse() * f.mount;
        (
            d.translation.vector.norm() * 1e3,
            d.rotation.angle().to_degrees(),
        )
    };
    let storage = Storage::new("nominal-kinematics");
    let mut cfg = test_config(&storage.0, f.view);
    cfg.robot.kinematics = config::KinematicsSource::Nominal;
    let nominal = start(
        &calibrated_robot(f),
        &camera,
        f,
        &cfg,
        RunMode::Calibrate,
        false,
    )
    .await;
    let kin = &nominal.preflight.as_ref().expect("preflight").kinematics;
    assert_eq!(kin.source, KinematicsOrigin::Nominal);

    let file = storage.0.join("calibration.yaml");
    std::fs::write(
        &file,
        crate::model::ur_calibration_yaml(&f.dh, &UrModel::Ur5e.dh(), "calib_12345"),
    )
    .expect("yaml");
    cfg.robot.calibration = Some(file.clone());
    let posed = start(
        &calibrated_robot(f),
        &camera,
        f,
        &cfg,
        RunMode::Calibrate,
        false,
    )
    .await;
    let kin = &posed.preflight.as_ref().expect("preflight").kinematics;
    assert_eq!(kin.source, KinematicsOrigin::File, "{kin:?}");
    assert!(
        kin.note
            .as_deref()
            .is_some_and(|n| n.contains("calibration.yaml")),
        "{kin:?}"
    );
    let (nominal_mm, nominal_deg) = error(&nominal);
    let (file_mm, file_deg) = error(&posed);
    let sigma = |record: &RunRecord| {
        record
            .result
            .as_ref()
            .expect("a result")
            .uncertainty
            .translation_mm
    };
    let (nominal_sigma, file_sigma) = (sigma(&nominal), sigma(&posed));
    eprintln!(
        "nominal URDF: {nominal_mm:.3} mm / {nominal_deg:.4}° (1σ {nominal_sigma:.3} mm); \
         calibration file: {file_mm:.3} mm / {file_deg:.4}° (1σ {file_sigma:.3} mm)"
    );
    // One scan says little about which error is smaller (the bench compares them over many);
    // what the file buys on every scan is that the arm's joint error is gone from what the run
    // can promise, and both results stay within what they promise.
    assert!(
        file_mm < crate::bench::PASS_TRANSLATION_MM,
        "{file_mm} mm with the calibration file"
    );
    // The file takes the joints' error out of the promise; the housings' stays in both.
    assert!(
        file_sigma < 0.95 * nominal_sigma,
        "1σ {file_sigma} mm with the file vs {nominal_sigma} mm nominal"
    );
    assert!(nominal_mm < 3.0 * nominal_sigma && file_mm < 3.0 * file_sigma);

    // A file that cannot be read fails the preflight, before anything moves.
    std::fs::write(&file, "kinematics:\n  shoulder: {x: .nan}\n").expect("yaml");
    let robot = calibrated_robot(f);
    let bad = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    assert_eq!(
        bad.failed_stage,
        Some(Stage::Preflight),
        "{:?}",
        bad.reasons
    );
    assert!(
        reasons(&bad).contains("robot.calibration"),
        "{:?}",
        bad.reasons
    );
    assert!(robot.moves().is_empty());
}

/// Issue 23: with the storage full before the run, nothing moves and nothing is written; the
/// record says why and no temporary file is left.
#[tokio::test]
async fn issue_23_a_full_storage_moves_nothing_and_writes_nothing() {
    let Some(f) = fixture() else { return };
    let Some(fs) = SmallFs::mount("run-full", 16 << 20) else {
        return;
    };
    fs.fill();
    let cfg = test_config(fs.path(), f.view);
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    let why = assert_refused_before_moving(&record, &robot, fs.path()).await;
    assert!(
        why.contains("free") && why.contains("nothing moved"),
        "{why}"
    );
    assert_eq!(camera.captures(), 0);
    assert_eq!(fs.temporary_files(), Vec::<PathBuf>::new());
}

/// Issue 23: the controller took the TCP and the registers, then the disk filled before the
/// record describing them could be written: the TCP read at preflight and the registers read
/// before writing are written back, the error says so, `current/` stays as it was and no
/// temporary file is left. Once space is freed the next run goes through.
#[tokio::test]
async fn issue_23_a_result_that_cannot_be_recorded_is_undone_on_the_controller() {
    let Some(f) = fixture() else { return };
    let Some(fs) = SmallFs::mount("run-undo", 64 << 20) else {
        return;
    };
    let fs = Arc::new(fs);
    let cfg = test_config(fs.path(), f.view);
    let robot = calibrated_robot(f);
    // What the controller held before: a tool's TCP and a pendant program's last result.
    let before_tcp = Isometry3::new(Vector3::new(0.01, -0.02, 0.15), Vector3::new(0.0, 0.1, 0.0));
    robot.set_tcp(&before_tcp).await.expect("tcp");
    let before: [f64; 6] = [0.1, -0.2, 0.3, 0.04, -0.05, 0.06];
    for (k, v) in before.iter().enumerate() {
        robot
            .write_double_register(DOUBLE_START + k as u32, *v)
            .await
            .expect("register");
    }
    robot
        .write_int_register(SEQUENCE_INT, 7)
        .await
        .expect("seq");
    // The disk fills the moment the controller has taken the new TCP.
    let filler = Arc::clone(&fs);
    robot.after_set_tcp(move || {
        if !filler.path().join("filler").exists() {
            filler.fill();
        }
    });
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    let record = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;

    assert_eq!(record.outcome, Outcome::Error, "{:?}", record.reasons);
    assert_eq!(record.failed_stage, Some(Stage::WriteBack));
    let why = reasons(&record);
    assert!(
        why.contains("the run record could not be written")
            && why.contains("undone")
            && why.contains("the previous tcp")
            && why.contains("were written back"),
        "{why}"
    );
    assert!(record.written.is_empty(), "{:?}", record.written);
    // The new TCP was taken, then the previous one put back: the controller is as before.
    let history = robot.tcp_history();
    assert_eq!(history.len(), 3, "{history:?}");
    assert!(close(&history[1], &estimate(&record), 1e-9));
    assert!(!close(&history[1], &before_tcp, 1e-3));
    assert!(close(&robot.tcp(), &before_tcp, 1e-12), "{}", robot.tcp());
    for (k, v) in before.iter().enumerate() {
        let now = robot
            .read_double_register(DOUBLE_START + k as u32)
            .await
            .expect("read");
        assert_eq!(now, *v, "register {}", DOUBLE_START + k as u32);
    }
    // A new sequence number after the result's: a pendant program applies the old values.
    assert_eq!(robot.read_int_register(SEQUENCE_INT).await.expect("seq"), 9);
    assert!(
        !fs.path().join(CURRENT_DIR).exists(),
        "current/ was written"
    );
    assert_eq!(fs.temporary_files(), Vec::<PathBuf>::new());

    fs.free();
    robot.after_set_tcp(|| {});
    let again = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    assert_eq!(again.outcome, Outcome::Accepted, "{:?}", again.reasons);
    assert!(close(&robot.tcp(), &estimate(&again), 1e-9));
    assert!(fs.path().join(CURRENT_DIR).join("result.json").is_file());
}

/// Reports each stage to a closure (to act at a given point of a run).
struct OnStage<F: Fn(Stage) + Send + Sync>(F);

impl<F: Fn(Stage) + Send + Sync> super::Progress for OnStage<F> {
    fn stage(&self, stage: Stage, _: &str) {
        (self.0)(stage)
    }
}

/// Issue 23: the storage fills up after the room check, while the arm moves: the scans cannot
/// be kept, the result files and the record cannot be written, so nothing is written to the
/// controller; no temporary file is left. Once space is freed the next run goes through.
#[tokio::test]
async fn issue_23_storage_filling_during_the_run_writes_nothing_to_the_controller() {
    let Some(f) = fixture() else { return };
    let Some(fs) = SmallFs::mount("run-fills", 64 << 20) else {
        return;
    };
    let mut cfg = test_config(fs.path(), f.view);
    cfg.storage.keep_captures = true;
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    let fill_at_move = OnStage(|stage| {
        if stage == Stage::Move && !fs.path().join("filler").exists() {
            fs.fill();
        }
    });
    let req = RunRequest::new(RunMode::Calibrate);
    let cancel = CancellationToken::new();
    let record = run(&robot, &camera, &f.model, &cfg, req, &cancel, &fill_at_move).await;
    assert_eq!(record.outcome, Outcome::Error, "{:?}", record.reasons);
    assert_eq!(
        record.failed_stage,
        Some(Stage::WriteBack),
        "{:?}",
        record.reasons
    );
    let why = reasons(&record);
    assert!(
        why.contains("nothing was written to the controller"),
        "{why}"
    );
    assert!(record.result.is_some(), "the run got as far as a result");
    assert_eq!(robot.moves(), vec![f.view.to_vec(), HOME.to_vec()]);
    assert_nothing_written(&record, &robot, fs.path()).await;
    assert_eq!(fs.temporary_files(), Vec::<PathBuf>::new());
    // Hidden staging folders for `current/` are gone too.
    let hidden: Vec<_> = std::fs::read_dir(fs.path())
        .expect("storage")
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
        .map(|e| e.path())
        .collect();
    assert!(hidden.is_empty(), "{hidden:?}");

    fs.free();
    let again = start(&robot, &camera, f, &cfg, RunMode::Calibrate, false).await;
    assert_eq!(again.outcome, Outcome::Accepted, "{:?}", again.reasons);
    assert!(fs.path().join(CURRENT_DIR).join("result.json").is_file());
    assert_eq!(fs.temporary_files(), Vec::<PathBuf>::new());
}

/// Issue 36: the disk fills right after `current/` is swapped in (during the return move):
/// the run's end is still recorded — its history row `accepted` at once (the storage's
/// reserve is released for it), never left `running` and later read as aborted — and the
/// latest calibration is this run, also after a restart.
#[tokio::test]
async fn issue_36_a_disk_filling_after_the_write_back_leaves_the_run_accepted() {
    use crate::record::Trigger;
    use crate::store::{RunStatus, Store};
    let Some(f) = fixture() else { return };
    let Some(fs) = SmallFs::mount("run-fills-late", 64 << 20) else {
        return;
    };
    let cfg = test_config(fs.path(), f.view);
    let robot = calibrated_robot(f);
    let camera = FakeCamera::new(vec![f.scan.clone()]);
    let db = fs.path().join(crate::store::HISTORY_FILE);
    let store = Arc::new(Store::open(&db).expect("history"));
    let fill_at_return = OnStage(|stage| {
        if stage == Stage::Return && !fs.path().join("filler").exists() {
            fs.fill();
        }
    });
    let req = RunRequest::new(RunMode::Calibrate);
    let cancel = CancellationToken::new();
    let record = super::Recorder::new(Arc::clone(&store), Trigger::Cli)
        .run(
            &robot,
            &camera,
            &f.model,
            &cfg,
            req,
            &cancel,
            &fill_at_return,
        )
        .await;
    assert!(fs.path().join("filler").exists(), "the disk was filled");
    assert_eq!(record.outcome, Outcome::Accepted, "{:?}", record.reasons);
    let row = store.summary(&record.run_id).expect("read").expect("row");
    assert_eq!(row.outcome, RunStatus::Ended(Outcome::Accepted), "{row:?}");
    let latest = store
        .latest(Some(RunMode::Calibrate), Some(Outcome::Accepted))
        .expect("latest")
        .expect("one");
    assert_eq!(latest.run_id, record.run_id);
    assert!(!fs.path().join(crate::storage::JOURNAL_FILE).exists());
    drop(store);
    let store = super::open_history(&db).expect("reopened");
    let row = store.summary(&record.run_id).expect("read").expect("row");
    assert_eq!(row.outcome, RunStatus::Ended(Outcome::Accepted), "{row:?}");
}

/// Issue 42: a message's way out works where it is printed. A command's run names the command
/// line (with its configuration); the daemon's runs name the page, the API and the pendant,
/// never `handeye calibrate`, which is refused beside the daemon.
#[test]
fn issue_42_the_way_out_works_where_the_run_was_asked_for() {
    use crate::record::Trigger;
    let moved = format!(
        "the result moved 8.00 mm / 2.000° from the previous calibration (max 5.00 mm / 1.000°): check the camera mount; {}",
        crate::calib::gate::REMOUNT
    );
    let cli = super::with_remount_way_out(&moved, Some(Trigger::Cli), "/etc/handeye/handeye.toml");
    assert!(
        cli.ends_with("accept the new mount with `handeye calibrate --config /etc/handeye/handeye.toml --accept-change`"),
        "{cli}"
    );
    for t in [
        Trigger::Api,
        Trigger::Pendant,
        Trigger::Schedule,
        Trigger::Startup,
        Trigger::Drift,
    ] {
        let daemon = super::with_remount_way_out(&moved, Some(t), "c.toml");
        assert!(
            daemon.contains("with the Accept remount button on the daemon's page or POST /api/calibrate/accept-change")
                && !daemon.contains("handeye calibrate"),
            "{t:?}: {daemon}"
        );
        let first = super::calibrate_way_out(Some(t), "c.toml");
        assert!(
            first.contains("the Calibrate button on the daemon's page, POST /api/calibrate")
                && !first.contains("handeye calibrate"),
            "{t:?}: {first}"
        );
    }
    assert_eq!(
        super::calibrate_way_out(Some(Trigger::Cli), "c.toml"),
        ": `handeye calibrate --config c.toml`"
    );
    let other = "frame 0: only 40% of the visible model surface is in the scan (min 60%)";
    assert_eq!(
        super::with_remount_way_out(other, Some(Trigger::Api), "c"),
        other
    );
}
