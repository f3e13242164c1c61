//! The control loop (2 ms e-Series, 8 ms CB3): advances the running [`Motion`] in the
//! controller's state at the speed slider's fraction, stops at joint limits, and fires the RTDE
//! watchdog.

use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::Isometry3;

use super::motion::{inverse, ramp, Motion};
use super::state::JOINT_LIMIT;
use super::{Shared, State};

/// Advance the state by `dt` seconds of wall time. Programmed motion runs at the speed
/// slider's fraction (the controller scales trajectory time); stops are not scaled.
pub(crate) fn step(s: &mut State, wall_dt: f64) {
    if let Some((mode, at)) = s.mode_change {
        if std::time::Instant::now() >= at {
            s.mode_change = None;
            s.robot_mode = mode;
        }
    }
    let Some(mut m) = s.motion.take() else {
        s.qd = [0.0; 6];
        return;
    };
    let dt = if matches!(m, Motion::Stop { .. }) {
        wall_dt
    } else {
        wall_dt * s.speed_slider
    };
    let done;
    let mut fraction = 0.0;
    match &mut m {
        Motion::Joint {
            start,
            goal,
            profile,
            t,
        } => {
            *t += dt;
            let (d, v) = profile.at(*t);
            fraction = if profile.len > 0.0 {
                d / profile.len
            } else {
                1.0
            };
            for i in 0..6 {
                let delta = goal[i] - start[i];
                let k = if profile.len > 0.0 {
                    delta / profile.len
                } else {
                    0.0
                };
                s.q[i] = start[i] + k * d;
                s.qd[i] = k * v * s.speed_slider;
            }
            s.target_q = *goal;
            done = *t >= profile.total;
        }
        Motion::Linear {
            start,
            goal,
            profile,
            t,
        } => {
            *t += dt;
            let (d, _) = profile.at(*t);
            fraction = if profile.len > 0.0 {
                d / profile.len
            } else {
                1.0
            };
            let pose = start.lerp_slerp(goal, fraction);
            match inverse(&s.dh, &pose, &s.q, 50) {
                Some(q) => {
                    for ((qd, new), old) in s.qd.iter_mut().zip(q).zip(s.q) {
                        *qd = (new - old) / wall_dt.max(1e-6);
                    }
                    s.q = q;
                    s.target_q = q;
                }
                None => {
                    s.push_log("movel: target pose is not reachable along a straight line".into());
                    s.stop_program(Some("movel: no inverse kinematics solution"));
                    return;
                }
            }
            done = *t >= profile.total;
        }
        Motion::Speed {
            joint,
            target,
            accel,
            current,
        } => {
            ramp(current, target, *accel, dt);
            let next = if *joint {
                let mut q = s.q;
                for (qi, v) in q.iter_mut().zip(current.iter()) {
                    *qi += v * dt;
                }
                q
            } else {
                let tcp = Isometry3::from(s.tcp);
                let now = s.flange_pose() * tcp;
                let v = nalgebra::Vector3::new(current[0], current[1], current[2]);
                let w = nalgebra::Vector3::new(current[3], current[4], current[5]);
                let next_tcp = Isometry3::from_parts(
                    (now.translation.vector + v * dt).into(),
                    nalgebra::UnitQuaternion::from_scaled_axis(w * dt) * now.rotation,
                );
                match inverse(&s.dh, &(next_tcp * tcp.inverse()), &s.q, 50) {
                    Some(q) => q,
                    None => {
                        s.stop_program(Some("speedl: the tool cannot move on along this twist (no inverse kinematics solution)"));
                        return;
                    }
                }
            };
            for ((qd, new), old) in s.qd.iter_mut().zip(next).zip(s.q) {
                *qd = (new - old) / wall_dt.max(1e-6);
            }
            s.q = next;
            s.target_q = next;
            done = false;
        }
        Motion::Servo { target, left, .. } => {
            let max_step = std::f64::consts::PI * dt;
            let k = (dt / left.max(dt)).min(1.0);
            *left = (*left - dt).max(0.0);
            let mut next = s.q;
            for ((n, t), q) in next.iter_mut().zip(target.iter()).zip(s.q) {
                *n = q + (k * (t - q)).clamp(-max_step, max_step);
            }
            for ((qd, new), old) in s.qd.iter_mut().zip(next).zip(s.q) {
                *qd = (new - old) / wall_dt.max(1e-6);
            }
            s.q = next;
            s.target_q = *target;
            done = false;
        }
        Motion::Stop { decel } => {
            let mut moving = false;
            for i in 0..6 {
                let v = s.qd[i];
                let nv = if v > 0.0 {
                    (v - *decel * dt).max(0.0)
                } else {
                    (v + *decel * dt).min(0.0)
                };
                s.q[i] += 0.5 * (v + nv) * dt;
                s.qd[i] = nv;
                moving |= nv != 0.0;
            }
            s.target_q = s.q;
            done = !moving;
        }
    }
    if !matches!(m, Motion::Stop { .. }) && s.q.iter().any(|q| q.abs() > JOINT_LIMIT + 1e-9) {
        s.push_log("C153: joint position limit violated".into());
        s.protective_stop();
        return;
    }
    if let (Some(f), Motion::Joint { .. } | Motion::Linear { .. }) = (s.pstop_at_fraction, &m) {
        if fraction >= f && fraction > 0.0 {
            s.pstop_at_fraction = None;
            s.motion = Some(m);
            s.protective_stop();
            return;
        }
    }
    if done {
        if !matches!(m, Motion::Stop { .. }) {
            s.qd = [0.0; 6];
        }
    } else {
        s.motion = Some(m);
    }
}

