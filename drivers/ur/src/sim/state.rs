//! The simulated controller's state and how RTDE fields map onto it.

use std::collections::{HashMap, VecDeque};
use std::time::{Duration, Instant};

use handeye_hal::ur_dh::{DhParams, PhysicalArm, UrModel};
use nalgebra::Isometry3;

use super::motion::Motion;
use super::SimConfig;
use crate::rtde::{FieldType, Value};
use crate::UrPose;

pub(crate) const RUNTIME_STOPPED: u32 = 1;
pub(crate) const RUNTIME_PLAYING: u32 = 2;
pub(crate) const RUNTIME_PAUSED: u32 = 4;
const LOG_LINES: usize = 32;

/// Joint position limit of every joint, rad (±2π, as the controller's default configuration;
/// the hal's UR limits table).
pub(crate) const JOINT_LIMIT: f64 = handeye_hal::ur_limits::JOINT_POSITION_LIMIT_RAD;

/// Rated payload of the arm, kg (the datasheets').
pub(crate) fn max_payload(model: UrModel) -> f64 {
    match model {
        UrModel::Ur3 | UrModel::Ur3e => 3.0,
        UrModel::Ur5 | UrModel::Ur5e => 5.0,
        UrModel::Ur7e => 7.5,
        UrModel::Ur10 => 10.0,
        UrModel::Ur10e => 12.5,
        UrModel::Ur12e => 12.0,
        UrModel::Ur15 => 15.0,
        UrModel::Ur16e => 16.0,
        UrModel::Ur20 => 20.0,
        UrModel::Ur30 => 30.0,
    }
}

/// ConfigurationData robot type, numbered as real controllers and URCL's `datatypes.h`
/// (`RobotType`) do: UR5 = 1, UR10 = 2, UR3 = 3, UR16 = 4, UR20 = 7, UR30 = 8, UR15 = 9. The
/// e-Series variants share their CB3 sibling's number (a URSim UR5e sends 1) and differ by the
/// sub-type.
pub(crate) fn robot_type(model: UrModel) -> i32 {
    match model {
        UrModel::Ur5 | UrModel::Ur5e | UrModel::Ur7e => 1,
        UrModel::Ur10 | UrModel::Ur10e | UrModel::Ur12e => 2,
        UrModel::Ur3 | UrModel::Ur3e => 3,
        UrModel::Ur16e => 4,
        UrModel::Ur20 => 7,
        UrModel::Ur30 => 8,
        UrModel::Ur15 => 9,
    }
}

/// An RTDE input watchdog set by a running program (`rtde_set_watchdog(name, hz, "stop")`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct RtdeWatchdog {
    /// The watched `input_int_register_N`.
    pub(crate) register: usize,
    /// Least update frequency, Hz.
    pub(crate) min_hz: f64,
    /// The program that set it (the watchdog ends with it).
    pub(crate) program_gen: u64,
}

/// Robot mode codes (RTDE `robot_mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(missing_docs)]
pub enum RobotModeCode {
    PowerOff = 3,
    PowerOn = 4,
    Idle = 5,
    Running = 7,
}

impl RobotModeCode {
    /// Dashboard name.
    pub fn name(self) -> &'static str {
        match self {
            RobotModeCode::PowerOff => "POWER_OFF",
            RobotModeCode::PowerOn => "POWER_ON",
            RobotModeCode::Idle => "IDLE",
            RobotModeCode::Running => "RUNNING",
        }
    }
}

/// Safety mode codes (RTDE `safety_mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(missing_docs)]
pub enum SafetyModeCode {
    Normal = 1,
    ProtectiveStop = 3,
    RobotEmergencyStop = 7,
}

impl SafetyModeCode {
    /// Dashboard name.
    pub fn name(self) -> &'static str {
        match self {
            SafetyModeCode::Normal => "NORMAL",
            SafetyModeCode::ProtectiveStop => "PROTECTIVE_STOP",
            SafetyModeCode::RobotEmergencyStop => "ROBOT_EMERGENCY_STOP",
        }
    }
}

