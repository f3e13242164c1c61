use std::path::Path;

use super::{CellOptions, KinematicError, ScanNoise};

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
    /// A perfect sensor, nothing around the robot, the arm exactly its model.
    pub fn ideal() -> Self {
        Self {
            noise: ScanNoise::none(),
            cell: CellOptions::none(),
            kinematic_error: KinematicError::none(),
        }
    }

    /// Parses settings from TOML text.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, SettingsError> {
        let s: SimSettings = toml::from_str(text).map_err(|e| SettingsError::Invalid {
            path: origin.to_string(),
            message: e.to_string(),
        })?;
        s.noise
            .validate()
            .map_err(|message| SettingsError::Invalid {
                path: origin.to_string(),
                message,
            })?;
        Ok(s)
    }

    /// Loads settings from a TOML file.
    pub fn load(path: &Path) -> Result<Self, SettingsError> {
        let text = std::fs::read_to_string(path).map_err(|source| SettingsError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_toml(&text, &path.display().to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_example_file_loads_and_unknown_keys_are_refused() {
        let example = concat!(env!("CARGO_MANIFEST_DIR"), "/config/simulator.example.toml");
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
}
