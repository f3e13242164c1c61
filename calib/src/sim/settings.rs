use std::path::Path;

use super::{CellOptions, Intrinsics, KinematicError, ScanNoise};

/// Largest simulator settings file read (the commented example is ~3 kB).
const MAX_SETTINGS_BYTES: u64 = 1 << 20;

/// All simulator knobs, as loaded from a TOML file with `[noise]`, `[cell]` and
/// `[kinematic_error]` tables (each optional; missing keys take the realistic defaults).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimSettings {
    /// Sensor imperfections.
    pub noise: ScanNoise,
    /// Surroundings of the robot.
    pub cell: CellOptions,
    /// Real arm vs nominal model.
    pub kinematic_error: KinematicError,
}

/// A settings file that could not be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SettingsError {
    /// The file could not be read.
    #[error("cannot read simulator settings {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The file is not valid TOML for these settings.
    #[error("invalid simulator settings in {path}: {message}")]
    Invalid {
        /// The file.
        path: String,
        /// What is wrong (with the key and line where known).
        message: String,
    },
}

impl SimSettings {
    /// The realistic defaults with the noise of camera preset `camera`'s sensor class (see
    /// [`Intrinsics::preset_class`] and [`ScanNoise::of_class`]); an unknown name gets the
    /// structured-light defaults.
    pub fn for_camera(camera: &str) -> Self {
        let noise =
            Intrinsics::preset_class(camera).map_or_else(ScanNoise::default, ScanNoise::of_class);
        Self {
            noise,
            ..Self::default()
        }
    }

    /// A perfect sensor, nothing around the robot, the arm exactly its model.
    pub fn ideal() -> Self {
        Self {
            noise: ScanNoise::none(),
            cell: CellOptions::none(),
            kinematic_error: KinematicError::none(),
        }
    }

    /// Whether every knob is plausible; the message names the key, unit and range.
    pub fn validate(&self) -> Result<(), String> {
        self.noise.validate()?;
        self.cell.validate()?;
        self.kinematic_error.validate()
    }