/// The controller.
#[derive(Debug)]
pub(crate) struct State {
    pub(crate) boot: Instant,
    pub(crate) dh: DhParams,
    /// What the model's joints can do (the hal's UR limits table): no move is faster.
    pub(crate) limits: handeye_hal::ur_limits::UrLimits,
    pub(crate) robot_mode: RobotModeCode,
    pub(crate) safety_mode: SafetyModeCode,
    pub(crate) pstop_since: Option<Instant>,
    /// A mode change under way, as a real controller takes its time: `power on` passes through
    /// POWER_ON to IDLE, `brake release` stays IDLE until the brakes are off, then RUNNING.
    pub(crate) mode_change: Option<(RobotModeCode, Instant)>,
    pub(crate) remote_control: bool,
    pub(crate) q: [f64; 6],
    pub(crate) qd: [f64; 6],
    pub(crate) target_q: [f64; 6],
    pub(crate) motion: Option<Motion>,
    pub(crate) pstop_at_fraction: Option<f64>,
    pub(crate) tcp: UrPose,
    pub(crate) runtime_state: u32,
    /// Bumped whenever the running program must stop; script threads compare their copy.
    pub(crate) program_gen: u64,
    pub(crate) program_name: Option<String>,
    pub(crate) loaded_program: Option<String>,
    pub(crate) dashboard_playing: u32,
    pub(crate) in_int: [i32; 48],
    /// When each input int register was last written by an RTDE client (controller seconds;
    /// the RTDE watchdog of ur_rtde's control program watches one).
    pub(crate) in_int_written: [f64; 48],
    /// The RTDE watchdog of the running program, if it set one.
    pub(crate) rtde_watchdog: Option<RtdeWatchdog>,
    pub(crate) in_double: [f64; 48],
    pub(crate) in_bits: u128,
    pub(crate) out_int: [i32; 48],
    pub(crate) out_double: [f64; 48],
    pub(crate) out_bits: u128,
    pub(crate) speed_slider: f64,
    /// Payload mass (kg), centre of gravity (m, flange frame) and inertia (kg m²: Ixx, Iyy,
    /// Izz, Ixy, Ixz, Iyz) set by `set_payload` / `set_target_payload`.
    pub(crate) payload: (f64, [f64; 3], [f64; 6]),
    pub(crate) std_do: u8,
    pub(crate) conf_do: u8,
    pub(crate) tool_do: u8,
    pub(crate) analog_out: [f64; 2],
    pub(crate) latency: Duration,
    /// RTDE input ownership: field → connection id.
    pub(crate) owners: HashMap<String, u64>,
    pub(crate) next_conn: u64,
    /// Last few robot messages (bounded).
    pub(crate) log: VecDeque<String>,
    pub(crate) operational_mode: Option<&'static str>,
}

impl State {
    pub(crate) fn new(c: &SimConfig) -> Self {
        // Every pose the controller reports (RTDE, URScript, primary) uses this one set.
        let dh = c
            .arm
            .as_ref()
            .map_or_else(|| c.model.dh(), PhysicalArm::controller_dh);
        Self {
            // Controllers report seconds since boot; clients (URCL) expect > 40 s.
            boot: Instant::now()
                .checked_sub(Duration::from_secs(60))
                .unwrap_or_else(Instant::now),
            dh,
            limits: c.model.limits(),
            robot_mode: if c.start_running {
                RobotModeCode::Running
            } else {
                RobotModeCode::PowerOff
            },
            safety_mode: SafetyModeCode::Normal,
            pstop_since: None,
            mode_change: None,
            remote_control: c.remote_control || c.model.is_cb3(),
            q: c.initial_q,
            qd: [0.0; 6],
            target_q: c.initial_q,
            motion: None,
            pstop_at_fraction: c.protective_stop_during_move,
            tcp: UrPose([0.0; 6]),
            runtime_state: RUNTIME_STOPPED,
            program_gen: 0,
            program_name: None,
            loaded_program: None,
            dashboard_playing: RUNTIME_STOPPED,
            in_int: [0; 48],
            in_int_written: [0.0; 48],
            rtde_watchdog: None,
            in_double: [0.0; 48],
            in_bits: 0,
            out_int: [0; 48],
            out_double: [0.0; 48],
            out_bits: 0,
            speed_slider: 1.0,
            payload: (0.0, [0.0; 3], [0.0; 6]),
            std_do: 0,
            conf_do: 0,
            tool_do: 0,
            analog_out: [0.0; 2],
            latency: c.latency,
            owners: HashMap::new(),
            next_conn: 1,
            log: VecDeque::new(),
            operational_mode: None,
        }
    }

    pub(crate) fn timestamp(&self) -> f64 {
        self.boot.elapsed().as_secs_f64()
    }

