//! Issue 23: a full storage directory (a real tmpfs filled to `ENOSPC`) stops runs before
//! anything moves: `handeye calibrate` and the daemon's runs move nothing, write nothing to
//! the controller (TCP, registers) and say why; the daemon says so in its status, metrics and
//! log, and accepts runs again once there is room.

use std::path::{Path, PathBuf};

use crate::daemon::{self, http, start_daemon, wait_status, TOKEN};
use crate::small_fs::SmallFs;
use crate::support::{
    joints, max_change, rig_config, run, secs, shared, start_rig, Output, TempDir,
};

/// What the controller holds that a calibration could change: the TCP and, when
/// `registers`, registers 24..29 / 24 (a running daemon holds them, so only without one).
fn controller(robot_ip: &str, registers: bool) -> serde_json::Value {
    let status = run(&["robot", "--host", robot_ip, "status", "--json"], secs(15)).success();
    let regs = registers.then(|| {
        run(
            &["robot", "--host", robot_ip, "registers", "--json"],
            secs(15),
        )
        .success()
        .json()
    });
    serde_json::json!({
        "tcp": status.json()["flange_from_tcp_ur_pose"],
        "registers": regs,
    })
}

/// The result also in registers 24..29 / 24 (a `[write_back.registers]` table).
const REGISTERS: &str = "[write_back.registers]\ndouble_start = 24\nsequence_int = 24\n";

/// Moves the storage of the configuration at `path` into `storage`.
pub(crate) fn store_in(path: &Path, storage: &Path) -> PathBuf {
    let text = std::fs::read_to_string(path).expect("config");
    assert!(text.contains("dir = \"data\""), "{text}");
    let text = text.replace(
        "dir = \"data\"",
        &format!("dir = \"{}\"", storage.display()),
    );
    std::fs::write(path, text).expect("config");
    path.to_path_buf()
}

fn calibrate(cfg: &Path) -> Output {
    run(
        &[
            "calibrate",
            "--config",
            cfg.to_str().expect("utf-8"),
            "--json",
        ],
        secs(120),
    )
}

#[test]
fn issue_23_calibrate_on_a_full_disk_moves_and_writes_nothing() {
    let Some(_) = shared("issue_23_calibrate_on_a_full_disk_moves_and_writes_nothing") else {
        return;
    };
    let Some(fs) = SmallFs::mount("e2e-calibrate", 128 << 20) else {
        return;
    };
    let dir = TempDir::new("storage-full-cli");
    let (robot_ip, camera_ip) = ("127.0.0.201", "127.0.0.202");
    let rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = store_in(
        &rig_config(&dir, robot_ip, camera_ip, "", REGISTERS),
        fs.path(),
    );
    fs.fill();
    let (before, held) = (joints(robot_ip), controller(robot_ip, true));

    let out = calibrate(&cfg);
    assert_eq!(out.code(), 2, "{out}\n{}", rig.log());
    let doc = out.json();
    assert_eq!(doc["outcome"], "error", "{out}");
    assert_eq!(doc["failed_stage"], "preflight", "{out}");
    let why = doc["reasons"].to_string();
    assert!(
        why.contains("MB free") && why.contains("nothing moved"),
        "{out}"
    );
    assert_eq!(doc["written"].as_array().map(Vec::len), Some(0), "{out}");
    assert!(
        max_change(&joints(robot_ip), &before) < 1e-9,
        "the arm moved"
    );
    assert_eq!(
        controller(robot_ip, true),
        held,
        "the controller was written"
    );
    assert!(!fs.path().join("current").exists());
    assert_eq!(fs.temporary_files(), Vec::<PathBuf>::new());

    // With room again, the same command calibrates and writes back.
    fs.free();
    let out = calibrate(&cfg);
    assert_eq!(out.code(), 0, "{out}\n{}", rig.log());
    assert_ne!(
        controller(robot_ip, true),
        held,
        "nothing written once there is room"
    );
    assert_eq!(fs.temporary_files(), Vec::<PathBuf>::new());
}

