//! Primary/secondary interface (30001/30002) package format: `int32 length` (whole package) +
//! `uint8 type` + body. Only what the simulator sends and the client reads is modelled.

use handeye_hal::ur_dh::DhParams;
use handeye_hal::ControllerKinematics;

use crate::rtde::Reader;
use crate::UrError;

const P: &str = "primary";
/// Largest package we accept (real ones are a few kB).
pub const MAX_PACKAGE: usize = 1 << 20;

/// ROBOT_STATE package type.
pub const ROBOT_STATE: u8 = 16;
/// ROBOT_MESSAGE package type.
pub const ROBOT_MESSAGE: u8 = 20;
/// Kinematics info: the ROBOT_STATE sub-package type of [`KinematicsInfo`].
pub const KINEMATICS_INFO: u8 = 5;

/// Robot-message source used by the simulator (`-2` = controller in URCL's list).
const SOURCE: i8 = -2;

pub(crate) fn frame(kind: u8, body: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(body.len() + 5);
    out.extend_from_slice(&((body.len() + 5) as i32).to_be_bytes());
    out.push(kind);
    out.extend_from_slice(body);
    out
}

fn message(timestamp_us: u64, mtype: u8, rest: &[u8]) -> Vec<u8> {
    let mut b = Vec::with_capacity(rest.len() + 10);
    b.extend_from_slice(&timestamp_us.to_be_bytes());
    b.push(SOURCE as u8);
    b.push(mtype);
    b.extend_from_slice(rest);
    frame(ROBOT_MESSAGE, &b)
}

/// Version message (first package after connecting to 30001).
pub fn encode_version(timestamp_us: u64, major: u8, minor: u8, bugfix: i32, build: i32) -> Vec<u8> {
    let name = b"URControl";
    let mut b = vec![name.len() as u8];
    b.extend_from_slice(name);
    b.push(major);
    b.push(minor);
    b.extend_from_slice(&bugfix.to_be_bytes());
    b.extend_from_slice(&build.to_be_bytes());
    b.extend_from_slice(b"01-01-2024, 12:00:00");
    message(timestamp_us, 3, &b)
}

/// Text message (e.g. URScript `textmsg`).
pub fn encode_text(timestamp_us: u64, text: &str) -> Vec<u8> {
    message(timestamp_us, 0, text.as_bytes())
}

/// Key message, e.g. title `PROGRAM_XXX_STARTED`, text = program name.
pub fn encode_key(timestamp_us: u64, code: i32, title: &str, text: &str) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(&code.to_be_bytes());
    b.extend_from_slice(&0i32.to_be_bytes());
    let t = &title.as_bytes()[..title.len().min(255)];
    b.push(t.len() as u8);
    b.extend_from_slice(t);
    b.extend_from_slice(text.as_bytes());
    message(timestamp_us, 7, &b)
}

/// Error-code message (e.g. C210 read-only connection), report level 3 VIOLATION / 4 FAULT.
pub fn encode_error_code(timestamp_us: u64, code: i32, level: i32, text: &str) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(&code.to_be_bytes());
    b.extend_from_slice(&0i32.to_be_bytes());
    b.extend_from_slice(&level.to_be_bytes());
    b.push(0);
    b.extend_from_slice(&0u32.to_be_bytes());
    b.extend_from_slice(text.as_bytes());
    message(timestamp_us, 6, &b)
}

/// Runtime-exception message: line, column, text.
pub fn encode_runtime_exception(timestamp_us: u64, line: i32, column: i32, text: &str) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(&line.to_be_bytes());
    b.extend_from_slice(&column.to_be_bytes());
    b.extend_from_slice(text.as_bytes());
    message(timestamp_us, 10, &b)
}

/// Robot mode data (sub-package 0).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RobotModeData {
    /// Microseconds.
    pub timestamp_us: u64,
    /// Robot powered.
    pub power_on: bool,
    /// E-stopped.
    pub emergency_stopped: bool,
    /// Protective stopped.
    pub protective_stopped: bool,
    /// A program runs.
    pub program_running: bool,
    /// Paused.
    pub program_paused: bool,
    /// RTDE-style robot mode.
    pub robot_mode: i8,
    /// Speed slider.
    pub target_speed_fraction: f64,
}

