use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::*;
use crate::calib::report::{QualitySummary, ReportTimings};
use crate::calib::{CalibrationReport, Mount, Uncertainty};
use crate::record::{DriftRecord, ResultRecord, RunTimings, Stage, WriteTarget, Written};
use crate::run::recorder::prune_captures;
use crate::storage::RUNS_DIR;

/// A fresh folder for one test (removed first, so a failed earlier run leaves nothing).
fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("handeye-store-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn pose(x: f64, y: f64, z: f64) -> [[f64; 4]; 4] {
    [
        [1.0, 0.0, 0.0, x],
        [0.0, 1.0, 0.0, y],
        [0.0, 0.0, 1.0, z],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// A complete record built from the public fields, as `run` returns them.
pub(crate) fn record(run_id: &str, mode: RunMode, outcome: Outcome, started: f64) -> RunRecord {
    let uncertainty = Uncertainty {
        translation_mm: 0.21,
        rotation_deg: 0.03,
        workspace: None,
    };
    let report = CalibrationReport {
        outcome,
        reasons: vec![],
        mount: Mount::EyeInHand,
        base_frame: "base".into(),
        base_from_camera: pose(0.4, -0.1, 0.5),
        flange_from_camera: Some(pose(0.0, -0.08, 0.04)),
        uncertainty,
        quality: QualitySummary {
            coverage: 0.8,
            link_support: [Some(0.9), Some(0.8), None],
            free_space_violations: 0.01,
            rmse_mm: 0.4,
            inlier_fraction: 0.9,
            depth_scale: None,
            depth_offset_mm: None,
            frames_used: 3,
            frames: 3,
            views_used: 1,
            views: 1,
        },
        timings_ms: ReportTimings::default(),
        frames: vec![],
        views: vec![],
        split_half: None,
        outline: None,
    };
    let accepted = outcome == Outcome::Accepted;
    RunRecord {
        run_id: run_id.into(),
        mode,
        dry_run: false,
        config: "/etc/handeye/cell.toml".into(),
        trigger: None,
        started_unix_s: started,
        outcome,
        reasons: if accepted {
            vec![]
        } else {
            vec![
                "coverage 0.31 < 0.6: the camera sees too little of the base".into(),
                "second".into(),
            ]
        },
        warnings: vec![],
        failed_stage: (!accepted).then_some(Stage::Solve),
        preflight: None,
        views: vec![],
        forecast: None,
        captures: vec![],
        capture_file: Some(format!("/var/lib/handeye/runs/{run_id}/capture.json")),
        result: Some(ResultRecord {
            mount: Mount::EyeInHand,
            flange_from_camera: Some(pose(0.0, -0.08, 0.04)),
            base_from_camera: pose(0.4, -0.1, 0.5),
            ur_pose: [0.0, -0.08, 0.04, -0.26, 0.0, 0.0],
            uncertainty,
            report,
        }),
        drift: (mode == RunMode::Check).then(|| DriftRecord {
            reference: "result of run X".into(),
            reference_pose: pose(0.0, -0.08, 0.04),
            translation_mm: 0.42,
            rotation_deg: 0.05,
            max_translation_mm: 2.0,
            max_rotation_deg: 0.5,
            drifted: false,
        }),
        change_accepted: None,
        written: if accepted && mode == RunMode::Calibrate {
            vec![
                Written {
                    target: WriteTarget::Tcp,
                    detail: "set_tcp p[0,-0.08,0.04,-0.26,0,0]".into(),
                },
                Written {
                    target: WriteTarget::Files,
                    detail: "current/".into(),
                },
            ]
        } else {
            vec![]
        },
        returned_to_start: true,
        timings_ms: RunTimings {
            total: 4200.0,
            ..RunTimings::default()
        },
    }
}

fn start(run_id: &str, mode: RunMode, started: f64) -> RunStart {
    RunStart {
        run_id: run_id.into(),
        trigger: Trigger::Api,
        mode,
        config_origin: "/etc/handeye/cell.toml".into(),
        config_digest: config_digest("[robot]\nmodel = \"ur5e\"\n"),
        started_unix_s: started,
    }
}

fn now() -> f64 {
    unix_now()
}

#[test]
fn the_store_is_send_sync_and_shareable() {
    fn shareable<T: Send + Sync + 'static>() {}
    shareable::<Store>();
    shareable::<Arc<Store>>();
}

#[test]
fn runs_round_trip_through_begin_finish_list_get_latest() {
    let dir = temp_dir("round-trip");
    let store = Store::open(&dir.join("sub/history.sqlite")).expect("open");
    // A time with a short decimal form: serde_json parses long ones to within 1 ulp only.
    let t = 1_764_000_000.5;
    let a = record("run-a", RunMode::Calibrate, Outcome::Accepted, t);
    let b = record("run-b", RunMode::Check, Outcome::Accepted, t + 10.0);
    let c = record("run-c", RunMode::Calibrate, Outcome::Rejected, t + 20.0);
    store
        .begin(&start("run-a", RunMode::Calibrate, t))
        .expect("begin a");
    let running = store.list(10, None).expect("list");
    assert_eq!(running.len(), 1);
    assert_eq!(running[0].outcome, RunStatus::Running);
    assert_eq!(running[0].outcome.outcome(), None);
    store.finish(Trigger::Api, &a).expect("finish a");
    store
        .begin(&start("run-b", RunMode::Check, t + 10.0))
        .expect("begin b");
    store.finish(Trigger::Schedule, &b).expect("finish b");
    // Finished without begin (the start could not be recorded): inserted whole.
    store.finish(Trigger::Cli, &c).expect("finish c");

    let list = store.list(10, None).expect("list");
    let ids: Vec<&str> = list.iter().map(|s| s.run_id.as_str()).collect();
    assert_eq!(ids, ["run-c", "run-b", "run-a"], "newest first");
    let sa = &list[2];
    assert_eq!(sa.outcome, RunStatus::Ended(Outcome::Accepted));
    assert_eq!(sa.trigger, Trigger::Api);
    assert_eq!(sa.mode, RunMode::Calibrate);
    assert_eq!(sa.started_unix_s, t);
    assert_eq!(sa.duration_ms, Some(4200.0));
    assert_eq!(sa.ur_pose, Some([0.0, -0.08, 0.04, -0.26, 0.0, 0.0]));
    assert_eq!(sa.uncertainty_translation_mm, Some(0.21));
    assert_eq!(sa.uncertainty_rotation_deg, Some(0.03));
    assert_eq!(sa.written, [WriteTarget::Tcp, WriteTarget::Files]);
    assert_eq!(sa.drifted, None);
    assert_eq!(sa.reason, None);
    assert_eq!(
        sa.config_digest.as_deref(),
        Some(config_digest("[robot]\nmodel = \"ur5e\"\n").as_str())
    );
    assert!(sa.finished_unix_s.is_some());
    let sb = &list[1];
    assert_eq!(sb.trigger, Trigger::Schedule);
    assert_eq!(sb.drift_translation_mm, Some(0.42));
    assert_eq!(sb.drift_rotation_deg, Some(0.05));
    assert_eq!(sb.drifted, Some(false));
    let sc = &list[0];
    assert_eq!(sc.outcome, RunStatus::Ended(Outcome::Rejected));
    assert_eq!(sc.failed_stage, Some(Stage::Solve));
    assert!(sc
        .reason
        .as_deref()
        .is_some_and(|r| r.starts_with("coverage 0.31")));
    assert_eq!(sc.config_digest, None);
    assert_eq!(sc.config_origin, "/etc/handeye/cell.toml");

    // Paging.
    let page = store.list(1, Some(sb.started_unix_s)).expect("page");
    assert_eq!(page.len(), 1);
    assert_eq!(page[0].run_id, "run-a");

    // The record, exactly as serialised.
    let got = store.get("run-a").expect("get").expect("present");
    assert_eq!(
        serde_json::to_value(got).expect("json"),
        serde_json::to_value(&a).expect("json")
    );
    assert_eq!(store.get("nope").expect("get"), None);
    assert_eq!(store.summary("run-b").expect("summary").as_ref(), Some(sb));

    let latest = |m, o| store.latest(m, o).expect("latest").map(|s| s.run_id);
    assert_eq!(latest(None, None).as_deref(), Some("run-c"));
    assert_eq!(latest(Some(RunMode::Check), None).as_deref(), Some("run-b"));
    assert_eq!(
        latest(Some(RunMode::Calibrate), Some(Outcome::Accepted)).as_deref(),
        Some("run-a")
    );
    assert_eq!(latest(Some(RunMode::Check), Some(Outcome::Rejected)), None);

    // Summaries serialise with the status as one string.
    let json = serde_json::to_value(sa).expect("json");
    assert_eq!(json["outcome"], "accepted");
    assert_eq!(json["mode"], "calibrate");
    let back: RunSummary = serde_json::from_value(json).expect("back");
    assert_eq!(&back, sa);

    // Same id twice is refused with a clear error.
    let err = store
        .begin(&start("run-a", RunMode::Calibrate, t))
        .expect_err("duplicate");
    assert!(matches!(err, StoreError::DuplicateRun { .. }), "{err}");
    drop(store);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_run_left_running_is_aborted_on_the_next_open() {
    let dir = temp_dir("interrupted");
    let path = dir.join("history.sqlite");
    let t = now();
    {
        let store = Store::open(&path).expect("open");
        store
            .begin(&start("done", RunMode::Check, t - 5.0))
            .expect("begin");
        store
            .finish(
                Trigger::Api,
                &record("done", RunMode::Check, Outcome::Accepted, t - 5.0),
            )
            .expect("finish");
        store
            .begin(&start("open", RunMode::Calibrate, t))
            .expect("begin");
        // A second writer while the first lives must not touch its run in progress.
        let second = Store::open(&path).expect("second writer");
        let s = second.summary("open").expect("summary").expect("present");
        assert_eq!(s.outcome, RunStatus::Running);
    }
    let store = Store::open(&path).expect("reopen");
    let s = store.summary("open").expect("summary").expect("present");
    assert_eq!(s.outcome, RunStatus::Ended(Outcome::Aborted));
    assert_eq!(s.reason.as_deref(), Some(INTERRUPTED_REASON));
    let done = store.summary("done").expect("summary").expect("present");
    assert_eq!(done.outcome, RunStatus::Ended(Outcome::Accepted));
    let partial = store.get("open").expect("get").expect("present");
    assert!(matches!(partial, StoredRun::Partial(_)), "{partial:?}");
    let partial = serde_json::to_value(partial).expect("json");
    assert_eq!(partial["outcome"], "aborted");
    assert_eq!(partial["complete"], false);
    assert_eq!(partial["reasons"][0], INTERRUPTED_REASON);
    assert_eq!(partial["mode"], "calibrate");
    // Read-only opens never recover.
    store
        .begin(&start("open2", RunMode::Check, t + 1.0))
        .expect("begin");
    drop(store);
    let reader = Store::open_read_only(&path).expect("read only");
    let s = reader.summary("open2").expect("summary").expect("present");
    assert_eq!(s.outcome, RunStatus::Running);
    drop(reader);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Set for the child process of [`a_process_killed_mid_run_leaves_a_usable_history`].
const CHILD_ENV: &str = "HANDEYE_STORE_KILL_CHILD";

/// The child half of the kill test: does nothing unless [`CHILD_ENV`] names a folder.
#[test]
fn killed_writer_child() {
    let Some(dir) = std::env::var_os(CHILD_ENV).map(PathBuf::from) else {
        return;
    };
    let store = Store::open(&dir.join("history.sqlite")).expect("child open");
    let t = now();
    store
        .begin(&start("open-run", RunMode::Calibrate, t))
        .expect("child begin");
    // Keep writing until killed: the kill lands in the middle of some statement.
    for i in 0..100_000 {
        let id = format!("run-{i:05}");
        let started = t + 1.0 + i as f64;
        store
            .begin(&start(&id, RunMode::Check, started))
            .expect("child begin");
        store
            .finish(
                Trigger::Schedule,
                &record(&id, RunMode::Check, Outcome::Accepted, started),
            )
            .expect("child finish");
        if i == 3 {
            std::fs::write(dir.join("ready"), b"4 runs finished").expect("ready");
        }
    }
    std::thread::sleep(Duration::from_secs(60));
}

#[test]
fn a_process_killed_mid_run_leaves_a_usable_history() {
    if std::env::var_os(CHILD_ENV).is_some() {
        return;
    }
    let dir = temp_dir("killed");
    let name = format!(
        "{}::killed_writer_child",
        module_path!().split_once("::").map_or("", |(_, rest)| rest)
    );
    let mut child = std::process::Command::new(std::env::current_exe().expect("test binary"))
        .args([name.as_str(), "--exact", "--nocapture", "--test-threads=1"])
        .env(CHILD_ENV, &dir)
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("spawn the child");
    let t0 = Instant::now();
    while !dir.join("ready").exists() {
        if let Some(status) = child.try_wait().expect("wait") {
            panic!("the child ended before it was ready: {status}");
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the child never got ready"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(30));
    child.kill().expect("SIGKILL"); // SIGKILL on unix: no destructor, no flush
    let status = child.wait().expect("reaped");
    assert!(!status.success(), "killed, not ended: {status}");

    let store = Store::open(&dir.join("history.sqlite")).expect("opens after the kill");
    let open = store
        .summary("open-run")
        .expect("summary")
        .expect("present");
    assert_eq!(open.outcome, RunStatus::Ended(Outcome::Aborted));
    assert_eq!(open.reason.as_deref(), Some(INTERRUPTED_REASON));
    let all = store.list(usize::MAX, None).expect("list");
    assert!(
        all.len() >= 5,
        "the open run and at least 4 finished ones: {}",
        all.len()
    );
    let mut finished = 0;
    for s in &all {
        if s.run_id == "open-run" {
            continue;
        }
        match s.outcome {
            RunStatus::Ended(Outcome::Accepted) => {
                finished += 1;
                let json = serde_json::to_value(store.get(&s.run_id).expect("get")).expect("json");
                assert_eq!(json["run_id"], s.run_id.as_str());
                assert_eq!(s.drift_translation_mm, Some(0.42));
            }
            // The one begun but not finished when the kill landed.
            RunStatus::Ended(Outcome::Aborted) => {
                assert_eq!(s.reason.as_deref(), Some(INTERRUPTED_REASON));
            }
            other => panic!("{}: unexpected {other}", s.run_id),
        }
    }
    assert!(
        finished >= 4,
        "the runs finished before `ready` are intact: {finished}"
    );
    for i in 0..4 {
        let s = store
            .summary(&format!("run-{i:05}"))
            .expect("summary")
            .expect("present");
        assert_eq!(s.outcome, RunStatus::Ended(Outcome::Accepted));
    }
    drop(store);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_reader_reads_while_a_writer_writes() {
    let dir = temp_dir("concurrent");
    let path = dir.join("history.sqlite");
    let writer = Arc::new(Store::open(&path).expect("open"));
    let reader = Store::open_read_only(&path).expect("read only");
    let t = now();
    let w = Arc::clone(&writer);
    let writing = std::thread::spawn(move || {
        for i in 0..40 {
            let id = format!("w{i:03}");
            w.begin(&start(&id, RunMode::Check, t + i as f64))
                .expect("begin");
            w.finish(
                Trigger::Schedule,
                &record(&id, RunMode::Check, Outcome::Accepted, t + i as f64),
            )
            .expect("finish");
        }
    });
    let mut seen = 0;
    while !writing.is_finished() {
        let list = reader
            .list(1000, None)
            .expect("reader lists while the writer writes");
        assert!(list.len() >= seen, "never goes back");
        seen = list.len();
        if let Some(s) = list.first() {
            reader
                .get(&s.run_id)
                .expect("reader gets")
                .expect("present");
        }
    }
    writing.join().expect("writer");
    assert_eq!(reader.list(1000, None).expect("list").len(), 40);
    // A second, independent reader in another thread too.
    let p2 = path.clone();
    std::thread::spawn(move || {
        let r = Store::open_read_only(&p2).expect("read only");
        assert_eq!(r.list(5, None).expect("list").len(), 5);
    })
    .join()
    .expect("reader thread");
    // Writes through a read-only store are refused.
    let err = reader
        .begin(&start("x", RunMode::Check, t))
        .expect_err("read only");
    assert!(matches!(err, StoreError::ReadOnly { .. }), "{err}");
    let err = reader.captures_to_prune(0, 0.0).expect_err("read only");
    assert!(matches!(err, StoreError::ReadOnly { .. }), "{err}");
    drop((reader, writer));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn pruning_removes_only_the_old_raw_captures() {
    let dir = temp_dir("prune");
    let store = Store::open(&dir.join("history.sqlite")).expect("open");
    let day = 86_400.0;
    let t = now();
    // Oldest first: 3 runs 40 days old, 1 run 40 days old still running, 2 recent ones.
    let runs = [
        ("old-1", t - 42.0 * day, true),
        ("old-2", t - 41.0 * day, true),
        ("old-3", t - 40.0 * day, true),
        ("old-running", t - 39.0 * day, false),
        ("new-1", t - 2.0 * day, true),
        ("new-2", t - 1.0 * day, true),
    ];
    for (id, started, finished) in runs {
        let run_dir = dir.join(RUNS_DIR).join(id);
        std::fs::create_dir_all(&run_dir).expect("run dir");
        for name in [
            "view0_frame0.ply",
            "view1_frame2.ply",
            "capture.json",
            "record.json",
            "notes.ply",
        ] {
            std::fs::write(run_dir.join(name), b"x").expect("file");
        }
        store
            .begin(&start(id, RunMode::Calibrate, started))
            .expect("begin");
        if finished {
            store
                .finish(
                    Trigger::Api,
                    &record(id, RunMode::Calibrate, Outcome::Accepted, started),
                )
                .expect("finish");
        }
    }
    // Keep the newest 3 runs (new-2, new-1, old-running) and everything younger than 30 days:
    // old-3, the 4th newest, goes.
    let mut removed = prune_captures(&store, &dir, 3, 30.0).expect("prune");
    removed.sort();
    let expected: Vec<PathBuf> = ["old-1", "old-2", "old-3"]
        .iter()
        .flat_map(|id| {
            ["view0_frame0.ply", "view1_frame2.ply"].map(|f| dir.join(RUNS_DIR).join(id).join(f))
        })
        .collect();
    assert_eq!(removed, expected);
    for (id, _, _) in runs {
        let run_dir = dir.join(RUNS_DIR).join(id);
        let pruned = id.starts_with("old-") && id != "old-running";
        assert_eq!(!run_dir.join("view0_frame0.ply").exists(), pruned, "{id}");
        for kept in ["capture.json", "record.json", "notes.ply"] {
            assert!(run_dir.join(kept).exists(), "{id}/{kept} kept");
        }
        let s = store.summary(id).expect("summary").expect("present");
        assert_eq!(s.captures_pruned_unix_s.is_some(), pruned, "{id}");
        assert!(store.get(id).expect("get").is_some(), "{id}: record kept");
    }
    // Nothing left to do; a run that is still running is never pruned, even with keep 0.
    assert_eq!(
        prune_captures(&store, &dir, 3, 30.0).expect("prune"),
        Vec::<PathBuf>::new()
    );
    let removed = prune_captures(&store, &dir, 0, 0.0).expect("prune all");
    assert_eq!(removed.len(), 4, "new-1, new-2: {removed:?}");
    assert!(dir
        .join(RUNS_DIR)
        .join("old-running/view0_frame0.ply")
        .exists());
    // A run whose folder is gone is fine.
    std::fs::remove_dir_all(dir.join(RUNS_DIR).join("old-running")).expect("rm");
    store
        .finish(
            Trigger::Api,
            &record(
                "old-running",
                RunMode::Calibrate,
                Outcome::Error,
                t - 39.0 * day,
            ),
        )
        .expect("finish");
    assert_eq!(
        prune_captures(&store, &dir, 0, 0.0).expect("prune"),
        Vec::<PathBuf>::new()
    );
    assert!(store
        .summary("old-running")
        .expect("summary")
        .expect("present")
        .captures_pruned_unix_s
        .is_some());
    drop(store);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_corrupted_file_is_set_aside_by_a_writer_and_refused_clearly_by_a_reader() {
    let dir = temp_dir("corrupt");
    for (name, bytes) in [
        ("short.sqlite", b"not a database".to_vec()),
        (
            "garbage.sqlite",
            (0..16_384u32)
                .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
                .collect(),
        ),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, &bytes).expect("garbage");
        let err = Store::open_read_only(&path).expect_err("refused");
        assert!(matches!(err, StoreError::Corrupt { .. }), "{name}: {err:?}");
        let msg = err.to_string();
        assert!(msg.contains(&path.display().to_string()), "{msg}");
        assert!(
            msg.contains("corrupted") && msg.contains("sets it aside"),
            "{msg}"
        );
        // A writer moves it aside, kept as it was, and starts a new history.
        let store = Store::open(&path).expect("a new history");
        let aside = store.set_aside().expect("set aside").clone();
        assert!(store.is_new());
        assert_eq!(
            std::fs::read(&aside.path).expect("kept"),
            bytes,
            "{aside:?}"
        );
        assert!(
            aside.path.to_string_lossy().contains(".damaged-"),
            "{aside:?}"
        );
        assert!(store.list(10, None).expect("list").is_empty());
    }
    // A database of someone else's.
    let foreign = dir.join("foreign.sqlite");
    Connection::open(&foreign)
        .and_then(|c| c.execute_batch("CREATE TABLE t (x)"))
        .expect("foreign db");
    let err = Store::open(&foreign).expect_err("foreign");
    assert!(matches!(err, StoreError::Foreign { .. }), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_newer_schema_is_refused() {
    let dir = temp_dir("newer");
    let path = dir.join("history.sqlite");
    drop(Store::open(&path).expect("create"));
    Connection::open(&path)
        .and_then(|c| {
            c.execute(
                "INSERT INTO schema_version (version, applied_unix_s) VALUES (?1, 0)",
                [SCHEMA_VERSION + 1],
            )
        })
        .expect("bump the version");
    for result in [Store::open(&path), Store::open_read_only(&path)] {
        let err = result.expect_err("refused");
        assert!(
            matches!(err, StoreError::TooNew { found, supported, .. } if found == SCHEMA_VERSION + 1 && supported == SCHEMA_VERSION),
            "{err:?}"
        );
        assert!(err.to_string().contains("newer than this program"), "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_missing_history_says_who_writes_it() {
    let dir = temp_dir("missing");
    let path = dir.join("history.sqlite");
    let err = Store::open_read_only(&path).expect_err("missing");
    assert!(matches!(err, StoreError::NoHistory { .. }), "{err}");
    assert_eq!(
        err.to_string(),
        format!(
            "no history yet at {}: the daemon (or calibrate with history) writes it",
            path.display()
        )
    );
    assert!(!path.exists(), "a read-only open creates nothing");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_schema_is_versioned_and_migrated_once() {
    let dir = temp_dir("schema");
    let path = dir.join("history.sqlite");
    drop(Store::open(&path).expect("create"));
    drop(Store::open(&path).expect("reopen"));
    let conn = Connection::open(&path).expect("raw");
    let versions: i64 = conn
        .query_row("SELECT count(*) FROM schema_version", [], |r| r.get(0))
        .expect("versions");
    assert_eq!(versions, SCHEMA_VERSION);
    let mode: String = conn
        .query_row("PRAGMA journal_mode", [], |r| r.get(0))
        .expect("mode");
    assert_eq!(mode, "wal");
    let indexes: Vec<String> = conn
        .prepare("SELECT name FROM sqlite_master WHERE type = 'index' AND tbl_name = 'runs' ORDER BY name")
        .and_then(|mut s| s.query_map([], |r| r.get(0))?.collect())
        .expect("indexes");
    assert!(
        indexes.contains(&"runs_started".into()) && indexes.contains(&"runs_outcome".into()),
        "{indexes:?}"
    );
    drop(conn);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn digests_and_times_are_stable() {
    // FNV-1a 64 test vectors.
    assert_eq!(config_digest(""), "cbf29ce484222325");
    assert_eq!(config_digest("a"), "af63dc4c8601ec8c");
    assert_eq!(config_digest("foobar"), "85944171f73967e8");
    assert!(RunStatus::parse("bogus").is_none());
    for s in [
        "running", "accepted", "rejected", "aborted", "error", "planned",
    ] {
        assert_eq!(RunStatus::parse(s).map(RunStatus::name), Some(s));
    }
}

/// Runs `ids` recorded in `store` and each with its record in `storage`'s run folder, as the
/// recorder leaves them.
fn recorded_runs(store: &Store, storage: &std::path::Path, ids: &[&str]) {
    for (k, id) in ids.iter().enumerate() {
        let mut r = record(
            id,
            RunMode::Calibrate,
            Outcome::Accepted,
            1_000.0 + k as f64,
        );
        r.trigger = Some(Trigger::Api);
        store.finish(Trigger::Api, &r).expect("finish");
        crate::storage::write_record(&storage.join(RUNS_DIR).join(id), &r).expect("record");
    }
}

/// Issue 23: a history with damaged pages is set aside (kept) when opened for writing and a
/// new one is rebuilt from the run folders' records, with every run still listed.
#[test]
fn issue_23_a_damaged_history_is_set_aside_and_rebuilt_from_the_run_folders() {
    let dir = temp_dir("damaged-pages");
    let db = dir.join(HISTORY_FILE);
    let ids = ["r1", "r2", "r3"];
    {
        let store = Store::open(&db).expect("open");
        recorded_runs(&store, &dir, &ids);
    }
    // Damage every page after the first (the schema's root): `quick_check` sees it.
    let mut bytes = std::fs::read(&db).expect("db");
    assert!(bytes.len() >= 8192, "{} bytes", bytes.len());
    for (i, b) in bytes.iter_mut().enumerate().skip(4096) {
        *b = (i as u32).wrapping_mul(2_654_435_761).to_le_bytes()[1];
    }
    std::fs::write(&db, &bytes).expect("damage");
    let store = crate::run::open_history(&db).expect("rebuilt");
    let aside = store.set_aside().expect("set aside");
    assert_eq!(std::fs::read(&aside.path).expect("kept"), bytes);
    let listed: Vec<(String, Trigger)> = store
        .list(10, None)
        .expect("list")
        .into_iter()
        .map(|r| (r.run_id, r.trigger))
        .collect();
    assert_eq!(
        listed,
        [
            ("r3", Trigger::Api),
            ("r2", Trigger::Api),
            ("r1", Trigger::Api)
        ]
        .map(|(i, t)| (i.to_string(), t))
    );
    // Opening again finds it healthy: nothing more set aside, nothing added twice.
    drop(store);
    let store = crate::run::open_history(&db).expect("open");
    assert!(store.set_aside().is_none() && !store.is_new());
    assert_eq!(store.list(10, None).expect("list").len(), 3);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 23: a 0-byte history beside run folders is not silently a new empty history: it is
/// set aside and the runs are listed again.
#[test]
fn issue_23_an_empty_history_file_beside_run_folders_is_rebuilt() {
    let dir = temp_dir("zero-bytes");
    let db = dir.join(HISTORY_FILE);
    {
        let store = Store::open(&db).expect("open");
        recorded_runs(&store, &dir, &["a", "b"]);
    }
    std::fs::write(&db, b"").expect("truncate");
    for suffix in ["-wal", "-shm"] {
        let _ = std::fs::remove_file(dir.join(format!("{HISTORY_FILE}{suffix}")));
    }
    let store = crate::run::open_history(&db).expect("rebuilt");
    let aside = store.set_aside().expect("set aside");
    assert!(aside.why.contains("empty"), "{aside:?}");
    assert_eq!(store.list(10, None).expect("list").len(), 2);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 23: one row that does not read back is skipped with a warning; the others list.
#[test]
fn issue_23_one_bad_row_does_not_fail_the_list() {
    let dir = temp_dir("bad-row");
    let db = dir.join(HISTORY_FILE);
    let store = Store::open(&db).expect("open");
    recorded_runs(&store, &dir, &["good1", "good2"]);
    store
        .lock()
        .execute(
            "INSERT INTO runs (run_id, trigger, mode, outcome, started_unix_s, config_origin)
             VALUES ('bad', 'teleport', 'calibrate', 'exploded', 1500.0, 'x')",
            [],
        )
        .expect("bad row");
    let listed: Vec<String> = store
        .list(10, None)
        .expect("list")
        .into_iter()
        .map(|r| r.run_id)
        .collect();
    assert_eq!(listed, ["good2", "good1"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 46: `history.sqlite-lock` (and the database, and its `-wal`) are never opened
/// through a link (an outside file was created or locked): the history refuses to open,
/// saying so, and the link's target is not made.
#[cfg(unix)]
#[test]
fn issue_46_the_writers_lock_is_never_opened_through_a_link() {
    let dir = temp_dir("lock-link");
    let db = dir.join(HISTORY_FILE);
    let outside = dir.join("outside");
    std::os::unix::fs::symlink(&outside, dir.join("history.sqlite-lock")).expect("link");
    let e = Store::open(&db).expect_err("a link in the lock's place");
    assert!(e.to_string().contains("is a symbolic link"), "{e}");
    assert!(!outside.exists(), "the link's target was created");
    std::fs::remove_file(dir.join("history.sqlite-lock")).expect("rm");
    // … nor the database or the files SQLite keeps beside it.
    for name in [HISTORY_FILE, "history.sqlite-wal"] {
        std::os::unix::fs::symlink(&outside, dir.join(name)).expect("link");
        let e = Store::open(&db).expect_err("a link in the history's place");
        assert!(
            e.to_string()
                .contains("is a symbolic link; the history is never opened"),
            "{name}: {e}"
        );
        assert!(!outside.exists(), "{name}: the link's target was created");
        std::fs::remove_file(dir.join(name)).expect("rm");
    }
    // A storage reached through a linked folder is no link in the history's place.
    let real = dir.join("real");
    std::fs::create_dir_all(&real).expect("real");
    std::os::unix::fs::symlink(&real, dir.join("via")).expect("folder link");
    let store = Store::open(&dir.join("via").join(HISTORY_FILE)).expect("through a folder link");
    drop(store);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 46: a run whose process lived on but could not record its end (a full disk) is not
/// called "crash, power loss or kill" at the next open (it was); one without the mark still is.
#[test]
fn issue_46_a_run_ended_unrecorded_is_not_called_killed() {
    let dir = temp_dir("unrecorded");
    let db = dir.join(HISTORY_FILE);
    let (full, killed) = ("20261124T100000Z-00a1", "20261124T100100Z-00a2");
    {
        let store = Store::open(&db).expect("store");
        for id in [full, killed] {
            let r = record(id, RunMode::Check, Outcome::Accepted, 1_700_000_000.0);
            store
                .begin(&RunStart::new(&r, Trigger::Api, String::new()))
                .expect("begin");
        }
        let run_dir = crate::storage::run_folder(&dir, full);
        std::fs::create_dir_all(&run_dir).expect("run folder");
        crate::storage::mark_run_unrecorded(&run_dir).expect("mark");
    }
    let store = Store::open(&db).expect("opens again");
    let reason = |id| store.summary(id).expect("summary").expect("row").reason;
    assert_eq!(reason(full).as_deref(), Some(UNRECORDED_REASON));
    assert_eq!(reason(killed).as_deref(), Some(INTERRUPTED_REASON));
    let _ = std::fs::remove_dir_all(&dir);
}
