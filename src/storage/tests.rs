//! The run folder's files: ids, atomic writes under a kill, planted links and records, the
//! result files.

use super::current::write_exports;
use super::*;
use crate::calib::export::{ExportMeta, Exports};
use crate::record::RunMode;
use nalgebra::Isometry3;
use std::time::{Duration, Instant};

/// Names the file whose write stops between the flushed temporary file and the rename.
const STALL_ENV: &str = "HANDEYE_TEST_STALL_BEFORE_RENAME";
/// Set in the child process of the crash test: the folder it writes into.
const CHILD_ENV: &str = "HANDEYE_TEST_STORAGE_CHILD";

/// Test hook of [`write_atomically`]: with [`STALL_ENV`] naming `path`'s file name, the
/// write leaves `<path>.stalled` as a sign and waits forever before the rename (to be
/// killed there).
pub(super) fn stall_before_rename(path: &Path) {
    let Ok(name) = std::env::var(STALL_ENV) else {
        return;
    };
    if path.file_name().is_some_and(|n| n == name.as_str()) {
        let _ = std::fs::write(path.with_extension("stalled"), b"");
        loop {
            std::thread::sleep(Duration::from_secs(1));
        }
    }
}

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("handeye-storage-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("dir");
    dir
}

/// The id of the record in `dir`, which must parse whole.
fn read_record(dir: &Path) -> String {
    let text = std::fs::read_to_string(dir.join(RECORD_FILE)).expect("record.json");
    let record: RunRecord =
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("a torn record ({e}): {text}"));
    record.run_id
}

#[test]
fn run_ids_carry_the_utc_date_and_name_one_folder() {
    let id = new_run_id();
    assert_eq!(id.len(), "20261124T142300Z-3f9a".len(), "{id}");
    assert!(id.as_bytes()[8] == b'T' && id.contains("Z-"), "{id}");
    assert!(is_run_id(&id));
    for bad in ["", ".", "..", "../x", "a/b", "a b", "x%2F", &"a".repeat(65)] {
        assert!(!is_run_id(bad), "{bad}");
        assert_eq!(run_dir(Path::new("/s"), bad), None, "{bad}");
    }
    assert_eq!(
        report_picture_path(Path::new("/s"), &id),
        Some(PathBuf::from(format!("/s/runs/{id}/report.png")))
    );
}

