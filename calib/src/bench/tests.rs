//! The bench's own tests: trials counted, runs planned, drift checks.

use super::*;
use crate::calib::pipeline::{calibrate_frames, Frame};
use crate::calib::solve::distance_at;
use crate::calib::testutil::eye_to_hand_plan;
use crate::sim::simulate_scan;

/// Eye-to-hand: a fixed camera 0.8–2 m from the base sees the whole arm in random
/// configurations; on structured-light scans each trial is accepted and within 2 mm /
/// 0.5° of the true `base_from_camera`.
#[test]
fn an_eye_to_hand_bench_on_structured_light_scans_is_correct() {
    let Some((model, cfg, plan)) = eye_to_hand_plan("ur/ur5e/ur5e.urdf", 2, 3) else {
        return;
    };
    let (near, far) = FIXED_CAMERA_DISTANCE_M;
    let d = plan.mount.translation.vector.norm();
    assert!(
        d > near - 0.1 && d < far + 0.5,
        "camera {d} m from the base"
    );
    eprintln!(
        "camera {:.3} m from the base",
        plan.mount.translation.vector.norm()
    );
    let summary = run_robot(&model, &cfg, |t| {
        eprintln!(
            "view {}: {:?} {:.3} mm {:.4}° (σ {:.3} mm) {:?}",
            t.view,
            t.outcome,
            t.translation_error_mm,
            t.rotation_error_deg,
            t.uncertainty_translation_mm,
            t.reasons
        )
    })
    .expect("plans");
    assert_eq!(summary.trials, 2);
    assert_eq!(summary.correct, 2, "{:?}", summary.details);
    // The same seed draws the same camera and arm configurations.
    let again = plan_trials(&model, &cfg).expect("views");
    assert_eq!(again.mount, plan.mount);
    assert_eq!(again.views, plan.views);
    // Eye-in-hand draws stay as they were: the mount is the wrist mount of the seed.
    let eih = plan_trials(
        &model,
        &BenchConfig {
            views: 1,
            seed: 3,
            ..BenchConfig::default()
        },
    )
    .expect("views");
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    assert_eq!(eih.mount, random_mount(&mut rng));
}

/// A fixed camera 1.6 m from a UR10e: a turn of the camera by its rotation σ moves its
/// origin by more than the gate's 1 mm, the robot base it looks at by well under. The gate
/// judges the base (accepted), and the result is right there.
#[test]
fn a_fixed_camera_far_from_the_arm_is_judged_at_the_robot_base() {
    // The camera 1.62 m from the base.
    let Some((model, cfg, plan)) = eye_to_hand_plan("ur/ur10e/ur10e.urdf", 1, 2) else {
        return;
    };
    let req = cfg.scan_request(&model, &plan.views[0], plan.mount, plan.scan_seeds[0][0]);
    let req = match cfg.true_arm(&model, plan.scan_seeds[0][0]) {
        Some(arm) => req.with_arm(arm),
        None => req,
    };
    let scan = simulate_scan(&req).expect("simulated");
    let frame = Frame {
        view: 0,
        cloud: scan.cloud,
        joints: plan.views[0].clone(),
        model_from_flange: Some(scan.truth.model_from_flange_reported),
        source: "far".into(),
        image: None,
    };
    let c = calibrate_frames(&model, &[frame], &PipelineOptions::new(Mount::EyeToHand))
        .expect("registered");
    let u = c.registrations[0].uncertainty;
    let w = u.workspace.expect("a registration reports the base's σ");
    eprintln!("{u:?} {:?}", c.verdict);
    assert!(w.distance_m > 1.5 && w.distance_m < 2.0, "{w:?}");
    assert!(u.translation_mm > 1.0, "{u:?}");
    // Under the gate's 1 mm at the base (0.71 mm with the housings' prior, 2026-11-28).
    assert!(w.translation_mm < 0.9, "{u:?}");
    assert!(c.verdict.passed(), "{:?}", c.verdict);
    assert_eq!(
        c.report.uncertainty.workspace.map(|f| f.distance_m),
        Some(w.distance_m)
    );
    // Right where the camera looks: the true base, in the camera frame, lands within 2 mm.
    let base = Point3::from(plan.mount.inverse().translation.vector);
    let (off_mm, turn_deg) = distance_at(&c.base_from_camera, &plan.mount, &base);
    assert!(
        off_mm < WRONG_TRANSLATION_MM && turn_deg < WRONG_ROTATION_DEG,
        "{off_mm} mm {turn_deg}°"
    );
}

/// A wrist camera's bench of six views, one scan each, calibrated three views at a time.
fn two_runs_of_three_views() -> BenchConfig {
    BenchConfig {
        views: 6,
        scans_per_view: 1,
        views_per_run: 3,
        ..BenchConfig::new(Mount::EyeInHand)
    }
}