    pub(crate) fn push_log(&mut self, line: String) {
        if self.log.len() == LOG_LINES {
            self.log.pop_front();
        }
        self.log.push_back(line);
    }

    /// What the primary interface publishes as KinematicsInfo (a real controller is always
    /// factory calibrated; a nominal simulator is a perfectly built arm).
    pub(crate) fn kinematics_info(&self) -> crate::primary::KinematicsInfo {
        crate::primary::KinematicsInfo::for_arm(self.dh, crate::primary::CALIBRATION_LINEARISED)
    }

    /// Everything the primary/secondary ROBOT_STATE package reports, mode data given.
    pub(crate) fn primary_state(
        &self,
        mode: crate::primary::RobotModeData,
        model: UrModel,
    ) -> crate::primary::RobotStateData {
        use crate::primary::{CartesianInfo, ConfigurationData, RobotStateData};
        RobotStateData {
            mode,
            q_actual: self.q,
            q_target: self.target_q,
            qd_actual: self.qd,
            joint_mode: self.joint_mode(),
            cartesian: CartesianInfo {
                tool_pose: self.tcp_pose().0,
                tcp_offset: self.tcp.0,
            },
            kinematics: self.kinematics_info(),
            configuration: ConfigurationData {
                joint_limits: [(-JOINT_LIMIT, JOINT_LIMIT); 6],
                joint_motion_limits: std::array::from_fn(|i| {
                    (
                        self.limits.joint_speed_rad_s[i],
                        self.limits.joint_accel_rad_s2,
                    )
                }),
                defaults: [1.05, 1.4, 0.25, 1.2, 0.045],
                dh: self.dh,
                masterboard_version: if model.is_cb3() { 3 } else { 4 },
                controller_box_type: if model.is_cb3() { 3 } else { 5 },
                robot_type: robot_type(model),
                robot_sub_type: if model.is_cb3() { 1 } else { 3 },
            },
            digital_outputs: u32::from(self.std_do)
                | (u32::from(self.conf_do) << 8)
                | (u32::from(self.tool_do) << 16),
            analog_outputs: self.analog_out,
            safety_mode: self.safety_mode as u8,
        }
    }

    /// Joint mode code of every joint: 253 running, 239 power off, 255 idle (brakes on).
    pub(crate) fn joint_mode(&self) -> u8 {
        match self.robot_mode {
            RobotModeCode::Running => 253,
            RobotModeCode::PowerOff => 239,
            _ => 255,
        }
    }

    pub(crate) fn flange_pose(&self) -> Isometry3<f64> {
        self.dh.forward(&self.q)
    }

    /// The TCP's twist in `base` (m/s, rad/s) from the joint speeds, by differentiating the
    /// forward kinematics along `qd`.
    pub(crate) fn tcp_speed(&self) -> [f64; 6] {
        if self.qd.iter().all(|v| *v == 0.0) {
            return [0.0; 6];
        }
        let h = 1e-6;
        let tcp = Isometry3::from(self.tcp);
        let now = self.flange_pose() * tcp;
        let q: [f64; 6] = std::array::from_fn(|i| self.q[i] + self.qd[i] * h);
        let next = self.dh.forward(&q) * tcp;
        let v = (next.translation.vector - now.translation.vector) / h;
        let w = (next.rotation * now.rotation.inverse()).scaled_axis() / h;
        [v.x, v.y, v.z, w.x, w.y, w.z]
    }

    pub(crate) fn tcp_pose(&self) -> UrPose {
        UrPose::from(self.flange_pose() * Isometry3::from(self.tcp))
    }

    /// Enforces the RTDE watchdog: `Some(message)` when the watched register was not updated
    /// in time, after stopping the program that set it (a watchdog of a program that already
    /// ended is dropped).
    pub(crate) fn check_rtde_watchdog(&mut self) -> Option<String> {
        let w = self.rtde_watchdog?;
        if w.program_gen != self.program_gen || self.runtime_state == RUNTIME_STOPPED {
            self.rtde_watchdog = None;
            return None;
        }
        let age = self.timestamp() - self.in_int_written[w.register];
        if age <= 1.0 / w.min_hz {
            return None;
        }
        self.rtde_watchdog = None;
        let msg = format!(
            "RTDE input watchdog: input_int_register_{} was not updated for {age:.3} s \
             (minimum frequency {} Hz); program stopped",
            w.register, w.min_hz
        );
        self.push_log(msg.clone());
        self.stop_program(None);
        Some(msg)
    }

