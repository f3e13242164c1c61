//! The configuration's key table: every key the TOML schema accepts, with its type, unit,
//! default and allowed range, taken from the same constants the validation uses
//! (`validation::ranges`, [`super::defaults`]). `handeye config reference` prints it as the
//! book's page `docs/src/config-reference.md`; a test checks that page against this table and
//! this table against the keys the schema accepts, so a key missing on either side fails CI.

use handeye_hal::ur_dh::UrModel;

use super::defaults;
use super::validation::ranges;
use super::validation::Range;
use super::{KinematicsSource, MAX_OBSTACLES, MAX_VIEW_TARGETS};

/// One configuration key as the book documents it.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyDoc {
    /// Dotted key; `[]` marks the entries of an array of tables (`views.obstacles[].name`).
    pub key: &'static str,
    /// What kind of value it takes (`number`, `integer`, `string`, `true/false`, …).
    pub kind: &'static str,
    /// The unit of a number (empty when none).
    pub unit: &'static str,
    /// The default, or `required`, or `—` when the key is optional without a default.
    pub default: String,
    /// The allowed values or interval.
    pub range: String,
    /// What it does, in one sentence.
    pub what: &'static str,
}

/// The sections in the order the book shows them.
pub const SECTIONS: [&str; 9] = [
    "robot",
    "camera",
    "mount",
    "views",
    "gate",
    "check",
    "write_back",
    "storage",
    "daemon",
];

fn row(
    key: &'static str,
    kind: &'static str,
    default: impl Into<String>,
    range: impl Into<String>,
    what: &'static str,
) -> KeyDoc {
    KeyDoc {
        key,
        kind,
        unit: "",
        default: default.into(),
        range: range.into(),
        what,
    }
}

fn number(key: &'static str, default: Option<f64>, range: Range, what: &'static str) -> KeyDoc {
    KeyDoc {
        key,
        kind: "number",
        unit: range.unit,
        default: default.map_or_else(|| "—".to_string(), |d| d.to_string()),
        range: range.interval(),
        what,
    }
}

fn integer(key: &'static str, default: Option<f64>, range: Range, what: &'static str) -> KeyDoc {
    KeyDoc {
        kind: "integer",
        ..number(key, default, range, what)
    }
}

fn flag(key: &'static str, default: bool, what: &'static str) -> KeyDoc {
    row(key, "true/false", default.to_string(), "", what)
}

