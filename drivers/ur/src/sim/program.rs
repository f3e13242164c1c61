//! What a running program sees: the controller as a URScript [`Host`] ([`SimHost`]: moves,
//! waits, registers, the stop request, the step budget) and the start of a move as the
//! controller checks it ([`begin_move`]). URScript programs and ur_rtde's control script both
//! run on it.

use std::time::{Duration, Instant};

use nalgebra::Isometry3;

use super::motion::{self, Motion};
use super::state::{State, JOINT_LIMIT};
use super::urscript::{num, Host, Val};
use super::Shared;
use crate::primary;
use crate::UrPose;

/// The message of a program ended by a stop request (not reported as a runtime exception).
pub(crate) const STOPPED: &str = "program stopped";
/// Statements a program may run without letting time pass.
const STEP_BUDGET: u32 = 100_000;

/// The controller as a running program sees it.
pub(crate) struct SimHost<'a> {
    pub(crate) shared: &'a Shared,
    gen: u64,
    secondary: bool,
    steps: u32,
}

impl<'a> SimHost<'a> {
    /// The host of a program started as generation `gen` of the controller's programs (a
    /// secondary program runs beside them and is never stopped by a new one).
    pub(crate) fn new(shared: &'a Shared, gen: u64, secondary: bool) -> Self {
        Self {
            shared,
            gen,
            secondary,
            steps: 0,
        }
    }

    /// `Err(STOPPED)` once the program has been asked to stop.
    pub(crate) fn alive(&self) -> Result<(), String> {
        if !self.secondary && self.shared.lock().program_gen != self.gen {
            return Err(STOPPED.into());
        }
        Ok(())
    }

    /// Let `d` pass (physical time), `Err` if the program is stopped meanwhile.
    pub(crate) fn wait(&mut self, d: Duration) -> Result<(), String> {
        let end = Instant::now() + d;
        self.steps = 0;
        loop {
            self.alive()?;
            let now = Instant::now();
            if now >= end {
                return Ok(());
            }
            std::thread::sleep((end - now).min(Duration::from_millis(2)));
        }
    }

