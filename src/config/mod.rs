//! The configuration a cell integrator writes: one TOML file describing the robot, the camera,
//! how the camera is mounted, where to look from, the pass/fail gate, what to write back and
//! where to keep results.
//!
//! TOML → private `Raw*` structs (serde, unknown keys refused) → validated [`Config`]. Every
//! number is checked (finite, within a sane range, units in the key names); every error names
//! the file, the dotted key and its line, and says what is allowed:
//!
//! ```text
//! cell.toml:7: robot.max_joint_speed_rad_s = 5: expected 0 < value <= 3.15 rad/s
//! ```
//!
//! Relative paths (`robot.urdf`, `camera.files`, `storage.dir`, `{config_dir}` in
//! `camera.command`) are resolved against the directory of the configuration file. Defaults
//! live in [`defaults`] and nowhere else; the files `config/*.example.toml` document every key
//! and are loaded by a test so they never rot.
//!
//! The types are in `types.rs`, the raw TOML shape in `raw.rs`, the ranges and the validation
//! in `validation.rs`, the defaults in `defaults.rs`, ready-made configurations in
//! `presets.rs`.

pub mod defaults;
mod locate;
mod presets;
mod raw;
pub mod reference;
#[cfg(test)]
mod tests;
mod types;
mod validation;

use std::path::Path;

use locate::KeyIndex;
use raw::RawConfig;
use validation::{schema_error, Ctx};

pub use presets::sim_rig;
pub use types::*;
pub use validation::check_gate_uncertainty;

/// Largest configuration file read (the example, every key commented, is ~10 kB).
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;
/// Most joint targets `views.joints` may list (each one is moved to, captured and registered).
pub const MAX_VIEW_TARGETS: usize = 32;
/// Most boxes `views.obstacles` may list (every target and path sample is checked against each).
pub const MAX_OBSTACLES: usize = 256;

/// A configuration that could not be used. Every variant but [`ConfigError::Read`] names the
/// origin, the 1-based line and, where there is one, the dotted key (`robot.ports.rtde`,
/// `views.obstacles[0].size_m`: arrays count from 0).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// Not valid TOML.
    #[error("{origin}:{line}:{column}: invalid TOML: {message}")]
    Syntax {
        /// File or other origin.
        origin: String,
        /// 1-based line.
        line: usize,
        /// 1-based column (bytes).
        column: usize,
        /// What the parser expected.
        message: String,
    },
    /// A key this program does not know (often a typo or a missing unit suffix).
    #[error("{origin}:{line}: unknown key `{key}`; allowed here: {allowed}")]
    UnknownKey {
        /// File or other origin.
        origin: String,
        /// 1-based line.
        line: usize,
        /// Dotted key.
        key: String,
        /// The keys allowed in that table.
        allowed: String,
    },
    /// A required key is absent.
    #[error("{origin}:{line}: `{key}` is required")]
    MissingKey {
        /// File or other origin.
        origin: String,
        /// 1-based line (of the table that lacks it).
        line: usize,
        /// Dotted key.
        key: String,
    },
    /// A value of the wrong type or shape.
    #[error("{origin}:{line}: {key}: {message}")]
    WrongType {
        /// File or other origin.
        origin: String,
        /// 1-based line.
        line: usize,
        /// Dotted key.
        key: String,
        /// What was found and what is expected.
        message: String,
    },
    /// A value out of range, or keys that contradict each other.
    #[error("{}: {}", at(origin, *line), keyed(key, message))]
    Invalid {
        /// File or other origin.
        origin: String,
        /// 1-based line of the key (or of the closest key or table that is in the file);
        /// `None` when nothing relevant is written in the file at all.
        line: Option<usize>,
        /// Dotted key.
        key: String,
        /// The value and what is allowed.
        message: String,
    },
}

/// `message`, prefixed with `key` unless it already starts with it.
fn keyed(key: &str, message: &str) -> String {
    if message.starts_with(key) {
        message.to_string()
    } else {
        format!("{key}: {message}")
    }
}

fn at(origin: &str, line: Option<usize>) -> String {
    match line {
        Some(l) => format!("{origin}:{l}"),
        None => origin.to_string(),
    }
}

impl ConfigError {
    /// The 1-based line the error is about, when known.
    pub fn line(&self) -> Option<usize> {
        match self {
            ConfigError::Read { .. } => None,
            ConfigError::Syntax { line, .. }
            | ConfigError::UnknownKey { line, .. }
            | ConfigError::MissingKey { line, .. }
            | ConfigError::WrongType { line, .. } => Some(*line),
            ConfigError::Invalid { line, .. } => *line,
        }
    }

    /// The dotted key the error is about, when known.
    pub fn key(&self) -> Option<&str> {
        match self {
            ConfigError::Read { .. } | ConfigError::Syntax { .. } => None,
            ConfigError::UnknownKey { key, .. }
            | ConfigError::MissingKey { key, .. }
            | ConfigError::WrongType { key, .. }
            | ConfigError::Invalid { key, .. } => Some(key),
        }
    }
}

impl Config {
    /// Parses and validates TOML `text`; `origin` names it in messages (a path, `"<stdin>"`),
    /// `base_dir` is what relative paths are resolved against.
    pub fn from_toml(text: &str, origin: &str, base_dir: &Path) -> Result<Config, ConfigError> {
        let index = KeyIndex::new(text);
        if let Err(e) = text.parse::<toml::Table>() {
            let offset = e.span().map_or(0, |s| s.start);
            return Err(ConfigError::Syntax {
                origin: origin.to_string(),
                line: index.line_at(offset),
                column: index.column_at(offset),
                message: handeye_hal::limits::sanitize_message(
                    &e.message().trim().replace('\n', "; "),
                ),
            });
        }
        let raw: RawConfig = toml::from_str(text).map_err(|e| schema_error(&e, origin, &index))?;
        let ctx = Ctx {
            origin,
            index,
            base_dir,
        };
        ctx.config(raw)
    }

    /// Reads and validates a configuration file; relative paths in it are resolved against
    /// its directory (made absolute). Blocking I/O.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        // A regular file of bounded size: a FIFO would block forever, `/dev/zero` never end.
        let text =
            handeye_hal::limits::read_text_file(path, MAX_CONFIG_BYTES).map_err(|source| {
                ConfigError::Read {
                    path: path.display().to_string(),
                    source,
                }
            })?;
        let base_dir = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        // Absolute, so the paths stay right if the process changes directory later.
        let base_dir = std::path::absolute(base_dir).unwrap_or_else(|_| base_dir.to_path_buf());
        Config::from_toml(&text, &path.display().to_string(), &base_dir)
    }
}
