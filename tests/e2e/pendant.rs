//! The pendant button against `handeye sim rig`: a PolyScope program's statements (URScript
//! `sec` programs on the secondary interface) write the request register, the daemon answers in
//! the status register, and ur-rtde reads what the program copied of the answer.

use std::io::Write;
use std::net::TcpStream;
use std::path::Path;
use std::time::Duration;

use crate::daemon::{config, http, start_daemon, wait_status, TOKEN};
use crate::support::{history, joints, max_change, run, secs, shared, start_rig, TempDir};

/// The `[daemon.pendant]` handshake (request in output_int_register_25, answer in
/// input_int_register_26) with the example's register write-back.
const PENDANT: &str = "[daemon.pendant]\nrequest_register = 25\nstatus_register = 26\n\n[write_back.registers]\ndouble_start = 24\nsequence_int = 24";

/// Sends a URScript `sec` program to the controller's secondary interface, as a pendant
/// program's statements would run there.
fn urscript(robot_ip: &str, name: &str, body: &str) {
    let mut s = TcpStream::connect((robot_ip, 30002)).expect("secondary interface");
    write!(s, "sec {name}():\n{body}end\n").expect("send script");
    std::thread::sleep(Duration::from_millis(300));
}

/// What ur-rtde's RTDEReceiveInterface reads from `output_int_register_N`.
fn ur_rtde_output_int(py: &Path, host: &str, register: u32) -> i64 {
    let code = format!(
        "import rtde_receive\nr = rtde_receive.RTDEReceiveInterface('{host}', 125.0, ['timestamp', 'output_int_register_{register}'])\nprint(r.getOutputIntRegister({register}))\nr.disconnect()\n"
    );
    let out = std::process::Command::new(py)
        .arg("-c")
        .arg(code)
        .output()
        .expect("python runs");
    assert!(
        out.status.success(),
        "ur-rtde: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .trim()
        .parse()
        .expect("an integer from ur-rtde")
}

#[test]
fn the_pendant_button_asks_for_a_calibration_through_registers() {
    let Some(_) = shared("the_pendant_button_asks_for_a_calibration_through_registers") else {
        return;
    };
    let dir = TempDir::new("pendant");
    let (robot_ip, camera_ip) = ("127.0.0.134", "127.0.0.135");
    let _rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = config(
        &dir,
        robot_ip,
        camera_ip,
        "[daemon.pendant]\nrequest_register = 25\nstatus_register = 26\n\n[write_back.registers]\ndouble_start = 24\nsequence_int = 24",
    );
    let daemon = start_daemon(&dir, "daemon", &cfg);
    let api = format!("{robot_ip}:8650");

    // The button: the pendant program writes 1 into output_int_register_25.
    urscript(robot_ip, "ask", "  write_output_integer_register(25, 1)\n");
    let st = wait_status(&api, secs(90), "the pendant's calibration ends", |s| {
        s["last"]["trigger"] == "pendant"
    });
    assert_eq!(st["last"]["outcome"], "accepted", "{st}\n{}", daemon.log());

    // The program reads the answer (2 = done) and the result's sequence number; a real client
    // (ur-rtde) reads what the program copied into its output registers.
    urscript(
        robot_ip,
        "answer",
        "  write_output_integer_register(12, read_input_integer_register(26))\n  write_output_integer_register(13, read_input_integer_register(24))\n",
    );
    if let Some(py) = crate::support::python() {
        assert_eq!(ur_rtde_output_int(&py, robot_ip, 12), 2, "status register");
        assert_eq!(ur_rtde_output_int(&py, robot_ip, 13), 1, "sequence number");
    }
    // Clearing the request resets the answer to 0; the next press runs again.
    urscript(
        robot_ip,
        "clear",
        "  write_output_integer_register(25, 0)\n",
    );
    std::thread::sleep(Duration::from_millis(600));
    urscript(
        robot_ip,
        "answer2",
        "  write_output_integer_register(12, read_input_integer_register(26))\n",
    );
    if let Some(py) = crate::support::python() {
        assert_eq!(
            ur_rtde_output_int(&py, robot_ip, 12),
            0,
            "status after clearing"
        );
    }
    urscript(
        robot_ip,
        "check",
        "  write_output_integer_register(25, 2)\n",
    );
    let st = wait_status(&api, secs(90), "the pendant's check ends", |s| {
        s["last"]["mode"] == "check" && s["last"]["trigger"] == "pendant"
    });
    assert_eq!(st["last"]["outcome"], "accepted", "{st}");
}

/// What the program reads in the status register (input_int_register_26), through ur-rtde:
/// the program copies it into output_int_register_12. `None` without ur-rtde (a developer's
/// machine; CI has it).
fn pendant_answer(robot_ip: &str, name: &str) -> Option<i64> {
    urscript(
        robot_ip,
        name,
        "  write_output_integer_register(12, read_input_integer_register(26))\n",
    );
    crate::support::python().map(|py| ur_rtde_output_int(&py, robot_ip, 12))
}

/// Issue 42: a request left in the register when the daemon starts (a program aborted before
/// it wrote 0, a reboot, `Restart=on-failure`) never moves the arm: it is answered 4; a
/// request while another run goes is answered 4 at once and never runs afterwards.
#[test]
fn issue_42_a_stale_request_never_moves_the_arm_and_a_request_during_a_run_is_answered() {
    let Some(_) = shared(
        "issue_42_a_stale_request_never_moves_the_arm_and_a_request_during_a_run_is_answered",
    ) else {
        return;
    };
    let dir = TempDir::new("pendant-stale");
    let (robot_ip, camera_ip) = ("127.0.0.184", "127.0.0.185");
    let _rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = config(&dir, robot_ip, camera_ip, PENDANT);
    let api = format!("{robot_ip}:8650");
    // A calibration request left from before the daemon started.
    urscript(
        robot_ip,
        "stale",
        "  write_output_integer_register(25, 1)\n",
    );
    let q0 = joints(robot_ip);
    // Issue 42: `robot registers --config` reads the registers (it claimed none before).
    let cfg_arg = cfg.to_str().expect("utf-8");
    let regs = run(
        &["robot", "--config", cfg_arg, "registers", "--json"],
        secs(15),
    );
    assert_eq!(regs.code(), 0, "{regs}");
    assert_eq!(regs.json()[0]["index"], 24, "{regs}");
    let daemon = start_daemon(&dir, "daemon", &cfg);
    std::thread::sleep(Duration::from_secs(3));
    let (_, body) = http(&api, "GET", "/api/status", None);
    assert!(
        body.contains("\"state\":\"idle\"") && body.contains("\"last\":null"),
        "the stale request started a run: {body}\n{}",
        daemon.log()
    );
    assert!(max_change(&q0, &joints(robot_ip)) < 1e-9, "the arm moved");
    assert!(
        daemon.log().contains("not taken as a request"),
        "{}",
        daemon.log()
    );
    if let Some(answer) = pendant_answer(robot_ip, "answer_stale") {
        assert_eq!(answer, 4, "a stale request is answered refused");
    }

    // The program resets (answered 0); another run goes; the program asks meanwhile.
    urscript(
        robot_ip,
        "reset",
        "  write_output_integer_register(25, 0)\n",
    );
    std::thread::sleep(Duration::from_millis(600));
    if let Some(answer) = pendant_answer(robot_ip, "answer_reset") {
        assert_eq!(answer, 0, "a reset is answered idle");
    }
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    wait_status(&api, secs(60), "the calibration moves the arm", |s| {
        s["current"]["stage"] == "move"
    });
    urscript(robot_ip, "ask", "  write_output_integer_register(25, 1)\n");
    std::thread::sleep(Duration::from_millis(800));
    let (_, body) = http(&api, "GET", "/api/status", None);
    assert!(
        body.contains("\"state\":\"running\""),
        "the calibration ended before the pendant asked: {body}"
    );
    if let Some(answer) = pendant_answer(robot_ip, "answer_busy") {
        assert_eq!(answer, 4, "a request during a run is refused at once");
    }
    let st = wait_status(&api, secs(120), "the calibration ends", |s| {
        s["state"] == "idle"
    });
    assert_eq!(st["last"]["trigger"], "api", "{st}");
    // The refused request is not run afterwards, though the program never reset it.
    std::thread::sleep(Duration::from_secs(2));
    let (_, body) = http(&api, "GET", "/api/status", None);
    assert!(body.contains("\"state\":\"idle\""), "{body}");
    let runs = history(&cfg);
    assert_eq!(
        runs.as_array().map(Vec::len),
        Some(1),
        "only the API's calibration ran: {runs}"
    );
    // Issue 42: a dry run claims no register, so it runs beside the daemon that holds them.
    let before = joints(robot_ip);
    let out = run(&["calibrate", "--config", cfg_arg, "--dry-run"], secs(60));
    assert_eq!(out.code(), 0, "{out}");
    assert!(
        max_change(&before, &joints(robot_ip)) < 1e-9,
        "the arm moved"
    );
}

/// The book's URScript block whose info string is `urscript <name>` (docs/src/daemon.md).
fn book_program(name: &str) -> String {
    let page =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/src/daemon.md"))
            .expect("docs/src/daemon.md");
    let fence = format!("```urscript {name}\n");
    let start = page
        .find(&fence)
        .unwrap_or_else(|| panic!("no `{fence}` block in docs/src/daemon.md"))
        + fence.len();
    let len = page[start..].find("```").expect("the block ends");
    page[start..start + len].to_string()
}

/// Sends a program to the controller's secondary interface, as the pendant's Play button
/// would start it (it replaces the running program, if any).
fn start_program(robot_ip: &str, program: &str) {
    let mut s = TcpStream::connect((robot_ip, 30002)).expect("secondary interface");
    s.write_all(program.as_bytes()).expect("send program");
    std::thread::sleep(Duration::from_millis(300));
}

/// The active TCP offset (`flange_from_tcp`, UR pose) and whether a program runs.
fn tcp_and_program(robot_ip: &str) -> (Vec<f64>, bool) {
    let out = run(&["robot", "--host", robot_ip, "status", "--json"], secs(15)).success();
    let doc = out.json();
    let tcp = serde_json::from_value(doc["flange_from_tcp_ur_pose"].clone()).expect("tcp");
    (tcp, doc["status"]["program_running"] == true)
}

/// Issue 42: the book's two pendant programs, as written, against the simulated controller
/// and a daemon: the first asks for a calibration, hands the arm over (the daemon's first move
/// stops it) and is answered done; the second applies the result from the registers and resets
/// the request, answered 0.
#[test]
fn issue_42_the_book_s_pendant_programs_ask_and_apply() {
    let Some(_) = shared("issue_42_the_book_s_pendant_programs_ask_and_apply") else {
        return;
    };
    let dir = TempDir::new("pendant-book");
    let (robot_ip, camera_ip) = ("127.0.0.186", "127.0.0.187");
    let _rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = config(&dir, robot_ip, camera_ip, PENDANT);
    let api = format!("{robot_ip}:8650");
    let daemon = start_daemon(&dir, "daemon", &cfg);

    start_program(robot_ip, &book_program("pendant-ask"));
    let st = wait_status(&api, secs(120), "the pendant's calibration ends", |s| {
        s["last"]["trigger"] == "pendant"
    });
    assert_eq!(st["last"]["outcome"], "accepted", "{st}\n{}", daemon.log());
    if let Some(answer) = pendant_answer(robot_ip, "answer_done") {
        assert_eq!(answer, 2, "done");
    }
    let (written, program_running) = tcp_and_program(robot_ip);
    assert!(
        !program_running,
        "the daemon's move stopped the asking program"
    );
    assert!(
        written.iter().any(|v| v.abs() > 1e-3),
        "a TCP was written: {written:?}"
    );

    // The cell program starts later with the TCP lost (a restart; set on the pendant here: the
    // command line does not move or set an arm the daemon holds): the apply program sets it
    // from the registers and resets the request.
    urscript(robot_ip, "lose_tcp", "  set_tcp(p[0,0,0,0,0,0])\n");
    let (lost, _) = tcp_and_program(robot_ip);
    assert!(
        max_change(&lost, &[0.0; 6]) < 1e-9,
        "the TCP was not lost: {lost:?}"
    );
    start_program(robot_ip, &book_program("pendant-apply"));
    std::thread::sleep(Duration::from_millis(700));
    let (applied, _) = tcp_and_program(robot_ip);
    assert!(
        max_change(&applied, &written) < 1e-9,
        "applied {applied:?}, written {written:?}"
    );
    if let Some(answer) = pendant_answer(robot_ip, "answer_reset") {
        assert_eq!(answer, 0, "the reset is answered idle");
    }
}