    pub(crate) fn can_move(&self) -> Result<(), String> {
        if self.safety_mode != SafetyModeCode::Normal {
            return Err(format!("safety mode is {}", self.safety_mode.name()));
        }
        if self.robot_mode != RobotModeCode::Running {
            return Err(format!("robot mode is {}", self.robot_mode.name()));
        }
        Ok(())
    }

    /// Stop the running program (and decelerate the arm).
    pub(crate) fn stop_program(&mut self, why: Option<&str>) {
        self.program_gen += 1;
        if self.runtime_state != RUNTIME_STOPPED {
            if let Some(w) = why {
                self.push_log(format!("program stopped: {w}"));
            }
        }
        self.runtime_state = RUNTIME_STOPPED;
        self.dashboard_playing = RUNTIME_STOPPED;
        self.program_name = None;
        self.stop_motion(10.0);
    }

    pub(crate) fn stop_motion(&mut self, decel: f64) {
        if self.motion.is_some() || self.qd.iter().any(|v| *v != 0.0) {
            self.motion = Some(Motion::stop(self.qd, decel));
        }
    }

    pub(crate) fn protective_stop(&mut self) {
        self.safety_mode = SafetyModeCode::ProtectiveStop;
        self.pstop_since = Some(Instant::now());
        self.push_log("protective stop".into());
        self.stop_program(Some("protective stop"));
        self.motion = Some(Motion::stop(
            self.qd,
            handeye_hal::ur_limits::MAX_JOINT_ACCEL_RAD_S2,
        ));
    }

    pub(crate) fn emergency_stop(&mut self, pressed: bool) {
        if pressed {
            self.safety_mode = SafetyModeCode::RobotEmergencyStop;
            self.stop_program(Some("emergency stop"));
            self.motion = None;
            self.qd = [0.0; 6];
            self.robot_mode = RobotModeCode::PowerOff;
        } else if self.safety_mode == SafetyModeCode::RobotEmergencyStop {
            self.safety_mode = SafetyModeCode::Normal;
        }
    }

    fn robot_status_bits(&self) -> u32 {
        u32::from(self.robot_mode != RobotModeCode::PowerOff)
            | (u32::from(self.runtime_state == RUNTIME_PLAYING) << 1)
    }

    fn safety_status_bits(&self) -> u32 {
        match self.safety_mode {
            SafetyModeCode::Normal => 1,
            SafetyModeCode::ProtectiveStop => 1 << 2,
            SafetyModeCode::RobotEmergencyStop => (1 << 6) | (1 << 7) | (1 << 10),
        }
    }

    /// The value of an output field (any known field; unmodelled ones read zero).
    pub(crate) fn output(&self, name: &str, t: FieldType) -> Value {
        if let Some(v) = self.register_value(name) {
            return v;
        }
        let flange = self.flange_pose();
        match name {
            "timestamp" => Value::Double(self.timestamp()),
            "actual_q" => Value::Vector6d(self.q),
            "target_q" => Value::Vector6d(self.target_q),
            "actual_qd" | "target_qd" => Value::Vector6d(self.qd),
            "actual_TCP_pose" | "target_TCP_pose" => Value::Vector6d(self.tcp_pose().0),
            "tcp_offset" => Value::Vector6d(self.tcp.0),
            "actual_TCP_speed" | "target_TCP_speed" => Value::Vector6d(self.tcp_speed()),
            "robot_mode" => Value::Int32(self.robot_mode as i32),
            "joint_mode" => Value::Vector6Int32([i32::from(self.joint_mode()); 6]),
            "safety_mode" | "safety_status" => Value::Int32(self.safety_mode as i32),
            "safety_status_bits" => Value::Uint32(self.safety_status_bits()),
            "robot_status_bits" => Value::Uint32(self.robot_status_bits()),
            "runtime_state" => Value::Uint32(self.runtime_state),
            "speed_scaling" => Value::Double(1.0),
            "target_speed_fraction" => Value::Double(self.speed_slider),
            "payload" => Value::Double(self.payload.0),
            "payload_cog" => Value::Vector3d(self.payload.1),
            "payload_inertia" => Value::Vector6d(self.payload.2),
            "actual_digital_output_bits" => Value::Uint64(
                u64::from(self.std_do)
                    | (u64::from(self.conf_do) << 8)
                    | (u64::from(self.tool_do) << 16),
            ),
            "standard_analog_output0" => Value::Double(self.analog_out[0]),
            "standard_analog_output1" => Value::Double(self.analog_out[1]),
            "actual_main_voltage" | "actual_robot_voltage" => Value::Double(48.0),
            "joint_temperatures" => Value::Vector6d([30.0; 6]),
            "actual_joint_voltage" => Value::Vector6d([48.0; 6]),
            "elbow_position" => {
                let e = self.dh.link_poses(&self.q)[2].translation.vector;
                Value::Vector3d([e.x, e.y, e.z])
            }
            "actual_tool_accelerometer" => {
                let g = flange.rotation.inverse() * nalgebra::Vector3::new(0.0, 0.0, -9.81);
                Value::Vector3d([g.x, g.y, g.z])
            }
            "control_step" => Value::Uint64((self.timestamp() * 500.0) as u64),
            _ => Value::zero(t),
        }
    }

