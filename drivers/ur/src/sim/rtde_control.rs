//! ur_rtde's control program (`def rtde_control():`, uploaded by `RTDEControlInterface` to port
//! 30003), recognised and executed natively.
//!
//! The program is a 42 kB URScript server: a loop that reads a command word from
//! `input_int_register_{0+o}`, its arguments from `input_int_register_{1..7+o}` and
//! `input_double_register_{0..17+o}`, answers in `output_*_register_*` and handshakes through
//! `output_int_register_{0+o}` (1 ready for a command, 2 done with it; the client clears the
//! command word with 0 after "done"). Asynchronous moves and stops report in
//! `output_int_register_{2+o}` (bit 15 running, bits 16–22 a write counter, 24–30 the
//! operation id). Real-time commands (speed, servo, …) are processed on every control cycle and
//! answered "ready" at once. `o` (0 or 24) is injected by the client after a comment on the line
//! `global reg_offset_int = # int register offset`.
//!
//! We execute that protocol here command by command, as the program's `process_cmd` does,
//! through the same simulated arm as every other program ([`begin_move`], the motion loop):
//! protective stops, the speed slider, joint limits and the runtime state apply. Commands the
//! program implements with features the simulator does not model (force mode, freedrive,
//! contact detection, dynamics, …) stop the program with a runtime exception naming the
//! command, so the client's call returns `false` instead of waiting.

use std::collections::HashMap;
use std::time::Duration;

use nalgebra::Isometry3;

use super::motion::{self, Motion};
use super::program::{begin_move, SimHost, Target};
use super::state::{max_payload, State, JOINT_LIMIT};
use super::urscript::{CompileError, RuntimeError};
use crate::primary;
use crate::UrPose;

/// Register offsets of a recognised control program.
#[derive(Debug, Clone)]
pub(crate) struct ControlProgram {
    /// Added to every int register index (0 or 24).
    int_offset: usize,
    /// Added to every double register index (0 or 24).
    float_offset: usize,
    /// Line of `cmd == N` in the received text, for runtime exceptions.
    lines: HashMap<i32, usize>,
}

/// Commands the program answers "ready" for on every cycle without a handshake (its main
/// loop's list).
const REAL_TIME: &[i32] = &[24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71];

/// Commands the program implements with controller features the simulator does not model.
const UNSUPPORTED: &[(i32, &str)] = &[
    (6, "forceMode"),
    (7, "forceModeStop"),
    (8, "zeroFtSensor"),
    (12, "servoC"),
    (18, "teachMode"),
    (19, "endTeachMode"),
    (20, "forceModeSetDamping"),
    (21, "forceModeSetGainScaling"),
    (24, "servoL"),
    (25, "toolContact"),
    (27, "getActualJointPositionsHistory"),
    (38, "getJointTorques"),
    (41, "jogStart"),
    (42, "jogStop"),
    (45, "movePath"),
    (51, "moveUntilContact"),
    (52, "freedriveMode"),
    (53, "endFreedriveMode"),
    (54, "getFreedriveStatus"),
    (55, "setExternalForceTorque"),
    (56, "ftRtdeInputEnable"),
    (57, "enableExternalFtSensor"),
    (59, "setGravity"),
    (62, "startContactDetection"),
    (63, "stopContactDetection"),
    (64, "readContactDetection"),
    (66, "directTorque"),
    (67, "getMassMatrix"),
    (68, "getCoriolisAndCentrifugalTorques"),
    (69, "getTargetJointAccelerations"),
    (70, "getJacobian"),
    (71, "getJacobianTimeDerivative"),
    (254, "contact detection (internal)"),
];