    /// Wait until the arm has finished its motion, `Err` if the program is stopped meanwhile.
    pub(crate) fn wait_motion(&mut self) -> Result<(), String> {
        self.steps = 0;
        loop {
            self.alive()?;
            if self.shared.lock().motion.is_none() {
                return Ok(());
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// Where a move goes: joint angles (rad) or a TCP pose (`base_from_tcp`, UR pose).
#[derive(Debug, Clone, Copy)]
pub(crate) enum Target {
    Joints([f64; 6]),
    Pose([f64; 6]),
}

/// Start a `movej` (`linear` false) or `movel` on the simulated arm without waiting: checks
/// the arm can move, the speeds, the inverse kinematics and the joint limits, as the
/// controller does before a move starts.
pub(crate) fn begin_move(
    s: &mut State,
    linear: bool,
    target: Target,
    a: f64,
    v: f64,
) -> Result<(), String> {
    let name = if linear { "movel" } else { "movej" };
    if !(a > 0.0 && v > 0.0 && a.is_finite() && v.is_finite()) {
        return Err(format!("{name}: speed and acceleration must be positive"));
    }
    let (Target::Joints(q) | Target::Pose(q)) = target;
    if q.iter().any(|x| !x.is_finite()) {
        return Err(format!("{name}: the target is not finite"));
    }
    s.can_move()?;
    let m = if linear {
        let goal = match target {
            Target::Pose(p) => motion::flange_target(&UrPose(p), &s.tcp),
            Target::Joints(q) => s.dh.forward(&q),
        };
        Motion::linear(s.flange_pose(), goal, v.min(3.0), a)
    } else {
        let goal = match target {
            Target::Pose(p) => {
                let f = motion::flange_target(&UrPose(p), &s.tcp);
                motion::inverse(&s.dh, &f, &s.q, 300)
                    .ok_or("movej: no inverse kinematics solution for the pose")?
            }
            Target::Joints(q) => q,
        };
        if goal.iter().any(|g| g.abs() > JOINT_LIMIT + 1e-9) {
            return Err("movej: joint target outside ±2π".into());
        }
        Motion::joint(s.q, goal, v.min(s.limits.move_speed_rad_s()), a)
    };
    s.motion = Some(m);
    Ok(())
}

fn joints(v: &Val) -> Result<[f64; 6], String> {
    match v {
        Val::List(l) if l.len() == 6 => {
            let mut q = [0.0; 6];
            for (o, x) in q.iter_mut().zip(l) {
                *o = num(x)?;
            }
            Ok(q)
        }
        other => Err(format!("expected a list of 6 joint angles, got `{other}`")),
    }
}

fn pose(v: &Val) -> Result<[f64; 6], String> {
    match v {
        Val::Pose(p) => Ok(*p),
        other => Err(format!("expected a pose p[...], got `{other}`")),
    }
}

fn reg_index(v: Option<&Val>, max: usize) -> Result<usize, String> {
    let i = num(v.ok_or("missing register index")?)?;
    if i < 0.0 || i.fract() != 0.0 || i as usize >= max {
        return Err(format!("register index {i} out of range 0..{}", max - 1));
    }
    Ok(i as usize)
}

impl Host for SimHost<'_> {
    fn tick(&mut self) -> Result<(), String> {
        self.alive()?;
        self.steps += 1;
        if self.steps > STEP_BUDGET {
            return Err("Runtime is too much behind: a loop runs without sync() or sleep()".into());
        }
        Ok(())
    }

    fn call(
        &mut self,
        name: &str,
        args: Vec<Val>,
        named: Vec<(String, Val)>,
    ) -> Result<Val, String> {
        let arg = |i: usize, key: &str| {
            args.get(i)
                .or_else(|| named.iter().find(|(n, _)| n == key).map(|(_, v)| v))
        };
        let num_or =
            |i: usize, key: &str, d: f64| arg(i, key).map(num).transpose().map(|v| v.unwrap_or(d));
        let sh = self.shared;
        match name {
            "movej" | "movel" => {
                let target = match arg(0, "q").ok_or(format!("{name} needs a target"))? {
                    Val::Pose(p) => Target::Pose(*p),
                    other => Target::Joints(joints(other)?),
                };
                let (a, v) = if name == "movej" {
                    (num_or(1, "a", 1.4)?, num_or(2, "v", 1.05)?)
                } else {
                    (num_or(1, "a", 1.2)?, num_or(2, "v", 0.25)?)
                };
                begin_move(&mut sh.lock(), name == "movel", target, a, v)?;
                self.wait_motion()?;
                let s = sh.lock();
                s.can_move()?;
                Ok(Val::None)
            }
            "stopj" | "stopl" => {
                let a = num_or(0, "a", 2.0)?.max(0.01);
                sh.lock()
                    .stop_motion(if name == "stopl" { a * 4.0 } else { a });
                self.wait_motion()?;
                Ok(Val::None)
            }
            "sleep" => {
                let t = num(arg(0, "t").ok_or("sleep needs a time")?)?;
                if !(0.0..=86_400.0).contains(&t) {
                    return Err(format!("sleep: invalid time {t}"));
                }
                self.wait(Duration::from_secs_f64(t))?;
                Ok(Val::None)
            }
            "sync" => {
                self.wait(if sh.config.model.is_cb3() {
                    Duration::from_millis(8)
                } else {
                    Duration::from_millis(2)
                })?;
                Ok(Val::None)
            }
            "set_tcp" => {
                let p = pose(arg(0, "pose").ok_or("set_tcp needs a pose")?)?;
                if p.iter().any(|x| !x.is_finite()) {
                    return Err("set_tcp: pose is not finite".into());
                }
                sh.lock().tcp = UrPose(p);
                Ok(Val::None)
            }
            "textmsg" => {
                let text = format!(
                    "{}{}",
                    arg(0, "s1").map(|v| v.to_string()).unwrap_or_default(),
                    arg(1, "s2").map(|v| v.to_string()).unwrap_or_default()
                );
                sh.lock().push_log(text.clone());
                sh.publish(primary::encode_text(sh.timestamp_us(), &text));
                Ok(Val::None)
            }
            "write_output_integer_register"
            | "write_output_float_register"
            | "write_output_boolean_register" => {
                let max = if name.contains("boolean") { 128 } else { 48 };
                let i = reg_index(args.first(), max)?;
                let v = args.get(1).ok_or("missing value")?;
                let mut s = sh.lock();
                match name {
                    "write_output_integer_register" => {
                        let x = num(v)?;
                        if x.fract() != 0.0 || x < f64::from(i32::MIN) || x > f64::from(i32::MAX) {
                            return Err(format!("{x} is not a 32-bit integer"));
                        }
                        s.out_int[i] = x as i32;
                    }
                    "write_output_float_register" => s.out_double[i] = num(v)?,
                    _ => {
                        if num(v)? != 0.0 {
                            s.out_bits |= 1 << i;
                        } else {
                            s.out_bits &= !(1 << i);
                        }
                    }
                }
                Ok(Val::None)
            }
            "read_input_integer_register" | "read_output_integer_register" => {
                let i = reg_index(args.first(), 48)?;
                let s = sh.lock();
                Ok(Val::Num(f64::from(if name.contains("input") {
                    s.in_int[i]
                } else {
                    s.out_int[i]
                })))
            }
            "read_input_float_register" | "read_output_float_register" => {
                let i = reg_index(args.first(), 48)?;
                let s = sh.lock();
                Ok(Val::Num(if name.contains("input") {
                    s.in_double[i]
                } else {
                    s.out_double[i]
                }))
            }
            "read_input_boolean_register" | "read_output_boolean_register" => {
                let i = reg_index(args.first(), 128)?;
                let s = sh.lock();
                let bits = if name.contains("input") {
                    s.in_bits
                } else {
                    s.out_bits
                };
                Ok(Val::Bool(bits >> i & 1 == 1))
            }
            "get_actual_joint_positions" => Ok(Val::List(
                sh.lock().q.iter().map(|x| Val::Num(*x)).collect(),
            )),
            "get_target_joint_positions" => Ok(Val::List(
                sh.lock().target_q.iter().map(|x| Val::Num(*x)).collect(),
            )),
            "get_actual_tcp_pose" | "get_target_tcp_pose" => Ok(Val::Pose(sh.lock().tcp_pose().0)),
            "get_tcp_offset" => Ok(Val::Pose(sh.lock().tcp.0)),
            "get_forward_kin" => {
                let s = sh.lock();
                let q = match arg(0, "q") {
                    Some(v) => joints(v)?,
                    None => s.q,
                };
                let tcp = match arg(1, "tcp") {
                    Some(v) => UrPose(pose(v)?),
                    None => s.tcp,
                };
                Ok(Val::Pose(
                    UrPose::from(s.dh.forward(&q) * Isometry3::from(tcp)).0,
                ))
            }
            "pose_trans" => {
                let a = pose(args.first().ok_or("missing pose")?)?;
                let b = pose(args.get(1).ok_or("missing pose")?)?;
                Ok(Val::Pose(
                    UrPose::from(Isometry3::from(UrPose(a)) * Isometry3::from(UrPose(b))).0,
                ))
            }
            "pose_inv" => {
                let a = pose(args.first().ok_or("missing pose")?)?;
                Ok(Val::Pose(
                    UrPose::from(Isometry3::from(UrPose(a)).inverse()).0,
                ))
            }
            "sin" | "cos" | "sqrt" | "floor" => {
                let x = num(args.first().ok_or("missing argument")?)?;
                Ok(Val::Num(match name {
                    "sin" => x.sin(),
                    "cos" => x.cos(),
                    "floor" => x.floor(),
                    _ if x < 0.0 => return Err("sqrt of a negative number".into()),
                    _ => x.sqrt(),
                }))
            }
            "norm" => match args.first() {
                Some(Val::List(l)) => Ok(Val::Num(
                    l.iter()
                        .map(num)
                        .collect::<Result<Vec<_>, _>>()?
                        .iter()
                        .map(|x| x * x)
                        .sum::<f64>()
                        .sqrt(),
                )),
                Some(Val::Pose(p)) => {
                    Ok(Val::Num(p[..3].iter().map(|x| x * x).sum::<f64>().sqrt()))
                }
                Some(v) => Ok(Val::Num(num(v)?.abs())),
                None => Err("missing argument".into()),
            },
            "to_str" => Ok(Val::Str(
                args.first().map(|v| v.to_string()).unwrap_or_default(),
            )),
            other => Err(format!("name '{other}' is not defined")),
        }
    }
}
