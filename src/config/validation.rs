//! Validation: every number's allowed interval with its unit, stated once ([`Range`]), the
//! schema errors located in the file, and the raw TOML turned into a [`Config`] ([`Ctx`]).

use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::time::Duration;

use handeye_hal::limits::Quoted;
use handeye_hal::ur_dh::UrModel;
use handeye_hal::{CaptureSettings, MotionLimits, UrPose};
use nalgebra::Isometry3;

use crate::calib::{GateThresholds, Mount};
use crate::geometry::SensorClass;

use super::locate::KeyIndex;
use super::raw::*;
use super::types::*;
use super::{defaults, ConfigError};

mod camera_settings;

// Ranges: every number's allowed interval, with its unit, stated once.

#[derive(Debug, Clone, Copy)]
pub(super) struct Range {
    lo: f64,
    lo_inclusive: bool,
    hi: f64,
    hi_inclusive: bool,
    pub(super) unit: &'static str,
}

/// `lo < value <= hi`.
const fn above(lo: f64, hi: f64, unit: &'static str) -> Range {
    Range {
        lo,
        lo_inclusive: false,
        hi,
        hi_inclusive: true,
        unit,
    }
}

/// `lo <= value <= hi`.
const fn within(lo: f64, hi: f64, unit: &'static str) -> Range {
    Range {
        lo,
        lo_inclusive: true,
        hi,
        hi_inclusive: true,
        unit,
    }
}

impl Range {
    fn contains(&self, v: f64) -> bool {
        v.is_finite()
            && (if self.lo_inclusive {
                v >= self.lo
            } else {
                v > self.lo
            })
            && (if self.hi_inclusive {
                v <= self.hi
            } else {
                v < self.hi
            })
    }

    /// The interval alone, without the unit: `(0, 3.15]`.
    pub(super) fn interval(&self) -> String {
        let lo = if self.lo_inclusive { '[' } else { '(' };
        let hi = if self.hi_inclusive { ']' } else { ')' };
        format!("{lo}{}, {}{hi}", self.lo, self.hi)
    }

    pub(super) fn describe(&self) -> String {
        let lo = if self.lo_inclusive { "<=" } else { "<" };
        let hi = if self.hi_inclusive { "<=" } else { "<" };
        let unit = if self.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", self.unit)
        };
        format!("{} {lo} value {hi} {}{unit}", self.lo, self.hi)
    }
}

/// Checks `solve --max-uncertainty` against the ranges of the `[gate]` keys it stands for
/// (`max_uncertainty_translation_mm`, `max_uncertainty_rotation_deg`): `Err` says them.
pub fn check_gate_uncertainty(mm: f64, deg: f64) -> Result<(f64, f64), String> {
    let (t, r) = (ranges::GATE_MM, ranges::GATE_DEG);
    if t.contains(mm) && r.contains(deg) {
        Ok((mm, deg))
    } else {
        Err(format!(
            "position σ {}, rotation σ {}",
            t.describe(),
            r.describe()
        ))
    }
}

pub(super) mod ranges {
    use super::{above, within, Range};
    use std::f64::consts::PI;

