//! `handeye daemon` against `handeye sim rig` over loopback: the startup calibration, the HTTP
//! API with and without its token, one run at a time, the scheduled drift check and its alarm,
//! SIGTERM mid-run, kill -9 mid-run and the history after a restart, the queue, and the
//! reconnection after the simulated controller and camera restart.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Vector3};

use crate::support::{
    csv, history, iso, joints, max_change, pose_arg, pose_error, rig_config, run, secs, shared,
    start_rig, true_mount, Daemon, TempDir,
};

#[test]
fn the_api_answers_while_the_robot_is_unreachable_and_a_second_daemon_refuses() {
    let Some(_) =
        shared("the_api_answers_while_the_robot_is_unreachable_and_a_second_daemon_refuses")
    else {
        return;
    };
    // issue 24: no controller listens at this address.
    let dir = TempDir::new("unreachable");
    let (robot_ip, camera_ip) = ("127.0.0.175", "127.0.0.176");
    let cfg = config(&dir, robot_ip, camera_ip, "startup = \"calibrate\"");
    let api = format!("{robot_ip}:8650");
    let mut first = Daemon::start(
        &dir,
        "daemon",
        &["daemon", "--config", cfg.to_str().expect("utf-8")],
    );
    first.wait_for_log("handeye daemon starting", secs(30));
    let waiting = format!("waiting for robot at {robot_ip} (attempt ");
    let st = wait_status(&api, secs(30), "the status says what it waits for", |s| {
        s["waiting"].as_str().is_some_and(|w| w.contains(&waiting))
    });
    assert_eq!(st["robot_connected"], false, "{st}");
    let out = run(
        &["status", "--config", cfg.to_str().expect("utf-8")],
        secs(15),
    );
    assert_eq!(out.code(), 0, "{out}");
    assert!(out.stdout.contains(&waiting), "{out}");
    assert!(out.stdout.contains(", next in "), "{out}");
    // A run is refused at once with the reason, not accepted and aborted later.
    let (code, body) = http(&api, "POST", "/api/check", Some(TOKEN));
    assert_eq!(code, 503, "{body}");
    assert!(body.contains(&waiting), "{body}");

    // A second daemon on the same storage refuses to start, naming the first.
    let second = run(
        &["daemon", "--config", cfg.to_str().expect("utf-8")],
        secs(20),
    );
    assert_eq!(second.code(), 2, "{second}");
    assert!(
        second.stderr.contains(&format!(
            "another handeye daemon (pid {}, user ",
            first.pid()
        )),
        "{second}"
    );
    // The first is unharmed.
    let (code, _) = http(&api, "GET", "/api/status", None);
    assert_eq!(code, 200);
    first.signal(libc::SIGTERM);
    assert!(first.wait_exit(secs(10)).success(), "{}", first.log());
}

pub(crate) const TOKEN: &str = "e2e-secret-token";

/// A daemon configuration for the rig; `daemon` is the `[daemon]` table's body (more tables
/// may follow it).
pub(crate) fn config(dir: &TempDir, robot_ip: &str, camera_ip: &str, daemon: &str) -> PathBuf {
    let listen = format!("{robot_ip}:8650");
    config_listening(dir, robot_ip, camera_ip, &listen, daemon)
}

/// [`config`] with the API on `listen`.
pub(crate) fn config_listening(
    dir: &TempDir,
    robot_ip: &str,
    camera_ip: &str,
    listen: &str,
    daemon: &str,
) -> PathBuf {
    let token = dir.join("token");
    std::fs::write(&token, format!("{TOKEN}\n")).expect("token");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    }
    rig_config(
        dir,
        robot_ip,
        camera_ip,
        "",
        &format!("[daemon]\nlisten = \"{listen}\"\ntoken_file = \"token\"\n{daemon}"),
    )
}

/// One HTTP/1.0 request to `addr`; (status code, body).
pub(crate) fn http(addr: &str, method: &str, path: &str, token: Option<&str>) -> (u16, String) {
    try_http(addr, method, path, token).unwrap_or_else(|e| panic!("{method} {addr}{path}: {e}"))
}

/// One HTTP/1.0 request to `addr`, its transport errors returned (a daemon over its
/// connection limits resets new connections until it has seen the old ones close).
pub(crate) fn try_http(
    addr: &str,
    method: &str,
    path: &str,
    token: Option<&str>,
) -> std::io::Result<(u16, String)> {
    let mut s = TcpStream::connect(addr)?;
    s.set_read_timeout(Some(Duration::from_secs(10)))?;
    let auth = token.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
    write!(
        s,
        "{method} {path} HTTP/1.0\r\nHost: {addr}\r\n{auth}Content-Length: 0\r\n\r\n"
    )?;
    let mut text = String::new();
    s.read_to_string(&mut text)?;
    let code = text
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    // HTTP/1.0: the body is not chunked and ends with the connection.
    let body = text.split_once("\r\n\r\n").map_or("", |(_, b)| b);
    Ok((code, body.to_string()))
}