/// The control loop (2 ms e-Series, 8 ms CB3).
pub(crate) async fn run(shared: Arc<Shared>) {
    let period = if shared.config.model.is_cb3() {
        Duration::from_millis(8)
    } else {
        Duration::from_millis(2)
    };
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut last = Instant::now();
    loop {
        tick.tick().await;
        let now = Instant::now();
        let dt = (now - last).as_secs_f64().min(0.05);
        last = now;
        let fired = {
            let mut s = shared.lock();
            step(&mut s, dt);
            s.check_rtde_watchdog()
        };
        if let Some(msg) = fired {
            tracing::warn!("{msg}");
            shared.publish(crate::primary::encode_runtime_exception(
                shared.timestamp_us(),
                0,
                0,
                &msg,
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use handeye_hal::ur_dh::UrModel;

    fn state() -> State {
        let c = crate::sim::SimConfig::new(UrModel::Ur5e, [127, 0, 0, 1].into());
        let mut s = State::new(&c);
        s.robot_mode = crate::sim::RobotModeCode::Running;
        s
    }

    fn run_until_done(s: &mut State, limit_s: f64) -> f64 {
        let mut t = 0.0;
        while s.motion.is_some() && t < limit_s {
            step(s, 0.002);
            t += 0.002;
        }
        t
    }

    #[test]
    fn the_speed_slider_scales_trajectory_time() {
        let mut times = Vec::new();
        for slider in [1.0, 0.5, 0.25] {
            let mut s = state();
            s.speed_slider = slider;
            let mut goal = s.q;
            goal[0] += 0.5;
            s.motion = Some(Motion::joint(s.q, goal, 1.0, 2.0));
            times.push(run_until_done(&mut s, 20.0));
            assert!(
                (s.q[0] - goal[0]).abs() < 1e-12,
                "reaches the goal at {slider}"
            );
        }
        // 0.5 rad at 1 rad/s, 2 rad/s²: 1.0 s at full speed.
        assert!((times[0] - 1.0).abs() < 0.01, "{times:?}");
        assert!((times[1] / times[0] - 2.0).abs() < 0.02, "{times:?}");
        assert!((times[2] / times[0] - 4.0).abs() < 0.04, "{times:?}");
    }

    #[test]
    fn a_speed_command_running_into_a_joint_limit_protective_stops() {
        let mut s = state();
        s.q[5] = JOINT_LIMIT - 0.05;
        s.motion = Some(Motion::speed(
            None,
            true,
            [0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            5.0,
        ));
        let mut t = 0.0;
        while s.safety_mode == crate::sim::SafetyModeCode::Normal && t < 2.0 {
            step(&mut s, 0.002);
            t += 0.002;
        }
        assert_eq!(s.safety_mode, crate::sim::SafetyModeCode::ProtectiveStop);
        assert!(s.log.iter().any(|l| l.contains("joint position limit")));
        run_until_done(&mut s, 2.0);
        assert!(s.qd.iter().all(|v| *v == 0.0));
        assert!(s.q[5] - JOINT_LIMIT < 0.05, "{}", s.q[5]);
    }

    #[test]
    fn speedj_ramps_to_the_commanded_speed_and_servoj_follows_its_target() {
        let mut s = state();
        s.motion = Some(Motion::speed(
            None,
            true,
            [0.4, 0.0, 0.0, 0.0, 0.0, -0.2],
            1.0,
        ));
        for _ in 0..100 {
            step(&mut s, 0.002);
        }
        // After 0.2 s at 1 rad/s² the speed vector is 0.2 long, in the commanded direction.
        let expect = 0.2 * 0.4 / 0.4f64.hypot(0.2);
        assert!((s.qd[0] - expect).abs() < 1e-6, "on the ramp: {:?}", s.qd);
        for _ in 0..500 {
            step(&mut s, 0.002);
        }
        assert!((s.qd[0] - 0.4).abs() < 1e-9 && (s.qd[5] + 0.2).abs() < 1e-9);
        let mut target = s.q;
        target[2] += 0.01;
        s.motion = Some(Motion::Servo {
            target,
            time: 0.008,
            left: 0.008,
        });
        for _ in 0..20 {
            step(&mut s, 0.002);
        }
        assert!(
            (s.q[2] - target[2]).abs() < 1e-9,
            "{} vs {}",
            s.q[2],
            target[2]
        );
    }
}