fn quoted(names: &[&str]) -> String {
    names
        .iter()
        .map(|n| format!("\"{n}\""))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Every key of the configuration, section by section.
pub fn keys() -> Vec<KeyDoc> {
    let motion = defaults::motion_limits();
    let capture = defaults::capture();
    let gate = defaults::gate();
    let daemon = defaults::daemon();
    let ports = defaults::ROBOT_PORTS;
    let models: Vec<&str> = UrModel::ALL.iter().map(|m| m.name()).collect();
    let kinematics = match defaults::KINEMATICS {
        KinematicsSource::Controller => "controller",
        KinematicsSource::Nominal => "nominal",
    };
    let sensor = serde_json::to_value(defaults::SENSOR)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    let mount = match defaults::MOUNT {
        crate::calib::Mount::EyeInHand => "eye-in-hand",
        crate::calib::Mount::EyeToHand => "eye-to-hand",
    };
    let f = |x: usize| Some(x as f64);
    use ranges::*;
    vec![
        // [robot]
        row("robot.model", "string", "required", quoted(&models), "the arm's model; checked against what the controller reports"),
        row("robot.urdf", "path", "`<model>.urdf` under `$HANDEYE_ROBOTS`", "", "the robot's URDF (relative to the configuration file)"),
        row("robot.host", "IP address", "required", "IPv4 or IPv6, no host names", "the controller's address (pendant: Settings → System → Network)"),
        integer("robot.ports.dashboard", Some(ports.dashboard.into()), PORT, "dashboard server port (a real controller: the default)"),
        integer("robot.ports.primary", Some(ports.primary.into()), PORT, "primary interface port"),
        integer("robot.ports.secondary", Some(ports.secondary.into()), PORT, "secondary interface port"),
        integer("robot.ports.realtime", Some(ports.realtime.into()), PORT, "real-time interface port"),
        integer("robot.ports.rtde", Some(ports.rtde.into()), PORT, "RTDE port"),
        number("robot.max_joint_speed_rad_s", Some(motion.max_joint_speed_rad_s), JOINT_SPEED, "speed cap of every joint in every move"),
        number("robot.max_joint_accel_rad_s2", Some(motion.max_joint_accel_rad_s2), JOINT_ACCEL, "acceleration cap of every joint"),
        number("robot.move_timeout_s", Some(motion.timeout.as_secs_f64()), MOVE_TIMEOUT, "a move that has not arrived by then is stopped and fails"),
        flag("robot.allow_power_on", defaults::ALLOW_POWER_ON, "power the arm on and release its brakes in preflight (otherwise do it on the pendant)"),
        row("robot.kinematics", "string", format!("\"{kinematics}\""), "\"controller\", \"nominal\"", "pose the model by the controller's calibrated kinematics, or by the nominal URDF"),
        row("robot.calibration", "path", "—", "", "ur_calibration's kinematics file: poses the model when the controller publishes none"),
        // [camera]
        row("camera.backend", "string", "required", "\"gige\", \"gentl\", \"exec\", \"file\"", "how the camera is reached: GigE Vision, a vendor's GenTL producer, a capture command, or recorded files"),
        row("camera.address", "string", "required with gige", "`IP` or `IP:PORT` (GVCP 3956 by default)", "the GigE Vision camera's address"),
        row("camera.command", "list of strings", "required with exec", "", "the capture command and its arguments (`{out}`, `{frame}`, `{config_dir}` replaced)"),
        row("camera.producer", "path", "the first `*.cti` on `GENICAM_GENTL64_PATH`", "a `.cti` file", "gentl: the vendor's GenTL producer"),
        row("camera.device", "string", "the first device", "serial number, model, GenTL id or index", "gentl: which of the producer's cameras (`handeye camera probe --gentl FILE.cti` lists them)"),
        number("camera.call_timeout_s", Some(defaults::CALL_TIMEOUT_S), CALL_TIMEOUT, "gentl: each producer call's deadline (EventGetData: the frame timeout + 1 s); past it the producer's host process is killed and replaced, and the request fails naming the call"),
        number("camera.timeout_s", Some(defaults::EXEC_TIMEOUT_S), EXEC_TIMEOUT, "exec: one frame's time limit; the command is killed after it"),
        row("camera.files", "list of paths", "required with file", "PLY or PCD", "file: the recorded scans replayed, one per frame"),
        integer("camera.frames", Some(capture.frames.into()), FRAMES, "frames per view, fused by the solver"),
        number("camera.frame_timeout_s", Some(capture.frame_timeout.as_secs_f64()), FRAME_TIMEOUT, "give up on one frame after this"),
        number("camera.exposure_us", None, EXPOSURE, "exposure, when the camera supports setting it (default: the camera's own)"),
        number("camera.settle_s", Some(defaults::SETTLE_S), SETTLE, "wait after the arm stops before capturing"),
        row("camera.sensor", "string", format!("\"{sensor}\""), "\"structured-light\", \"active-stereo\", \"time-of-flight\"", "how the camera measures depth; tunes the registration"),
        row("camera.trigger", "string", format!("\"{}\"", defaults::TRIGGER.name()), "\"free\", \"software\"", "gige, gentl: free running (TriggerMode set Off), or one TriggerSoftware per frame"),
        row("camera.user_set", "string", "—", "a `UserSetSelector` entry", "gige, gentl: loaded (UserSetSelector, UserSetLoad) before every capture, before `[camera.features]`"),
        row("camera.features", "table of name = value", "—", "the feature's own range or entries (`handeye camera probe`)", "gige, gentl: GenICam features written in the order given before every capture (e.g. `PixelFormat = \"Coord3D_C16\"`); not the ones handeye sets itself"),
        // [mount]
        row("mount.type", "string", format!("\"{mount}\""), "\"eye-in-hand\", \"eye-to-hand\"", "camera on the flange, or fixed in the cell"),
        row("mount.prior", "[x, y, z, rx, ry, rz]", "—", format!("x, y, z {} m; rx, ry, rz {} rad", PRIOR_TRANSLATION.interval(), PRIOR_ROTATION.interval()), "a guess of flange_from_camera (UR pose: m, rotation vector); needed by views.mode = \"auto\""),
        number("mount.max_camera_flange_distance_m", Some(defaults::MAX_CAMERA_FLANGE_DISTANCE_M), CAMERA_FLANGE_DISTANCE, "eye-in-hand: the camera is sought within this distance of the flange"),
        // [views]
        row("views.mode", "string", "\"auto\"", "\"joints\", \"auto\"", "the configured joint targets, or generated views of the base"),
        row("views.joints", "list of [q1, …, q6]", "required with joints", format!("each {} rad; at most {MAX_VIEW_TARGETS} targets", JOINT.interval()), "joint targets (URDF order) from which the camera sees the base"),
        integer("views.count", f(defaults::VIEW_COUNT), VIEW_COUNT, "auto: how many views to generate (3 or more: the run separates the arm's housings from the mount, see Benchmarks)"),
        number("views.min_distance_m", Some(defaults::MIN_DISTANCE_M), VIEW_DISTANCE, "auto: nearest camera-to-base distance"),
        number("views.max_distance_m", Some(defaults::MAX_DISTANCE_M), VIEW_DISTANCE, "auto: farthest camera-to-base distance"),
        integer("views.seed", Some(defaults::SEED as f64), SEED, "auto: the view generator's seed"),
        row("views.obstacles", "list of tables", "none", format!("at most {MAX_OBSTACLES}"), "boxes every target and path is checked against"),
        row("views.obstacles[].name", "string", "required", "", "the box's name, used in refusals"),
        row("views.obstacles[].centre_m", "[x, y, z]", "required", format!("each {} m", OBSTACLE_CENTRE.interval()), "the box's centre in the robot's base frame"),
        row("views.obstacles[].size_m", "[x, y, z]", "required", format!("each {} m", OBSTACLE_SIZE.interval()), "the box's edge lengths"),
        number("views.floor_clearance_m", Some(defaults::FLOOR_CLEARANCE_M), FLOOR_CLEARANCE, "how far above the mounting plane the arm and camera stay"),
        flag("views.return_to_start", defaults::RETURN_TO_START, "move back to the start pose after the run"),
        // [gate]
        number("gate.min_coverage", Some(gate.min_coverage), FRACTION, "least share of the expected visible model surface with scan points on it"),
        number("gate.min_link_support", Some(gate.min_link_support), FRACTION, "least support of each fitted link on its own"),
        number("gate.max_free_space_violations", Some(gate.max_free_space_violations), FRACTION, "largest share of the expected surface the scan sees through; active stereo (`camera.sensor`): 0.12 by default (its depth lies up to 1 % of the distance behind the arm)"),
        number("gate.max_rmse_mm", Some(gate.max_rmse_mm), GATE_MM, "largest RMS residual for a precise scan (widens with the scan's noise)"),
        number("gate.min_inlier_fraction", Some(gate.min_inlier_fraction), FRACTION, "least share of scan points near the model that fit it"),
        number("gate.max_uncertainty_translation_mm", Some(gate.max_uncertainty_translation_mm), GATE_MM, "largest 1σ of the camera position per registration (eye-to-hand: at the robot base); time of flight (`camera.sensor`): 1.3 by default; active stereo: 2.5 (at the robot base)"),
        number("gate.max_uncertainty_rotation_deg", Some(gate.max_uncertainty_rotation_deg), GATE_DEG, "largest 1σ of the camera rotation per registration; active stereo (`camera.sensor`): 0.25 by default"),
        number("gate.max_residual_translation_mm", Some(gate.max_residual_translation_mm), GATE_MM, "largest disagreement of a frame or view with the fused result"),
        number("gate.max_residual_rotation_deg", Some(gate.max_residual_rotation_deg), GATE_DEG, "largest disagreement of a frame or view with the fused result"),
        number("gate.max_dropped_fraction", Some(gate.max_dropped_fraction), FRACTION, "largest share of frames the fusion may drop as outliers"),
        number("gate.max_ambiguity", Some(gate.max_ambiguity), FRACTION, "how well another pose may explain the scan, relative to the result"),
        number("gate.max_depth_scale_error", Some(gate.max_depth_scale_error), DEPTH_SCALE_ERROR, "largest estimated |depth scale − 1|"),
        number("gate.max_depth_offset_mm", Some(gate.max_depth_offset_mm), GATE_MM, "largest estimated range offset (time of flight)"),
        number("gate.max_change_translation_mm", Some(gate.max_change_translation_mm), GATE_MM, "largest move from the previous calibration (a remount: see Recovering)"),
        number("gate.max_change_rotation_deg", Some(gate.max_change_rotation_deg), GATE_DEG, "largest turn from the previous calibration (a remount: see Recovering)"),
        number("gate.max_split_half_mm", gate.max_split_half.map(|s| s.0), GATE_MM, "several configurations: largest disagreement of two halves fitted apart (eye-to-hand: at the robot base); active stereo (`camera.sensor`): 5 by default; otherwise not checked"),
        number("gate.max_split_half_deg", gate.max_split_half.map(|s| s.1), GATE_DEG, "same, degrees; active stereo: 0.5 by default"),
        // [check]
        number("check.max_drift_translation_mm", Some(defaults::MAX_DRIFT_TRANSLATION_MM), DRIFT_MM, "a check beyond this has drifted and raises the alarm; time of flight (`camera.sensor`): 1.5 by default; active stereo: 5"),
        number("check.max_drift_rotation_deg", Some(defaults::MAX_DRIFT_ROTATION_DEG), DRIFT_DEG, "a check beyond this has drifted and raises the alarm; time of flight (`camera.sensor`): 0.15 by default; active stereo: 0.5"),
        // [write_back]
        row("write_back.tcp", "true/false", format!("{} (eye-to-hand: false, and true is refused)", defaults::WRITE_BACK_TCP_EYE_IN_HAND), "", "set the result as the controller's TCP (volatile: persist it)"),
        row("write_back.registers", "table", "none", "", "write the result to RTDE input registers"),
        integer("write_back.registers.double_start", None, REGISTER, "first of six input_double_registers for x, y, z, rx, ry, rz (at most 42)"),
        integer("write_back.registers.sequence_int", None, REGISTER, "input_int_register with a sequence number, written last"),
        flag("write_back.files", defaults::WRITE_BACK_FILES, "result files (JSON, TOML, ROS, URDF) in storage.dir"),
        // [storage]
        row("storage.dir", "path", format!("\"{}\" beside the configuration file", defaults::STORAGE_DIR), "", "history, run folders, current calibration (systemd: /var/lib/handeye)"),
        flag("storage.keep_captures", defaults::KEEP_CAPTURES, "keep each run's raw scans (to replay it with solve --capture)"),
        // [daemon]
        row("daemon.startup", "string", "\"none\"", "\"none\", \"calibrate\", \"check\"", "the run the daemon starts with"),
        row("daemon.listen", "IP:PORT", format!("\"{}\"", defaults::DAEMON_LISTEN), "", "where the HTTP API and the page listen (localhost only by default)"),
        row("daemon.token_file", "path", "—", "mode 0600, at least 16 characters", "the API token for requests that move the arm (systemd: its credential instead)"),
        number("daemon.check_interval_s", None, CHECK_INTERVAL, "a drift check this often"),
        row("daemon.check_at", "list of strings", "none", "`\"[Mon-Fri ]HH:MM\"`, local time", "drift checks at these calendar times"),
        row("daemon.when_busy", "string", format!("\"{}\"", match daemon.when_busy { super::WhenBusy::Queue => "queue", _ => "refuse" }), "\"refuse\", \"queue\"", "a trigger while a run is going: answered busy, or queued (up to 4)"),
        flag("daemon.recalibrate_on_drift", daemon.recalibrate_on_drift, "calibrate and write back after a drifted check"),
        integer("daemon.keep_captures_runs", f(defaults::KEEP_CAPTURES_RUNS), KEEP_RUNS, "raw captures kept for at least the newest this many runs"),
        number("daemon.keep_captures_days", Some(defaults::KEEP_CAPTURES_DAYS), KEEP_DAYS, "and for runs younger than this"),
        row("daemon.pendant", "table", "none", "", "the pendant button: a register handshake that asks for a run"),
        integer("daemon.pendant.request_register", None, REGISTER, "output_int_register a PolyScope program writes 1 (calibrate) or 2 (check) into"),
        integer("daemon.pendant.status_register", None, REGISTER, "input_int_register the daemon answers in: 1 busy, 2 done, 3 failed, 4 refused"),
    ]
}

/// The key table as the book's page `docs/src/config-reference.md`.
pub fn markdown() -> String {
    use std::fmt::Write as _;
    let keys = keys();
    let mut s = String::from(
        "# Configuration keys\n\n\
         <!-- Generated by `handeye config reference` from the code's key table \
         (src/config/reference.rs); do not edit. A test fails when this page, the table or \
         the keys the configuration accepts disagree. -->\n\n\
         A cell's configuration is one TOML file (`config/handeye.example.toml` is a commented \
         example). Unknown keys are refused, every number is range-checked, and every error \
         names the file, the line and the key. Units are in the key names: `_m` metres, `_mm` \
         millimetres, `_rad` radians, `_deg` degrees, `_s` seconds, `_us` microseconds. \
         Relative paths are relative to the configuration file's directory. Ranges: `(a, b]` \
         means a < value ≤ b.\n",
    );
    for section in SECTIONS {
        let _ = write!(
            s,
            "\n## [{section}]\n\n| key | type | unit | default | range | what |\n|---|---|---|---|---|---|\n"
        );
        for k in keys
            .iter()
            .filter(|k| k.key.split('.').next() == Some(section))
        {
            let cell = |t: &str| {
                if t.is_empty() {
                    "—".to_string()
                } else {
                    t.replace('|', "\\|")
                }
            };
            let _ = writeln!(
                s,
                "| `{}` | {} | {} | {} | {} | {} |",
                k.key,
                cell(k.kind),
                cell(k.unit),
                cell(&k.default),
                cell(&k.range),
                cell(k.what)
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;
    use std::path::Path;

    use super::*;
    use crate::config::{Config, ConfigError};

    /// The keys the schema accepts in `section` (`""`: the top level), asked of the schema
    /// itself: a configuration with an unknown key there is refused naming the allowed ones.
    fn schema_keys(section: &str) -> BTreeSet<String> {
        let probe = "zz_probe = 1\n";
        let (top, robot, camera, tail) = match section {
            "" => (probe, "", "", String::new()),
            "robot" => ("", probe, "", String::new()),
            "camera" => ("", "", probe, String::new()),
            "robot.ports" => ("", "", "", format!("[robot.ports]\n{probe}")),
            "views.obstacles" => (
                "",
                "",
                "",
                format!("[[views.obstacles]]\nname = \"a\"\ncentre_m = [0, 0, 0]\nsize_m = [1, 1, 1]\n{probe}"),
            ),
            "write_back.registers" => (
                "",
                "",
                "",
                format!("[write_back.registers]\ndouble_start = 24\nsequence_int = 24\n{probe}"),
            ),
            "daemon.pendant" => (
                "",
                "",
                "",
                format!("[daemon.pendant]\nrequest_register = 25\nstatus_register = 26\n{probe}"),
            ),
            other => ("", "", "", format!("[{other}]\n{probe}")),
        };
        let text = format!(
            "{top}[robot]\nmodel = \"ur5e\"\nhost = \"127.0.0.1\"\n{robot}\
             [camera]\nbackend = \"gige\"\naddress = \"127.0.0.1\"\n{camera}{tail}"
        );
        match Config::from_toml(&text, "probe.toml", Path::new("/")) {
            Err(ConfigError::UnknownKey { allowed, .. }) => allowed
                .split(", ")
                .flat_map(|a| a.split(" or "))
                .map(|k| k.trim().to_string())
                .filter(|k| !k.is_empty())
                .collect(),
            other => panic!("section `{section}`: expected an unknown-key refusal, got {other:?}"),
        }
    }

    /// Every key the schema accepts is in the table, and every key in the table is accepted.
    #[test]
    fn the_key_table_matches_the_keys_the_configuration_accepts() {
        let table: Vec<String> = keys().iter().map(|k| k.key.replace("[]", "")).collect();
        let mut sections: BTreeSet<String> = BTreeSet::from([String::new()]);
        for k in &table {
            let parts: Vec<&str> = k.split('.').collect();
            for n in 1..parts.len() {
                sections.insert(parts[..n].join("."));
            }
        }
        for section in &sections {
            let documented: BTreeSet<String> = table
                .iter()
                .filter_map(|k| {
                    let rest = if section.is_empty() {
                        k.as_str()
                    } else {
                        k.strip_prefix(section.as_str())?.strip_prefix('.')?
                    };
                    rest.split('.').next().map(str::to_string)
                })
                .collect();
            let accepted = schema_keys(section);
            assert_eq!(
                documented, accepted,
                "section `{section}`: the key table (src/config/reference.rs) and the keys the \
                 configuration accepts (src/config/raw.rs) differ"
            );
        }
        // Every section shown in the book has its keys.
        let top = schema_keys("");
        assert_eq!(top, SECTIONS.iter().map(|s| s.to_string()).collect());
    }

    /// The book's page is this table, as `handeye config reference` prints it.
    #[test]
    fn the_books_configuration_page_is_the_key_table() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/src/config-reference.md");
        let page = std::fs::read_to_string(&path).unwrap_or_default();
        assert!(
            page == markdown(),
            "{} is not what the key table generates; run \
             `cargo run -- config reference > docs/src/config-reference.md`",
            path.display()
        );
    }

    /// Every key is documented with a type and what it does; the numbers carry their range.
    #[test]
    fn every_key_says_what_it_takes() {
        for k in keys() {
            assert!(!k.kind.is_empty() && !k.what.is_empty(), "{k:?}");
            if k.kind == "number" || k.kind == "integer" {
                assert!(
                    k.range.starts_with('[') || k.range.starts_with('('),
                    "{k:?}"
                );
            }
        }
    }
}
