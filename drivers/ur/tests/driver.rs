//! Our driver (`UrRobot`, `RtdeClient`, `DashboardClient`, `ScriptClient`) against our
//! simulator on ephemeral ports, including every fault the simulator can inject.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::time::Duration;

use handeye_hal::ur_dh::{DhParams, JointErrorSizes, PhysicalArm, UrModel};
use handeye_hal::{HalError, MotionLimits, Robot, RobotMode, SafetyMode};
use handeye_ur::client::{RtdeClient, RtdeConfig, ScriptClient};
use handeye_ur::dashboard::DashboardClient;
use handeye_ur::rtde::Protocol;
use handeye_ur::sim::{SafetyModeCode, SimConfig, SimHandle, Simulator};
use handeye_ur::{UrConfig, UrError, UrPose, UrRobot};
use nalgebra::Isometry3;

const LOCAL: IpAddr = IpAddr::V4(Ipv4Addr::LOCALHOST);

fn sim_config() -> SimConfig {
    let mut c = SimConfig::new(UrModel::Ur5e, LOCAL).ephemeral();
    c.start_running = true;
    c.unlock_delay = Duration::ZERO;
    c
}

async fn start(c: SimConfig) -> (SimHandle, UrRobot) {
    let sim = Simulator::start(c).await.expect("sim starts");
    let mut cfg = UrConfig::new(LOCAL);
    cfg.ports = sim.ports();
    cfg.max_joint_speed_rad_s = 2.0;
    cfg.max_joint_accel_rad_s2 = 8.0;
    cfg.max_backoff = Duration::from_millis(200);
    let robot = tokio::time::timeout(Duration::from_secs(10), UrRobot::connect(cfg))
        .await
        .expect("no hang")
        .expect("connects");
    (sim, robot)
}

fn limits(v: f64, timeout_s: u64) -> MotionLimits {
    MotionLimits {
        max_joint_speed_rad_s: v,
        max_joint_accel_rad_s2: 8.0,
        timeout: Duration::from_secs(timeout_s),
    }
}

