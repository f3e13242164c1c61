//! Real UR clients from PyPI against the UR controller simulator (issue 14): ur-rtde's
//! `RTDEControlInterface` (the control program it uploads runs natively), python-urx (primary
//! state and one-line programs), and programs built to exhaust a parser's stack sent to
//! 30001–30003 of a `handeye sim robot` process. The Python scripts are in `tests/python/`;
//! without `$REPO/.venv` (`.ci/install.d/ur-rtde.sh`) the client tests print SKIP, and fail when
//! env `CI` is set. Loopback addresses: 127.0.0.150–127.0.0.152.

use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{IpAddr, SocketAddr, TcpStream};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use handeye_hal::ur_dh::UrModel;
use handeye_ur::primary::{self, PrimaryPackage};
use handeye_ur::sim::{SafetyModeCode, SimConfig, SimHandle, Simulator};
use handeye_ur::UrPose;
use nalgebra::Isometry3;
use serde_json::Value;

use crate::support::{python, secs, sim_robot, TempDir};

/// A simulator in this process (so the test can inject faults and read the truth), on its own
/// runtime. Fields drop in order: the simulator stops before its runtime.
struct InProcessSim {
    sim: SimHandle,
    _runtime: tokio::runtime::Runtime,
}

fn start_sim(ip: &str) -> InProcessSim {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    // A physical arm: the controller publishes the exact DH of its nearly parallel joints 2–4
    // (d of hundreds of metres) and computes every pose from it, as a real one does.
    let mut c =
        SimConfig::new(UrModel::Ur5e, ip.parse::<IpAddr>().expect("ip")).factory_calibrated(4);
    assert!(c.arm.expect("an arm").controller_dh().d[1].abs() > 1.0);
    c.start_running = true;
    c.unlock_delay = Duration::ZERO;
    let sim = runtime
        .block_on(Simulator::start(c))
        .expect("simulator starts");
    InProcessSim {
        sim,
        _runtime: runtime,
    }
}

/// Runs `tests/python/<script> <host>`: every stdout line is JSON; `{"event": E}` lines call
/// `on_event(E)` and are answered `ok` on stdin, `{"step": S, …}` lines are collected by S.
/// Panics with the script's stderr if it fails or takes longer than `limit`.
fn drive_python(
    py: &Path,
    script: &str,
    host: &str,
    limit: Duration,
    mut on_event: impl FnMut(&str),
) -> HashMap<String, Value> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/python")
        .join(script);
    let mut child = Command::new(py)
        .arg(&path)
        .arg(host)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python starts");
    let mut stdin = child.stdin.take().expect("stdin");
    let stdout = child.stdout.take().expect("stdout");
    let mut stderr = child.stderr.take().expect("stderr");
    let err_reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = stderr.read_to_string(&mut s);
        s
    });
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let deadline = Instant::now() + limit;
    let mut steps = HashMap::new();
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(line) => {
                let v: Value = serde_json::from_str(&line)
                    .unwrap_or_else(|e| panic!("{script}: not JSON ({e}): {line}"));
                if let Some(event) = v["event"].as_str() {
                    on_event(event);
                    writeln!(stdin, "ok").expect("answer the script");
                    stdin.flush().expect("answer the script");
                } else if let Some(step) = v["step"].as_str() {
                    steps.insert(step.to_string(), v.clone());
                } else {
                    steps.insert("result".to_string(), v);
                }
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
            Err(mpsc::RecvTimeoutError::Timeout) => {
                let _ = child.kill();
                let _ = child.wait();
                panic!(
                    "{script} did not finish within {limit:?}; steps so far: {:?}\n{}",
                    steps.keys().collect::<Vec<_>>(),
                    err_reader.join().unwrap_or_default()
                );
            }
        }
    }
    let status = child.wait().expect("python ends");
    let stderr = err_reader.join().unwrap_or_default();
    assert!(
        status.success(),
        "{script} failed ({status}) after steps {:?}:\n{stderr}",
        steps.keys().collect::<Vec<_>>()
    );
    steps
}