/// `Some` if `text` is ur_rtde's control program (its name, header, command dispatcher and
/// main loop), with the register offsets it carries or a compile error if they are unusable.
pub(crate) fn recognise(text: &str) -> Option<Result<ControlProgram, CompileError>> {
    let first = text.lines().find(|l| !l.trim().is_empty())?.trim();
    let markers = [
        "# HEADER_BEGIN",
        "def rtde_cmd():",
        "def process_cmd(cmd):",
        "def signal_ready():",
        "# NODE_CONTROL_LOOP_BEGINS",
    ];
    if first != "def rtde_control():" || !markers.iter().all(|m| text.contains(m)) {
        return None;
    }
    let offset = |name: &str| -> Result<usize, CompileError> {
        let err = |message: String| CompileError {
            line: line_of(text, name),
            message,
        };
        let decl = format!("global {name} =");
        let at = text
            .find(&decl)
            .ok_or_else(|| err(format!("`{decl}` is missing")))?;
        let mut rest = text[at + decl.len()..].trim_start();
        // The client injects the value on the line after a comment.
        if rest.starts_with('#') {
            rest = rest.split_once('\n').map_or("", |(_, r)| r).trim_start();
        }
        let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
        match digits.parse::<usize>() {
            Ok(o) if o == 0 || o == 24 => Ok(o),
            Ok(o) => Err(err(format!(
                "{name} = {o}: register offsets are 0 (lower range) or 24 (upper range)"
            ))),
            Err(_) => Err(err(format!("{name} has no value"))),
        }
    };
    let int_offset = match offset("reg_offset_int") {
        Ok(o) => o,
        Err(e) => return Some(Err(e)),
    };
    let float_offset = match offset("reg_offset_float") {
        Ok(o) => o,
        Err(e) => return Some(Err(e)),
    };
    let mut lines = HashMap::new();
    for (i, l) in text.lines().enumerate() {
        let l = l.trim();
        if let Some(n) = l
            .strip_prefix("if cmd == ")
            .or_else(|| l.strip_prefix("elif cmd == "))
            .and_then(|r| r.split(':').next())
            .and_then(|n| n.trim().parse::<i32>().ok())
        {
            lines.entry(n).or_insert(i + 1);
        }
    }
    Some(Ok(ControlProgram {
        int_offset,
        float_offset,
        lines,
    }))
}

fn line_of(text: &str, needle: &str) -> usize {
    text.lines()
        .position(|l| l.contains(needle))
        .map_or(1, |i| i + 1)
}

/// Run the program until it is stopped, ends (`stopScript`) or fails.
pub(crate) fn run(p: &ControlProgram, host: &mut SimHost<'_>) -> Result<(), RuntimeError> {
    let period = if host.shared.config.model.is_cb3() {
        Duration::from_millis(8)
    } else {
        Duration::from_millis(2)
    };
    let mut c = Control {
        p,
        period,
        wr_count: 0,
        op_id: 0,
        async_op: None,
    };
    let rt = |line: usize| move |message: String| RuntimeError { line, message };
    host.textmsg("RTDE Control Script Loaded (handeye simulator: native protocol)");
    {
        let mut s = host.shared.lock();
        c.write_async(&mut s, -1);
        c.signal(&mut s, 1);
    }
    let mut executing = false;
    let mut last_cmd = 0;
    loop {
        host.alive().map_err(rt(0))?;
        let cmd = {
            let mut s = host.shared.lock();
            c.poll(&mut s);
            s.in_int[p.int_offset]
        };
        let line = p.lines.get(&cmd).copied().unwrap_or(0);
        if cmd != last_cmd {
            tracing::debug!(cmd, "ur_rtde control program: command word");
            last_cmd = cmd;
        }
        if REAL_TIME.contains(&cmd) {
            c.process(host, cmd).map_err(rt(line))?;
            c.signal(&mut host.shared.lock(), 1);
        } else if cmd == 0 {
            executing = false;
            c.signal(&mut host.shared.lock(), 1);
        } else if !executing {
            executing = true;
            if !c.process(host, cmd).map_err(rt(line))? {
                host.textmsg("RTDE Control Script Terminated");
                return Ok(());
            }
            c.signal(&mut host.shared.lock(), 2);
        }
        host.wait(period).map_err(rt(0))?;
    }
}