    pub(in crate::config) const PORT: Range = within(1.0, 65535.0, "");
    // The hal's UR limits table: no cap above what a UR joint can do.
    pub(in crate::config) const JOINT_SPEED: Range = above(
        0.0,
        handeye_hal::ur_limits::MAX_JOINT_SPEED_CAP_RAD_S,
        "rad/s",
    );
    pub(in crate::config) const JOINT_ACCEL: Range = above(
        0.0,
        handeye_hal::ur_limits::MAX_JOINT_ACCEL_RAD_S2,
        "rad/s²",
    );
    pub(in crate::config) const MOVE_TIMEOUT: Range = above(0.0, 3600.0, "s");
    pub(in crate::config) const FRAMES: Range = within(1.0, 100.0, "");
    pub(in crate::config) const FRAME_TIMEOUT: Range = above(0.0, 600.0, "s");
    pub(in crate::config) const EXPOSURE: Range = above(0.0, 10_000_000.0, "µs");
    pub(in crate::config) const SETTLE: Range = within(0.0, 60.0, "s");
    pub(in crate::config) const EXEC_TIMEOUT: Range = above(0.0, 3600.0, "s");
    pub(in crate::config) const CALL_TIMEOUT: Range = above(0.0, 600.0, "s");
    pub(in crate::config) const PRIOR_TRANSLATION: Range = within(-5.0, 5.0, "m");
    pub(in crate::config) const PRIOR_ROTATION: Range = within(-2.0 * PI, 2.0 * PI, "rad");
    pub(in crate::config) const CAMERA_FLANGE_DISTANCE: Range = above(0.0, 2.0, "m");
    pub(in crate::config) const JOINT: Range = within(-2.0 * PI, 2.0 * PI, "rad (±2π)");
    pub(in crate::config) const VIEW_COUNT: Range = within(1.0, 10.0, "");
    pub(in crate::config) const VIEW_DISTANCE: Range = above(0.1, 3.0, "m");
    pub(in crate::config) const SEED: Range = within(0.0, 9.007_199_254_740_992e15, "");
    pub(in crate::config) const OBSTACLE_CENTRE: Range = within(-10.0, 10.0, "m");
    pub(in crate::config) const OBSTACLE_SIZE: Range = above(0.0, 20.0, "m");
    pub(in crate::config) const CHECK_INTERVAL: Range = within(1.0, 31_536_000.0, "s");
    pub(in crate::config) const KEEP_RUNS: Range = within(0.0, 1_000_000.0, "");
    pub(in crate::config) const KEEP_DAYS: Range = within(0.0, 36_500.0, "days");
    pub(in crate::config) const FLOOR_CLEARANCE: Range = within(0.0, 0.5, "m");
    pub(in crate::config) const FRACTION: Range = within(0.0, 1.0, "");
    pub(in crate::config) const GATE_MM: Range = above(0.0, 1000.0, "mm");
    pub(in crate::config) const GATE_DEG: Range = above(0.0, 180.0, "°");
    pub(in crate::config) const DEPTH_SCALE_ERROR: Range = within(0.0, 0.5, "");
    pub(in crate::config) const DRIFT_MM: Range = above(0.0, 1000.0, "mm");
    pub(in crate::config) const DRIFT_DEG: Range = above(0.0, 180.0, "°");
    pub(in crate::config) const REGISTER: Range = within(0.0, 47.0, "");
}

// ---------------------------------------------------------------------------------------------
// Errors from serde/toml, mapped to keys and lines.

pub(super) fn schema_error(e: &toml::de::Error, origin: &str, index: &KeyIndex) -> ConfigError {
    let span = e.span().unwrap_or(0..0);
    let line = index.line_at(span.start);
    // serde's messages quote the file's own text ("unknown variant `…`"): made safe for a
    // terminal (found by the config fuzz target: a tab inside a variant name).
    let message = handeye_hal::limits::sanitize_message(&e.message().trim().replace('\n', "; "));
    let origin = origin.to_string();
    if let Some(rest) = message.strip_prefix("missing field `") {
        let field = rest.split('`').next().unwrap_or_default();
        let key = match index.table_starting_at(span.start) {
            Some(table) if span.end > span.start => format!("{table}.{field}"),
            _ => field.to_string(),
        };
        return ConfigError::MissingKey { origin, line, key };
    }
    let key = index.path_at(span.start).unwrap_or("?").to_string();
    if message.starts_with("unknown field `") {
        let allowed = message
            .split_once(", expected ")
            .map(|(_, a)| a.trim_start_matches("one of ").replace('`', ""))
            .unwrap_or_else(|| "nothing".to_string());
        return ConfigError::UnknownKey {
            origin,
            line,
            key,
            allowed,
        };
    }
    let message = message
        .replace("expected f64", "expected a number")
        .replace("expected i64", "expected an integer")
        .replace("expected a boolean", "expected true or false");
    ConfigError::WrongType {
        origin,
        line,
        key,
        message,
    }
}

// ---------------------------------------------------------------------------------------------
// Validation.

pub(super) struct Ctx<'a> {
    pub(super) origin: &'a str,
    pub(super) index: KeyIndex,
    pub(super) base_dir: &'a Path,
}

