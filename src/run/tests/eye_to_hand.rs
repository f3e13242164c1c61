//! The eye-to-hand cell: a camera fixed in the cell found in the base frame, from joint targets
//! and from where the arm stands.

use super::*;

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