/// `calibration_status` value of a factory-calibrated arm ("Linearised" in the controller's
/// `calibration.conf`: 0 = not initialized, 1 = not linearised, 2 = linearised).
pub const CALIBRATION_LINEARISED: u32 = 2;

/// Kinematics info (ROBOT_STATE sub-package 5): the DH set the controller computes every pose
/// with (nominal + factory calibration, absolute values).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KinematicsInfo {
    /// Per-joint checksums (of the joints' calibration data).
    pub checksum: [u32; 6],
    /// Calibrated DH parameters, UR `base` frame.
    pub dh: DhParams,
    /// [`CALIBRATION_LINEARISED`] for a factory-calibrated arm (URCL reads 4 bytes; the manual
    /// says uint8).
    pub calibration_status: u32,
}

impl KinematicsInfo {
    /// Payload size on the wire: 6 × u32 + 24 × f64 + u32.
    pub const SIZE: usize = 6 * 4 + 24 * 8 + 4;

    /// The hal view: `calibrated` iff the status is [`CALIBRATION_LINEARISED`].
    pub fn to_controller_kinematics(&self) -> ControllerKinematics {
        ControllerKinematics {
            dh: self.dh,
            checksum: self.checksum,
            calibrated: self.calibration_status == CALIBRATION_LINEARISED,
        }
    }

    /// The controller's kinematics as it would publish them: `dh`, checksums derived from the
    /// DH values (stable per arm, like a real controller's), and the given status.
    pub fn for_arm(dh: DhParams, calibration_status: u32) -> Self {
        let checksum = std::array::from_fn(|i| {
            // FNV-1a over the joint's four DH values.
            let mut h: u32 = 0x811c_9dc5;
            for v in [dh.theta[i], dh.a[i], dh.d[i], dh.alpha[i]] {
                for b in v.to_be_bytes() {
                    h = (h ^ u32::from(b)).wrapping_mul(0x0100_0193);
                }
            }
            h
        });
        Self {
            checksum,
            dh,
            calibration_status,
        }
    }

    pub(crate) fn encode(&self, p: &mut Vec<u8>) {
        for c in &self.checksum {
            p.extend_from_slice(&c.to_be_bytes());
        }
        for arr in [&self.dh.theta, &self.dh.a, &self.dh.d, &self.dh.alpha] {
            for v in arr.iter() {
                p.extend_from_slice(&v.to_be_bytes());
            }
        }
        p.extend_from_slice(&self.calibration_status.to_be_bytes());
    }

    pub(crate) fn decode(r: &mut Reader<'_>) -> Result<Self, UrError> {
        let mut checksum = [0u32; 6];
        for c in &mut checksum {
            *c = r.u32()?;
        }
        let mut six = || -> Result<[f64; 6], UrError> {
            let mut a = [0.0; 6];
            for v in &mut a {
                *v = r.f64()?;
            }
            Ok(a)
        };
        let theta = six()?;
        let a = six()?;
        let d = six()?;
        let alpha = six()?;
        Ok(Self {
            checksum,
            dh: DhParams { a, d, alpha, theta },
            calibration_status: r.u32()?,
        })
    }
}

/// Cartesian info (ROBOT_STATE sub-package 4): where the TCP is and the active TCP offset.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CartesianInfo {
    /// `base_from_tcp` as UR's `[x, y, z, rx, ry, rz]` (m, rotation vector).
    pub tool_pose: [f64; 6],
    /// `flange_from_tcp` (the TCP offset set by `set_tcp`), same convention.
    pub tcp_offset: [f64; 6],
}

impl CartesianInfo {
    /// Payload size on the wire: 12 × f64 (CB3.2 and later).
    pub const SIZE: usize = 12 * 8;
}

