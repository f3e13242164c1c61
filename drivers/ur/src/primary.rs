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

/// Robot-message source used by the simulator (`-2` = controller in URCL's list).
const SOURCE: i8 = -2;

fn frame(kind: u8, body: &[u8]) -> Vec<u8> {
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

    fn encode(&self, p: &mut Vec<u8>) {
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

    fn decode(r: &mut Reader<'_>) -> Result<Self, UrError> {
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

/// ROBOT_STATE with sub-packages 0 (mode data), 1 (joint data, positions only) and 5
/// (kinematics info: checksums, `θ, a, d, α` × 6, calibration status).
pub fn encode_robot_state(m: &RobotModeData, q: &[f64; 6], kin: &KinematicsInfo) -> Vec<u8> {
    let mut body = Vec::new();
    let mut sub = |t: u8, p: Vec<u8>| {
        body.extend_from_slice(&((p.len() + 5) as u32).to_be_bytes());
        body.push(t);
        body.extend_from_slice(&p);
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
    for v in [m.target_speed_fraction, 1.0, 1.0] {
        p.extend_from_slice(&v.to_be_bytes());
    }
    sub(0, p);
    let mut p = Vec::new();
    for qi in q {
        // q_actual, q_target, qd_actual, I_actual, V_actual, T_motor, T_micro, mode
        for v in [*qi, *qi, 0.0] {
            p.extend_from_slice(&v.to_be_bytes());
        }
        p.extend_from_slice(&0f32.to_be_bytes());
        p.extend_from_slice(&48f32.to_be_bytes());
        p.extend_from_slice(&30f32.to_be_bytes());
        p.extend_from_slice(&0f32.to_be_bytes());
        p.push(253);
    }
    sub(1, p);
    let mut p = Vec::with_capacity(KinematicsInfo::SIZE);
    kin.encode(&mut p);
    sub(5, p);
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
        /// Kinematics info (sub-package 5; sent on connect and on change).
        kinematics: Option<KinematicsInfo>,
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
            let mut kinematics = None;
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
                } else if t == 5 {
                    kinematics = Some(KinematicsInfo::decode(&mut s)?);
                }
            }
            Ok(PrimaryPackage::RobotState { mode, kinematics })
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
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_fuzz() {
        let nominal = handeye_hal::ur_dh::UrModel::Ur5e.dh();
        let kin = KinematicsInfo::for_arm(
            nominal.plus(&DhParams::factory_calibration_delta(7)),
            CALIBRATION_LINEARISED,
        );
        let m = RobotModeData {
            timestamp_us: 5,
            power_on: true,
            program_running: true,
            robot_mode: 7,
            ..Default::default()
        };
        let seeds = [
            encode_version(1, 5, 11, 1, 108318),
            encode_text(1, "hello"),
            encode_key(1, 0, "PROGRAM_XXX_STARTED", "prog"),
            encode_error_code(1, 210, 3, "read-only"),
            encode_runtime_exception(1, 3, 1, "unknown function: foo"),
            encode_robot_state(&m, &[0.1; 6], &kin),
            encode_robot_state(&m, &[-0.2; 6], &KinematicsInfo::for_arm(nominal, 0)),
        ];
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
        assert_eq!(
            p,
            PrimaryPackage::RobotState {
                mode: Some(m),
                kinematics: Some(kin)
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
                kinematics: Some(kin)
            }
        );
        assert!(split(&kinematics_only(-1)).is_err());
        assert!(split(&kinematics_only(-(KinematicsInfo::SIZE as isize))).is_err());
        let mut rng = crate::rtde::tests::Lcg(7);
        for _ in 0..20_000 {
            let mut b = seeds[rng.below(seeds.len())].clone();
            for _ in 0..=rng.below(3) {
                let i = rng.below(b.len());
                match rng.below(3) {
                    0 => b[i] = rng.next() as u8,
                    1 => b.truncate(i),
                    _ => b.insert(i, rng.next() as u8),
                }
                if b.is_empty() {
                    break;
                }
            }
            // Never a panic; a robot state that still decodes carries whole sub-packages.
            if let Ok(Some((PrimaryPackage::RobotState { kinematics, .. }, n))) = split(&b) {
                assert!(n <= b.len());
                if let Some(k) = kinematics {
                    let _ = k.to_controller_kinematics().is_finite();
                }
            }
        }
    }
}
