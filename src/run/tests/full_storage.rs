//! A storage that is or becomes full: nothing moves or nothing reaches the controller, what the
//! controller took is undone, and a run whose end is recorded late stays accepted.

use super::*;

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