/// Configuration data (ROBOT_STATE sub-package 6): joint limits, default speeds, the DH set and
/// the robot type, as the controller's configuration holds them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConfigurationData {
    /// Joint position limits (min, max), rad.
    pub joint_limits: [(f64, f64); 6],
    /// Joint speed (rad/s) and acceleration (rad/s²) limits.
    pub joint_motion_limits: [(f64, f64); 6],
    /// Default joint speed (rad/s), joint acceleration (rad/s²), tool speed (m/s), tool
    /// acceleration (m/s²) and equivalent radius (m) of the pendant's move screens.
    pub defaults: [f64; 5],
    /// The DH parameters (the same set as KinematicsInfo).
    pub dh: DhParams,
    /// Masterboard version.
    pub masterboard_version: i32,
    /// Controller box type.
    pub controller_box_type: i32,
    /// Robot type (URCL's numbering: UR3 1, UR5 2, UR10 3, UR16 4, UR20 7, UR30 8).
    pub robot_type: i32,
    /// Robot sub-type.
    pub robot_sub_type: i32,
}

impl ConfigurationData {
    /// Payload size on the wire: 24 × f64 limits, 5 defaults, 24 DH values, 4 × i32.
    pub const SIZE: usize = 24 * 8 + 5 * 8 + 24 * 8 + 4 * 4;

    fn encode(&self, p: &mut Vec<u8>) {
        for (lo, hi) in self.joint_limits.iter().chain(&self.joint_motion_limits) {
            p.extend_from_slice(&lo.to_be_bytes());
            p.extend_from_slice(&hi.to_be_bytes());
        }
        for v in self.defaults {
            p.extend_from_slice(&v.to_be_bytes());
        }
        for arr in [&self.dh.a, &self.dh.d, &self.dh.alpha, &self.dh.theta] {
            for v in arr.iter() {
                p.extend_from_slice(&v.to_be_bytes());
            }
        }
        for v in [
            self.masterboard_version,
            self.controller_box_type,
            self.robot_type,
            self.robot_sub_type,
        ] {
            p.extend_from_slice(&v.to_be_bytes());
        }
    }

    fn decode(r: &mut Reader<'_>) -> Result<Self, UrError> {
        let mut pairs = || -> Result<[(f64, f64); 6], UrError> {
            let mut a = [(0.0, 0.0); 6];
            for v in &mut a {
                *v = (r.f64()?, r.f64()?);
            }
            Ok(a)
        };
        let joint_limits = pairs()?;
        let joint_motion_limits = pairs()?;
        let mut defaults = [0.0; 5];
        for v in &mut defaults {
            *v = r.f64()?;
        }
        let mut six = || -> Result<[f64; 6], UrError> {
            let mut a = [0.0; 6];
            for v in &mut a {
                *v = r.f64()?;
            }
            Ok(a)
        };
        let (a, d, alpha, theta) = (six()?, six()?, six()?, six()?);
        Ok(Self {
            joint_limits,
            joint_motion_limits,
            defaults,
            dh: DhParams { a, d, alpha, theta },
            masterboard_version: r.i32()?,
            controller_box_type: r.i32()?,
            robot_type: r.i32()?,
            robot_sub_type: r.i32()?,
        })
    }
}

/// Everything one ROBOT_STATE package carries, as the simulator publishes it at 10 Hz.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotStateData {
    /// Sub-package 0.
    pub mode: RobotModeData,
    /// Actual joint positions (rad), sub-package 1.
    pub q_actual: [f64; 6],
    /// Target joint positions (rad), sub-package 1.
    pub q_target: [f64; 6],
    /// Actual joint speeds (rad/s), sub-package 1.
    pub qd_actual: [f64; 6],
    /// Joint mode of every joint (253 running, 239 power off, 255 idle), sub-package 1.
    pub joint_mode: u8,
    /// Sub-package 4.
    pub cartesian: CartesianInfo,
    /// Sub-package 5.
    pub kinematics: KinematicsInfo,
    /// Sub-package 6.
    pub configuration: ConfigurationData,
    /// Standard (bits 0–7), configurable (8–15) and tool (16–17) digital outputs, sub-package 3.
    pub digital_outputs: u32,
    /// Standard analog outputs (A or V), sub-package 3.
    pub analog_outputs: [f64; 2],
    /// Safety mode code (as RTDE `safety_mode`), sub-package 3.
    pub safety_mode: u8,
}