    /// Parses settings from TOML text.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, SettingsError> {
        // The parser's message quotes the offending line: escape what it copied from the file.
        let s: SimSettings = toml::from_str(text).map_err(|e| SettingsError::Invalid {
            path: origin.to_string(),
            message: handeye_hal::limits::sanitize_message(&e.to_string()),
        })?;
        s.validate().map_err(|message| SettingsError::Invalid {
            path: origin.to_string(),
            message,
        })?;
        Ok(s)
    }

    /// Loads settings from a TOML file.
    pub fn load(path: &Path) -> Result<Self, SettingsError> {
        let read_error = |source| SettingsError::Read {
            path: path.display().to_string(),
            source,
        };
        let text =
            handeye_hal::limits::read_text_file(path, MAX_SETTINGS_BYTES).map_err(read_error)?;
        Self::from_toml(&text, &path.display().to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_preset_simulates_its_sensor_class() {
        assert_eq!(
            SimSettings::for_camera("realsense-d435").noise,
            ScanNoise::active_stereo()
        );
        assert_eq!(
            SimSettings::for_camera("helios2").noise,
            ScanNoise::time_of_flight()
        );
        assert_eq!(SimSettings::for_camera("compact"), SimSettings::default());
        assert_eq!(
            SimSettings::for_camera("zivid2-m60"),
            SimSettings::default()
        );
    }

    #[test]
    fn the_example_file_loads_and_unknown_keys_are_refused() {
        let example = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../config/simulator.example.toml"
        );
        let s = SimSettings::load(Path::new(example)).expect("example settings load");
        assert_eq!(
            s,
            SimSettings::default(),
            "the example documents the defaults"
        );
        let err =
            SimSettings::from_toml("[noise]\ndepth_sigma = 1.0\n", "t.toml").expect_err("invalid");
        assert!(err.to_string().contains("depth_sigma"), "{err}");
        let err = SimSettings::from_toml("[noise]\nrandom_dropout_probability = 2.0\n", "t.toml")
            .expect_err("invalid");
        assert!(
            err.to_string().contains("random_dropout_probability"),
            "{err}"
        );
    }

    /// Fuzz target `sim-settings` (hal::fuzz; issue 16): mutations of the commented example
    /// — odd numbers in values, nesting tokens, dropped and doubled lines — load or are refused
    /// with a message, and what loads is within range.
    #[test]
    fn fuzz_sim_settings() {
        let example = std::fs::read(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../config/simulator.example.toml"
        ))
        .expect("example");
        let nested = b"[cell]\nfloor = true\n[noise]\ndepth_sigma_at_1m_m = 0.001\n".to_vec();
        handeye_hal::fuzz::Target::new("sim-settings", vec![example, nested]).run(|b| {
            let s = SimSettings::from_toml(&String::from_utf8_lossy(b), "fuzz.toml")
                .map_err(|e| e.to_string())?;
            if let Err(e) = s.validate() {
                panic!("settings that loaded are invalid: {e}");
            }
            Ok::<(), String>(())
        });
    }

    /// Issue 23 (found by the `sim-settings` fuzz target): the TOML parser's message quotes
    /// the offending line, and a control character in it reached the terminal raw.
    #[test]
    fn issue_23_toml_error_escapes_control_characters() {
        let e = SimSettings::from_toml("\u{6}", "x.toml").expect_err("not TOML");
        let msg = e.to_string();
        assert!(msg.contains("x.toml") && msg.contains("line 1"), "{msg}");
        assert!(!msg.chars().any(|c| c.is_control() && c != '\n'), "{msg:?}");
    }

    /// Issue 16: every knob is range-checked (negative, NaN, infinite, absurd), the message
    /// names the key; the TOML parser survives deep nesting; a FIFO is not read.
    #[test]
    fn issue_16_absurd_knobs_are_refused_by_key() {
        for (text, key) in [
            (
                "[noise]\ndepth_sigma_at_1m_m = -0.001\n",
                "noise.depth_sigma_at_1m_m",
            ),
            (
                "[noise]\ndepth_sigma_at_1m_m = nan\n",
                "noise.depth_sigma_at_1m_m",
            ),
            (
                "[noise]\ndepth_sigma_at_1m_m = 1e300\n",
                "noise.depth_sigma_at_1m_m",
            ),
            (
                "[noise]\nflying_pixel_edge_m = -1\n",
                "noise.flying_pixel_edge_m",
            ),
            (
                "[noise]\ndropout_start_deg = -10\n",
                "noise.dropout_start_deg",
            ),
            (
                "[noise]\ndropout_full_deg = inf\n",
                "noise.dropout_full_deg",
            ),
            (
                "[noise]\ndropout_start_deg = 89\ndropout_full_deg = 80\n",
                "noise.dropout_start_deg",
            ),
            ("[noise]\nmax_range_m = -inf\n", "noise.max_range_m"),
            ("[noise]\nmax_range_m = 1e9\n", "noise.max_range_m"),
            (
                "[noise]\ndepth_scale_error = nan\n",
                "noise.depth_scale_error",
            ),
            (
                "[cell]\nplate_thickness_m = -0.01\n",
                "cell.plate_thickness_m",
            ),
            (
                "[cell]\nplate_thickness_m = inf\n",
                "cell.plate_thickness_m",
            ),
            (
                "[cell]\nclutter_objects = 1000000000\n",
                "cell.clutter_objects",
            ),
            (
                "[kinematic_error]\nlink_length_sigma_m = 1e160\n",
                "kinematic_error.link_length_sigma_m",
            ),
            (
                "[kinematic_error]\njoint_offset_sigma_rad = -1\n",
                "kinematic_error.joint_offset_sigma_rad",
            ),
        ] {
            let t = std::time::Instant::now();
            let err = SimSettings::from_toml(text, "t.toml")
                .expect_err(text)
                .to_string();
            assert!(err.contains(&format!("{key} = ")), "{text}: {err}");
            assert!(t.elapsed().as_millis() < 100);
        }
        // Infinite range is the documented "no limit".
        SimSettings::from_toml("[noise]\nmax_range_m = inf\n", "t.toml").expect("no range limit");
        // Deeply nested TOML values are an error from the parser, not a stack overflow.
        let n = 100_000;
        let deep = format!("[cell]\nfloor = {}{}\n", "[".repeat(n), "]".repeat(n));
        SimSettings::from_toml(&deep, "t.toml").expect_err("deep");
        let deep = format!("[cell]\nfloor = {}1{}\n", "{a=".repeat(n), "}".repeat(n));
        SimSettings::from_toml(&deep, "t.toml").expect_err("deep");
        #[cfg(unix)]
        {
            let fifo =
                std::env::temp_dir().join(format!("handeye-sim-{}.toml", std::process::id()));
            let _ = std::fs::remove_file(&fifo);
            let ok = std::process::Command::new("mkfifo")
                .arg(&fifo)
                .status()
                .expect("mkfifo");
            assert!(ok.success());
            let err = SimSettings::load(&fifo).expect_err("fifo").to_string();
            assert!(err.contains("FIFO"), "{err}");
            let _ = std::fs::remove_file(&fifo);
        }
    }
}
