//! Runs that stop before or while the arm moves: a dry run, cancels before the start, during a
//! capture and during a long plan, an obstacle on the path.

use super::*;

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
