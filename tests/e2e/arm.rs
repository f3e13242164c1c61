//! Issue 46: one arm, one master. Two daemons with two storages on one simulated arm: the
//! first runs, the second refuses to start naming the first (pid, user, storage); a command on
//! a third storage refuses too; the arm moves for the first alone. Addresses 127.0.0.70–73.

use crate::daemon::{config_listening, http, wait_status, TOKEN};
use crate::support::{joints, max_change, run, secs, shared, start_rig, Daemon, TempDir};

/// A daemon's configuration in `dir` for the rig at 127.0.0.70/71, its API on `listen`.
fn config(dir: &TempDir, listen: &str) -> std::path::PathBuf {
    config_listening(dir, "127.0.0.70", "127.0.0.71", listen, "")
}

#[test]
fn issue_46_two_daemons_on_two_storages_never_both_drive_one_arm() {
    let Some(_) = shared("issue_46_two_daemons_on_two_storages_never_both_drive_one_arm") else {
        return;
    };
    let rig_dir = TempDir::new("arm-rig");
    let _rig = start_rig(&rig_dir, "127.0.0.70", "127.0.0.71", &[]);
    let (a, b, c) = (
        TempDir::new("arm-a"),
        TempDir::new("arm-b"),
        TempDir::new("arm-c"),
    );
    let (cfg_a, cfg_b, cfg_c) = (
        config(&a, "127.0.0.72:8650"),
        config(&b, "127.0.0.73:8650"),
        config(&c, "127.0.0.73:8651"),
    );
    let mut first = Daemon::start(
        &a,
        "daemon-a",
        &["daemon", "--config", cfg_a.to_str().expect("utf-8")],
    );
    first.wait_for_log("handeye daemon ready", secs(60));
    let before = joints("127.0.0.70");

    // The second daemon, on its own storage, refuses before it connects anything.
    let second = run(
        &["daemon", "--config", cfg_b.to_str().expect("utf-8")],
        secs(20),
    );
    assert_eq!(second.code(), 2, "{second}");
    let storage_a = std::fs::canonicalize(a.join("data")).expect("storage a");
    assert!(
        second.stderr.contains(&format!(
            "the arm at 127.0.0.70:29999 is held by another process (pid {}, user ",
            first.pid()
        )) && second
            .stderr
            .contains(&format!("storage {}", storage_a.display())),
        "{second}"
    );
    // … and so does a command's run on a third storage; a dry run needs no claim.
    let cli = run(
        &["calibrate", "--config", cfg_c.to_str().expect("utf-8")],
        secs(30),
    );
    assert_eq!(cli.code(), 2, "{cli}");
    assert!(
        cli.stderr
            .contains(&format!("is held by another process (pid {}", first.pid())),
        "{cli}"
    );
    let dry = run(
        &[
            "calibrate",
            "--config",
            cfg_c.to_str().expect("utf-8"),
            "--dry-run",
        ],
        secs(60),
    );
    assert_eq!(dry.code(), 0, "{dry}");
    assert!(
        max_change(&joints("127.0.0.70"), &before) < 1e-9,
        "the arm moved for a refused process"
    );

    // The holder still runs the arm.
    let (code, body) = http("127.0.0.72:8650", "POST", "/api/check", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    wait_status("127.0.0.72:8650", secs(120), "the check has ended", |s| {
        s["state"] == "idle" && s["last"]["mode"] == "check"
    });
    first.signal(libc::SIGTERM);
    assert!(first.wait_exit(secs(20)).success(), "{}", first.log());

    // Once it has gone, the other storage's daemon takes the arm.
    let mut next = Daemon::start(
        &b,
        "daemon-b",
        &["daemon", "--config", cfg_b.to_str().expect("utf-8")],
    );
    next.wait_for_log("handeye daemon ready", secs(60));
    next.signal(libc::SIGTERM);
    assert!(next.wait_exit(secs(20)).success(), "{}", next.log());
}