#[test]
fn issue_23_the_daemon_refuses_runs_while_the_disk_is_full() {
    let Some(_) = shared("issue_23_the_daemon_refuses_runs_while_the_disk_is_full") else {
        return;
    };
    let Some(fs) = SmallFs::mount("e2e-daemon", 128 << 20) else {
        return;
    };
    let dir = TempDir::new("storage-full-daemon");
    let (robot_ip, camera_ip) = ("127.0.0.203", "127.0.0.204");
    let rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = store_in(&daemon::config(&dir, robot_ip, camera_ip, ""), fs.path());
    let daemon = start_daemon(&dir, "daemon", &cfg);
    let api = format!("{robot_ip}:8650");
    fs.fill();
    let (before, held) = (joints(robot_ip), controller(robot_ip, false));

    // Within one health check (5 s) the status says why; runs are refused with 507.
    let st = wait_status(&api, secs(15), "the status shows the full disk", |s| {
        s["storage_problem"].is_string()
    });
    let problem = st["storage_problem"].as_str().unwrap_or_default();
    assert!(problem.contains("MB free"), "{st}");
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 507, "{body}");
    assert!(body.contains("MB free"), "{body}");
    let (_, metrics) = http(&api, "GET", "/metrics", None);
    assert!(metrics.contains("handeye_storage_usable 0"), "{metrics}");
    assert!(
        daemon.log().contains("storage unusable, runs are refused"),
        "{}",
        daemon.log()
    );
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert!(
        max_change(&joints(robot_ip), &before) < 1e-9,
        "the arm moved"
    );
    assert_eq!(
        controller(robot_ip, false),
        held,
        "the controller was written"
    );

    // Room again: the next health check clears it and a calibration runs.
    fs.free();
    wait_status(&api, secs(15), "the storage problem clears", |s| {
        s["storage_problem"].is_null()
    });
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let st = wait_status(&api, secs(90), "the calibration ends", |s| {
        s["state"] == "idle" && s["last"]["outcome"].is_string()
    });
    assert_eq!(st["last"]["outcome"], "accepted", "{st}\n{}", daemon.log());
    assert_ne!(controller(robot_ip, false), held);
    assert_eq!(fs.temporary_files(), Vec::<PathBuf>::new());
    drop(daemon);
    drop(rig);
}

/// Issue 23: a history whose pages were damaged is set aside (kept, named in the log and the
/// status) when the daemon starts, and rebuilt from the run folders with every run listed.
#[test]
fn issue_23_a_corrupted_history_is_set_aside_and_rebuilt() {
    let Some(_) = shared("issue_23_a_corrupted_history_is_set_aside_and_rebuilt") else {
        return;
    };
    let dir = TempDir::new("history-damaged");
    let (robot_ip, camera_ip) = ("127.0.0.205", "127.0.0.206");
    let rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = daemon::config(&dir, robot_ip, camera_ip, "");
    let mut ids = Vec::new();
    for _ in 0..2 {
        let out = calibrate(&cfg);
        assert_eq!(out.code(), 0, "{out}\n{}", rig.log());
        ids.push(out.json()["run_id"].as_str().expect("run id").to_string());
    }
    let db = dir.join("data/history.sqlite");
    let mut bytes = std::fs::read(&db).expect("history");
    assert!(bytes.len() > 8192, "{} bytes", bytes.len());
    for (i, b) in bytes.iter_mut().enumerate().skip(4096) {
        *b = (i as u32).wrapping_mul(2_654_435_761).to_le_bytes()[1];
    }
    std::fs::write(&db, &bytes).expect("damage the history");

    let daemon = start_daemon(&dir, "daemon", &cfg);
    let api = format!("{robot_ip}:8650");
    let (code, body) = http(&api, "GET", "/api/status", None);
    assert_eq!(code, 200, "{body}");
    let st: serde_json::Value = serde_json::from_str(&body).expect("status JSON");
    let aside = st["history_set_aside"]["path"].as_str().unwrap_or_default();
    assert!(aside.contains("history.sqlite.damaged-"), "{st}");
    assert_eq!(
        std::fs::read(aside).expect("kept"),
        bytes,
        "not kept as it was"
    );
    assert!(daemon.log().contains(aside), "{}", daemon.log());
    let (code, body) = http(&api, "GET", "/api/runs", None);
    assert_eq!(code, 200, "{body}");
    let doc: serde_json::Value = serde_json::from_str(&body).expect("runs JSON");
    let mut listed: Vec<String> = doc["runs"]
        .as_array()
        .expect("runs")
        .iter()
        .map(|r| r["run_id"].as_str().unwrap_or_default().to_string())
        .collect();
    listed.sort();
    ids.sort();
    assert_eq!(listed, ids, "{body}");
    drop(daemon);
    drop(rig);
}