    fn register_value(&self, name: &str) -> Option<Value> {
        let idx = |prefix: &str| {
            name.strip_prefix(prefix)
                .and_then(|s| s.parse::<usize>().ok())
        };
        let bits = |b: u128, lo: u32| Value::Uint32((b >> lo) as u32);
        Some(match name {
            "input_bit_registers0_to_31" => bits(self.in_bits, 0),
            "input_bit_registers32_to_63" => bits(self.in_bits, 32),
            "output_bit_registers0_to_31" => bits(self.out_bits, 0),
            "output_bit_registers32_to_63" => bits(self.out_bits, 32),
            _ => {
                if let Some(i) = idx("input_int_register_") {
                    Value::Int32(*self.in_int.get(i)?)
                } else if let Some(i) = idx("input_double_register_") {
                    Value::Double(*self.in_double.get(i)?)
                } else if let Some(i) = idx("output_int_register_") {
                    Value::Int32(*self.out_int.get(i)?)
                } else if let Some(i) = idx("output_double_register_") {
                    Value::Double(*self.out_double.get(i)?)
                } else if let Some(i) = idx("input_bit_register_") {
                    Value::Bool(i < 128 && self.in_bits >> i & 1 == 1)
                } else if let Some(i) = idx("output_bit_register_") {
                    Value::Bool(i < 128 && self.out_bits >> i & 1 == 1)
                } else {
                    return None;
                }
            }
        })
    }