/// ROBOT_STATE in the e-Series order: 0 robot mode data, 1 joint data, 2 tool data, 3
/// masterboard data, 4 Cartesian info, 5 kinematics info, 6 configuration data, 7 force mode
/// data, 8 additional info. Under 2000 bytes (python-urx drops larger packages).
pub fn encode_robot_state(st: &RobotStateData) -> Vec<u8> {
    let m = &st.mode;
    let mut body = Vec::with_capacity(1300);
    let mut sub = |t: u8, p: Vec<u8>| {
        body.extend_from_slice(&((p.len() + 5) as u32).to_be_bytes());
        body.push(t);
        body.extend_from_slice(&p);
    };
    let f64s = |p: &mut Vec<u8>, v: &[f64]| {
        for x in v {
            p.extend_from_slice(&x.to_be_bytes());
        }
    };
    let f32s = |p: &mut Vec<u8>, v: &[f32]| {
        for x in v {
            p.extend_from_slice(&x.to_be_bytes());
        }
    };
    let mut p = Vec::new();
    p.extend_from_slice(&m.timestamp_us.to_be_bytes());
    for b in [
        true,
        true,
        m.power_on,
        m.emergency_stopped,
        m.protective_stopped,
        m.program_running,
        m.program_paused,
    ] {
        p.push(u8::from(b));
    }
    p.push(m.robot_mode as u8);
    p.push(0);
    // target speed fraction, speed scaling, target speed fraction limit
    f64s(&mut p, &[m.target_speed_fraction, 1.0, 1.0]);
    sub(0, p);
    let mut p = Vec::new();
    for i in 0..6 {
        // q_actual, q_target, qd_actual, I_actual, V_actual, T_motor, T_micro, mode
        f64s(&mut p, &[st.q_actual[i], st.q_target[i], st.qd_actual[i]]);
        f32s(&mut p, &[0.0, 48.0, 30.0, 0.0]);
        p.push(st.joint_mode);
    }
    sub(1, p);
    let mut p = Vec::new();
    // analog input ranges 2/3, analog inputs 2/3, tool voltage, output voltage, current,
    // temperature, tool mode
    p.extend_from_slice(&[0, 0]);
    f64s(&mut p, &[0.0, 0.0]);
    f32s(&mut p, &[24.0]);
    p.push(0);
    f32s(&mut p, &[0.0, 30.0]);
    p.push(st.joint_mode);
    sub(2, p);
    let mut p = Vec::new();
    p.extend_from_slice(&0i32.to_be_bytes());
    p.extend_from_slice(&(st.digital_outputs as i32).to_be_bytes());
    p.extend_from_slice(&[0, 0]);
    f64s(&mut p, &[0.0, 0.0]);
    p.extend_from_slice(&[0, 0]);
    f64s(&mut p, &st.analog_outputs);
    // masterboard temperature, robot voltage, robot current, IO current
    f32s(&mut p, &[35.0, 48.0, 0.5, 0.1]);
    // safety mode, in reduced mode, euromap67 installed (no), unused, operational mode
    // selector input, three-position enabling device input, unused
    p.extend_from_slice(&[st.safety_mode, 0, 0]);
    p.extend_from_slice(&0u32.to_be_bytes());
    p.extend_from_slice(&[0, 0, 0]);
    sub(3, p);
    let mut p = Vec::with_capacity(CartesianInfo::SIZE);
    f64s(&mut p, &st.cartesian.tool_pose);
    f64s(&mut p, &st.cartesian.tcp_offset);
    sub(4, p);
    let mut p = Vec::with_capacity(KinematicsInfo::SIZE);
    st.kinematics.encode(&mut p);
    sub(5, p);
    let mut p = Vec::with_capacity(ConfigurationData::SIZE);
    st.configuration.encode(&mut p);
    sub(6, p);
    let mut p = Vec::new();
    // wrench x, y, z, rx, ry, rz, robot dexterity
    f64s(&mut p, &[0.0; 7]);
    sub(7, p);
    // freedrive button pressed, enabled, IO-enabled freedrive, reserved
    sub(8, vec![0, 0, 0, 0]);
    frame(ROBOT_STATE, &body)
}

