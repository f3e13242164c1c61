use super::*;
use crate::calib::testutil::{base_only, look_at, render, toy_robot, Scene};
use nalgebra::{Point3, Vector3};

fn errors(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    // Camera-origin position error and rotation error.
    let ca = a.inverse().translation.vector;
    let cb = b.inverse().translation.vector;
    ((ca - cb).norm() * 1000.0, d.rotation.angle().to_degrees())
}

#[test]
fn recovers_pose_without_prior() {
    let q = [0.7, -1.2, 1.0];
    let model = toy_robot(&q);
    let truth = look_at(Point3::new(0.45, -0.3, 0.55), Point3::new(0.05, 0.0, 0.1));
    let scan = render(&model, &truth, &Scene::default());
    let reg = register_posed(&scan, &model, None, &RegisterOptions::default()).expect("found");
    let (t, r) = errors(&reg.camera_from_model, &truth);
    eprintln!("{reg:?}\nerr {t:.3} mm {r:.4} deg");
    assert!(t < 1.0 && r < 0.2, "error {t} mm {r} deg");
    assert!(reg.quality.coverage > 0.8, "{:?}", reg.quality);
    assert!(reg.degenerate_directions.is_empty());
}

#[test]
fn recovers_pose_with_prior_and_rejects_empty_scene() {
    let q = [-0.4, -1.5, 1.2];
    let model = toy_robot(&q);
    let truth = look_at(Point3::new(-0.2, 0.5, 0.6), Point3::new(0.0, 0.05, 0.1));
    let scan = render(
        &model,
        &truth,
        &Scene {
            seed: 3,
            ..Scene::default()
        },
    );
    let prior = Isometry3::new(
        Vector3::new(0.01, -0.008, 0.012),
        Vector3::new(0.02, -0.03, 0.04),
    ) * truth;
    let reg =
        register_posed(&scan, &model, Some(prior), &RegisterOptions::default()).expect("found");
    assert!(reg.quality.from_prior);
    let (t, r) = errors(&reg.camera_from_model, &truth);
    assert!(t < 1.0 && r < 0.2, "error {t} mm {r} deg");

    // A floor and nothing else: not found, with or without a prior.
    let empty = render(&PosedModel::default(), &truth, &Scene::default());
    let e = register_posed(&empty, &model, None, &RegisterOptions::default());
    assert!(matches!(e, Err(CalibError::RobotNotFound { .. })), "{e:?}");
    let e = register_posed(&empty, &model, Some(truth), &RegisterOptions::default());
    assert!(matches!(e, Err(CalibError::RobotNotFound { .. })), "{e:?}");
}

#[test]
fn wrong_prior_is_recovered_by_the_global_search() {
    let q = [0.3, -1.0, 0.8];
    let model = toy_robot(&q);
    let truth = look_at(Point3::new(0.5, 0.3, 0.5), Point3::new(0.0, 0.0, 0.1));
    let scan = render(
        &model,
        &truth,
        &Scene {
            seed: 4,
            ..Scene::default()
        },
    );
    // 90° of yaw and 10 cm off: the prior cannot be refined into the right pose.
    let wrong = truth * Isometry3::new(Vector3::new(0.1, 0.0, 0.0), Vector3::z() * 1.57);
    let reg =
        register_posed(&scan, &model, Some(wrong), &RegisterOptions::default()).expect("found");
    assert!(!reg.quality.from_prior);
    let (t, r) = errors(&reg.camera_from_model, &truth);
    assert!(t < 1.0 && r < 0.2, "error {t} mm {r} deg");
}

#[test]
fn covariance_shrinks_with_points_and_round_base_is_degenerate() {
    let q = [0.7, -1.2, 1.0];
    let model = toy_robot(&q);
    let truth = look_at(Point3::new(0.45, -0.3, 0.55), Point3::new(0.05, 0.0, 0.1));
    let scan = render(
        &model,
        &truth,
        &Scene {
            seed: 5,
            ..Scene::default()
        },
    );
    let few = RegisterOptions {
        max_icp_points: 1000,
        ..RegisterOptions::default()
    };
    let many = RegisterOptions {
        max_icp_points: 8000,
        ..RegisterOptions::default()
    };
    let a = register_posed(&scan, &model, Some(truth), &few).expect("found");
    let b = register_posed(&scan, &model, Some(truth), &many).expect("found");
    assert!(b.quality.points_used > 2 * a.quality.points_used);
    assert!(
        b.uncertainty.translation_mm < a.uncertainty.translation_mm,
        "{:?} {:?}",
        a.uncertainty,
        b.uncertainty
    );
    assert!(b.covariance_6x6.trace() < a.covariance_6x6.trace());

    let base = base_only();
    let scan = render(
        &base,
        &truth,
        &Scene {
            seed: 6,
            ..Scene::default()
        },
    );
    let reg =
        register_posed(&scan, &base, Some(truth), &RegisterOptions::default()).expect("found");
    // The free direction is a rotation about the base axis (model z) seen in the camera.
    let axis_cam = truth.rotation * Vector3::z();
    let about_axis = reg.degenerate_directions.iter().any(|d| {
        let rot = Vector3::new(d[3], d[4], d[5]);
        rot.norm() > 0.7 && rot.normalize().dot(&axis_cam).abs() > 0.95
    });
    assert!(about_axis, "{:?}", reg.degenerate_directions);
}

/// The same scan gives the same result to the last bit, however many threads share the work
/// (a recalibration that is repeated on the same data is not to move).
#[test]
fn the_same_scan_gives_the_same_result_on_any_number_of_threads() {
    let q = [0.7, -1.2, 1.0];
    let model = toy_robot(&q);
    let truth = look_at(Point3::new(0.45, -0.3, 0.55), Point3::new(0.05, 0.0, 0.1));
    let scan = render(&model, &truth, &Scene::default());
    let on = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool")
            .install(|| register_posed(&scan, &model, None, &RegisterOptions::default()))
            .expect("found")
    };
    let one = on(1);
    // Several chunks of correspondences are summed.
    assert!(one.quality.points_used > 2048, "{:?}", one.quality);
    for threads in [2, 3, 2] {
        let r = on(threads);
        assert_eq!(
            r.camera_from_model, one.camera_from_model,
            "{threads} threads"
        );
        assert_eq!(r.covariance_6x6, one.covariance_6x6, "{threads} threads");
        assert_eq!(r.quality, one.quality, "{threads} threads");
    }
}
