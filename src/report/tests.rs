use std::path::PathBuf;

use nalgebra::{Isometry3, Vector3};

use super::*;
use crate::run::{calibrate_frames, Frame, PipelineOptions};
use crate::sim::{
    simulate_scan, CellOptions, Intrinsics, KinematicError, Placement, ScanNoise, ScanRequest,
};
use crate::testutil::shared_robot;

/// Where the tests leave their pictures for a person to look at.
fn out_dir() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/report-test");
    std::fs::create_dir_all(&dir).expect("target/report-test");
    dir
}

fn decode(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .expect("a PNG");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buf).expect("a frame");
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

fn pixel(img: &(u32, u32, Vec<u8>), x: u32, y: u32) -> [u8; 3] {
    let i = ((y * img.0 + x) * 3) as usize;
    [img.2[i], img.2[i + 1], img.2[i + 2]]
}

/// Share of the scan points within 5 mm of the model that are within 1 mm.
fn tight_share(view: &ScanView) -> f64 {
    let d = view.distances(5.0);
    d.iter().filter(|v| **v <= 1.0).count() as f64 / d.len().max(1) as f64
}

#[test]
fn a_right_fit_looks_right_and_a_wrong_one_wrong() {
    let Some(model) = shared_robot("ur/ur5e/ur5e.urdf") else {
        return;
    };
    let mount = Isometry3::new(
        Vector3::new(0.0, -0.08, 0.03),
        Vector3::new(-15f64.to_radians(), 0.0, 0.0),
    );
    let intr = Intrinsics::compact_1280x960();
    let planner =
        crate::plan::ViewPlanner::new(&model, mount, intr, crate::plan::ViewConstraints::default());
    let q = planner.generate(1, 5).expect("a view").remove(0);
    let sim = simulate_scan(&ScanRequest {
        model: &model,
        joints: q.clone(),
        placement: Placement::EyeInHand {
            flange_from_camera: mount,
        },
        intrinsics: intr,
        noise: ScanNoise::default(),
        cell: CellOptions::default(),
        kinematic_error: KinematicError::none(),
        arm: None,
        seed: 4,
    })
    .expect("simulated");
    let frame = Frame {
        view: 0,
        cloud: sim.cloud.clone(),
        joints: q.clone(),
        model_from_flange: Some(sim.truth.model_from_flange_reported),
        source: "simulated".into(),
        image: None,
    };
    let calibration = calibrate_frames(
        &model,
        std::slice::from_ref(&frame),
        &PipelineOptions::new(Mount::EyeInHand),
    )
    .expect("calibrates");
    assert!(calibration.verdict.passed(), "{:?}", calibration.verdict);

    let t = std::time::Instant::now();
    let right = scan_view(
        &model,
        &q,
        None,
        &sim.cloud,
        &calibration.registrations[0],
        "view 1 of 1, frame 1 of 1: simulated UR5e scan",
        1,
    )
    .expect("scan view");
    let summary = Summary::from_report(&calibration.report, "simulated UR5e scan");
    let png_right = render(&summary, std::slice::from_ref(&right)).expect("renders");
    eprintln!(
        "report: scan view + render {:.0} ms, {} bytes",
        t.elapsed().as_secs_f64() * 1e3,
        png_right.len()
    );

    // The model 2 cm and 8° away from where registration put it: the picture a wrong fit gives.
    let off = Isometry3::new(Vector3::new(0.02, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.14));
    let mut misplaced = calibration.registrations[0].clone();
    misplaced.camera_from_model *= off;
    let wrong = scan_view(
        &model,
        &q,
        None,
        &sim.cloud,
        &misplaced,
        "view 1 of 1, frame 1 of 1: the model misplaced by 2 cm / 8°",
        1,
    )
    .expect("scan view");
    // The right fit: the robot's points hug the model; the misplaced one: they do not.
    let (r, w) = (tight_share(&right), tight_share(&wrong));
    eprintln!("points within 1 mm (of those within 5 mm): right {r:.2}, wrong {w:.2}");
    assert!(r > 0.8, "right fit: {r}");
    assert!(w < 0.4, "wrong fit: {w}");
    assert!(right.edge_pixels() > 500, "an outline is drawn");
    assert!(right.valid() > 100_000, "{}", right.valid());

    // Its picture says what it is: no result, the numbers of the comparison.
    let misplaced_summary = Summary {
        title: "the same scan, the model misplaced".into(),
        subtitle: "2 cm and 8° from where registration put it: what a wrong fit looks like".into(),
        outcome: Outcome::Rejected,
        headline: "WRONG FIT".into(),
        reasons: vec![format!(
            "of the scan points within 5 mm of the model, {:.0} % are within 1 mm ({:.0} % at \
             the registered pose)",
            100.0 * w,
            100.0 * r
        )],
        result: None,
        drift: None,
        notes: Vec::new(),
    };
    let png_wrong = render(&misplaced_summary, std::slice::from_ref(&wrong)).expect("renders");
    let dir = out_dir();
    std::fs::write(dir.join("right.png"), &png_right).expect("write");
    std::fs::write(dir.join("wrong.png"), &png_wrong).expect("write");

    let a = decode(&png_right);
    let b = decode(&png_wrong);
    assert_eq!((a.0, a.1), (REPORT_WIDTH as u32, REPORT_HEIGHT as u32));
    // The verdict bar under the header: green for accepted, red for rejected.
    assert_eq!(pixel(&a, 5, 61), GOOD);
    assert_eq!(pixel(&b, 5, 61), BAD);
    // The right fit's scan is mostly blue (≤ 1 mm), the wrong one's is not.
    let blue = |img: &(u32, u32, Vec<u8>)| {
        let mut n = 0;
        for y in 80..560 {
            for x in 16..656 {
                let p = pixel(img, x, y);
                if p[2] > 120 && u16::from(p[2]) > u16::from(p[0]) + 60 && p[2] > p[1] {
                    n += 1;
                }
            }
        }
        n
    };
    let (blue_right, blue_wrong) = (blue(&a), blue(&b));
    assert!(
        blue_right > 3 * blue_wrong,
        "blue pixels: right {blue_right}, wrong {blue_wrong}"
    );

    // Issue 42: a run of three views shows each view's scan, a panel each, numbered from 1.
    let panels: Vec<ScanView> = (1..=3)
        .map(|k| {
            scan_view(
                &model,
                &q,
                None,
                &sim.cloud,
                &calibration.registrations[0],
                &format!("view {k} of 3"),
                3,
            )
            .expect("scan view")
        })
        .collect();
    assert!(
        panels[0].width <= 318 && panels[0].height <= 238,
        "a quarter of the area"
    );
    let png_three = render(&summary, &panels).expect("renders");
    std::fs::write(dir.join("three.png"), &png_three).expect("write");
    let three = decode(&png_three);
    // Scan pixels (blue, on the model) in the three panels, none in the fourth.
    let blue_in = |x0: u32, y0: u32| {
        let mut n = 0;
        for y in y0..y0 + 238 {
            for x in x0..x0 + 318 {
                let p = pixel(&three, x, y);
                if p[2] > 120 && u16::from(p[2]) > u16::from(p[0]) + 60 && p[2] > p[1] {
                    n += 1;
                }
            }
        }
        n
    };
    let quadrants = [
        blue_in(16, 80),
        blue_in(16 + 322, 80),
        blue_in(16, 80 + 242),
        blue_in(16 + 322, 80 + 242),
    ];
    assert!(
        quadrants[..3].iter().all(|n| *n > 1000) && quadrants[3] == 0,
        "blue pixels per panel: {quadrants:?}"
    );
}