/// Issue 43: with several views per run the bench measures the runs `calibrate` plans: a
/// random first view, the others near it (the base and upper arm turned a little, within
/// [`NEARBY_SPAN_RAD`]), the flange turned between them, every path clear. Random views
/// grouped three at a time swung the base anywhere, which no run does.
#[test]
fn issue_43_a_run_s_views_are_planned_as_calibrate_plans_them() {
    use crate::plan::NEARBY_SPAN_RAD;
    let Some(model) = crate::testutil::shared_robot("ur/ur5e/ur5e.urdf") else {
        return;
    };
    let cfg = two_runs_of_three_views();
    let plan = plan_trials(&model, &cfg).expect("plans");
    assert_eq!(plan.views.len(), 6);
    let planner = ViewPlanner::new(
        &model,
        plan.mount,
        cfg.intrinsics,
        ViewConstraints::default(),
    );
    for run in plan.views.chunks(3) {
        for q in &run[1..] {
            for (k, span) in NEARBY_SPAN_RAD.iter().enumerate() {
                assert!(
                    (q[k] - run[0][k]).abs() <= span + 1e-9,
                    "joint {k}: {q:?} vs {:?}",
                    run[0]
                );
            }
            assert!(planner.flange_turn(&run[0], q).expect("posed") > 0.1);
        }
        for pair in run.windows(2) {
            let path = planner
                .check_path(&pair[0], &pair[1], PATH_STEP_RAD)
                .expect("posed");
            assert!(path.is_ok(), "{path:?}");
        }
    }
}

/// Issue 43: flange poses handed in a frame 0.3 mm / 0.3 mrad off the model's (a ROS
/// `world`, a URDF root whose z is not joint 1's axis) with the nominal URDF, three views
/// per run: each result is either refused or within 3σ of the truth. Fitting the views as
/// if the poses were in the model's frame put these runs 4–6σ off (0.45–1.15 mm with σ
/// near 0.1 mm), accepted.
#[test]
fn issue_43_poses_in_a_frame_off_the_model_s_stay_within_their_sigma() {
    let Some(model) = crate::testutil::shared_robot("ur/ur5e/ur5e.urdf") else {
        return;
    };
    let cfg = BenchConfig {
        seed: 1,
        kinematics: BenchKinematics::Unknown,
        pose_frame: (3e-4, 3e-4),
        ..two_runs_of_three_views()
    }
    .solver_told_the_arm();
    let summary = run_robot(&model, &cfg, |_| ()).expect("plans");
    assert_eq!(summary.trials, 2);
    for t in &summary.details {
        eprintln!(
            "view {}: {:?} {:.3} mm ({:.2} σ) {:.4}° ({:.2} σ) {:?}",
            t.view,
            t.outcome,
            t.translation_error_mm,
            t.translation_over_sigma(),
            t.rotation_error_deg,
            t.rotation_over_sigma(),
            t.reasons
        );
        assert!(
            t.outcome != Outcome::Accepted
                || (t.translation_over_sigma() <= 3.0 && t.rotation_over_sigma() <= 3.0),
            "accepted {:.3} mm with σ {:.3} mm, {:.4}° with σ {:.4}°",
            t.translation_error_mm,
            t.uncertainty_translation_mm,
            t.rotation_error_deg,
            t.uncertainty_rotation_deg
        );
    }
}

#[test]
fn stats_are_the_textbook_ones_and_ignore_nan() {
    let s = Stats::of([1.0, 2.0, 3.0, 4.0, f64::NAN, 100.0]);
    assert_eq!(s.median, 3.0);
    assert_eq!(s.max, 100.0);
    assert!((s.mean - 22.0).abs() < 1e-12);
    assert!(Stats::of([]).mean.is_nan());
}

#[test]
fn a_wrong_accepted_result_is_counted_as_wrong() {
    let t = |outcome, e: f64| Trial {
        outcome,
        translation_error_mm: e,
        rotation_error_deg: 0.01,
        uncertainty_translation_mm: 0.1,
        uncertainty_rotation_deg: 0.01,
        register_ms: 1.0,
        ..Trial::new(0, 0)
    };
    let s = RobotSummary::new(
        "r",
        vec![
            t(Outcome::Accepted, 0.2),
            t(Outcome::Accepted, 3.0),
            t(Outcome::Rejected, 9.0),
            t(Outcome::Error, f64::NAN),
        ],
    );
    assert_eq!(
        (s.correct, s.wrong_accepted, s.rejected, s.errors),
        (1, 1, 1, 1)
    );
    assert_eq!(s.success_rate, 0.25);
    assert_eq!(s.translation_mm.max, 3.0);
}