/// A decoded primary package (what the client needs from it).
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
// One package is decoded at a time (~10 Hz); boxing the kinematics would only cost clarity.
#[allow(clippy::large_enum_variant)]
pub enum PrimaryPackage {
    /// Version message.
    Version {
        /// Major.
        major: u8,
        /// Minor.
        minor: u8,
        /// Bugfix.
        bugfix: i32,
        /// Build.
        build: i32,
    },
    /// Robot state: the sub-packages the client uses, each if present.
    RobotState {
        /// Robot mode data (sub-package 0).
        mode: Option<RobotModeData>,
        /// Actual joint positions, rad (sub-package 1).
        joints: Option<[f64; 6]>,
        /// Cartesian info (sub-package 4).
        cartesian: Option<CartesianInfo>,
        /// Kinematics info (sub-package 5; sent on connect and on change).
        kinematics: Option<KinematicsInfo>,
        /// Configuration data (sub-package 6).
        configuration: Option<ConfigurationData>,
    },
    /// Text message.
    Text(String),
    /// Key message.
    Key {
        /// Code.
        code: i32,
        /// Title, e.g. `PROGRAM_XXX_STARTED`.
        title: String,
        /// Text.
        text: String,
    },
    /// Error code.
    ErrorCode {
        /// Code (`210` = read-only connection).
        code: i32,
        /// Report level.
        level: i32,
        /// Text.
        text: String,
    },
    /// Runtime exception.
    RuntimeException {
        /// Line.
        line: i32,
        /// Text.
        text: String,
    },
    /// Any other package type.
    Other(u8),
}

/// Cut one package off the front of `buf`; `Ok(None)` if incomplete.
pub fn split(buf: &[u8]) -> Result<Option<(PrimaryPackage, usize)>, UrError> {
    if buf.len() < 5 {
        return Ok(None);
    }
    let len = i32::from_be_bytes([buf[0], buf[1], buf[2], buf[3]]);
    if len < 5 || len as usize > MAX_PACKAGE {
        return Err(UrError::malformed(
            P,
            format!("package length {len} is impossible"),
        ));
    }
    let len = len as usize;
    if buf.len() < len {
        return Ok(None);
    }
    Ok(Some((decode(buf[4], &buf[5..len])?, len)))
}