#[test]
fn a_run_without_a_scan_still_gets_a_picture() {
    let summary = Summary {
        title: "calibration 20261124T142300Z-3f9a".into(),
        subtitle: "2026-11-24T14:23:00Z  |  /etc/handeye/handeye.toml".into(),
        outcome: Outcome::Error,
        headline: "ERROR".into(),
        reasons: vec![
            "preflight: robot is in local control; enable Remote Control on the teach pendant"
                .into(),
        ],
        result: None,
        drift: None,
        notes: vec!["failed at stage: preflight".into()],
    };
    let png = render(&summary, &[]).expect("renders");
    let img = decode(&png);
    assert_eq!((img.0, img.1), (REPORT_WIDTH as u32, REPORT_HEIGHT as u32));
    assert_eq!(pixel(&img, 5, 61), BAD);
    std::fs::write(out_dir().join("error.png"), &png).expect("write");
}

#[test]
fn the_drift_chart_shows_checks_against_the_limits() {
    let limits = DriftLimits {
        translation_mm: 1.0,
        rotation_deg: 0.2,
    };
    let t0 = 1_795_000_000.0;
    let points: Vec<DriftPoint> = (0..12)
        .map(|k| {
            let slip = if k >= 9 { 2.0 } else { 0.05 * f64::from(k) };
            DriftPoint {
                unix_s: t0 + 3600.0 * f64::from(k),
                translation_mm: slip,
                rotation_deg: slip * 0.25,
                drifted: k >= 9,
            }
        })
        .collect();
    let png = drift_chart(&points, &[t0 - 600.0], limits, 900, 360).expect("renders");
    std::fs::write(out_dir().join("drift.png"), &png).expect("write");
    let img = decode(&png);
    assert_eq!((img.0, img.1), (900, 360));
    let count = |c: [u8; 3]| {
        (0..img.1)
            .flat_map(|y| (0..img.0).map(move |x| (x, y)))
            .filter(|&(x, y)| pixel(&img, x, y) == c)
            .count()
    };
    // Three drifted checks in red dots, nine in green, and the red limit lines.
    assert!(count(GOOD) > 9 * 2 * 20, "green {}", count(GOOD));
    assert!(count(BAD) > 3 * 2 * 20 + 400, "red {}", count(BAD));
    let empty = drift_chart(&[], &[], limits, 900, 360).expect("renders");
    assert!(
        decode(&empty).2.iter().any(|v| *v < 200),
        "says no checks yet"
    );
}