fn six(v: &Value) -> [f64; 6] {
    let list: Vec<f64> = serde_json::from_value(v.clone())
        .unwrap_or_else(|e| panic!("six numbers expected ({e}): {v}"));
    list.try_into()
        .unwrap_or_else(|l: Vec<f64>| panic!("six numbers expected, got {}", l.len()))
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

fn assert_poses_close(a: [f64; 6], b: [f64; 6], m: f64, what: &str) {
    assert!(
        UrPose(a).approx_eq(&UrPose(b), m, m),
        "{what}: {a:?} vs {b:?}"
    );
}

/// The Python venv with `module` importable, or `None` after printing SKIP (a failure under CI).
fn python_with(module: &str, test: &str) -> Option<std::path::PathBuf> {
    let py = python()?;
    let ok = Command::new(&py)
        .args(["-c", &format!("import {module}")])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if ok {
        return Some(py);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{test}: `{module}` is not installed in {} (CI is set): run .ci/install.d/ur-rtde.sh",
        py.display()
    );
    crate::support::skip(&format!(
        "SKIP {test}: `{module}` not installed in {}",
        py.display()
    ));
    None
}

#[test]
fn issue_14_ur_rtde_control_interface_drives_the_simulated_arm() {
    let Some(py) = python_with("rtde_control", "ur_rtde_control_interface") else {
        return;
    };
    let ip = "127.0.0.150";
    let s = start_sim(ip);
    let sim = &s.sim;
    // A primary-interface client listening all along: program start/stop and exceptions.
    let mut primary_sock = TcpStream::connect((ip, 30001)).expect("primary");
    let stop = Arc::new(AtomicBool::new(false));
    primary_messages(
        &mut primary_sock,
        Instant::now() + Duration::from_millis(300),
        &stop,
    );
    let stop_listening = stop.clone();
    let listener = std::thread::spawn(move || {
        primary_messages(
            &mut primary_sock,
            Instant::now() + secs(150),
            &stop_listening,
        )
    });
    let steps = drive_python(
        &py,
        "ur_rtde_control.py",
        ip,
        secs(120),
        |event| match event {
            "slider_half" => sim.set_speed_slider(0.5),
            "slider_full" => sim.set_speed_slider(1.0),
            "arm_protective_stop" => sim.protective_stop_during_next_move(0.5),
            other => panic!("unknown event {other}"),
        },
    );
    let step = |name: &str| {
        steps
            .get(name)
            .unwrap_or_else(|| panic!("no step {name}: {steps:?}"))
    };

    let connect = step("connect");
    assert_eq!(connect["running"], true, "{connect}");
    eprintln!(
        "RTDEControlInterface connected in {:.2} s",
        connect["seconds"].as_f64().unwrap_or(f64::NAN)
    );

    // moveJ: the arm is where it was asked to go, as RTDE reports it.
    let mj = step("moveJ");
    assert_eq!(mj["ok"], true, "{mj}");
    assert!(max_diff(&six(&mj["q"]), &six(&mj["target"])) < 1e-6, "{mj}");

    // moveL (sync): the TCP reached the pose.
    let ml = step("moveL");
    assert_eq!(ml["ok"], true, "{ml}");
    assert_poses_close(six(&ml["pose"]), six(&ml["target"]), 1e-6, "moveL");

    // moveL (async): the call returned at once, progress was reported while the arm moved
    // (the TCP between start and goal), then the operation finished at the goal.
    let ma = step("moveL_async");
    assert_eq!(ma["ok"], true, "{ma}");
    assert!(
        ma["seconds"].as_f64().expect("s") < 0.3,
        "async returned late: {ma}"
    );
    let progress: Vec<i64> = serde_json::from_value(ma["progress"].clone()).expect("progress");
    assert!(progress.len() >= 5, "{ma}");
    assert!(
        progress[..progress.len() - 1].iter().all(|p| *p >= 0),
        "{ma}"
    );
    assert!(*progress.last().expect("last") < 0, "{ma}");
    let zs: Vec<f64> = serde_json::from_value(ma["z_while_running"].clone()).expect("z");
    let (z_start, z_goal) = (six(&ml["pose"])[2], six(&ma["target"])[2]);
    assert!(
        zs.iter()
            .any(|z| *z > z_start + 0.005 && *z < z_goal - 0.005),
        "no sample while moving: {zs:?}"
    );
    assert_poses_close(six(&ma["pose"]), six(&ma["target"]), 1e-6, "moveL async");

    // setTcp + getTCPOffset, and the controller's kinematics seen through the client.
    let st = step("setTcp");
    assert_eq!(st["ok"], true, "{st}");
    let tcp = [0.0, 0.0, 0.12, 0.0, 0.0, 0.3];
    assert!(max_diff(&six(&st["offset"]), &tcp) < 1e-12, "{st}");
    let q = six(&st["q"]);
    let truth = UrPose::from(sim.dh().forward(&q) * Isometry3::from(UrPose(tcp)));
    assert_poses_close(six(&st["pose"]), truth.0, 1e-9, "TCP pose after setTcp");
    assert_poses_close(six(&st["fk"]), truth.0, 1e-9, "getForwardKinematics");
    assert!(
        max_diff(&six(&st["ik"]), &q) < 1e-6,
        "getInverseKinematics: {st}"
    );

    // The other motion and kinematics calls.
    let mc = step("more_calls");
    let ik = &mc["moveJ_IK"];
    assert_eq!(ik[0], true, "{mc}");
    assert_poses_close(six(&ik[1]), six(&ik[2]), 1e-6, "moveJ_IK");
    let fk = &mc["moveL_FK"];
    assert_eq!(fk[0], true, "{mc}");
    assert!(
        max_diff(&six(&fk[1]), &six(&fk[2])) < 1e-6,
        "moveL_FK: {fk}"
    );
    let sl = &mc["speedL"];
    assert_eq!(sl[0], true, "{mc}");
    let twist = six(&sl[1]);
    assert!(
        (twist[2] - 0.02).abs() < 1e-4 && max_diff(&[twist[0], twist[1]], &[0.0; 2]) < 1e-4,
        "speedL: TCP speed {twist:?}"
    );
    let rise = sl[2].as_f64().expect("dz");
    assert!(
        (0.006..0.03).contains(&rise),
        "speedL raised the TCP {rise} m"
    );
    let sv = &mc["servoJ"];
    assert_eq!(sv[0], true, "{mc}");
    let turned = sv[1].as_f64().expect("dq");
    assert!(
        (0.15..=0.2 + 1e-9).contains(&turned),
        "servoJ turned wrist 3 by {turned}"
    );
    let sj = &mc["stopJ"];
    assert_eq!(sj[0], true, "{mc}");
    let part = sj[1].as_f64().expect("dq");
    assert!((0.02..0.9).contains(&part), "stopJ after {part} rad of 1.0");
    assert!(
        sj[2].as_i64().expect("progress") < 0,
        "async move finished: {sj}"
    );
    assert!(six(&sj[3]).iter().all(|v| v.abs() < 1e-9), "{sj}");
    let pl = &mc["setPayload"];
    assert_eq!(pl[0], true, "{mc}");
    assert_eq!(pl[1], 1.5, "{mc}");
    assert_eq!(pl[2], serde_json::json!([0.0, 0.01, 0.05]), "{mc}");
    let qs = &mc["queries"];
    for (key, want) in [
        ("steady", true),
        ("joints_ok", true),
        ("joints_out", false),
        ("ik_has_solution", true),
        ("ik_no_solution", false),
    ] {
        assert_eq!(qs[key], want, "{key}: {qs}");
    }
    assert!(max_diff(&six(&qs["pose_trans"]), &[0.1, 0.2, 0.0, 0.0, 0.0, 0.0]) < 1e-12);
    let flange = UrPose::from(sim.dh().forward(&six(&qs["q"]))).0;
    assert_poses_close(six(&qs["flange"]), flange, 1e-9, "getActualToolFlangePose");
    assert_eq!(qs["step_time"], 0.002, "{qs}");
    let st = &mc["stopL"];
    assert_eq!(st[0], true, "{mc}");
    let part = st[1].as_f64().expect("dz");
    assert!((0.01..0.14).contains(&part), "stopL after {part} m of 0.15");
    assert!(six(&st[2]).iter().all(|v| v.abs() < 1e-9), "stopped: {st}");
    assert!(st[3].as_i64().expect("progress") < 0, "{st}");
    // While moving, the target waypoint was the move's goal.
    assert_poses_close(six(&st[4]), six(&st[5]), 1e-6, "getTargetWaypoint");
    let tp = &mc["setTargetPayload"];
    assert_eq!(tp[0], true, "{mc}");
    assert_eq!(tp[1], 2.0);
    assert_eq!(tp[2], serde_json::json!([0.0, 0.0, 0.1]));
    assert_eq!(tp[3], serde_json::json!([0.01, 0.01, 0.02, 0.0, 0.0, 0.0]));
    let ikn = &mc["ik_near"];
    assert!(max_diff(&six(&ikn[0]), &six(&ikn[1])) < 1e-6, "{ikn}");
    assert_eq!(mc["pose_limits"], serde_json::json!([true, false]), "{mc}");

    // speedJ then speedStop: the joints ran at the commanded speed, then stopped.
    let sj = step("speedJ");
    assert_eq!(
        (sj["ok"].clone(), sj["stopped"].clone()),
        (true.into(), true.into())
    );
    let qd = six(&sj["qd_running"]);
    assert!(
        (qd[0] - 0.15).abs() < 1e-6 && (qd[5] + 0.1).abs() < 1e-6,
        "{qd:?}"
    );
    assert!(six(&sj["qd_after"]).iter().all(|v| v.abs() < 1e-9), "{sj}");
    let moved = six(&sj["q_after"])[0] - six(&sj["q_before"])[0];
    assert!((0.08..0.4).contains(&moved), "base moved {moved} rad");

    // The speed slider at 50 % doubles the duration of the same move.
    let sl = step("slider");
    assert_eq!(sl["ok"], serde_json::json!([true, true]), "{sl}");
    let ratio = sl["seconds_half"].as_f64().expect("s") / sl["seconds_full"].as_f64().expect("s");
    assert!(
        (1.6..2.4).contains(&ratio),
        "slider 0.5: {ratio:.2}× the time"
    );

    // Protective stop half way: moveJ returns False, RTDE reports the stop, the arm stopped
    // between start and target, the control program is no longer running.
    let ps = step("protective_stop");
    assert_eq!(ps["ok"], false, "{ps}");
    assert_eq!(
        ps["safety_mode"],
        SafetyModeCode::ProtectiveStop as i64,
        "{ps}"
    );
    assert_eq!(ps["protective_stopped"], true, "{ps}");
    assert_eq!(ps["running"], false, "{ps}");
    let (start, target, at) = (six(&ps["start"]), six(&ps["target"]), six(&ps["q"]));
    let fraction = (at[0] - start[0]) / (target[0] - start[0]);
    assert!(
        (0.4..0.75).contains(&fraction),
        "stopped at {fraction:.2} of the path"
    );

    let rc = step("recover");
    assert_eq!(rc["safety_mode"], SafetyModeCode::Normal as i64, "{rc}");
    assert_eq!(
        (rc["reuploaded"].clone(), rc["running"].clone()),
        (true.into(), true.into()),
        "{:?}",
        sim.recent_log()
    );

    let ss = step("stopScript");
    assert_eq!(ss["running"], false, "{ss}");
    assert_eq!(ss["connected"], false, "{ss}");

    // Reconnect uploads the program again; the arm goes back where it started.
    let re = step("reconnect");
    assert_eq!(re["reconnected"], true, "{re}");
    assert_eq!(
        (re["running"].clone(), re["ok"].clone()),
        (true.into(), true.into())
    );
    assert!(max_diff(&six(&re["q"]), &six(&re["target"])) < 1e-6, "{re}");

    let wd = step("watchdog");
    assert_eq!(wd["ok"], true, "{wd}");
    assert_eq!(wd["running_kicked"], true, "{wd}");
    assert_eq!(wd["running_unkicked"], false, "{wd}");

    let un = step("unsupported");
    assert_eq!(un["running_before"], true, "{un}");
    assert_eq!(un["ok"], false, "{un}");
    assert_eq!(un["running"], false, "{un}");
    assert!(un["seconds"].as_f64().expect("s") < 2.0, "{un}");
    let log = sim.recent_log().join("\n");
    assert!(log.contains("RTDE input watchdog"), "{log}");
    assert!(log.contains("teachMode) is not supported"), "{log}");
    let up = step("upper_range");
    assert_eq!(up["ok"], serde_json::json!([true, true]), "{up}");
    assert!(max_diff(&six(&up["q"]), &six(&up["target"])) < 1e-6, "{up}");
    assert!(max_diff(&six(&up["offset"]), &[0.0, 0.0, 0.05, 0.0, 0.0, 0.0]) < 1e-12);
    assert!(
        max_diff(&sim.joint_positions(), &six(&up["q"])) < 1e-9,
        "RTDE and the arm agree"
    );
    assert!(steps.contains_key("done"));

    // The primary interface announced each run of the program and its two runtime exceptions.
    stop.store(true, Ordering::Relaxed);
    let primary = listener.join().expect("listener");
    let runs = |title: &str| {
        primary
            .keys
            .iter()
            .filter(|(t, n)| t == title && n == "rtde_control")
            .count()
    };
    // connect, reupload after the protective stop, reconnect, reupload after the watchdog,
    // the upper register range
    assert_eq!(runs("PROGRAM_XXX_STARTED"), 5, "{primary:?}");
    assert_eq!(runs("PROGRAM_XXX_STOPPED"), 5, "{primary:?}");
    assert!(
        primary
            .exceptions
            .iter()
            .any(|e| e.contains("RTDE input watchdog"))
            && primary
                .exceptions
                .iter()
                .any(|e| e.contains("(teachMode) is not supported")),
        "{primary:?}"
    );
}

#[test]
fn issue_14_python_urx_reads_state_and_moves() {
    let Some(py) = python_with("urx", "python_urx") else {
        return;
    };
    let ip = "127.0.0.151";
    let s = start_sim(ip);
    let sim = &s.sim;
    let q0 = sim.joint_positions();
    let out = drive_python(&py, "urx_client.py", ip, secs(90), |e| {
        panic!("unexpected event {e}")
    });
    let out = &out["result"];
    assert_eq!(out["running"], true, "urx sees a running robot: {out}");
    assert!(max_diff(&six(&out["getj"]), &q0) < 1e-12, "{out}");
    let tcp0 = UrPose::from(sim.dh().forward(&q0)).0;
    assert_poses_close(six(&out["getl"]), tcp0, 1e-9, "getl at the start");
    assert!(
        max_diff(&six(&out["after_movej"]), &six(&out["movej_target"])) < 1e-6,
        "{out}"
    );
    assert_poses_close(
        six(&out["after_movel"]),
        six(&out["movel_target"]),
        1e-6,
        "movel",
    );
    let q = six(&out["getj_with_tcp"]);
    let tcp = six(&out["tcp"]);
    assert!(max_diff(&sim.tcp_offset().0, &tcp) < 1e-12);
    let expect = UrPose::from(sim.dh().forward(&q) * Isometry3::from(UrPose(tcp))).0;
    assert_poses_close(
        six(&out["getl_with_tcp"]),
        expect,
        1e-9,
        "getl after set_tcp",
    );
    assert!(max_diff(&sim.joint_positions(), &q) < 1e-9);
}

/// What a primary-interface client saw: runtime exceptions, text messages and key messages
/// (title, text).
#[derive(Debug, Default)]
struct PrimaryLog {
    exceptions: Vec<String>,
    texts: Vec<String>,
    keys: Vec<(String, String)>,
}

/// Reads primary-interface packages from `sock` until `deadline` or until `stop` is set.
fn primary_messages(sock: &mut TcpStream, deadline: Instant, stop: &AtomicBool) -> PrimaryLog {
    let mut log = PrimaryLog::default();
    let mut buf = Vec::new();
    let mut chunk = [0u8; 65536];
    while Instant::now() < deadline && !stop.load(Ordering::Relaxed) {
        sock.set_read_timeout(Some(Duration::from_millis(100)))
            .expect("timeout");
        match sock.read(&mut chunk) {
            Ok(0) => panic!("the simulator closed the primary connection"),
            Ok(n) => buf.extend_from_slice(&chunk[..n]),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => panic!("primary stream: {e}"),
        }
        while let Some((p, n)) = primary::split(&buf).expect("well-formed primary stream") {
            buf.drain(..n);
            match p {
                PrimaryPackage::RuntimeException { text, .. } => log.exceptions.push(text),
                PrimaryPackage::Text(t) => log.texts.push(t),
                PrimaryPackage::Key { title, text, .. } => log.keys.push((title, text)),
                _ => {}
            }
        }
    }
    log
}

#[test]
fn issue_14_programs_built_to_overflow_the_parser_get_a_compile_error() {
    let dir = TempDir::new("ur-clients-nesting");
    let ip = "127.0.0.152";
    let mut d = sim_robot(&dir, ip, &["--powered"]);
    let at = |port: u16| SocketAddr::new(ip.parse().expect("ip"), port);
    let mut listener = TcpStream::connect(at(30001)).expect("primary");
    // Once the first packages arrived, the connection receives every robot message.
    let never = AtomicBool::new(false);
    primary_messages(
        &mut listener,
        Instant::now() + Duration::from_millis(300),
        &never,
    );
    let nested_ifs = format!(
        "def deep():\n{} x = 1\n{}end\n",
        " if 1:\n".repeat(5000),
        " end\n".repeat(5000)
    );
    let minus_chain = format!("def neg():\n  x = {}1\nend\n", "-".repeat(100_000));
    // The senders stay open while the answers arrive (closing a socket with unread data in it
    // resets the connection, which may discard what was sent).
    let mut senders = Vec::new();
    for port in [30001, 30002, 30003] {
        for program in [&nested_ifs, &minus_chain] {
            let mut sock = TcpStream::connect(at(port)).expect("connect");
            sock.write_all(program.as_bytes()).expect("send");
            senders.push(sock);
        }
    }
    let sent = senders.len();
    let exceptions = primary_messages(&mut listener, Instant::now() + secs(3), &never).exceptions;
    let refused: Vec<&String> = exceptions
        .iter()
        .filter(|e| e.contains("compile error") && e.contains("nested too deeply"))
        .collect();
    assert_eq!(refused.len(), sent, "{exceptions:?}");
    // Still serving: the process is alive, the dashboard answers, a program runs.
    d.wait_for_port(at(29999), secs(2));
    let mut dash = TcpStream::connect(at(29999)).expect("dashboard");
    dash.set_read_timeout(Some(secs(5))).expect("timeout");
    let mut r = BufReader::new(dash.try_clone().expect("clone"));
    let mut line = String::new();
    r.read_line(&mut line).expect("banner");
    dash.write_all(b"robotmode\n").expect("send");
    line.clear();
    r.read_line(&mut line).expect("reply");
    assert_eq!(line.trim(), "Robotmode: RUNNING");
    let mut sock = TcpStream::connect(at(30002)).expect("secondary");
    sock.write_all(b"def alive():\n  textmsg(\"still answering\")\nend\n")
        .expect("send");
    let texts = primary_messages(&mut listener, Instant::now() + secs(2), &never).texts;
    assert!(texts.iter().any(|t| t == "still answering"), "{texts:?}");
    drop(senders);
    let log = d.stop();
    assert!(log.contains("nested too deeply"), "{log}");
}