fn target_from(q0: [f64; 6], delta: f64) -> Vec<f64> {
    q0.iter()
        .enumerate()
        .map(|(i, q)| if i == 0 || i == 5 { q + delta } else { *q })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_move_and_flange_pose() {
    let (sim, robot) = start(sim_config()).await;
    let st = robot.status().await.expect("status");
    assert_eq!(st.robot_mode, RobotMode::Running);
    assert_eq!(st.safety_mode, SafetyMode::Normal);
    assert!(st.remote_control && !st.program_running);
    let target = target_from(sim.joint_positions(), 0.3);
    robot
        .move_joints(&target, limits(2.0, 10))
        .await
        .expect("move");
    let q = sim.joint_positions();
    for (a, b) in q.iter().zip(&target) {
        assert!((a - b).abs() < 1e-3, "{q:?} vs {target:?}");
    }
    let got = robot.joint_positions().await.expect("q");
    assert!(got.iter().zip(&target).all(|(a, b)| (a - b).abs() < 1e-3));
    let q6: [f64; 6] = got.try_into().expect("6");
    let expect = sim.dh().forward(&q6);
    let flange = robot.flange_pose().await.expect("flange");
    assert!((flange.translation.vector - expect.translation.vector).norm() < 1e-6);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn speed_cap_limits_the_joint_speed_seen_over_rtde() {
    let (sim, robot) = start(sim_config()).await;
    let target = target_from(sim.joint_positions(), 0.4);
    let r2 = robot.clone();
    let watcher = tokio::spawn(async move {
        let mut max: f64 = 0.0;
        let mut last = std::time::Instant::now();
        for _ in 0..2000 {
            let Ok(s) = r2.rtde().next_sample(last, Duration::from_secs(1)).await else {
                break;
            };
            last = s.received;
            let qd = s.vec6("actual_qd").expect("qd");
            max = qd.iter().fold(max, |m, v| m.max(v.abs()));
            if s.f64("runtime_state") == Some(1.0) && max > 0.0 {
                break;
            }
        }
        max
    });
    robot
        .move_joints(&target, limits(0.5, 20))
        .await
        .expect("move");
    let max = watcher.await.expect("watcher");
    assert!(max > 0.1 && max <= 0.5 + 1e-6, "max joint speed {max}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn set_tcp_is_confirmed_and_tcp_pose_follows() {
    let (sim, robot) = start(sim_config()).await;
    let flange_from_tcp = Isometry3::from(UrPose([0.01, -0.02, 0.15, 0.1, 0.2, -0.3]));
    robot.set_tcp(&flange_from_tcp).await.expect("set_tcp");
    assert!(sim
        .tcp_offset()
        .approx_eq(&UrPose::from(flange_from_tcp), 1e-9, 1e-9));
    let flange = robot.flange_pose().await.expect("flange");
    let tcp = robot.tcp_pose().await.expect("tcp");
    let expect = flange * flange_from_tcp;
    assert!((tcp.translation.vector - expect.translation.vector).norm() < 1e-6);
    assert!(tcp.rotation.angle_to(&expect.rotation) < 1e-6);
    assert!(robot
        .set_tcp(&Isometry3::from(UrPose([
            f64::NAN,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0
        ])))
        .await
        .is_err());
}

/// Issue 46: a TCP the driver would refuse on read (farther than 2 m from the flange, or so
/// far that it is not finite once squared) is refused by `set_tcp` too, saying so, before
/// anything is sent: the controller keeps its TCP.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_46_set_tcp_refuses_a_tcp_the_driver_would_refuse_on_read() {
    let (sim, robot) = start(sim_config()).await;
    let before = sim.tcp_offset();
    for x in [2.5, 5.0, 1e300] {
        let far = Isometry3::from(UrPose([x, 0.0, 0.1, 0.0, 0.0, 0.0]));
        let err = robot.set_tcp(&far).await.expect_err("beyond 2 m");
        let text = err.to_string();
        assert!(
            matches!(err, HalError::InvalidArgument(_))
                && text.contains("at most 2 m")
                && text.contains("nothing was sent"),
            "{x} m: {text}"
        );
        assert_eq!(sim.tcp_offset(), before, "{x} m: the TCP changed");
        robot.tcp_offset().await.expect("the TCP still reads");
    }
    // Just inside the bound is a tool.
    let long_tool = Isometry3::from(UrPose([0.0, 0.0, 1.9, 0.0, 0.0, 0.0]));
    robot.set_tcp(&long_tool).await.expect("1.9 m");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn registers_round_trip_and_fieldbus_range_is_left_alone() {
    let (sim, robot) = start(sim_config().with_fieldbus_lower_range()).await;
    robot.write_double_register(24, 0.125).await.expect("write");
    assert_eq!(sim.input_double_register(24), 0.125);
    assert_eq!(robot.read_double_register(24).await.expect("read"), 0.125);
    sim.set_output_double_register(30, -2.5);
    tokio::time::sleep(Duration::from_millis(50)).await;
    assert_eq!(
        robot.read_output_double_register(30).await.expect("read"),
        -2.5
    );
    assert!(matches!(
        robot.write_double_register(3, 1.0).await,
        Err(HalError::InvalidArgument(_))
    ));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn register_held_by_fieldbus_is_a_clear_error() {
    let mut c = sim_config();
    c.fieldbus_held.push("input_double_register_30".into());
    let sim = Simulator::start(c).await.expect("sim");
    let mut cfg = UrConfig::new(LOCAL);
    cfg.ports = sim.ports();
    let err = UrRobot::connect(cfg).await.expect_err("IN_USE");
    let msg = err.to_string();
    assert!(
        matches!(err, UrError::FieldInUse { ref name, .. } if name == "input_double_register_30"),
        "{msg}"
    );
    assert!(
        msg.contains("IN_USE") && msg.contains("input_double_register_30"),
        "{msg}"
    );
    let hal: HalError = err.into();
    assert!(matches!(hal, HalError::RegisterInUse { .. }));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unknown_output_field_is_not_found() {
    let sim = Simulator::start(sim_config()).await.expect("sim");
    let cfg = RtdeConfig {
        addr: SocketAddr::new(LOCAL, sim.ports().rtde),
        frequency: Some(125.0),
        outputs: vec!["timestamp".into(), "actual_qq".into()],
        inputs: vec![],
        timeout: Duration::from_secs(2),
        max_backoff: Duration::from_millis(200),
    };
    let err = RtdeClient::connect(cfg).await.expect_err("NOT_FOUND");
    assert!(
        matches!(err, UrError::FieldNotFound { ref name } if name == "actual_qq"),
        "{err}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn protective_stop_during_move_fails_the_move() {
    let (sim, robot) = start(sim_config()).await;
    sim.protective_stop_during_next_move(0.3);
    let target = target_from(sim.joint_positions(), 0.5);
    let err = robot
        .move_joints(&target, limits(2.0, 10))
        .await
        .expect_err("pstop");
    assert!(matches!(err, HalError::ProtectiveStop { .. }), "{err}");
    assert_eq!(sim.safety_mode(), SafetyModeCode::ProtectiveStop);
    assert!(!sim.program_running());
    // A new move is refused until an operator unlocks.
    let err = robot
        .move_joints(&target, limits(2.0, 10))
        .await
        .expect_err("still stopped");
    assert!(matches!(err, HalError::ProtectiveStop { .. }), "{err}");
    robot
        .dashboard(|d| Box::pin(d.unlock_protective_stop()))
        .await
        .expect("unlock");
    robot
        .move_joints(&target, limits(2.0, 10))
        .await
        .expect("moves after unlock");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn emergency_stop_during_move_fails_the_move() {
    let (sim, robot) = start(sim_config()).await;
    let target = target_from(sim.joint_positions(), 1.0);
    let sim = std::sync::Arc::new(sim);
    let s2 = sim.clone();
    tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(200)).await;
        s2.emergency_stop(true);
    });
    let err = robot
        .move_joints(&target, limits(0.5, 10))
        .await
        .expect_err("estop");
    assert!(matches!(err, HalError::EmergencyStop { .. }), "{err}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn remote_control_off_refuses_and_aborts_moves() {
    let (sim, robot) = start(sim_config()).await;
    let target = target_from(sim.joint_positions(), 1.0);
    let sim = std::sync::Arc::new(sim);
    let s2 = sim.clone();
    tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(200)).await;
        s2.set_remote_control(false);
    });
    let err = robot
        .move_joints(&target, limits(0.5, 10))
        .await
        .expect_err("local");
    assert!(matches!(err, HalError::NotInRemoteControl), "{err}");
    let err = robot
        .move_joints(&target, limits(0.5, 10))
        .await
        .expect_err("local");
    assert!(matches!(err, HalError::NotInRemoteControl), "{err}");
    assert!(!robot.status().await.expect("status").remote_control);
    // Scripts are refused with C210, dashboard commands that change state are refused.
    let err = robot
        .run_program("x", "  textmsg(\"hi\")\n")
        .await
        .expect_err("C210");
    assert!(err.to_string().contains("C210"), "{err}");
    let err = robot
        .dashboard(|d| Box::pin(d.power_off()))
        .await
        .expect_err("refused");
    assert!(matches!(err, UrError::Refused { .. }), "{err}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn timeout_and_cancel_stop_the_arm() {
    let (sim, robot) = start(sim_config()).await;
    let target = target_from(sim.joint_positions(), 1.0);
    let mut lim = limits(0.3, 10);
    lim.timeout = Duration::from_millis(300);
    let err = robot.move_joints(&target, lim).await.expect_err("timeout");
    assert!(matches!(err, HalError::Timeout { .. }), "{err}");
    wait_until(|| !sim.program_running()).await;
    let err = robot
        .move_joints_until(
            &target,
            limits(0.3, 10),
            tokio::time::sleep(Duration::from_millis(300)),
        )
        .await
        .expect_err("cancel");
    assert!(matches!(err, HalError::Cancelled { .. }), "{err}");
    wait_until(|| !sim.program_running()).await;
    let q = sim.joint_positions();
    assert!(
        (q[0] - target[0]).abs() > 0.1,
        "the arm stopped short of the target"
    );
    // Dropping a move future (how callers cancel through the `Robot` trait) also stops the
    // arm: a 1 rad move at 0.3 rad/s would run for over 3 s.
    let far = target_from(sim.joint_positions(), -1.0);
    let fut = robot.move_joints(&far, limits(0.3, 10));
    assert!(tokio::time::timeout(Duration::from_millis(300), fut)
        .await
        .is_err());
    let dropped = std::time::Instant::now();
    wait_until(|| !sim.program_running()).await;
    assert!(
        dropped.elapsed() < Duration::from_millis(1500),
        "stopped {:?} after the drop",
        dropped.elapsed()
    );
    tokio::time::sleep(Duration::from_millis(200)).await;
    let q = sim.joint_positions();
    assert!((q[0] - far[0]).abs() > 0.5, "the arm kept going: {q:?}");
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(sim.joint_positions(), q, "the arm is still moving");

    // `stop` returns once the arm stands and the stop program has ended: whatever comes next
    // (a run's preflight) never finds our own stop still playing.
    let moving = robot.clone();
    let mover = tokio::spawn(async move { moving.move_joints(&target, limits(1.0, 2)).await });
    wait_until(|| sim.program_running()).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    robot.stop().await.expect("stop");
    assert!(!sim.program_running(), "a program still plays after stop");
    let q = sim.joint_positions();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(sim.joint_positions(), q, "the arm still moves after stop");
    assert!(robot.status().await.is_ok_and(|st| !st.program_running));
    let _ = mover.await;
}

async fn wait_until(mut f: impl FnMut() -> bool) {
    for _ in 0..500 {
        if f() {
            return;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("condition not reached within 5 s");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dropped_connections_reconnect_with_recipes() {
    let (sim, robot) = start(sim_config()).await;
    sim.drop_connections();
    for _ in 0..200 {
        if robot.rtde().reconnects() > 0 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(robot.rtde().reconnects() >= 1);
    // Input recipes were set up again: writes work, and the dashboard reconnects too.
    robot
        .write_double_register(25, 7.0)
        .await
        .expect("write after reconnect");
    assert_eq!(sim.input_double_register(25), 7.0);
    assert!(robot.status().await.expect("status").remote_control);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn latency_beyond_the_timeout_is_a_timeout() {
    let (sim, robot) = start(sim_config()).await;
    sim.set_latency(Duration::from_secs(5));
    let err = tokio::time::timeout(Duration::from_secs(10), robot.status())
        .await
        .expect("no hang")
        .expect_err("timeout");
    assert!(matches!(err, HalError::Timeout { .. }), "{err}");
    sim.set_latency(Duration::from_millis(50));
    let mut d = DashboardClient::connect(
        SocketAddr::new(LOCAL, sim.ports().dashboard),
        Duration::from_secs(2),
    )
    .await
    .expect("dash");
    assert_eq!(d.robot_mode().await.expect("mode"), RobotMode::Running);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtde_falls_back_to_protocol_v1() {
    let mut c = sim_config();
    c.rtde_v2 = false;
    let (_sim, robot) = start(c).await;
    assert_eq!(robot.rtde().protocol(), Protocol::V1);
    let err = robot
        .write_double_register(26, 4.5)
        .await
        .expect_err("v1 has no recipe ids");
    assert!(err.to_string().contains("protocol 1"), "{err}");
    assert_eq!(robot.joint_positions().await.expect("q").len(), 6);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unsupported_script_is_reported_not_ignored() {
    let sim = Simulator::start(sim_config()).await.expect("sim");
    let script = ScriptClient::new(
        SocketAddr::new(LOCAL, sim.ports().primary),
        Duration::from_secs(2),
    );
    let err = script
        .send(
            "def p():\n  force_mode(1)\nend\n",
            Some("p"),
            Duration::ZERO,
        )
        .await
        .expect_err("unsupported");
    assert!(err.to_string().contains("force_mode"), "{err}");
    let err = script
        .send("def p():\n  x = [1][5]\nend\n", Some("p"), Duration::ZERO)
        .await;
    // Started, then a runtime exception: either the start or the error is seen first.
    if let Err(e) = err {
        assert!(e.to_string().contains("index"), "{e}");
    }
    let (maj, _, _, _) = script.version().await.expect("version");
    assert_eq!(maj, 5);
    assert!(sim.recent_log().iter().any(|l| l.contains("force_mode")));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_bytes_close_the_connection_and_the_sim_keeps_serving() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let sim = Simulator::start(sim_config()).await.expect("sim");
    let addr = SocketAddr::new(LOCAL, sim.ports().rtde);
    for garbage in [
        &[0u8, 1, b'V'][..],
        &[0, 5, b'Z', 0, 0],
        &[0, 4, b'V', 2],
        &[0xff, 0xff, b'O', 1, 2],
    ] {
        let mut s = tokio::net::TcpStream::connect(addr).await.expect("connect");
        s.write_all(garbage).await.expect("write");
        let _ = s.shutdown().await;
        let mut buf = Vec::new();
        let r = tokio::time::timeout(Duration::from_secs(3), s.read_to_end(&mut buf)).await;
        assert!(r.is_ok(), "sim closed the connection for {garbage:?}");
    }
    // Client side: a server that answers garbage gives a clear error, not a hang.
    let fake = tokio::net::TcpListener::bind((LOCAL, 0))
        .await
        .expect("bind");
    let fake_addr = fake.local_addr().expect("addr");
    tokio::spawn(async move {
        if let Ok((mut s, _)) = fake.accept().await {
            let _ = s.write_all(&[0, 2, b'V', 0, 0, 0]).await;
            tokio::time::sleep(Duration::from_secs(5)).await;
        }
    });
    let cfg = RtdeConfig {
        addr: fake_addr,
        frequency: None,
        outputs: vec!["timestamp".into()],
        inputs: vec![],
        timeout: Duration::from_secs(2),
        max_backoff: Duration::from_millis(100),
    };
    let err = tokio::time::timeout(Duration::from_secs(5), RtdeClient::connect(cfg))
        .await
        .expect("no hang")
        .expect_err("malformed");
    assert!(matches!(err, UrError::Malformed { .. }), "{err}");
    // And the simulator still serves a well-behaved client.
    let mut d = DashboardClient::connect(
        SocketAddr::new(LOCAL, sim.ports().dashboard),
        Duration::from_secs(2),
    )
    .await
    .expect("dash");
    assert_eq!(
        d.request("robotmode").await.expect("reply"),
        "Robotmode: RUNNING"
    );
    assert_eq!(
        d.request("bogus").await.expect("reply"),
        "could not understand: 'bogus'"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dashboard_state_machine() {
    let mut c = sim_config();
    c.start_running = false;
    let sim = Simulator::start(c).await.expect("sim");
    let mut d = DashboardClient::connect(
        SocketAddr::new(LOCAL, sim.ports().dashboard),
        Duration::from_secs(2),
    )
    .await
    .expect("dash");
    assert_eq!(d.robot_mode().await.expect("m"), RobotMode::PowerOff);
    assert!(d.play().await.is_err(), "nothing loaded");
    // As a real controller: through POWER_ON to IDLE, then RUNNING once the brakes are off.
    d.power_on().await.expect("on");
    assert_eq!(d.robot_mode().await.expect("m"), RobotMode::PowerOn);
    let started = std::time::Instant::now();
    while d.robot_mode().await.expect("m") != RobotMode::Idle {
        assert!(started.elapsed() < Duration::from_secs(5), "never IDLE");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    d.brake_release().await.expect("release");
    assert_eq!(d.robot_mode().await.expect("m"), RobotMode::Idle);
    while d.robot_mode().await.expect("m") != RobotMode::Running {
        assert!(started.elapsed() < Duration::from_secs(10), "never RUNNING");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    d.load("cal.urp").await.expect("load");
    assert_eq!(
        d.request("programState").await.expect("r"),
        "STOPPED cal.urp"
    );
    d.play().await.expect("play");
    assert!(d.program_running().await.expect("r"));
    d.pause().await.expect("pause");
    assert_eq!(
        d.request("programState").await.expect("r"),
        "PAUSED cal.urp"
    );
    d.stop().await.expect("stop");
    assert!(!d.program_running().await.expect("r"));
    sim.protective_stop();
    assert_eq!(
        d.safety_status().await.expect("s"),
        SafetyMode::ProtectiveStop
    );
    d.unlock_protective_stop().await.expect("unlock");
    assert_eq!(d.safety_status().await.expect("s"), SafetyMode::Normal);
    assert_eq!(d.polyscope_version().await.expect("v")[0], 5);
    d.quit().await.expect("quit");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cb3_refuses_500_hz_and_has_no_remote_mode() {
    let mut c = sim_config();
    c.model = UrModel::Ur5;
    let sim = Simulator::start(c).await.expect("sim");
    let cfg = |hz| RtdeConfig {
        addr: SocketAddr::new(LOCAL, sim.ports().rtde),
        frequency: hz,
        outputs: vec!["timestamp".into(), "actual_q".into()],
        inputs: vec![],
        timeout: Duration::from_secs(2),
        max_backoff: Duration::from_millis(100),
    };
    let err = RtdeClient::connect(cfg(Some(500.0)))
        .await
        .expect_err("500 Hz on CB3");
    assert!(matches!(err, UrError::InvalidArgument(_)), "{err}");
    let client = RtdeClient::connect(cfg(None)).await.expect("125 Hz");
    assert_eq!(client.version()[0], 3);
    // Timestamps are controller time (> 40 s after boot, like URCL expects) and increase.
    let first = client
        .next_sample(std::time::Instant::now(), Duration::from_secs(2))
        .await
        .expect("sample");
    let next = client
        .next_sample(first.received, Duration::from_secs(2))
        .await
        .expect("sample");
    assert!(first.f64("timestamp").expect("ts") > 40.0);
    assert!(next.f64("timestamp") > first.f64("timestamp"));
    let mut d = DashboardClient::connect(
        SocketAddr::new(LOCAL, sim.ports().dashboard),
        Duration::from_secs(2),
    )
    .await
    .expect("dash");
    assert!(d
        .is_in_remote_control()
        .await
        .expect("CB3 is always remote"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn true_kinematics_deviation_shows_in_the_controller_pose() {
    let mut c = sim_config();
    let sizes = JointErrorSizes {
        zero_offset_rad: 2e-3,
        translation_m: 2e-3,
        misalignment_rad: 2e-3,
        housing_translation_m: 0.0,
        housing_rotation_rad: 0.0,
    };
    let arm = PhysicalArm::draw(UrModel::Ur5e.dh(), &sizes, 3);
    c.arm = Some(arm);
    let (sim, robot) = start(c).await;
    let q: [f64; 6] = robot
        .joint_positions()
        .await
        .expect("q")
        .try_into()
        .expect("6");
    let flange = robot.flange_pose().await.expect("flange");
    let nominal = UrModel::Ur5e.dh().forward(&q);
    let truth = arm.flange(&q);
    assert!((sim.dh().forward(&q).translation.vector - truth.translation.vector).norm() < 1e-9);
    assert!((flange.translation.vector - truth.translation.vector).norm() < 1e-9);
    assert!((flange.translation.vector - nominal.translation.vector).norm() > 1e-3);
}

fn dh_max_abs_diff(a: &DhParams, b: &DhParams) -> f64 {
    let flat = |d: &DhParams| -> Vec<f64> {
        d.a.iter()
            .chain(&d.d)
            .chain(&d.alpha)
            .chain(&d.theta)
            .copied()
            .collect()
    };
    flat(a)
        .iter()
        .zip(flat(b))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn factory_calibrated_kinematics_come_over_the_primary_interface() {
    let (sim, robot) = start(sim_config().factory_calibrated(7)).await;
    let published = sim.kinematics();
    let got = robot
        .kinematics()
        .await
        .expect("ok")
        .expect("the simulator publishes kinematics");
    assert!(got.calibrated && published.calibrated);
    assert_eq!(got.checksum, published.checksum);
    assert!(dh_max_abs_diff(&got.dh, &published.dh) < 1e-12);
    assert!(dh_max_abs_diff(&got.dh, &sim.dh()) < 1e-12);
    // A real controller's DH: the nearly parallel joints 2–4 put d₂ and d₃ far away.
    assert!(got.dh.d[1].abs() > 1.0, "{:?}", got.dh.d);
    assert!((got.dh.d[1] + got.dh.d[2] + got.dh.d[3] - UrModel::Ur5e.dh().d[3]).abs() < 5e-3);
    // The same seed is the same arm; another seed is another arm.
    let again = SimConfig::new(UrModel::Ur5e, LOCAL).factory_calibrated(7);
    assert_eq!(again.arm, sim_config().factory_calibrated(7).arm);
    assert_ne!(again.arm, sim_config().factory_calibrated(8).arm);
    // The controller reports poses of its calibrated arm, at every joint configuration.
    for delta in [0.0, 0.4] {
        let target = target_from(sim.joint_positions(), delta);
        robot
            .move_joints(&target, limits(2.0, 10))
            .await
            .expect("move");
        let q: [f64; 6] = robot
            .joint_positions()
            .await
            .expect("q")
            .try_into()
            .expect("6");
        let flange = robot.flange_pose().await.expect("flange");
        let truth = got.dh.forward(&q);
        assert!((flange.translation.vector - truth.translation.vector).norm() < 1e-6);
        assert!(flange.rotation.angle_to(&truth.rotation) < 1e-6);
        let nominal = UrModel::Ur5e.dh().forward(&q);
        assert!((flange.translation.vector - nominal.translation.vector).norm() > 1e-5);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nominal_simulator_publishes_nominal_kinematics() {
    let (_sim, robot) = start(sim_config()).await;
    let k = robot.kinematics().await.expect("ok").expect("published");
    assert!(k.calibrated);
    assert!(dh_max_abs_diff(&k.dh, &UrModel::Ur5e.dh()) < 1e-12);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn controller_without_kinematics_info_connects_with_none() {
    // A primary interface that sends the version message and then nothing (an old controller).
    let listener = tokio::net::TcpListener::bind((LOCAL, 0))
        .await
        .expect("bind");
    let primary = listener.local_addr().expect("addr").port();
    let server = tokio::spawn(async move {
        use tokio::io::AsyncWriteExt;
        let mut held = Vec::new();
        while let Ok((mut sock, _)) = listener.accept().await {
            let v = handeye_ur::primary::encode_version(1, 5, 11, 1, 1);
            let _ = sock.write_all(&v).await;
            held.push(sock);
        }
    });
    let sim = Simulator::start(sim_config()).await.expect("sim");
    let mut cfg = UrConfig::new(LOCAL);
    cfg.ports = sim.ports();
    cfg.ports.primary = primary;
    cfg.timeout = Duration::from_millis(500);
    let robot = tokio::time::timeout(Duration::from_secs(10), UrRobot::connect(cfg))
        .await
        .expect("no hang")
        .expect("connects without kinematics");
    assert_eq!(robot.kinematics().await.expect("ok"), None);
    assert!(robot.status().await.is_ok());
    server.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn int_registers_round_trip() {
    let (sim, robot) = start(sim_config().with_fieldbus_lower_range()).await;
    robot.write_int_register(24, -42).await.expect("write");
    assert_eq!(sim.input_int_register(24), -42);
    assert_eq!(robot.read_int_register(24).await.expect("read"), -42);
    robot.write_int_register(31, i32::MAX).await.expect("write");
    assert_eq!(robot.read_int_register(31).await.expect("read"), i32::MAX);
    robot.write_int_register(31, i32::MIN).await.expect("write");
    assert_eq!(sim.input_int_register(31), i32::MIN);
    sim.set_output_int_register(26, 17);
    tokio::time::sleep(Duration::from_millis(50)).await;
    assert_eq!(robot.read_output_int_register(26).await.expect("read"), 17);
    // Int and double registers of the same index are separate.
    robot.write_double_register(24, 0.5).await.expect("write");
    assert_eq!(robot.read_int_register(24).await.expect("read"), -42);
    assert!(matches!(
        robot.write_int_register(3, 1).await,
        Err(HalError::InvalidArgument(_))
    ));
    assert!(matches!(
        robot.read_int_register(32).await,
        Err(HalError::InvalidArgument(_))
    ));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn register_ranges_too_wide_for_one_recipe_are_refused_before_connecting() {
    let sim = Simulator::start(sim_config()).await.expect("sim");
    let mut cfg = UrConfig::new(LOCAL);
    cfg.ports = sim.ports();
    cfg.int_registers = 24..=47;
    let err = UrRobot::connect(cfg).await.expect_err("too many names");
    assert!(
        matches!(err, UrError::InvalidArgument(ref m) if m.contains("2048")),
        "{err}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn int_register_held_by_fieldbus_is_register_in_use() {
    let sim = Simulator::start(sim_config().with_fieldbus_lower_range())
        .await
        .expect("sim");
    let mut cfg = UrConfig::new(LOCAL);
    cfg.ports = sim.ports();
    // Doubles in the free upper range, ints in the range the fieldbus holds.
    cfg.int_registers = 22..=25;
    let err = UrRobot::connect(cfg).await.expect_err("IN_USE");
    assert!(
        matches!(err, UrError::FieldInUse { ref name, .. } if name == "input_int_register_22"),
        "{err}"
    );
    assert!(matches!(
        HalError::from(err),
        HalError::RegisterInUse { .. }
    ));
    // Only an int register held: that one is named.
    let mut c = sim_config();
    c.fieldbus_held.push("input_int_register_30".into());
    let sim = Simulator::start(c).await.expect("sim");
    let mut cfg = UrConfig::new(LOCAL);
    cfg.ports = sim.ports();
    let err = UrRobot::connect(cfg).await.expect_err("IN_USE");
    assert!(
        matches!(err, UrError::FieldInUse { ref name, .. } if name == "input_int_register_30"),
        "{err}"
    );
    assert!(matches!(
        HalError::from(err),
        HalError::RegisterInUse { ref name } if name == "input_int_register_30"
    ));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn speed_fraction_follows_the_speed_slider() {
    let (sim, robot) = start(sim_config()).await;
    assert_eq!(robot.status().await.expect("status").speed_fraction, 1.0);
    sim.set_speed_slider(0.25);
    assert_eq!(sim.speed_slider(), 0.25);
    wait_for_speed(&robot, 0.25).await;
    // Another RTDE client moves the slider over the real protocol (speed_slider_mask = 1).
    let other = RtdeClient::connect(RtdeConfig {
        addr: SocketAddr::new(LOCAL, sim.ports().rtde),
        frequency: Some(125.0),
        outputs: vec!["timestamp".into()],
        inputs: vec![vec![
            "speed_slider_mask".into(),
            "speed_slider_fraction".into(),
        ]],
        timeout: Duration::from_secs(2),
        max_backoff: Duration::from_millis(200),
    })
    .await
    .expect("second RTDE client");
    use handeye_ur::rtde::Value;
    other
        .write(0, vec![Value::Uint32(1), Value::Double(0.6)])
        .await
        .expect("write slider");
    wait_for_speed(&robot, 0.6).await;
    assert_eq!(sim.speed_slider(), 0.6);
    drop(other);
}

async fn wait_for_speed(robot: &UrRobot, want: f64) {
    for _ in 0..200 {
        if robot.status().await.expect("status").speed_fraction == want {
            return;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("speed_fraction never became {want}");
}

/// Issue 24: a client that claims no register (`handeye robot status`, `robot move`) connects and
/// reads beside one that holds them (a running daemon); a second claimer is refused by name.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_claiming_no_register_works_beside_one_that_holds_them() {
    let (sim, holder) = start(sim_config()).await;
    let mut cfg = UrConfig::new(LOCAL).without_registers();
    cfg.ports = sim.ports();
    let reader = UrRobot::connect(cfg)
        .await
        .expect("claims nothing, connects");
    let status = reader.status().await.expect("status");
    assert_eq!(status, holder.status().await.expect("status"));
    let mut cfg = UrConfig::new(LOCAL);
    cfg.ports = sim.ports();
    let err = UrRobot::connect(cfg)
        .await
        .expect_err("the registers are held");
    assert!(err.to_string().contains("handeye daemon"), "{err}");
}

/// The simulator with the fault proxy at `proxy_ip` in front of it (the simulator's ports),
/// `before_connect` applied to the proxy, and our driver connected through the proxy.
async fn start_proxied(
    proxy_ip: Ipv4Addr,
    before_connect: impl FnOnce(&handeye_ur::sim::fault_proxy::FaultProxy),
) -> (SimHandle, handeye_ur::sim::fault_proxy::FaultProxy, UrRobot) {
    let proxy_ip = IpAddr::V4(proxy_ip);
    let sim = Simulator::start(sim_config()).await.expect("sim starts");
    let proxy = handeye_ur::sim::fault_proxy::FaultProxy::start(proxy_ip, LOCAL, sim.ports())
        .await
        .expect("proxy starts");
    before_connect(&proxy);
    let mut cfg = UrConfig::new(proxy_ip);
    cfg.ports = sim.ports();
    cfg.max_joint_speed_rad_s = 2.0;
    cfg.max_joint_accel_rad_s2 = 8.0;
    let robot = tokio::time::timeout(Duration::from_secs(10), UrRobot::connect(cfg))
        .await
        .expect("no hang")
        .expect("connects");
    (sim, proxy, robot)
}

/// Issue 36: kinematics info no arm has (NaN DH, a calibration status no controller has),
/// corrupted on the primary interface by the fault proxy at 127.0.0.234, is a protocol error
/// naming the value (the driver connects; a run refuses it), read again at the next ask: once
/// the controller's own arrive, they are taken.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kinematics_info_no_arm_has_is_an_error_until_sound_ones_arrive() {
    use handeye_ur::sim::fault_proxy::KinematicsCorruption;
    let (sim, proxy, robot) = start_proxied(Ipv4Addr::new(127, 0, 0, 234), |p| {
        p.corrupt_kinematics(Some(KinematicsCorruption::Nan))
    })
    .await;
    let err = robot.kinematics().await.expect_err("NaN DH");
    assert!(
        matches!(err, HalError::Protocol { .. })
            && err.to_string().contains("published DH theta = [NaN"),
        "{err}"
    );
    assert_eq!(
        robot
            .identity()
            .await
            .expect("identity")
            .kinematics_checksum,
        None
    );
    proxy.corrupt_kinematics(Some(KinematicsCorruption::CalibrationStatus(7)));
    let err = robot.kinematics().await.expect_err("status 7");
    assert!(err.to_string().contains("calibration_status = 7"), "{err}");
    proxy.corrupt_kinematics(None);
    let k = robot
        .kinematics()
        .await
        .expect("healed")
        .expect("published");
    assert_eq!(k, sim.kinematics());
    assert_eq!(
        robot
            .identity()
            .await
            .expect("identity")
            .kinematics_checksum,
        Some(k.checksum)
    );
}

/// Issue 36: an RTDE stream that freezes (the same package again and again) or reorders
/// (packages swapped in pairs) while the arm moves fails the move within the frozen bound,
/// naming what was wrong, and the arm is stopped short of its target (`stopj` goes out on the
/// primary interface, which still works). Once healed, the stream is trusted again. Through
/// the fault proxy at 127.0.0.233 in front of the simulator.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stream_that_freezes_or_reorders_during_a_move_fails_it_and_stops_the_arm() {
    use handeye_ur::client::{MAX_FROZEN_TIMESTAMP, REORDERED_HOLD};
    use handeye_ur::sim::fault_proxy::StreamMode;
    let (sim, proxy, robot) = start_proxied(Ipv4Addr::new(127, 0, 0, 233), |_| {}).await;
    for (mode, says) in [
        (
            StreamMode::Frozen,
            "the controller's RTDE data stopped advancing",
        ),
        (
            StreamMode::Reordered,
            "the controller's RTDE data arrived out of order",
        ),
    ] {
        // 1 rad at 0.5 rad/s: two seconds; the fault comes after half a second.
        let target = target_from(sim.joint_positions(), 1.0);
        let moving = robot.move_joints(&target, limits(0.5, 20));
        let fault = async {
            tokio::time::sleep(Duration::from_millis(500)).await;
            proxy.stream(mode);
            std::time::Instant::now()
        };
        let started = std::time::Instant::now();
        let (moved, faulted_at) = tokio::join!(moving, fault);
        let err = moved.expect_err("the move fails");
        let failed_after = faulted_at.elapsed();
        assert!(err.to_string().contains(says), "{mode:?}: {err}");
        assert!(
            failed_after < MAX_FROZEN_TIMESTAMP + Duration::from_millis(800),
            "{mode:?}: failed {failed_after:?} after the fault ({:?} after the start)",
            started.elapsed()
        );
        wait_until(|| !sim.program_running()).await;
        let q = sim.joint_positions();
        assert!(
            (target[0] - q[0]).abs() > 0.2,
            "{mode:?}: the arm was not stopped short of the target: {q:?} vs {target:?}"
        );
        proxy.stream(StreamMode::Live);
        // Trusted again once it advances (frozen) or after the hold (reordered).
        tokio::time::sleep(REORDERED_HOLD + Duration::from_millis(300)).await;
        let now = robot.joint_positions().await.expect("healed");
        assert!(
            now.iter().zip(&q).all(|(a, b)| (a - b).abs() < 1e-3),
            "{now:?} vs {q:?}"
        );
    }
}

/// Issue 46: the controller's state watched on every RTDE sample of a move. Through the fault
/// proxy at 127.0.0.146, while the move program plays: a safety mode no controller has (99),
/// a safety mode other than the one the move started in (a safeguard stop, 5), a runtime
/// state no controller has, the speed slider at 3.0. Each fails the move naming what changed,
/// and the arm is stopped short of its target; healed, the same move arrives.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_46_a_controller_state_change_during_a_move_fails_it_and_stops_the_arm() {
    use handeye_ur::sim::fault_proxy::Corruption;
    let (sim, proxy, robot) = start_proxied(Ipv4Addr::new(127, 0, 0, 146), |_| {}).await;
    let cases = [
        ("safety_mode", 99.0, "safety_mode = [99.0]"),
        (
            "safety_mode",
            5.0,
            "safety mode changed from Normal to SafeguardStop",
        ),
        ("runtime_state", 99.0, "runtime_state = [99.0]"),
        (
            "target_speed_fraction",
            3.0,
            "target_speed_fraction = [3.0]",
        ),
    ];
    for (field, value, says) in cases {
        // 1 rad at 0.5 rad/s: two seconds.
        let start = sim.joint_positions();
        let target = target_from(start, 1.0);
        proxy.corrupt_while_playing(field, Corruption::Set(vec![value]));
        let err = robot
            .move_joints(&target, limits(0.5, 20))
            .await
            .err()
            .unwrap_or_else(|| panic!("{field} {value}: the move arrived"));
        assert!(err.to_string().contains(says), "{field} {value}: {err}");
        wait_until(|| !sim.program_running()).await;
        proxy.heal(field);
        let q = sim.joint_positions();
        assert!(
            (target[0] - q[0]).abs() > 0.5,
            "{field} {value}: the arm was not stopped short of the target: {q:?} vs {target:?}"
        );
    }
    let target = target_from(sim.joint_positions(), 0.2);
    robot
        .move_joints(&target, limits(0.5, 20))
        .await
        .expect("healed, the move arrives");
}