/// A `kill -9` between the record's write and its rename leaves the old record whole (and
/// the next write replaces it), never a torn one.
#[test]
fn a_kill_between_write_and_rename_leaves_the_old_or_the_new_record() {
    if let Ok(dir) = std::env::var(CHILD_ENV) {
        let new = RunRecord::starting("new".into(), RunMode::Check, false, "child".into());
        let _ = write_record(Path::new(&dir), &new);
        return;
    }
    let dir = temp_dir("crash");
    let old = RunRecord::starting("old".into(), RunMode::Calibrate, false, "parent".into());
    write_record(&dir, &old).expect("old record");
    let mut child = std::process::Command::new(std::env::current_exe().expect("test binary"))
        .args([
            "--exact",
            "storage::tests::a_kill_between_write_and_rename_leaves_the_old_or_the_new_record",
            "--test-threads=1",
            "--nocapture",
        ])
        .env(CHILD_ENV, &dir)
        .env(STALL_ENV, RECORD_FILE)
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("child");
    let sign = dir.join(RECORD_FILE).with_extension("stalled");
    let t = Instant::now();
    while !sign.exists() {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "the child never reached the rename"
        );
        if let Some(status) = child.try_wait().expect("child") {
            panic!("the child ended before the rename: {status}");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    child.kill().expect("kill -9"); // SIGKILL on unix
    child.wait().expect("reaped");
    assert_eq!(read_record(&dir), old.run_id, "the old record, whole");
    // The new one was complete on disk beside it, only not yet renamed.
    let mut tmp = dir.join(RECORD_FILE).into_os_string();
    tmp.push(".tmp");
    let text = std::fs::read_to_string(&tmp).expect("temporary file");
    let pending: RunRecord = serde_json::from_str(&text).expect("complete");
    assert_eq!(pending.run_id, "new");
    // The next write goes through and leaves no temporary file behind.
    let newer = RunRecord::starting("newer".into(), RunMode::Check, false, "parent".into());
    write_record(&dir, &newer).expect("newer record");
    assert_eq!(read_record(&dir), newer.run_id);
    assert!(!PathBuf::from(tmp).exists());
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

/// Issue 36: links and special files planted in the storage folder are never followed:
/// a write's temporary file, reads (a link, a FIFO, a file too large) and pruning.
#[cfg(unix)]
#[test]
fn issue_36_planted_links_and_special_files_are_not_followed() {
    use std::os::unix::fs::symlink;
    let dir = temp_dir("planted");
    let storage = dir.join("storage");
    let outside = dir.join("outside");
    std::fs::create_dir_all(storage.join(RUNS_DIR)).expect("storage");
    std::fs::create_dir_all(&outside).expect("outside");
    let victim = outside.join("victim");
    std::fs::write(&victim, "keep").expect("victim");
    // The check's probe: its temporary file planted as a link.
    symlink(&victim, storage.join(".probe.tmp")).expect("link");
    check_room(&storage, 0).expect("room");
    assert_eq!(std::fs::read_to_string(&victim).expect("victim"), "keep");
    // Reads: a link, a FIFO (must not block), a file beyond the bound.
    std::fs::create_dir_all(storage.join(CURRENT_DIR)).expect("current");
    let current = storage.join(CURRENT_DIR).join(CALIBRATION_FILE);
    let rel = Path::new(CURRENT_DIR).join(CALIBRATION_FILE);
    symlink("/dev/zero", &current).expect("link");
    let e = read_beneath(&storage, &rel, 1 << 20).expect_err("a link");
    assert!(e.to_string().contains("symbolic link"), "{e}");
    assert_eq!(load_current(&storage, Mount::EyeInHand), None);
    std::fs::remove_file(&current).expect("rm");
    let c = std::ffi::CString::new(current.to_str().expect("utf-8")).expect("c");
    // SAFETY: a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let t = Instant::now();
    let e = read_beneath(&storage, &rel, 1 << 20).expect_err("a FIFO");
    assert!(e.to_string().contains("not a regular file"), "{e}");
    assert_eq!(load_current(&storage, Mount::EyeInHand), None);
    assert!(t.elapsed() < Duration::from_secs(1));
    std::fs::remove_file(&current).expect("rm");
    std::fs::File::create(&current)
        .and_then(|f| f.set_len(2 << 20))
        .expect("large");
    let e = read_beneath(&storage, &rel, 1 << 20).expect_err("too large");
    assert!(e.to_string().contains("more than"), "{e}");
    // A folder on the way as a link.
    std::fs::remove_dir_all(storage.join(CURRENT_DIR)).expect("rm");
    std::fs::create_dir_all(outside.join("cur")).expect("dir");
    std::fs::write(outside.join("cur").join(CALIBRATION_FILE), "{}").expect("file");
    symlink(outside.join("cur"), storage.join(CURRENT_DIR)).expect("link");
    assert!(read_beneath(&storage, &rel, 1 << 20).is_err());
    // Pruning: a run folder replaced by a link to a folder outside.
    let scan = outside.join("view0_frame0.ply");
    std::fs::write(&scan, "keep").expect("scan");
    symlink(
        &outside,
        storage.join(RUNS_DIR).join("20261128T000000Z-0001"),
    )
    .expect("link");
    let removed = remove_raw_captures(&storage, "20261128T000000Z-0001").expect("prune");
    assert!(removed.is_empty(), "{removed:?}");
    assert_eq!(std::fs::read_to_string(&scan).expect("scan"), "keep");
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

/// Issue 36: a record planted in a run folder — dated after now, or naming another run —
/// is not taken for a run when the history is rebuilt.
#[test]
fn issue_36_forged_records_are_not_runs() {
    let dir = temp_dir("forged");
    let good = RunRecord::starting(new_run_id(), RunMode::Calibrate, false, "t".into());
    write_record(&run_folder(&dir, &good.run_id), &good).expect("good");
    let mut future = RunRecord::starting(
        "20991231T000000Z-ffff".into(),
        RunMode::Calibrate,
        false,
        "t".into(),
    );
    future.started_unix_s = 4_102_444_800.0;
    write_record(&run_folder(&dir, &future.run_id), &future).expect("future");
    let other = RunRecord::starting(good.run_id.clone(), RunMode::Calibrate, false, "t".into());
    write_record(&run_folder(&dir, "20261128T000000Z-0002"), &other).expect("other");
    let ids: Vec<String> = run_records(&dir).into_iter().map(|r| r.run_id).collect();
    assert_eq!(ids, vec![good.run_id.clone()]);
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

/// Issue 42 (item 7): `result.json`'s `timestamp` is when the run started, ISO 8601 in
/// UTC; it held the run id.
#[test]
fn issue_42_the_results_timestamp_is_an_iso_8601_time() {
    let dir = temp_dir("timestamp");
    let mut record = RunRecord::starting(
        "20261128T090525Z-64c5".into(),
        RunMode::Calibrate,
        false,
        "c.toml".into(),
    );
    record.started_unix_s = 1_795_857_925.4;
    let run = dir.join("runs/20261128T090525Z-64c5");
    let p = Isometry3::translation(0.0, -0.08, 0.04);
    let staged = stage_result(&dir, &run, &p, Mount::EyeInHand, &record, None).expect("staged");
    drop(staged);
    let text =
        std::fs::read_to_string(run.join(crate::calib::export::RESULT_JSON)).expect("result.json");
    let doc: serde_json::Value = serde_json::from_str(&text).expect("json");
    assert_eq!(doc["timestamp"], "2026-11-28T09:25:25Z", "{text}");
    assert_eq!(doc["run_id"], "20261128T090525Z-64c5", "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn exports_are_written_atomically() {
    use crate::calib::export::RESULT_JSON;
    let dir = temp_dir("exports");
    let meta = || ExportMeta {
        run_id: "r".into(),
        outcome: "accepted".into(),
        uncertainty_translation_mm: 0.1,
        uncertainty_rotation_deg: 0.01,
        timestamp: "r".into(),
    };
    let p = Isometry3::translation(0.0, -0.08, 0.04);
    let e = Exports::new(&p, "tool0", "camera", meta());
    let paths = write_exports(&dir.join("run"), &e).expect("written");
    assert_eq!(paths.len(), 5);
    for ((name, contents), path) in e.files().into_iter().zip(&paths) {
        assert_eq!(path.file_name().and_then(|n| n.to_str()), Some(name));
        assert_eq!(std::fs::read_to_string(path).expect("read"), contents);
    }
    // Overwriting replaces the files and leaves no temporary behind.
    let e2 = Exports::new(&p.inverse(), "tool0", "camera", meta());
    write_exports(&dir.join("run"), &e2).expect("rewritten");
    let names: Vec<String> = std::fs::read_dir(dir.join("run"))
        .expect("dir")
        .map(|d| d.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 5, "{names:?}");
    assert!(names.iter().all(|n| !n.ends_with(".tmp")));
    assert_eq!(
        std::fs::read_to_string(dir.join("run").join(RESULT_JSON)).expect("read"),
        e2.json()
    );
    std::fs::remove_dir_all(&dir).expect("cleanup");
}