fn lossy(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Decode one package body.
pub fn decode(kind: u8, body: &[u8]) -> Result<PrimaryPackage, UrError> {
    let mut r = Reader::for_protocol(body, P);
    match kind {
        ROBOT_STATE => {
            let mut mode = None;
            let mut joints = None;
            let mut cartesian = None;
            let mut kinematics = None;
            let mut configuration = None;
            while r.remaining() > 0 {
                let len = r.u32()? as usize;
                if len < 5 {
                    return Err(UrError::malformed(
                        P,
                        format!("sub-package length {len} is impossible"),
                    ));
                }
                let t = r.u8()?;
                let mut s = Reader::for_protocol(r.take(len - 5)?, P);
                if t == 0 {
                    let timestamp_us = s.u64()?;
                    let b = s.take(7)?;
                    let robot_mode = s.i8()?;
                    let _control = s.u8()?;
                    let target_speed_fraction = s.f64()?;
                    mode = Some(RobotModeData {
                        timestamp_us,
                        power_on: b[2] != 0,
                        emergency_stopped: b[3] != 0,
                        protective_stopped: b[4] != 0,
                        program_running: b[5] != 0,
                        program_paused: b[6] != 0,
                        robot_mode,
                        target_speed_fraction,
                    });
                } else if t == 1 {
                    let mut q = [0.0; 6];
                    for qi in &mut q {
                        *qi = s.f64()?;
                        s.take(2 * 8 + 4 * 4 + 1)?;
                    }
                    joints = Some(q);
                } else if t == 4 {
                    let mut v = [0.0; 12];
                    for x in &mut v {
                        *x = s.f64()?;
                    }
                    let mut c = CartesianInfo::default();
                    c.tool_pose.copy_from_slice(&v[..6]);
                    c.tcp_offset.copy_from_slice(&v[6..]);
                    cartesian = Some(c);
                } else if t == KINEMATICS_INFO {
                    kinematics = Some(KinematicsInfo::decode(&mut s)?);
                } else if t == 6 {
                    configuration = Some(ConfigurationData::decode(&mut s)?);
                }
            }
            Ok(PrimaryPackage::RobotState {
                mode,
                joints,
                cartesian,
                kinematics,
                configuration,
            })
        }
        ROBOT_MESSAGE => {
            let _ts = r.u64()?;
            let _source = r.i8()?;
            let mtype = r.u8()?;
            Ok(match mtype {
                0 => PrimaryPackage::Text(lossy(r.rest())),
                3 => {
                    let n = r.u8()? as usize;
                    r.take(n)?;
                    PrimaryPackage::Version {
                        major: r.u8()?,
                        minor: r.u8()?,
                        bugfix: r.i32()?,
                        build: r.i32()?,
                    }
                }
                6 => {
                    let code = r.i32()?;
                    let _arg = r.i32()?;
                    let level = r.i32()?;
                    let _dt = r.u8()?;
                    let _data = r.u32()?;
                    PrimaryPackage::ErrorCode {
                        code,
                        level,
                        text: lossy(r.rest()),
                    }
                }
                7 => {
                    let code = r.i32()?;
                    let _arg = r.i32()?;
                    let n = r.u8()? as usize;
                    let title = lossy(r.take(n)?);
                    PrimaryPackage::Key {
                        code,
                        title,
                        text: lossy(r.rest()),
                    }
                }
                10 => {
                    let line = r.i32()?;
                    let _col = r.i32()?;
                    PrimaryPackage::RuntimeException {
                        line,
                        text: lossy(r.rest()),
                    }
                }
                _ => PrimaryPackage::Other(ROBOT_MESSAGE),
            })
        }
        other => Ok(PrimaryPackage::Other(other)),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A robot state in `mode` at joints `q` with `kinematics` (the other sub-packages a
    /// controller's), for the parsers' and the fault proxy's tests.
    pub(crate) fn state(
        mode: RobotModeData,
        q: [f64; 6],
        kinematics: KinematicsInfo,
    ) -> RobotStateData {
        RobotStateData {
            mode,
            q_actual: q,
            q_target: q,
            qd_actual: [0.0; 6],
            joint_mode: 253,
            cartesian: CartesianInfo {
                tool_pose: [0.1, -0.2, 0.3, 0.4, -0.5, 0.6],
                tcp_offset: [0.0, 0.0, 0.15, 0.0, 0.0, 0.1],
            },
            kinematics,
            configuration: ConfigurationData {
                joint_limits: [(-6.0, 6.0); 6],
                joint_motion_limits: [(3.0, 40.0); 6],
                defaults: [1.05, 1.4, 0.25, 1.2, 0.045],
                dh: kinematics.dh,
                masterboard_version: 3,
                controller_box_type: 5,
                robot_type: 2,
                robot_sub_type: 3,
            },
            digital_outputs: 0x105,
            analog_outputs: [0.004, 0.0],
            safety_mode: 1,
        }
    }

    /// One package of every kind (robot states with the calibrated kinematics `.1` and the
    /// nominal ones, both in mode `.2`): the round trips' cases and the fuzz target's seeds.
    fn packages() -> (Vec<Vec<u8>>, KinematicsInfo, RobotModeData) {
        let nominal = handeye_hal::ur_dh::UrModel::Ur5e.dh();
        let kin = KinematicsInfo::for_arm(
            handeye_hal::ur_dh::PhysicalArm::factory(handeye_hal::ur_dh::UrModel::Ur5e, 7)
                .controller_dh(),
            CALIBRATION_LINEARISED,
        );
        let m = RobotModeData {
            timestamp_us: 5,
            power_on: true,
            program_running: true,
            robot_mode: 7,
            ..Default::default()
        };
        let seeds = vec![
            encode_version(1, 5, 11, 1, 108318),
            encode_text(1, "hello"),
            encode_key(1, 0, "PROGRAM_XXX_STARTED", "prog"),
            encode_error_code(1, 210, 3, "read-only"),
            encode_runtime_exception(1, 3, 1, "unknown function: foo"),
            encode_robot_state(&state(m, [0.1; 6], kin)),
            encode_robot_state(&state(m, [-0.2; 6], KinematicsInfo::for_arm(nominal, 0))),
        ];
        (seeds, kin, m)
    }

    #[test]
    fn round_trips() {
        let nominal = handeye_hal::ur_dh::UrModel::Ur5e.dh();
        let (seeds, kin, m) = packages();
        assert!(
            seeds[5].len() < 2000,
            "python-urx drops packages of 2000 bytes or more"
        );
        let (p, n) = split(&seeds[0]).expect("ok").expect("whole");
        assert_eq!(n, seeds[0].len());
        assert_eq!(
            p,
            PrimaryPackage::Version {
                major: 5,
                minor: 11,
                bugfix: 1,
                build: 108318
            }
        );
        let (p, _) = split(&seeds[5]).expect("ok").expect("whole");
        let st = state(m, [0.1; 6], kin);
        assert_eq!(
            p,
            PrimaryPackage::RobotState {
                mode: Some(m),
                joints: Some([0.1; 6]),
                cartesian: Some(st.cartesian),
                kinematics: Some(kin),
                configuration: Some(st.configuration),
            }
        );
        let k = kin.to_controller_kinematics();
        assert!(k.calibrated && k.dh == kin.dh && k.checksum == kin.checksum);
        assert_ne!(kin.checksum, KinematicsInfo::for_arm(nominal, 2).checksum);
        let (p, _) = split(&seeds[6]).expect("ok").expect("whole");
        let PrimaryPackage::RobotState {
            kinematics: Some(k0),
            ..
        } = p
        else {
            panic!("{p:?}")
        };
        assert!(!k0.to_controller_kinematics().calibrated && k0.dh == nominal);
        let (p, _) = split(&seeds[2]).expect("ok").expect("whole");
        assert!(
            matches!(p, PrimaryPackage::Key { ref title, ref text, .. } if title == "PROGRAM_XXX_STARTED" && text == "prog")
        );
        assert!(split(&[0, 0, 0, 2, 16]).is_err());
        assert!(split(&[0x7f, 0, 0, 0, 16]).is_err());
        // Sub-package 5 alone; longer (newer firmware) is fine, shorter is malformed.
        let kinematics_only = |extra: isize| {
            let mut p = Vec::new();
            kin.encode(&mut p);
            if extra < 0 {
                p.truncate(p.len() - extra.unsigned_abs());
            } else {
                p.extend(std::iter::repeat_n(0xab, extra as usize));
            }
            let mut body = ((p.len() + 5) as u32).to_be_bytes().to_vec();
            body.push(5);
            body.extend_from_slice(&p);
            frame(ROBOT_STATE, &body)
        };
        let (p, _) = split(&kinematics_only(7)).expect("ok").expect("whole");
        assert_eq!(
            p,
            PrimaryPackage::RobotState {
                mode: None,
                joints: None,
                cartesian: None,
                kinematics: Some(kin),
                configuration: None,
            }
        );
        assert!(split(&kinematics_only(-1)).is_err());
        assert!(split(&kinematics_only(-(KinematicsInfo::SIZE as isize))).is_err());
    }

    /// Fuzz target `primary` (hal::fuzz): mutated primary-interface packages (version, text,
    /// key, error code, runtime exception, robot states with and without calibrated
    /// kinematics) split into a package, wait for more bytes, or are refused with a message; a
    /// robot state that decodes carries whole sub-packages.
    #[test]
    fn fuzz_primary() {
        let (seeds, _, _) = packages();
        handeye_hal::fuzz::Target::new("primary", seeds)
            .allocation_cap(16, 1 << 16)
            .run(|b| {
                match split(b).map_err(|e| e.to_string())? {
                    Some((PrimaryPackage::RobotState { kinematics, .. }, n)) => {
                        assert!(n <= b.len());
                        if let Some(k) = kinematics {
                            let _ = k.to_controller_kinematics().is_finite();
                        }
                    }
                    Some((_, n)) => assert!(n <= b.len()),
                    None => {}
                }
                Ok::<(), String>(())
            });
    }
}