/// An asynchronous move or stop in progress.
#[derive(Debug, Clone, Copy, PartialEq)]
enum AsyncOp {
    Move,
    Stop,
}

struct Control<'a> {
    p: &'a ControlProgram,
    period: Duration,
    wr_count: i32,
    op_id: i32,
    async_op: Option<AsyncOp>,
}

impl Control<'_> {
    fn f(&self, s: &State, i: usize) -> f64 {
        s.in_double[self.p.float_offset + i]
    }

    fn i(&self, s: &State, i: usize) -> i32 {
        s.in_int[self.p.int_offset + i]
    }

    fn six(&self, s: &State, i: usize) -> [f64; 6] {
        std::array::from_fn(|k| self.f(s, i + k))
    }

    fn out6(&self, s: &mut State, i: usize, v: [f64; 6]) {
        let o = self.p.float_offset + i;
        s.out_double[o..o + 6].copy_from_slice(&v);
    }

    fn out_int(&self, s: &mut State, i: usize, v: i32) {
        s.out_int[self.p.int_offset + i] = v;
    }

    fn signal(&self, s: &mut State, v: i32) {
        self.out_int(s, 0, v);
    }

    /// The program's `write_async_progress_register`: `value` 0 starts an operation (new id),
    /// a positive value is progress, a negative one finishes it.
    fn write_async(&mut self, s: &mut State, value: i32) {
        self.wr_count = if self.wr_count >= 127 {
            0
        } else {
            self.wr_count + 1
        };
        if value == 0 {
            self.op_id = if self.op_id >= 127 { 0 } else { self.op_id + 1 };
        }
        let mut reg = self.wr_count * 65536 + self.op_id * 16_777_216;
        if value >= 0 {
            reg += value.min(32767) + 32768;
        }
        self.out_int(s, 2, reg);
    }

    /// Finish an asynchronous operation whose motion has ended.
    fn poll(&mut self, s: &mut State) {
        if self.async_op.is_some() && s.motion.is_none() {
            self.async_op = None;
            self.write_async(s, -1);
        }
    }

    /// The program's `stop_async_move`: an asynchronous move in progress is abandoned (the
    /// next motion replaces it) and reported finished.
    fn stop_async_move(&mut self, s: &mut State) {
        if self.async_op == Some(AsyncOp::Move) {
            self.async_op = None;
            self.write_async(s, -1);
        }
    }

    /// `movej`/`movel` to `target`, waiting unless `async_` (then progress is reported).
    fn do_move(
        &mut self,
        host: &mut SimHost<'_>,
        linear: bool,
        target: Target,
        async_: bool,
    ) -> Result<(), String> {
        {
            let mut s = host.shared.lock();
            let (v, a) = (self.f(&s, 6), self.f(&s, 7));
            self.stop_async_move(&mut s);
            begin_move(&mut s, linear, target, a, v)?;
            if async_ {
                self.write_async(&mut s, 0);
                self.async_op = Some(AsyncOp::Move);
                return Ok(());
            }
        }
        host.wait_motion()?;
        host.shared.lock().can_move()
    }

    /// `get_inverse_kin(x, qnear)`: joint angles (rad) putting the TCP at `x`, from `qnear`.
    fn inverse_kin(
        s: &State,
        x: [f64; 6],
        qnear: [f64; 6],
        tolerances: Option<(f64, f64)>,
    ) -> Option<[f64; 6]> {
        let flange = motion::flange_target(&UrPose(x), &s.tcp);
        let q = motion::inverse(&s.dh, &flange, &qnear, 300)?;
        if q.iter().any(|v| v.abs() > JOINT_LIMIT) {
            return None;
        }
        if let Some((pos, ori)) = tolerances {
            let got = s.dh.forward(&q);
            let dp = (got.translation.vector - flange.translation.vector).norm();
            let dr = got.rotation.angle_to(&flange.rotation);
            if dp > pos || dr > ori {
                return None;
            }
        }
        Some(q)
    }

    /// One command of `process_cmd`; `Ok(false)` ends the program (`stopScript`).
    fn process(&mut self, host: &mut SimHost<'_>, cmd: i32) -> Result<bool, String> {
        if let Some((_, name)) = UNSUPPORTED.iter().find(|(n, _)| *n == cmd) {
            return Err(format!(
                "ur_rtde command {cmd} ({name}) is not supported by the handeye simulator"
            ));
        }
        let sh = host.shared;
        let model = sh.config.model;
        match cmd {
            1..=4 => {
                let (target, linear, async_) = {
                    let s = sh.lock();
                    let v = self.six(&s, 0);
                    let async_ = self.i(&s, 1) == 1;
                    match cmd {
                        1 => (Target::Joints(v), false, async_),
                        2 => {
                            let q = Self::inverse_kin(&s, v, s.q, None)
                                .ok_or("get_inverse_kin: no solution for the pose")?;
                            (Target::Joints(q), false, async_)
                        }
                        3 => (Target::Pose(v), true, async_),
                        _ => (Target::Joints(v), true, async_),
                    }
                };
                self.do_move(host, linear, target, async_)?;
            }
            9 | 10 => {
                let mut s = sh.lock();
                s.can_move()?;
                let target = self.six(&s, 0);
                let accel = self.f(&s, 6);
                if target.iter().any(|v| !v.is_finite()) || !(accel.is_finite() && accel > 0.0) {
                    return Err(
                        "speedj/speedl: speeds must be finite, acceleration positive".into(),
                    );
                }
                let previous = s.motion.take();
                s.motion = Some(Motion::speed(previous.as_ref(), cmd == 9, target, accel));
            }
            11 => {
                let mut s = sh.lock();
                s.can_move()?;
                let target = self.six(&s, 0);
                let time = self.f(&s, 8);
                if target
                    .iter()
                    .any(|v| !v.is_finite() || v.abs() > JOINT_LIMIT)
                {
                    return Err("servoj: joint target not finite or outside ±2π".into());
                }
                if !(time.is_finite() && time > 0.0) {
                    return Err(format!("servoj: time {time} must be positive"));
                }
                // The program calls servoj with the latest target on every cycle; a repeated
                // target keeps its arrival time.
                let same = matches!(&s.motion,
                    Some(Motion::Servo { target: t, time: d, .. }) if *t == target && *d == time);
                if !same {
                    s.motion = Some(Motion::Servo {
                        target,
                        time,
                        left: time,
                    });
                }
            }
            15 | 16 => {
                {
                    let mut s = sh.lock();
                    let dec = self.f(&s, 0).max(0.01);
                    let linear =
                        cmd == 16 || matches!(s.motion, Some(Motion::Speed { joint: false, .. }));
                    s.stop_motion(if linear { dec * 4.0 } else { dec });
                }
                host.wait_motion()?;
            }
            17 | 65 => {
                let mut s = sh.lock();
                let mass = self.f(&s, 0);
                let cog = [self.f(&s, 1), self.f(&s, 2), self.f(&s, 3)];
                let max = max_payload(model);
                if !(0.0..=max).contains(&mass) {
                    return Err(format!("set_payload: mass {mass} kg outside 0–{max} kg"));
                }
                if cog.iter().any(|c| !c.is_finite()) {
                    return Err("set_payload: centre of gravity is not finite".into());
                }
                let cog = if cog == [0.0; 3] { s.payload.1 } else { cog };
                let inertia = if cmd == 65 {
                    std::array::from_fn(|k| self.f(&s, 4 + k))
                } else {
                    s.payload.2
                };
                s.payload = (mass, cog, inertia);
            }
            26 => {
                let mut s = sh.lock();
                let o = self.p.float_offset;
                s.out_double[o] = self.period.as_secs_f64();
            }
            28 => {
                // `get_target_waypoint`: where the active move goes (not the pose of this
                // control step); without a move, the target pose.
                let mut s = sh.lock();
                let flange = match &s.motion {
                    Some(Motion::Joint { goal, .. }) => s.dh.forward(goal),
                    Some(Motion::Linear { goal, .. }) => *goal,
                    _ => s.dh.forward(&s.target_q),
                };
                let pose = UrPose::from(flange * Isometry3::from(s.tcp));
                self.out6(&mut s, 0, pose.0);
            }
            29 => {
                let mut s = sh.lock();
                let p = self.six(&s, 0);
                if p.iter().any(|x| !x.is_finite()) {
                    return Err("set_tcp: pose is not finite".into());
                }
                s.tcp = UrPose(p);
            }
            30 | 46 => {
                let mut s = sh.lock();
                let x = self.six(&s, 0);
                let (qnear, tol) = if cmd == 30 {
                    (self.six(&s, 6), Some((self.f(&s, 12), self.f(&s, 13))))
                } else {
                    (s.q, None)
                };
                let q = Self::inverse_kin(&s, x, qnear, tol)
                    .ok_or("get_inverse_kin: no solution for the pose")?;
                self.out6(&mut s, 0, q);
            }
            31 => sh.lock().protective_stop(),
            33 | 34 => {
                let async_ = {
                    let mut s = sh.lock();
                    let dec = self.f(&s, 0).max(0.01);
                    let async_ = self.i(&s, 1) == 1;
                    if self.async_op == Some(AsyncOp::Stop) {
                        self.async_op = None;
                        self.write_async(&mut s, -1);
                    }
                    self.stop_async_move(&mut s);
                    s.stop_motion(if cmd == 33 { dec * 4.0 } else { dec });
                    if async_ && s.motion.is_some() {
                        self.write_async(&mut s, 0);
                        self.async_op = Some(AsyncOp::Stop);
                    }
                    async_
                };
                if !async_ {
                    host.wait_motion()?;
                }
            }
            35 => {
                let hz = self.f(&sh.lock(), 0);
                if !(hz.is_finite() && hz > 0.0) {
                    return Err(format!(
                        "rtde_set_watchdog: frequency {hz} must be positive"
                    ));
                }
                // `rtde_set_watchdog(…, "stop")`: the controller watches the register from now
                // on, also while this program waits in a move, for as long as it runs.
                let mut s = sh.lock();
                let program_gen = s.program_gen;
                s.rtde_watchdog = Some(super::state::RtdeWatchdog {
                    register: self.p.int_offset,
                    min_hz: hz,
                    program_gen,
                });
            }
            36 | 37 | 47 | 60 | 61 => {
                let mut s = sh.lock();
                let yes = match cmd {
                    36 | 60 => Self::inverse_kin(&s, self.six(&s, 0), s.q, None).is_some(),
                    37 => self
                        .six(&s, 0)
                        .iter()
                        .all(|q| q.is_finite() && q.abs() <= JOINT_LIMIT),
                    61 => Self::inverse_kin(
                        &s,
                        self.six(&s, 0),
                        self.six(&s, 6),
                        Some((self.f(&s, 12), self.f(&s, 13))),
                    )
                    .is_some(),
                    _ => s.motion.is_none() && s.qd.iter().all(|v| v.abs() < 1e-6),
                };
                self.out_int(&mut s, 1, i32::from(yes));
            }
            39 => {
                let mut s = sh.lock();
                let a = Isometry3::from(UrPose(self.six(&s, 0)));
                let b = Isometry3::from(UrPose(self.six(&s, 6)));
                self.out6(&mut s, 0, UrPose::from(a * b).0);
            }
            40 => {
                let mut s = sh.lock();
                let tcp = s.tcp.0;
                self.out6(&mut s, 0, tcp);
            }
            43 | 44 => {
                let mut s = sh.lock();
                let (q, tcp) = if cmd == 44 {
                    (self.six(&s, 0), UrPose(self.six(&s, 6)))
                } else {
                    (s.q, s.tcp)
                };
                let pose = UrPose::from(s.dh.forward(&q) * Isometry3::from(tcp));
                self.out6(&mut s, 0, pose.0);
            }
            58 => {
                let mut s = sh.lock();
                let flange = UrPose::from(s.flange_pose()).0;
                self.out6(&mut s, 0, flange);
            }
            255 => {
                host.textmsg("Received stop script!");
                return Ok(false);
            }
            // Numbers `process_cmd` has no branch for (e.g. 99, the watchdog kick): nothing
            // happens and the command is answered done, as in the program.
            _ => {}
        }
        Ok(true)
    }
}

