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
    open_history, pose_difference, run, KinematicsOrigin, Outcome, Progress, Recorder, RunMode,
    RunRecord, RunRequest, Silent, Stage,
};
use crate::config::{self, Config, RobotPorts, ViewTargets};
use crate::frames::from_row_major;
use crate::model::RobotModel;
use crate::plan::{ViewConstraints, ViewPlanner};
use crate::sim::{simulate_scan, Intrinsics, Placement, ScanRequest, SimSettings};
use crate::storage::{CURRENT_DIR, RUNS_DIR};
use crate::testutil::shared_robot;
// The tmpfs of the end-to-end tests (a real full disk), shared with them.
#[path = "../../../tests/e2e/small_fs.rs"]
mod small_fs;
use small_fs::SmallFs;

mod eye_to_hand;
mod full_storage;
mod outcomes;
mod preflight;
mod stops;

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