    /// Apply one input recipe's values (masks applied like the controller does).
    pub(crate) fn apply_inputs(&mut self, names: &[String], values: &[Value]) {
        let get = |n: &str| names.iter().position(|x| x == n).map(|i| values[i]);
        let u8_of = |v: Option<Value>| match v {
            Some(Value::Uint8(b)) => Some(b),
            _ => None,
        };
        for (name, v) in names.iter().zip(values) {
            let idx = |prefix: &str| {
                name.strip_prefix(prefix)
                    .and_then(|s| s.parse::<usize>().ok())
            };
            match (name.as_str(), *v) {
                ("input_bit_registers0_to_31", Value::Uint32(b)) => {
                    self.in_bits = (self.in_bits & !0xffff_ffff) | u128::from(b);
                }
                ("input_bit_registers32_to_63", Value::Uint32(b)) => {
                    self.in_bits =
                        (self.in_bits & !(0xffff_ffffu128 << 32)) | (u128::from(b) << 32);
                }
                ("speed_slider_fraction", Value::Double(f))
                    if matches!(get("speed_slider_mask"), Some(Value::Uint32(1)))
                        && (0.0..=1.0).contains(&f) =>
                {
                    self.speed_slider = f;
                }
                ("standard_digital_output", Value::Uint8(b)) => {
                    let m = u8_of(get("standard_digital_output_mask")).unwrap_or(0);
                    self.std_do = (self.std_do & !m) | (b & m);
                }
                ("configurable_digital_output", Value::Uint8(b)) => {
                    let m = u8_of(get("configurable_digital_output_mask")).unwrap_or(0);
                    self.conf_do = (self.conf_do & !m) | (b & m);
                }
                ("tool_digital_output", Value::Uint8(b)) => {
                    let m = u8_of(get("tool_digital_output_mask")).unwrap_or(0);
                    self.tool_do = (self.tool_do & !m) | (b & m);
                }
                ("standard_analog_output_0", Value::Double(x))
                    if u8_of(get("standard_analog_output_mask")).unwrap_or(0) & 1 != 0 =>
                {
                    self.analog_out[0] = x;
                }
                ("standard_analog_output_1", Value::Double(x))
                    if u8_of(get("standard_analog_output_mask")).unwrap_or(0) & 2 != 0 =>
                {
                    self.analog_out[1] = x;
                }
                (_, Value::Int32(x)) => {
                    if let Some(i) = idx("input_int_register_").filter(|i| *i < 48) {
                        self.in_int[i] = x;
                        self.in_int_written[i] = self.boot.elapsed().as_secs_f64();
                    }
                }
                (_, Value::Double(x)) => {
                    if let Some(r) =
                        idx("input_double_register_").and_then(|i| self.in_double.get_mut(i))
                    {
                        *r = x;
                    }
                }
                (_, Value::Bool(b)) => {
                    if let Some(i) = idx("input_bit_register_").filter(|i| *i < 128) {
                        if b {
                            self.in_bits |= 1 << i;
                        } else {
                            self.in_bits &= !(1 << i);
                        }
                    }
                }
                _ => {}
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rtde_watchdog_stops_its_program_and_ends_with_it() {
        let c = SimConfig::new(UrModel::Ur5e, [127, 0, 0, 1].into());
        let mut s = State::new(&c);
        s.runtime_state = RUNTIME_PLAYING;
        let write = |s: &mut State| {
            s.apply_inputs(&["input_int_register_0".into()], &[Value::Int32(0)]);
        };
        write(&mut s);
        s.rtde_watchdog = Some(RtdeWatchdog {
            register: 0,
            min_hz: 10.0,
            program_gen: s.program_gen,
        });
        // Kicked every 5 ms for 100 ms: the program runs on.
        for _ in 0..20 {
            std::thread::sleep(Duration::from_millis(5));
            write(&mut s);
            assert_eq!(s.check_rtde_watchdog(), None);
        }
        assert_eq!(s.runtime_state, RUNTIME_PLAYING);
        // Not kicked for 150 ms (more than 1/10 Hz): the program stops, once.
        std::thread::sleep(Duration::from_millis(150));
        let msg = s.check_rtde_watchdog().expect("fires");
        assert!(msg.contains("input_int_register_0"), "{msg}");
        assert_eq!(s.runtime_state, RUNTIME_STOPPED);
        assert_eq!(s.check_rtde_watchdog(), None);
        // A watchdog of a program that ended is dropped without firing.
        s.runtime_state = RUNTIME_PLAYING;
        s.rtde_watchdog = Some(RtdeWatchdog {
            register: 0,
            min_hz: 10.0,
            program_gen: s.program_gen,
        });
        s.stop_program(None);
        s.runtime_state = RUNTIME_PLAYING;
        std::thread::sleep(Duration::from_millis(150));
        assert_eq!(s.check_rtde_watchdog(), None);
        assert!(s.rtde_watchdog.is_none());
    }

    /// Issue 35: the ConfigurationData robot type on the wire is numbered as real controllers
    /// and URCL's `datatypes.h` do (a URSim UR5e sends 1); the simulator sent UR3 = 1, UR5 = 2,
    /// UR10 = 3, so a URCL-based client took a simulated UR5e for a UR10.
    #[test]
    fn robot_types_are_numbered_as_real_controllers_do() {
        use crate::primary::{encode_robot_state, split, PrimaryPackage};
        let urcl = [
            (UrModel::Ur5, 1),
            (UrModel::Ur5e, 1),
            (UrModel::Ur10, 2),
            (UrModel::Ur10e, 2),
            (UrModel::Ur3, 3),
            (UrModel::Ur3e, 3),
            (UrModel::Ur16e, 4),
            (UrModel::Ur20, 7),
            (UrModel::Ur30, 8),
            (UrModel::Ur15, 9),
        ];
        for (model, number) in urcl {
            let s = State::new(&SimConfig::new(model, [127, 0, 0, 1].into()));
            let wire = encode_robot_state(&s.primary_state(Default::default(), model));
            let Ok(Some((PrimaryPackage::RobotState { configuration, .. }, _))) = split(&wire)
            else {
                panic!("{model}: no robot state");
            };
            let c = configuration.expect("configuration data");
            assert_eq!(c.robot_type, number, "{model}");
            assert_eq!(
                c.robot_sub_type,
                if model.is_cb3() { 1 } else { 3 },
                "{model}"
            );
        }
    }
}