impl SimHost<'_> {
    /// `textmsg`: a text message on the primary stream and in the log.
    pub(crate) fn textmsg(&self, text: &str) {
        self.shared.lock().push_log(text.to_string());
        self.shared
            .publish(primary::encode_text(self.shared.timestamp_us(), text));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD: &str = "def rtde_control():\n# HEADER_BEGIN\n    global reg_offset_float = # float register offset\n24    global reg_offset_int = # int register offset\n24    global force_mode_type = 2\n    def signal_ready():\n        write_output_integer_reg(0, 1)\n    end\n    def rtde_cmd():\n      return 0\n    end\n    def process_cmd(cmd):\n        if cmd == 1:\n            movej(q)\n        elif cmd == 255:\n            textmsg(\"x\")\n        end\n    end\n# HEADER_END\n# NODE_CONTROL_LOOP_BEGINS\n# NODE_CONTROL_LOOP_ENDS\nend\n";

    #[test]
    fn recognises_the_control_program_and_its_register_offsets() {
        let p = recognise(HEAD).expect("recognised").expect("valid");
        assert_eq!((p.int_offset, p.float_offset), (24, 24));
        assert_eq!(p.lines.get(&1), Some(&13));
        assert_eq!(p.lines.get(&255), Some(&15));
        let lower = HEAD.replace("\n24 ", "\n0 ");
        let p = recognise(&lower).expect("recognised").expect("valid");
        assert_eq!((p.int_offset, p.float_offset), (0, 0));
        let bad = HEAD.replace("\n24 ", "\n7 ");
        let e = recognise(&bad).expect("recognised").expect_err("offset 7");
        assert!(e.message.contains("0 (lower range) or 24"), "{e:?}");
        assert_eq!(e.line, 4);
        // Other programs, and a look-alike without the dispatcher, are ordinary URScript.
        assert!(recognise("def prog():\n  textmsg(\"hi\")\nend\n").is_none());
        assert!(recognise(&HEAD.replace("def process_cmd(cmd):", "def other():")).is_none());
        assert!(recognise(&HEAD.replace("def rtde_control():", "def rtde_contro():")).is_none());
    }

    #[test]
    fn async_progress_register_follows_the_programs_layout() {
        let p = recognise(HEAD).expect("recognised").expect("valid");
        let config =
            super::super::SimConfig::new(handeye_hal::ur_dh::UrModel::Ur5e, [127, 0, 0, 1].into());
        let mut s = State::new(&config);
        let mut c = Control {
            p: &p,
            period: Duration::from_millis(2),
            wr_count: 0,
            op_id: 0,
            async_op: None,
        };
        c.write_async(&mut s, -1);
        assert_eq!(s.out_int[26], 65536, "finished, write 1, operation 0");
        c.write_async(&mut s, 0);
        let started = s.out_int[26];
        assert_eq!(started & 0x8000, 0x8000, "running");
        assert_eq!((started >> 24) & 0x7f, 1, "operation 1");
        assert_eq!((started >> 16) & 0x7f, 2, "write 2");
        c.write_async(&mut s, 40_000);
        assert_eq!(s.out_int[26] & 0x7fff, 32767, "progress saturates");
        c.write_async(&mut s, -1);
        assert_eq!(s.out_int[26] & 0x8000, 0, "finished");
        for _ in 0..200 {
            c.write_async(&mut s, 0);
        }
        assert!(c.wr_count <= 127 && c.op_id <= 127);
    }
}