fn json(body: &str) -> serde_json::Value {
    serde_json::from_str(body).unwrap_or_else(|e| panic!("not JSON ({e}): {body}"))
}

pub(crate) fn start_daemon(dir: &TempDir, name: &str, config: &Path) -> Daemon {
    let mut d = Daemon::start(
        dir,
        name,
        &["daemon", "--config", config.to_str().expect("utf-8")],
    );
    d.wait_for_log("handeye daemon ready", secs(60));
    d
}

/// Polls `/api/status` until `done` holds for it (a daemon that has logged its start may not
/// listen yet, one over its connection limits resets: either is tried again until `limit`).
pub(crate) fn wait_status(
    api: &str,
    limit: Duration,
    what: &str,
    done: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let deadline = Instant::now() + limit;
    loop {
        let Ok((code, body)) = try_http(api, "GET", "/api/status", None) else {
            assert!(
                Instant::now() < deadline,
                "{what}: no API answering at {api} within {limit:?}"
            );
            std::thread::sleep(Duration::from_millis(100));
            continue;
        };
        if code == 200 {
            let st = json(&body);
            if done(&st) {
                return st;
            }
            assert!(Instant::now() < deadline, "{what} within {limit:?}: {st}");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn daemon_calibrates_at_startup_and_serves_the_api() {
    let Some(_) = shared("daemon_calibrates_at_startup_and_serves_the_api") else {
        return;
    };
    let dir = TempDir::new("daemon");
    let (robot_ip, camera_ip) = ("127.0.0.126", "127.0.0.127");
    let rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = config(&dir, robot_ip, camera_ip, "startup = \"calibrate\"");
    // issue 24: without RUST_LOG, as systemd starts it: the journal tells the story.
    let mut daemon = Daemon::start_with_default_log(
        &dir,
        "daemon",
        &["daemon", "--config", cfg.to_str().expect("utf-8")],
    );
    daemon.wait_for_log("handeye daemon ready", secs(60));
    let api = format!("{robot_ip}:8650");

    // The startup calibration: accepted, on the truth, the camera is the controller's TCP.
    let st = wait_status(&api, secs(90), "the startup calibration ends", |s| {
        s["last"]["outcome"].is_string()
    });
    assert_eq!(st["last"]["outcome"], "accepted", "{st}\n{}", daemon.log());
    assert_eq!(st["last"]["trigger"], "startup", "{st}");
    let run_id = st["last"]["run_id"].as_str().expect("run id").to_string();
    let (code, body) = http(&api, "GET", &format!("/api/runs/{run_id}"), None);
    assert_eq!(code, 200, "{body}");
    let record = json(&body);
    let result = iso(&record["result"]["flange_from_camera"]);
    let (mm, deg) = pose_error(&true_mount(), &result);
    eprintln!("daemon startup calibration: {mm:.3} mm / {deg:.4}° from the truth");
    assert!(
        mm < handeye::bench::PASS_TRANSLATION_MM && deg < handeye::bench::PASS_ROTATION_DEG,
        "{mm} mm / {deg}°"
    );
    let tcp = run(&["robot", "--host", robot_ip, "status", "--json"], secs(15)).success();
    let tcp: Vec<f64> = serde_json::from_value(tcp.json()["flange_from_tcp_ur_pose"].clone())
        .unwrap_or_else(|e| panic!("flange_from_tcp_ur_pose in robot status ({e})"));
    let tcp = Isometry3::new(
        Vector3::new(tcp[0], tcp[1], tcp[2]),
        Vector3::new(tcp[3], tcp[4], tcp[5]),
    );
    assert!(pose_error(&result, &tcp).0 < 1e-3, "TCP {tcp:?}");

    // Without the token nothing moves.
    let before = joints(robot_ip);
    for token in [None, Some("wrong")] {
        let (code, body) = http(&api, "POST", "/api/check", token);
        assert_eq!(code, 401, "{token:?}: {body}");
    }
    std::thread::sleep(Duration::from_millis(300));
    let after = joints(robot_ip);
    let moved = before
        .iter()
        .zip(&after)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(moved < 1e-6, "moved without a token");

    // With it a check runs; a second trigger meanwhile is refused as busy.
    let (code, body) = http(&api, "POST", "/api/check", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 409, "{body}");
    assert!(body.contains("busy"), "{body}");
    let st = wait_status(&api, secs(90), "the check ends", |s| {
        s["state"] == "idle" && s["last"]["mode"] == "check"
    });
    assert_eq!(st["last"]["outcome"], "accepted", "{st}");
    assert_eq!(st["drift_alarm"], false, "{st}");
    let log = daemon.log();
    assert!(
        log.contains(&format!("run {run_id} started: calibrate asked by startup")),
        "{log}"
    );
    assert!(
        log.contains(&format!("run {run_id} ended: calibrate accepted in ")),
        "{log}"
    );
    let check = st["last"]["run_id"].as_str().expect("run id");
    assert!(
        log.contains(&format!("run {check} started: check asked by api")),
        "{log}"
    );
    let ended = format!("run {check} ended: check within limits in ");
    let line = log
        .lines()
        .find(|l| l.contains(&ended))
        .unwrap_or_else(|| panic!("no `{ended}` in\n{log}"));
    assert!(
        line.contains("; drift ") && line.contains(" mm / "),
        "{line}"
    );
    // Stages are debug: not in the default journal.
    assert!(!log.contains("stage=move"), "{log}");
    let (code, metrics) = http(&api, "GET", "/metrics", None);
    assert_eq!(code, 200);
    assert!(
        metrics.contains("handeye_runs_total{trigger=\"startup\",outcome=\"accepted\"} 1"),
        "{metrics}"
    );
    assert!(metrics.contains("handeye_drift_alarm 0"), "{metrics}");
    crate::monitoring::check_live_metrics(
        "daemon_calibrates_at_startup_and_serves_the_api",
        &metrics,
    );
    let (code, body) = http(&api, "GET", "/api/runs", None);
    assert_eq!(code, 200, "{body}");
    assert_eq!(
        json(&body)["runs"].as_array().map(Vec::len),
        Some(2),
        "{body}"
    );
    drop(daemon);
    drop(rig);
}

#[test]
fn scheduled_checks_raise_the_alarm_when_the_camera_slips() {
    let Some(_) = shared("scheduled_checks_raise_the_alarm_when_the_camera_slips") else {
        return;
    };
    let dir = TempDir::new("schedule");
    let (robot_ip, camera_ip) = ("127.0.0.128", "127.0.0.129");
    let _rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = config(
        &dir,
        robot_ip,
        camera_ip,
        "startup = \"calibrate\"\ncheck_interval_s = 3",
    );
    let daemon = start_daemon(&dir, "daemon", &cfg);
    let api = format!("{robot_ip}:8650");
    let st = wait_status(
        &api,
        secs(90),
        "a scheduled check on the unchanged mount",
        |s| s["last_check"]["trigger"] == "schedule",
    );
    assert_eq!(
        st["last_calibration"]["outcome"],
        "accepted",
        "{st}\n{}",
        daemon.log()
    );
    assert_eq!(
        st["drift_alarm"], false,
        "quiet on an unchanged mount: {st}"
    );

    // The camera slips by 2 mm and 0.5°.
    let slipped = true_mount()
        * Isometry3::new(
            Vector3::new(0.002, 0.0, 0.0),
            Vector3::new(0.0, 0.5f64.to_radians(), 0.0),
        );
    std::fs::write(dir.join("mount.txt"), pose_arg(&slipped)).expect("mount file");
    let st = wait_status(&api, secs(90), "the alarm", |s| s["drift_alarm"] == true);
    let drift = &st["last_check"]["drift"];
    eprintln!("scheduled check after a 2 mm / 0.5° slip: {drift}");
    let mm = drift["translation_mm"].as_f64().expect("drift mm");
    assert!((mm - 2.0).abs() < 0.4, "{st}");
    assert_eq!(drift["exceeded"], true, "{st}");
    let (_, metrics) = http(&api, "GET", "/metrics", None);
    assert!(metrics.contains("handeye_drift_alarm 1"), "{metrics}");
    // Issue 38: the drifted check counts as its own outcome, apart from the checks within
    // limits (`accepted`).
    assert!(
        metrics.contains("handeye_runs_total{trigger=\"schedule\",outcome=\"drifted\"} "),
        "{metrics}"
    );
    assert!(
        metrics.contains("handeye_runs_total{trigger=\"schedule\",outcome=\"accepted\"} "),
        "{metrics}"
    );
    assert!(daemon.log().contains("ALARM"), "{}", daemon.log());
    // The history lists the drifted check with the same word the status and the page use.
    let (code, body) = http(&api, "GET", "/api/runs", None);
    assert_eq!(code, 200, "{body}");
    let runs = json(&body);
    let listed = runs["runs"].as_array().expect("runs");
    let drifted = listed
        .iter()
        .find(|r| r["run_id"] == st["last_check"]["run_id"])
        .expect("the drifted check is listed");
    assert_eq!(drifted["verdict"], "drifted", "{drifted}");

    // issue 24: a restart (SIGTERM, as systemd stops it) keeps the alarm, the last check
    // and the last calibration: they come from the history.
    let mut daemon = daemon;
    let st = wait_status(&api, secs(90), "an idle daemon", |s| s["state"] == "idle");
    let (check, calibration) = (
        st["last_check"]["run_id"].clone(),
        st["last_calibration"]["run_id"].clone(),
    );
    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(secs(20)).success(), "{}", daemon.log());
    let daemon = start_daemon(&dir, "daemon-restarted", &cfg);
    let (code, body) = http(&api, "GET", "/api/status", None);
    assert_eq!(code, 200, "{body}");
    let st = json(&body);
    assert_eq!(
        st["drift_alarm"],
        true,
        "after the restart: {st}\n{}",
        daemon.log()
    );
    assert_eq!(st["last_check"]["run_id"], check, "{st}");
    assert_eq!(st["last_check"]["drift"]["exceeded"], true, "{st}");
    assert_eq!(st["last_calibration"]["run_id"], calibration, "{st}");
    let (_, metrics) = http(&api, "GET", "/metrics", None);
    assert!(metrics.contains("handeye_drift_alarm 1"), "{metrics}");
    assert!(!metrics.contains("handeye_last_drift_mm NaN"), "{metrics}");
    let text = run(
        &["status", "--config", cfg.to_str().expect("utf-8")],
        secs(15),
    );
    assert!(text.stdout.contains("drift alarm: ON"), "{}", text.stdout);
    // Issue 38: scripts see the alarm in the exit code.
    assert_eq!(text.code(), 1, "{text}");
}

/// Issue 38: after a deliberate remount the calibration is rejected naming the way out, and
/// accepted only when asked explicitly (`POST /api/calibrate/accept-change`); that clears the
/// alarm and the history says who accepted how large a change. `handeye status` exits 1 with
/// the alarm on and 0 once the cell is fine, 2 once no daemon answers.
#[test]
fn issue_38_a_deliberate_remount_is_accepted_explicitly() {
    let Some(_) = shared("issue_38_a_deliberate_remount_is_accepted_explicitly") else {
        return;
    };
    let dir = TempDir::new("remount");
    let (robot_ip, camera_ip) = ("127.0.0.160", "127.0.0.161");
    let _rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = config(&dir, robot_ip, camera_ip, "startup = \"calibrate\"");
    let cfg_arg = cfg.to_str().expect("utf-8");
    let mut daemon = start_daemon(&dir, "daemon", &cfg);
    let api = format!("{robot_ip}:8650");
    let st = wait_status(&api, secs(90), "the startup calibration", |s| {
        s["last_calibration"]["trigger"] == "startup" && s["state"] == "idle"
    });
    assert_eq!(
        st["last_calibration"]["outcome"],
        "accepted",
        "{st}\n{}",
        daemon.log()
    );
    assert_eq!(run(&["status", "--config", cfg_arg], secs(15)).code(), 0);

    // The camera is remounted 8 mm and 2° away (beyond gate.max_change_*: 5 mm / 1°).
    remount(&dir);
    let finished = |what: &str, run_id: &serde_json::Value| {
        wait_status(&api, secs(90), what, |s| {
            s["last"]["run_id"] == *run_id && s["state"] == "idle"
        })
    };
    let (code, body) = http(&api, "POST", "/api/check", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let st = finished("the check", &json(&body)["run_id"]);
    assert_eq!(st["drift_alarm"], true, "{st}");
    // Issue 42: the alarm's way out is the daemon's own (a command's `calibrate` is refused
    // beside it, and rejected for a remount).
    let log = daemon.log();
    let alarm = log
        .lines()
        .find(|l| l.contains("ALARM: the camera has drifted"))
        .unwrap_or_else(|| panic!("no ALARM line: {log}"));
    assert!(
        alarm.contains(
            "recalibrate through the daemon: the Calibrate button on its page, POST /api/calibrate"
        ) && alarm.contains("the Accept remount button or POST /api/calibrate/accept-change")
            && !alarm.contains("handeye calibrate"),
        "{alarm}"
    );

    // An ordinary calibration is rejected, naming the way out, and the alarm stays.
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let st = finished("the calibration", &json(&body)["run_id"]);
    assert_eq!(st["last"]["outcome"], "rejected", "{st}");
    let reasons = st["last"]["reasons"].to_string();
    // Issue 42: the way out named is the daemon's (the command's flag is refused beside it).
    assert!(
        reasons.contains("from the previous calibration")
            && reasons.contains("with the Accept remount button on the daemon's page or POST /api/calibrate/accept-change")
            && !reasons.contains("handeye calibrate"),
        "{reasons}"
    );
    assert_eq!(
        st["drift_alarm"], true,
        "a rejected calibration leaves the alarm: {st}"
    );
    let status = run(&["status", "--config", cfg_arg], secs(15));
    assert_eq!(status.code(), 1, "{status}");

    // Accepting needs the token, as every route that moves the arm.
    let (code, body) = http(&api, "POST", "/api/calibrate/accept-change", None);
    assert_eq!(code, 401, "{body}");
    let (code, body) = http(&api, "POST", "/api/calibrate/accept-change", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let run_id = json(&body)["run_id"].clone();
    let st = finished("the accepted remount", &run_id);
    assert_eq!(st["last"]["outcome"], "accepted", "{st}\n{}", daemon.log());
    assert_eq!(
        st["drift_alarm"], false,
        "the accepted calibration clears the alarm: {st}"
    );
    assert!(
        st["last"]["warnings"]
            .to_string()
            .contains("accepted as a deliberate remount by api client 127."),
        "{st}"
    );
    let (code, body) = http(
        &api,
        "GET",
        &format!("/api/runs/{}", run_id.as_str().expect("id")),
        None,
    );
    assert_eq!(code, 200, "{body}");
    let record = json(&body);
    let accepted = &record["change_accepted"];
    assert!(
        accepted["by"]
            .as_str()
            .is_some_and(|b| b.starts_with("api client 127.")),
        "{record}"
    );
    assert_eq!(accepted["beyond_limits"], true, "{record}");
    let mm = accepted["translation_mm"].as_f64().expect("mm");
    assert!(mm > 5.0, "{record}");
    let show = run(
        &[
            "history",
            "show",
            run_id.as_str().expect("id"),
            "--config",
            cfg_arg,
        ],
        secs(20),
    )
    .success();
    assert!(
        show.stdout
            .contains("remount   accepted by api client 127."),
        "{show}"
    );
    // The camera where it is now is the new reference: a check is within limits.
    let (code, body) = http(&api, "POST", "/api/check", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let st = finished("the check after the remount", &json(&body)["run_id"]);
    assert_eq!(st["last"]["verdict"], "within limits", "{st}");
    assert_eq!(run(&["status", "--config", cfg_arg], secs(15)).code(), 0);

    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(secs(20)).success(), "{}", daemon.log());
    assert_eq!(run(&["status", "--config", cfg_arg], secs(15)).code(), 2);
}

/// Remounts the camera of the rig started in `dir` 8 mm and 2° from [`true_mount`] (beyond
/// gate.max_change_*: 5 mm / 1°).
pub(crate) fn remount(dir: &TempDir) {
    let remounted = true_mount()
        * Isometry3::new(
            Vector3::new(0.0, 0.008, 0.0),
            Vector3::new(2f64.to_radians(), 0.0, 0.0),
        );
    std::fs::write(dir.join("mount.txt"), pose_arg(&remounted)).expect("mount file");
}

/// Issue 38: the command line's way to accept a remount, and one process moving the arm.
/// `handeye calibrate --accept-change` beside a running daemon is refused before anything is
/// connected, naming how to ask the daemon (the page's button, the HTTP route) or to stop it; a
/// daemon cannot start while the command's run holds the cell; once the daemon is stopped the
/// command accepts the remount, and the daemon started again has no alarm.
#[test]
fn issue_38_the_command_line_accepts_a_remount_but_never_beside_the_daemon() {
    let Some(_) = shared("issue_38_the_command_line_accepts_a_remount_but_never_beside_the_daemon")
    else {
        return;
    };
    let dir = TempDir::new("remount-cli");
    let (robot_ip, camera_ip) = ("127.0.0.162", "127.0.0.163");
    let _rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = config(&dir, robot_ip, camera_ip, "");
    let cfg_arg = cfg.to_str().expect("utf-8");
    let api = format!("{robot_ip}:8650");
    let out = run(&["calibrate", "--config", cfg_arg], secs(120));
    assert_eq!(out.code(), 0, "{out}");

    // The camera is remounted 8 mm and 2° away (beyond gate.max_change_*: 5 mm / 1°): the
    // check drifts, an ordinary calibration is rejected naming the way out.
    remount(&dir);
    let out = run(&["check", "--config", cfg_arg], secs(120));
    assert_eq!(out.code(), 1, "{out}");
    let out = run(&["calibrate", "--config", cfg_arg], secs(120));
    assert_eq!(out.code(), 1, "{out}");
    // Issue 42: the way out named is the command line's, with this configuration.
    assert!(
        out.stdout.contains("from the previous calibration")
            && out.stdout.contains(&format!(
                "accept the new mount with `handeye calibrate --config {cfg_arg} --accept-change`"
            ))
            && !out.stdout.contains("Accept remount"),
        "{out}"
    );

    // The daemon raises the alarm from the history; beside it the command refuses, moves
    // nothing and records nothing, and says how to ask the daemon.
    let mut daemon = start_daemon(&dir, "daemon-1", &cfg);
    let st = wait_status(&api, secs(30), "the daemon's status", |_| true);
    assert_eq!(st["drift_alarm"], true, "{st}");
    let (before, runs) = (joints(robot_ip), history(&cfg));
    let out = run(
        &["calibrate", "--config", cfg_arg, "--accept-change"],
        secs(30),
    );
    assert_eq!(out.code(), 2, "{out}");
    for needle in [
        format!("handeye daemon (pid {}, user ", daemon.pid()).as_str(),
        "`) runs this cell",
        "Accept remount button",
        "POST /api/calibrate/accept-change with the API token",
        &format!("http://{api}/api/calibrate/accept-change"),
        "systemctl stop handeye",
        &format!("`handeye calibrate --config {cfg_arg} --accept-change` again"),
    ] {
        assert!(out.stderr.contains(needle), "`{needle}` in\n{out}");
    }
    let out = run(&["check", "--config", cfg_arg], secs(30));
    assert_eq!(out.code(), 2, "{out}");
    assert!(out.stderr.contains("POST /api/check"), "{out}");
    // Nor does the arm move by hand on the cell's configuration.
    let target: Vec<f64> = before.iter().map(|q| q + 0.05).collect();
    let out = run(
        &[
            "robot",
            "move",
            "--config",
            cfg_arg,
            "--joints",
            &csv(&target),
        ],
        secs(30),
    );
    assert_eq!(out.code(), 2, "{out}");
    assert!(
        out.stderr
            .contains(&format!("handeye daemon (pid {}, user ", daemon.pid()))
            && out
                .stderr
                .contains("stop it (`systemctl stop handeye`) before moving the arm"),
        "{out}"
    );
    assert_eq!(history(&cfg), runs, "a refused command recorded a run");
    // A dry run moves nothing: it may run beside the daemon.
    let out = run(&["calibrate", "--config", cfg_arg, "--dry-run"], secs(60));
    assert_eq!(out.code(), 0, "{out}");
    assert!(
        max_change(&joints(robot_ip), &before) < 1e-9,
        "the arm moved"
    );
    let st = wait_status(&api, secs(15), "the daemon's status", |_| true);
    assert_eq!(st["drift_alarm"], true, "{st}");
    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(secs(20)).success(), "{}", daemon.log());

    // With the daemon stopped the command accepts the remount; while its run holds the cell a
    // daemon refuses to start, naming it.
    let mut cli = Daemon::start(
        &dir,
        "calibrate-accept-change",
        &["calibrate", "--config", cfg_arg, "--accept-change"],
    );
    cli.wait_for_log("move", secs(60));
    let second = run(&["daemon", "--config", cfg_arg], secs(20));
    assert_eq!(second.code(), 2, "{second}");
    assert!(
        second.stderr.contains(&format!(
            "another `handeye calibrate` run (pid {}, user ",
            cli.pid()
        )) && second.stderr.contains("wait until it has ended"),
        "{second}"
    );
    let done = cli.wait_exit(secs(120));
    assert!(done.success(), "{done}\n{}", cli.log());
    let runs = history(&cfg);
    let last = &runs[0];
    assert_eq!(last["outcome"], "accepted", "{runs}");
    let run_id = last["run_id"].as_str().expect("run id");
    let show = run(&["history", "show", run_id, "--config", cfg_arg], secs(20)).success();
    assert!(
        show.stdout.contains("remount   accepted by cli ("),
        "{show}"
    );

    // The daemon started again has no alarm, and compares with the new mount.
    let _daemon = start_daemon(&dir, "daemon-2", &cfg);
    let st = wait_status(&api, secs(30), "the daemon's status", |_| true);
    assert_eq!(st["drift_alarm"], false, "{st}");
    assert_eq!(run(&["status", "--config", cfg_arg], secs(15)).code(), 0);
    let (code, body) = http(&api, "POST", "/api/check", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let id = json(&body)["run_id"].clone();
    let st = wait_status(&api, secs(90), "the check after the remount", |s| {
        s["last"]["run_id"] == id && s["state"] == "idle"
    });
    assert_eq!(st["last"]["verdict"], "within limits", "{st}");
}

#[test]
fn sigterm_and_kill_mid_run_leave_an_honest_history() {
    let Some(_) = shared("sigterm_and_kill_mid_run_leave_an_honest_history") else {
        return;
    };
    let dir = TempDir::new("sigterm");
    let (robot_ip, camera_ip) = ("127.0.0.132", "127.0.0.133");
    let _rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = config(&dir, robot_ip, camera_ip, "");
    let api = format!("{robot_ip}:8650");

    // issue 24: `handeye cancel` while the arm moves: the run ends aborted, the daemon runs on.
    let mut daemon = start_daemon(&dir, "daemon-1", &cfg);
    let config_arg = cfg.to_str().expect("utf-8");
    let out = run(&["cancel", "--config", config_arg], secs(15));
    assert_eq!(out.code(), 0, "{out}");
    assert!(out.stdout.contains("nothing to cancel"), "{out}");
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let cancelled = json(&body)["run_id"].as_str().expect("run id").to_string();
    wait_status(&api, secs(30), "the move starts", |s| {
        s["current"]["stage"] == "move"
    });
    let out = run(&["cancel", "--config", config_arg], secs(15));
    assert_eq!(out.code(), 0, "{out}");
    assert!(out.stdout.starts_with("cancelled"), "{out}");
    let st = wait_status(&api, secs(30), "the cancelled run ends", |s| {
        s["state"] == "idle" && s["last"]["run_id"] == cancelled.as_str()
    });
    assert_eq!(st["last"]["outcome"], "aborted", "{st}");
    let (code, body) = http(&api, "GET", &format!("/api/runs/{cancelled}"), None);
    assert_eq!(code, 200, "{body}");
    let record = json(&body);
    // The move it was in took its time, also when aborted.
    assert!(
        record["timings_ms"]["moves"]
            .as_f64()
            .is_some_and(|ms| ms > 0.0),
        "{record}"
    );

    // SIGTERM while the arm moves: the arm stops, the run is recorded as aborted, the daemon
    // exits within a few seconds.
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let first = json(&body)["run_id"].as_str().expect("run id").to_string();
    wait_status(&api, secs(30), "the move starts", |s| {
        s["current"]["stage"] == "move"
    });
    daemon.signal(libc::SIGTERM);
    let status = daemon.wait_exit(secs(10));
    assert!(status.success(), "{status}\n{}", daemon.log());
    // The stop decelerates the arm (stopj, ≥ 2 rad/s²): give it a second, then it stands.
    std::thread::sleep(Duration::from_millis(1000));
    let q1 = joints(robot_ip);
    std::thread::sleep(Duration::from_millis(500));
    let q2 = joints(robot_ip);
    let moving = q1
        .iter()
        .zip(&q2)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(moving < 1e-4, "the arm still moves after SIGTERM");
    let runs = history(&cfg);
    let row = runs
        .as_array()
        .and_then(|r| r.iter().find(|r| r["run_id"] == first.as_str()))
        .unwrap_or_else(|| panic!("run {first} not in the history: {runs}"));
    assert_eq!(row["outcome"], "aborted", "{row}");

    // kill -9 mid-run: on restart the history opens and the run shows as interrupted.
    let daemon = start_daemon(&dir, "daemon-2", &cfg);
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let second = json(&body)["run_id"].as_str().expect("run id").to_string();
    wait_status(&api, secs(30), "the move starts", |s| {
        s["current"]["stage"] == "move"
    });
    daemon.signal(libc::SIGKILL);
    drop(daemon);
    let _daemon = start_daemon(&dir, "daemon-3", &cfg);
    let runs = history(&cfg);
    let rows = runs.as_array().expect("rows");
    assert!(rows.iter().any(|r| r["run_id"] == first.as_str()), "{runs}");
    let row = rows
        .iter()
        .find(|r| r["run_id"] == second.as_str())
        .unwrap_or_else(|| panic!("run {second} not in the history: {runs}"));
    assert_eq!(row["outcome"], "aborted", "{row}");
    assert!(
        row["reason"]
            .as_str()
            .is_some_and(|r| r.contains("interrupted")),
        "{row}"
    );
}

#[test]
fn the_daemon_queues_when_told_and_reconnects_after_the_rig_restarts() {
    let Some(_) = shared("the_daemon_queues_when_told_and_reconnects_after_the_rig_restarts")
    else {
        return;
    };
    let dir = TempDir::new("reconnect");
    let (robot_ip, camera_ip) = ("127.0.0.130", "127.0.0.131");
    let rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = config(&dir, robot_ip, camera_ip, "when_busy = \"queue\"");
    let daemon = start_daemon(&dir, "daemon", &cfg);
    let api = format!("{robot_ip}:8650");

    // A calibration, and a check asked for while it runs: queued behind it, then run.
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let (code, body) = http(&api, "POST", "/api/check", Some(TOKEN));
    assert_eq!(code, 202, "queued, not refused: {body}");
    let check_id = json(&body)["run_id"].as_str().expect("run id").to_string();
    let (_, body) = http(&api, "GET", "/api/status", None);
    let st = json(&body);
    assert_eq!(st["current"]["mode"], "calibrate", "{st}");
    assert_eq!(st["queued"][0]["run_id"], check_id.as_str(), "{st}");
    let st = wait_status(&api, secs(120), "both runs end", |s| {
        s["state"] == "idle" && s["last"]["run_id"] == check_id.as_str()
    });
    assert_eq!(
        st["last_calibration"]["outcome"],
        "accepted",
        "{st}\n{}",
        daemon.log()
    );
    assert_eq!(st["last"]["outcome"], "accepted", "{st}");
    assert_eq!(st["queued"].as_array().map(Vec::len), Some(0), "{st}");

    // The controller and the camera go away: the daemon keeps running and says so.
    drop(rig);
    let st = wait_status(&api, secs(30), "the robot shows as down", |s| {
        s["robot_connected"] == false
    });
    assert_eq!(st["state"], "idle", "{st}");
    // They come back (a restarted controller: a new RTDE session, the same mount).
    let _rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let st = wait_status(&api, secs(60), "the robot answers again", |s| {
        s["robot_connected"] == true && s["camera_connected"] == true
    });
    assert!(
        st["robot_reconnects"].as_u64().is_some_and(|n| n >= 1),
        "{st}\n{}",
        daemon.log()
    );
    let (_, metrics) = http(&api, "GET", "/metrics", None);
    assert!(metrics.contains("handeye_robot_connected 1"), "{metrics}");
    assert!(
        !metrics.contains("handeye_robot_reconnects_total 0"),
        "{metrics}"
    );
    // A check on the new connections: the mount has not moved, no alarm.
    let (code, body) = http(&api, "POST", "/api/check", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let again = json(&body)["run_id"].as_str().expect("run id").to_string();
    let st = wait_status(&api, secs(90), "the check after the restart ends", |s| {
        s["state"] == "idle" && s["last"]["run_id"] == again.as_str()
    });
    assert_eq!(st["last"]["outcome"], "accepted", "{st}\n{}", daemon.log());
    assert_eq!(st["drift_alarm"], false, "{st}");
}

/// Issue 23: 2 000 idle connections — from 125 client addresses, against a daemon held to the
/// common default of 1 024 file descriptors — leave the API answering: a calibration is
/// started, `POST /api/cancel` stops it, and the status answers throughout.
#[test]
fn issue_23_two_thousand_idle_connections_leave_the_api_and_cancel_working() {
    let Some(_) = shared("issue_23_two_thousand_idle_connections_leave_the_api_and_cancel_working")
    else {
        return;
    };
    let dir = TempDir::new("api-flood");
    let (robot_ip, camera_ip) = ("127.0.0.207", "127.0.0.208");
    // Slow moves: the calibration is still moving when it is cancelled.
    let rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = config(&dir, robot_ip, camera_ip, "");
    let text = std::fs::read_to_string(&cfg).expect("config");
    let slow = text.replace(
        "max_joint_speed_rad_s = 1.0",
        "max_joint_speed_rad_s = 0.05",
    );
    assert_ne!(slow, text, "{text}");
    std::fs::write(&cfg, slow).expect("config");
    let daemon = start_daemon(&dir, "daemon", &cfg);
    let nofile = libc::rlimit {
        rlim_cur: 1024,
        rlim_max: 1024,
    };
    // SAFETY: prlimit(2) on our own child with a valid rlimit; no memory is shared.
    let r = unsafe {
        libc::prlimit(
            i32::try_from(daemon.pid()).expect("pid fits in i32"),
            libc::RLIMIT_NOFILE,
            &nofile,
            std::ptr::null_mut(),
        )
    };
    assert_eq!(r, 0, "prlimit: {}", std::io::Error::last_os_error());
    let api = format!("{robot_ip}:8650");
    let target: std::net::SocketAddr = api.parse().expect("address");

    // 2 000 connections that send nothing, 16 from each of 125 addresses.
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    let t = Instant::now();
    let idle: Vec<tokio::net::TcpStream> = rt.block_on(async {
        let mut held = Vec::new();
        for k in 0..2000u32 {
            let from = std::net::SocketAddr::from(([127, 0, 1, 1 + (k % 125) as u8], 0));
            let socket = tokio::net::TcpSocket::new_v4().expect("socket");
            socket.bind(from).expect("bind");
            if let Ok(Ok(s)) =
                tokio::time::timeout(Duration::from_secs(2), socket.connect(target)).await
            {
                held.push(s);
            }
        }
        held
    });
    eprintln!(
        "{} idle connections opened in {:.1} s",
        idle.len(),
        t.elapsed().as_secs_f64()
    );
    assert!(idle.len() > 1500, "only {} connections opened", idle.len());

    let t = Instant::now();
    let (code, body) = http(&api, "GET", "/api/status", None);
    assert_eq!(code, 200, "{body}\n{}", daemon.log());
    let status_s = t.elapsed().as_secs_f64();
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 202, "{body}\n{}", daemon.log());
    wait_status(&api, secs(30), "the calibration moves", |s| {
        s["current"]["stage"] == "move"
    });
    let t = Instant::now();
    let (code, body) = http(&api, "POST", "/api/cancel", Some(TOKEN));
    let cancel_s = t.elapsed().as_secs_f64();
    assert_eq!(code, 200, "{body}\n{}", daemon.log());
    assert_eq!(json(&body)["cancelled"], true, "{body}");
    let st = wait_status(&api, secs(30), "the cancelled run ends", |s| {
        s["state"] == "idle" && s["last"]["outcome"].is_string()
    });
    assert_eq!(st["last"]["outcome"], "aborted", "{st}");
    eprintln!("under 2000 idle connections: status in {status_s:.3} s, cancel in {cancel_s:.3} s");
    assert!(
        status_s < 5.0 && cancel_s < 5.0,
        "{status_s} s / {cancel_s} s"
    );
    assert!(
        !daemon.log().contains("Too many open files"),
        "{}",
        daemon.log()
    );
    drop(idle);
    drop(daemon);
    drop(rig);
}