impl Ctx<'_> {
    /// An error about `key`, located at the first of `key` and `near` that is in the file.
    fn invalid_near(&self, key: &str, near: &[&str], message: impl Into<String>) -> ConfigError {
        let line = std::iter::once(key)
            .chain(near.iter().copied())
            .find_map(|k| self.index.line_of(k));
        ConfigError::Invalid {
            origin: self.origin.to_string(),
            line,
            key: key.to_string(),
            message: message.into(),
        }
    }

    /// An error about `key`, located at it or its enclosing tables.
    fn invalid(&self, key: &str, message: impl Into<String>) -> ConfigError {
        let parents: Vec<&str> = key
            .char_indices()
            .filter(|&(_, c)| c == '.' || c == '[')
            .map(|(i, _)| &key[..i])
            .rev()
            .collect();
        self.invalid_near(key, &parents, message)
    }

    fn check(&self, key: &str, v: f64, range: Range) -> Result<f64, ConfigError> {
        if range.contains(v) {
            return Ok(v);
        }
        let finite = if v.is_finite() {
            ""
        } else {
            "a finite number, "
        };
        Err(self.invalid(
            key,
            format!("{key} = {v}: expected {finite}{}", range.describe()),
        ))
    }

    fn num(&self, key: &str, v: Option<f64>, default: f64, r: Range) -> Result<f64, ConfigError> {
        v.map_or(Ok(default), |v| self.check(key, v, r))
    }

    fn int(&self, key: &str, v: i64, r: Range) -> Result<i64, ConfigError> {
        // Integers in the ranges used here are exact in f64.
        if r.contains(v as f64) {
            Ok(v)
        } else {
            Err(self.invalid(key, format!("{key} = {v}: expected {}", r.describe())))
        }
    }

    fn seconds(
        &self,
        key: &str,
        v: Option<f64>,
        default: Duration,
        r: Range,
    ) -> Result<Duration, ConfigError> {
        v.map_or(Ok(default), |v| {
            self.check(key, v, r).map(Duration::from_secs_f64)
        })
    }

    /// A relative path is taken relative to the config file's directory.
    fn path(&self, key: &str, p: &str) -> Result<PathBuf, ConfigError> {
        if p.trim().is_empty() {
            return Err(self.invalid(key, format!("{key} is empty: expected a file path")));
        }
        Ok(self.base_dir.join(p))
    }

    /// Refuses a key that means nothing in the chosen variant.
    fn unused<T>(&self, key: &str, v: &Option<T>, why: &str) -> Result<(), ConfigError> {
        match v {
            Some(_) => Err(self.invalid(key, format!("{key} is not used {why}; remove it"))),
            None => Ok(()),
        }
    }

    pub(super) fn config(&self, raw: RawConfig) -> Result<Config, ConfigError> {
        let robot = self.robot(raw.robot)?;
        let camera = self.camera(raw.camera)?;
        let mount = self.mount(raw.mount)?;
        let views = self.views(raw.views, &mount)?;
        let gate = self.gate(raw.gate, camera.sensor)?;
        let (drift_mm, drift_deg) = defaults::drift_for(camera.sensor);
        let check = CheckConfig {
            max_drift_translation_mm: self.num(
                "check.max_drift_translation_mm",
                raw.check.max_drift_translation_mm,
                drift_mm,
                ranges::DRIFT_MM,
            )?,
            max_drift_rotation_deg: self.num(
                "check.max_drift_rotation_deg",
                raw.check.max_drift_rotation_deg,
                drift_deg,
                ranges::DRIFT_DEG,
            )?,
        };
        let write_back = self.write_back(raw.write_back, mount.mount)?;
        let storage = StorageConfig {
            dir: match &raw.storage.dir {
                Some(d) => self.path("storage.dir", d)?,
                None => self.base_dir.join(defaults::STORAGE_DIR),
            },
            keep_captures: raw.storage.keep_captures.unwrap_or(defaults::KEEP_CAPTURES),
        };
        let daemon = self.daemon(raw.daemon)?;
        if let (Some(p), Some(r)) = (daemon.pendant, write_back.registers) {
            if p.status_register == r.sequence_int {
                return Err(self.invalid(
                    "daemon.pendant.status_register",
                    format!(
                        "daemon.pendant.status_register = {} is write_back.registers.sequence_int too; give the answer its own input_int register",
                        p.status_register
                    ),
                ));
            }
        }
        Ok(Config {
            origin: self.origin.to_string(),
            robot,
            camera,
            mount,
            views,
            gate,
            check,
            write_back,
            storage,
            daemon,
        })
    }

    fn daemon(&self, d: RawDaemon) -> Result<DaemonConfig, ConfigError> {
        let base = defaults::daemon();
        let startup = match d.startup.as_deref().map(str::trim) {
            None | Some("none") => None,
            Some(name) => match crate::record::RunMode::parse(name) {
                Some(mode) => Some(mode),
                None => {
                    return Err(self.invalid(
                        "daemon.startup",
                        format!(
                        "daemon.startup = \"{}\": expected \"none\", \"calibrate\" or \"check\"",
                        Quoted(name)
                    ),
                    ))
                }
            },
        };
        let listen = match &d.listen {
            None => base.listen,
            Some(l) => l.trim().parse().map_err(|_| {
                self.invalid(
                    "daemon.listen",
                    format!("daemon.listen = \"{}\": expected IP:PORT, e.g. \"127.0.0.1:8650\" (localhost only) or \"0.0.0.0:8650\"", Quoted(l)),
                )
            })?,
        };
        let token_file = d
            .token_file
            .as_deref()
            .map(|p| self.path("daemon.token_file", p))
            .transpose()?;
        let check_interval = d
            .check_interval_s
            .map(|v| {
                self.check("daemon.check_interval_s", v, ranges::CHECK_INTERVAL)
                    .map(Duration::from_secs_f64)
            })
            .transpose()?;
        let mut check_at = Vec::new();
        for (i, t) in d.check_at.iter().flatten().enumerate() {
            let key = format!("daemon.check_at[{i}]");
            check_at.push(
                t.parse::<crate::calendar::CalendarTime>()
                    .map_err(|e| self.invalid(&key, format!("{key}: {e}")))?,
            );
        }
        let when_busy = match d.when_busy.as_deref().map(str::trim) {
            None | Some("refuse") => WhenBusy::Refuse,
            Some("queue") => WhenBusy::Queue,
            Some(other) => {
                let shown: String = other.chars().take(40).collect();
                return Err(self.invalid(
                    "daemon.when_busy",
                    format!("daemon.when_busy = {shown:?}: expected \"refuse\" (answer busy) or \"queue\" (run it after the current one)"),
                ));
            }
        };
        let keep_captures_runs = match d.keep_captures_runs {
            Some(v) => self.int("daemon.keep_captures_runs", v, ranges::KEEP_RUNS)? as usize,
            None => base.keep_captures_runs,
        };
        let pendant = match d.pendant {
            None => None,
            Some(p) => {
                let request = self.int(
                    "daemon.pendant.request_register",
                    p.request_register,
                    ranges::REGISTER,
                )? as u32;
                let status = self.int(
                    "daemon.pendant.status_register",
                    p.status_register,
                    ranges::REGISTER,
                )? as u32;
                Some(PendantConfig {
                    request_register: request,
                    status_register: status,
                })
            }
        };
        Ok(DaemonConfig {
            pendant,
            startup,
            listen,
            token_file,
            check_interval,
            check_at,
            when_busy,
            recalibrate_on_drift: d.recalibrate_on_drift.unwrap_or(base.recalibrate_on_drift),
            keep_captures_runs,
            keep_captures_days: self.num(
                "daemon.keep_captures_days",
                d.keep_captures_days,
                base.keep_captures_days,
                ranges::KEEP_DAYS,
            )?,
        })
    }

    fn robot(&self, r: RawRobot) -> Result<RobotConfig, ConfigError> {
        let model = r
            .model
            .parse::<UrModel>()
            .map_err(|e| self.invalid("robot.model", e.to_string()))?;
        let host = r.host.trim().parse::<IpAddr>().map_err(|_| {
            self.invalid(
                "robot.host",
                format!(
                    "robot.host = {:?}: expected the controller's IPv4 or IPv6 address, e.g. \"192.168.56.101\" (host names are not resolved; the pendant shows the IP under Settings → System → Network)",
                    r.host
                ),
            )
        })?;
        let port = |name: &str, v: Option<i64>, default: u16| -> Result<u16, ConfigError> {
            match v {
                None => Ok(default),
                Some(v) => {
                    let key = format!("robot.ports.{name}");
                    // PORT's range fits in u16.
                    self.int(&key, v, ranges::PORT).map(|v| v as u16)
                }
            }
        };
        let std = defaults::ROBOT_PORTS;
        let ports = RobotPorts {
            dashboard: port("dashboard", r.ports.dashboard, std.dashboard)?,
            primary: port("primary", r.ports.primary, std.primary)?,
            secondary: port("secondary", r.ports.secondary, std.secondary)?,
            realtime: port("realtime", r.ports.realtime, std.realtime)?,
            rtde: port("rtde", r.ports.rtde, std.rtde)?,
        };
        let dl = defaults::motion_limits();
        let limits = MotionLimits {
            max_joint_speed_rad_s: self.num(
                "robot.max_joint_speed_rad_s",
                r.max_joint_speed_rad_s,
                dl.max_joint_speed_rad_s,
                ranges::JOINT_SPEED,
            )?,
            max_joint_accel_rad_s2: self.num(
                "robot.max_joint_accel_rad_s2",
                r.max_joint_accel_rad_s2,
                dl.max_joint_accel_rad_s2,
                ranges::JOINT_ACCEL,
            )?,
            timeout: self.seconds(
                "robot.move_timeout_s",
                r.move_timeout_s,
                dl.timeout,
                ranges::MOVE_TIMEOUT,
            )?,
        };
        Ok(RobotConfig {
            model,
            urdf: r
                .urdf
                .as_deref()
                .map(|p| self.path("robot.urdf", p))
                .transpose()?,
            host,
            ports,
            limits,
            allow_power_on: r.allow_power_on.unwrap_or(defaults::ALLOW_POWER_ON),
            kinematics: r.kinematics.unwrap_or(defaults::KINEMATICS),
            calibration: r
                .calibration
                .as_deref()
                .map(|p| self.path("robot.calibration", p))
                .transpose()?,
        })
    }

    fn camera(&self, c: RawCamera) -> Result<CameraConfig, ConfigError> {
        let backend = match c.backend {
            RawBackend::Gige => {
                let why = "with backend = \"gige\"";
                self.unused("camera.producer", &c.producer, why)?;
                self.unused("camera.device", &c.device, why)?;
                self.unused("camera.call_timeout_s", &c.call_timeout_s, why)?;
                self.unused("camera.command", &c.command, why)?;
                self.unused("camera.timeout_s", &c.timeout_s, why)?;
                self.unused("camera.files", &c.files, why)?;
                let Some(address) = c.address else {
                    return Err(self.invalid_near(
                        "camera.address",
                        &["camera.backend", "camera"],
                        "backend = \"gige\" needs `address = \"IP\"` or \"IP:PORT\" (the camera's IP, from the vendor's tool or `arv-tool-0.8`)",
                    ));
                };
                let a = address.trim();
                if a.parse::<IpAddr>().is_err() && a.parse::<SocketAddr>().is_err() {
                    return Err(self.invalid(
                        "camera.address",
                        format!("camera.address = {address:?}: expected \"IP\" or \"IP:PORT\", e.g. \"192.168.1.50\" (GVCP port 3956 by default)"),
                    ));
                }
                CameraBackend::Gige {
                    address: a.to_string(),
                }
            }
            RawBackend::Gentl => {
                let why = "with backend = \"gentl\"";
                self.unused("camera.address", &c.address, why)?;
                self.unused("camera.command", &c.command, why)?;
                self.unused("camera.timeout_s", &c.timeout_s, why)?;
                self.unused("camera.files", &c.files, why)?;
                if c.device.as_deref().is_some_and(|d| d.trim().is_empty()) {
                    return Err(self.invalid(
                        "camera.device",
                        "camera.device is empty: give the camera's serial number, model, GenTL id or index (`handeye camera probe --gentl FILE.cti` lists them), or remove it for the first device",
                    ));
                }
                CameraBackend::Gentl {
                    producer: c
                        .producer
                        .as_deref()
                        .map(|p| self.path("camera.producer", p))
                        .transpose()?,
                    device: c.device.map(|d| d.trim().to_owned()),
                    call_timeout: self.seconds(
                        "camera.call_timeout_s",
                        c.call_timeout_s,
                        Duration::from_secs_f64(defaults::CALL_TIMEOUT_S),
                        ranges::CALL_TIMEOUT,
                    )?,
                }
            }
            RawBackend::Exec => {
                let why = "with backend = \"exec\"";
                self.unused("camera.trigger", &c.trigger, why)?;
                self.unused("camera.user_set", &c.user_set, why)?;
                self.unused("camera.features", &c.features, why)?;
                self.unused("camera.address", &c.address, why)?;
                self.unused("camera.producer", &c.producer, why)?;
                self.unused("camera.device", &c.device, why)?;
                self.unused("camera.call_timeout_s", &c.call_timeout_s, why)?;
                self.unused("camera.files", &c.files, why)?;
                let command = c.command.unwrap_or_default();
                if command.first().is_none_or(|p| p.trim().is_empty()) {
                    return Err(self.invalid_near(
                        "camera.command",
                        &["camera.backend", "camera"],
                        "backend = \"exec\" needs `command = [\"program\", \"arg\", ...]` with a non-empty program; `{out}` in an argument is the file to write",
                    ));
                }
                let dir = self.base_dir.display().to_string();
                CameraBackend::Exec {
                    command: command
                        .iter()
                        .map(|a| a.replace("{config_dir}", &dir))
                        .collect(),
                    timeout: self.seconds(
                        "camera.timeout_s",
                        c.timeout_s,
                        Duration::from_secs_f64(defaults::EXEC_TIMEOUT_S),
                        ranges::EXEC_TIMEOUT,
                    )?,
                }
            }
            RawBackend::File => {
                let why = "with backend = \"file\"";
                self.unused("camera.trigger", &c.trigger, why)?;
                self.unused("camera.user_set", &c.user_set, why)?;
                self.unused("camera.features", &c.features, why)?;
                self.unused("camera.address", &c.address, why)?;
                self.unused("camera.producer", &c.producer, why)?;
                self.unused("camera.device", &c.device, why)?;
                self.unused("camera.call_timeout_s", &c.call_timeout_s, why)?;
                self.unused("camera.command", &c.command, why)?;
                self.unused("camera.timeout_s", &c.timeout_s, why)?;
                let files = c.files.unwrap_or_default();
                if files.is_empty() {
                    return Err(self.invalid_near(
                        "camera.files",
                        &["camera.backend", "camera"],
                        "backend = \"file\" needs at least one file: `files = [\"scan.ply\"]`",
                    ));
                }
                CameraBackend::File {
                    paths: files
                        .iter()
                        .enumerate()
                        .map(|(i, f)| self.path(&format!("camera.files[{i}]"), f))
                        .collect::<Result<_, _>>()?,
                }
            }
        };
        let settings = self.camera_settings(c.user_set, c.features)?;
        let dc = defaults::capture();
        let frames = match c.frames {
            // FRAMES fits in u32.
            Some(n) => self.int("camera.frames", n, ranges::FRAMES)? as u32,
            None => dc.frames,
        };
        let capture = CaptureSettings {
            frames,
            frame_timeout: self.seconds(
                "camera.frame_timeout_s",
                c.frame_timeout_s,
                dc.frame_timeout,
                ranges::FRAME_TIMEOUT,
            )?,
            exposure: match c.exposure_us {
                Some(us) => {
                    let us = self.check("camera.exposure_us", us, ranges::EXPOSURE)?;
                    Some(Duration::from_nanos((us * 1e3).round() as u64))
                }
                None => dc.exposure,
            },
        };
        Ok(CameraConfig {
            backend,
            capture,
            settle: self.seconds(
                "camera.settle_s",
                c.settle_s,
                Duration::from_secs_f64(defaults::SETTLE_S),
                ranges::SETTLE,
            )?,
            sensor: c.sensor.unwrap_or(defaults::SENSOR),
            trigger: c.trigger.unwrap_or(defaults::TRIGGER),
            settings,
        })
    }

    fn mount(&self, m: RawMount) -> Result<MountConfig, ConfigError> {
        let mount = match m.kind {
            None => defaults::MOUNT,
            Some(RawMountType::EyeInHand) => Mount::EyeInHand,
            Some(RawMountType::EyeToHand) => Mount::EyeToHand,
        };
        let max_camera_flange_distance_m = match mount {
            Mount::EyeInHand => Some(self.num(
                "mount.max_camera_flange_distance_m",
                m.max_camera_flange_distance_m,
                defaults::MAX_CAMERA_FLANGE_DISTANCE_M,
                ranges::CAMERA_FLANGE_DISTANCE,
            )?),
            Mount::EyeToHand => {
                self.unused(
                    "mount.max_camera_flange_distance_m",
                    &m.max_camera_flange_distance_m,
                    "with type = \"eye-to-hand\" (the camera is not on the flange)",
                )?;
                None
            }
        };
        let prior = match m.prior {
            None => None,
            Some(v) => {
                for (i, x) in v.iter().enumerate() {
                    let r = if i < 3 {
                        ranges::PRIOR_TRANSLATION
                    } else {
                        ranges::PRIOR_ROTATION
                    };
                    self.check(&format!("mount.prior[{i}]"), *x, r)?;
                }
                let p = Isometry3::from(UrPose::from(v));
                if let Some(max) = max_camera_flange_distance_m {
                    let d = p.translation.vector.norm();
                    if d > max {
                        return Err(self.invalid(
                            "mount.prior",
                            format!("mount.prior puts the camera {d:.3} m from the flange, farther than mount.max_camera_flange_distance_m = {max} m; fix the prior (x, y, z in metres, in the flange frame) or raise the limit"),
                        ));
                    }
                }
                Some(p)
            }
        };
        Ok(MountConfig {
            mount,
            prior,
            max_camera_flange_distance_m,
        })
    }

    fn views(&self, v: RawViews, mount: &MountConfig) -> Result<ViewsConfig, ConfigError> {
        let targets = match v.mode.unwrap_or(RawMode::Auto) {
            RawMode::Joints => {
                let why = "with mode = \"joints\"";
                self.unused("views.count", &v.count, why)?;
                self.unused("views.min_distance_m", &v.min_distance_m, why)?;
                self.unused("views.max_distance_m", &v.max_distance_m, why)?;
                self.unused("views.seed", &v.seed, why)?;
                let joints = v.joints.unwrap_or_default();
                if joints.is_empty() {
                    return Err(self.invalid_near(
                        "views.joints",
                        &["views.mode", "views"],
                        "mode = \"joints\" needs at least one target: `joints = [[q1, q2, q3, q4, q5, q6]]` in rad, URDF order (base, shoulder, elbow, wrist 1, 2, 3)",
                    ));
                }
                if joints.len() > super::MAX_VIEW_TARGETS {
                    return Err(self.invalid(
                        "views.joints",
                        format!(
                            "{} joint targets; at most {} are allowed (each is moved to, captured and registered): keep the few views that see the base best",
                            joints.len(),
                            super::MAX_VIEW_TARGETS
                        ),
                    ));
                }
                for (i, q) in joints.iter().enumerate() {
                    for (j, x) in q.iter().enumerate() {
                        self.check(&format!("views.joints[{i}][{j}]"), *x, ranges::JOINT)?;
                    }
                }
                ViewTargets::Joints(joints)
            }
            RawMode::Auto => {
                self.unused(
                    "views.joints",
                    &v.joints,
                    "with mode = \"auto\" (the default); set mode = \"joints\" to use them",
                )?;
                if mount.mount == Mount::EyeInHand && mount.prior.is_none() {
                    return Err(self.invalid_near(
                        "mount.prior",
                        &["views.mode", "mount", "views"],
                        "automatic views of an eye-in-hand camera need a guess of where it sits: give mount.prior = [x, y, z, rx, ry, rz] (flange_from_camera, m and rad, to a few cm and ~10°), or give joint targets ([views] mode = \"joints\", joints = [[...]])",
                    ));
                }
                let count = match v.count {
                    // VIEW_COUNT fits in usize.
                    Some(n) => self.int("views.count", n, ranges::VIEW_COUNT)? as usize,
                    None => defaults::VIEW_COUNT,
                };
                let min_distance_m = self.num(
                    "views.min_distance_m",
                    v.min_distance_m,
                    defaults::MIN_DISTANCE_M,
                    ranges::VIEW_DISTANCE,
                )?;
                let max_distance_m = self.num(
                    "views.max_distance_m",
                    v.max_distance_m,
                    defaults::MAX_DISTANCE_M,
                    ranges::VIEW_DISTANCE,
                )?;
                if min_distance_m >= max_distance_m {
                    return Err(self.invalid_near(
                        "views.min_distance_m",
                        &["views.max_distance_m", "views"],
                        format!("views.min_distance_m = {min_distance_m} must be less than views.max_distance_m = {max_distance_m}"),
                    ));
                }
                let seed = match v.seed {
                    // SEED is non-negative.
                    Some(s) => self.int("views.seed", s, ranges::SEED)? as u64,
                    None => defaults::SEED,
                };
                ViewTargets::Auto {
                    count,
                    min_distance_m,
                    max_distance_m,
                    seed,
                }
            }
        };
        if v.obstacles.len() > super::MAX_OBSTACLES {
            return Err(self.invalid(
                "views.obstacles",
                format!(
                    "{} obstacles; at most {} are allowed (every target and path sample is checked against each): merge neighbouring boxes into one",
                    v.obstacles.len(),
                    super::MAX_OBSTACLES
                ),
            ));
        }
        let mut obstacles = Vec::with_capacity(v.obstacles.len());
        for (i, o) in v.obstacles.into_iter().enumerate() {
            let key = format!("views.obstacles[{i}]");
            if o.name.trim().is_empty() {
                return Err(self.invalid(
                    &format!("{key}.name"),
                    "an obstacle needs a non-empty name (it appears in messages)",
                ));
            }
            for (j, x) in o.centre_m.iter().enumerate() {
                self.check(&format!("{key}.centre_m[{j}]"), *x, ranges::OBSTACLE_CENTRE)?;
            }
            for (j, x) in o.size_m.iter().enumerate() {
                self.check(&format!("{key}.size_m[{j}]"), *x, ranges::OBSTACLE_SIZE)?;
            }
            obstacles.push(Obstacle {
                name: o.name,
                centre_m: o.centre_m,
                size_m: o.size_m,
            });
        }
        Ok(ViewsConfig {
            targets,
            obstacles,
            floor_clearance_m: self.num(
                "views.floor_clearance_m",
                v.floor_clearance_m,
                defaults::FLOOR_CLEARANCE_M,
                ranges::FLOOR_CLEARANCE,
            )?,
            return_to_start: v.return_to_start.unwrap_or(defaults::RETURN_TO_START),
        })
    }

    /// `[gate]`: each key the user's, else the default of the camera's sensor class
    /// ([`GateThresholds::for_sensor`]).
    fn gate(&self, g: RawGate, sensor: SensorClass) -> Result<GateThresholds, ConfigError> {
        // Destructured without `..`: a new threshold fails to compile here until it has a key.
        let GateThresholds {
            min_coverage,
            min_link_support,
            max_free_space_violations,
            max_rmse_mm,
            min_inlier_fraction,
            max_uncertainty_translation_mm,
            max_uncertainty_rotation_deg,
            max_residual_translation_mm,
            max_residual_rotation_deg,
            max_dropped_fraction,
            max_ambiguity,
            max_depth_scale_error,
            max_depth_offset_mm,
            max_change_translation_mm,
            max_change_rotation_deg,
            max_split_half,
        } = defaults::gate_for(sensor);
        use ranges::{DEPTH_SCALE_ERROR, FRACTION, GATE_DEG, GATE_MM};
        Ok(GateThresholds {
            min_coverage: self.num("gate.min_coverage", g.min_coverage, min_coverage, FRACTION)?,
            min_link_support: self.num(
                "gate.min_link_support",
                g.min_link_support,
                min_link_support,
                FRACTION,
            )?,
            max_free_space_violations: self.num(
                "gate.max_free_space_violations",
                g.max_free_space_violations,
                max_free_space_violations,
                FRACTION,
            )?,
            max_rmse_mm: self.num("gate.max_rmse_mm", g.max_rmse_mm, max_rmse_mm, GATE_MM)?,
            min_inlier_fraction: self.num(
                "gate.min_inlier_fraction",
                g.min_inlier_fraction,
                min_inlier_fraction,
                FRACTION,
            )?,
            max_uncertainty_translation_mm: self.num(
                "gate.max_uncertainty_translation_mm",
                g.max_uncertainty_translation_mm,
                max_uncertainty_translation_mm,
                GATE_MM,
            )?,
            max_uncertainty_rotation_deg: self.num(
                "gate.max_uncertainty_rotation_deg",
                g.max_uncertainty_rotation_deg,
                max_uncertainty_rotation_deg,
                GATE_DEG,
            )?,
            max_residual_translation_mm: self.num(
                "gate.max_residual_translation_mm",
                g.max_residual_translation_mm,
                max_residual_translation_mm,
                GATE_MM,
            )?,
            max_residual_rotation_deg: self.num(
                "gate.max_residual_rotation_deg",
                g.max_residual_rotation_deg,
                max_residual_rotation_deg,
                GATE_DEG,
            )?,
            max_dropped_fraction: self.num(
                "gate.max_dropped_fraction",
                g.max_dropped_fraction,
                max_dropped_fraction,
                FRACTION,
            )?,
            max_ambiguity: self.num(
                "gate.max_ambiguity",
                g.max_ambiguity,
                max_ambiguity,
                FRACTION,
            )?,
            max_depth_scale_error: self.num(
                "gate.max_depth_scale_error",
                g.max_depth_scale_error,
                max_depth_scale_error,
                DEPTH_SCALE_ERROR,
            )?,
            max_depth_offset_mm: self.num(
                "gate.max_depth_offset_mm",
                g.max_depth_offset_mm,
                max_depth_offset_mm,
                GATE_MM,
            )?,
            max_change_translation_mm: self.num(
                "gate.max_change_translation_mm",
                g.max_change_translation_mm,
                max_change_translation_mm,
                GATE_MM,
            )?,
            max_change_rotation_deg: self.num(
                "gate.max_change_rotation_deg",
                g.max_change_rotation_deg,
                max_change_rotation_deg,
                GATE_DEG,
            )?,
            // Checked when the class checks it or the user gives either key (the other then
            // unbounded).
            max_split_half: match (max_split_half, g.max_split_half_mm, g.max_split_half_deg) {
                (None, None, None) => None,
                (class, mm, deg) => Some((
                    self.num(
                        "gate.max_split_half_mm",
                        mm,
                        class.map_or(GATE_MM.hi, |c| c.0),
                        GATE_MM,
                    )?,
                    self.num(
                        "gate.max_split_half_deg",
                        deg,
                        class.map_or(GATE_DEG.hi, |c| c.1),
                        GATE_DEG,
                    )?,
                )),
            },
        })
    }

    fn write_back(&self, w: RawWriteBack, mount: Mount) -> Result<WriteBackConfig, ConfigError> {
        let tcp = match (mount, w.tcp) {
            (Mount::EyeToHand, Some(true)) => {
                return Err(self.invalid(
                    "write_back.tcp",
                    "write_back.tcp = true with mount type = \"eye-to-hand\": a fixed camera is not a TCP; set tcp = false (use registers or files)",
                ))
            }
            (Mount::EyeToHand, _) => false,
            (Mount::EyeInHand, t) => t.unwrap_or(defaults::WRITE_BACK_TCP_EYE_IN_HAND),
        };
        let registers = match w.registers {
            None => None,
            Some(r) => {
                let double_start = self.int(
                    "write_back.registers.double_start",
                    r.double_start,
                    ranges::REGISTER,
                )?;
                if double_start + 5 > 47 {
                    return Err(self.invalid(
                        "write_back.registers.double_start",
                        format!("write_back.registers.double_start = {double_start}: the six doubles {double_start}..{} must fit in input_double_register_0..47; expected 0 <= value <= 42", double_start + 5),
                    ));
                }
                let sequence_int = self.int(
                    "write_back.registers.sequence_int",
                    r.sequence_int,
                    ranges::REGISTER,
                )?;
                // Both are within 0..=47.
                Some(RegisterMap {
                    double_start: double_start as u32,
                    sequence_int: sequence_int as u32,
                })
            }
        };
        Ok(WriteBackConfig {
            tcp,
            registers,
            files: w.files.unwrap_or(defaults::WRITE_BACK_FILES),
        })
    }
}