/// Every run gets its picture, also one that ends in an error before any scan: here the camera
/// delivers nothing after the arm moved to the view.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_run_that_fails_still_writes_its_picture() {
    use std::f64::consts::FRAC_PI_2;
    use std::net::{IpAddr, Ipv4Addr};

    use handeye_hal::fake::{FakeCamera, FakeRobot};
    use handeye_hal::ur_dh::UrModel;

    use crate::config::{RobotPorts, ViewTargets};
    use crate::run::{RunMode, RunRequest, Silent};
    use crate::storage::{REPORT_PICTURE, RUNS_DIR};

    let Some(model) = shared_robot("ur/ur5e/ur5e.urdf") else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("handeye-report-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut cfg = crate::config::sim_rig(
        IpAddr::V4(Ipv4Addr::LOCALHOST),
        RobotPorts::UR_STANDARD,
        "127.0.0.1".into(),
        dir.clone(),
    );
    let home = [0.0, -FRAC_PI_2, FRAC_PI_2, -FRAC_PI_2, -FRAC_PI_2, 0.0];
    let mut view = home;
    view[0] += 0.3;
    cfg.views.targets = ViewTargets::Joints(vec![view]);
    cfg.camera.settle = std::time::Duration::from_millis(10);
    let robot = FakeRobot::new(UrModel::Ur5e, home);
    let camera = FakeCamera::new(Vec::new());
    let record = crate::run::run(
        &robot,
        &camera,
        &model,
        &cfg,
        RunRequest::new(RunMode::Check),
        &tokio_util::sync::CancellationToken::new(),
        &Silent,
    )
    .await;
    assert_eq!(record.outcome, Outcome::Error, "{:?}", record.reasons);
    let path = dir.join(RUNS_DIR).join(&record.run_id).join(REPORT_PICTURE);
    let png = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let img = decode(&png);
    assert_eq!((img.0, img.1), (REPORT_WIDTH as u32, REPORT_HEIGHT as u32));
    assert_eq!(pixel(&img, 5, 61), BAD, "the error shows red");
    let _ = std::fs::remove_dir_all(&dir);
}
