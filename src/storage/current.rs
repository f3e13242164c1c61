//! The current calibration (`current/`): the accepted result staged beside it and swapped in
//! as a whole, completed after an interrupted write-back, and read back.

use std::path::{Path, PathBuf};

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use super::{
    json, read_beneath, read_text_beneath, write_atomically, CALIBRATION_FILE, CURRENT_DIR,
    MAX_RECORD_FILE_BYTES,
};
use crate::calib::export::{ExportMeta, Exports};
use crate::calib::Mount;
use crate::record::{ResultRecord, RunRecord};

/// The machine-readable current calibration (`current/calibration.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct CurrentCalibration {
    run_id: String,
    mount: Mount,
    /// `flange_from_camera` (eye-in-hand) or `base_from_camera` in `base` (eye-to-hand), 4×4.
    pose: [[f64; 4]; 4],
    /// The controller the calibration was made on (absent in files written before it was
    /// recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    controller: Option<handeye_hal::ControllerIdentity>,
}

/// The current calibration ([`load_current`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Current {
    /// `flange_from_camera` (eye-in-hand) or `base_from_camera` in `base` (eye-to-hand).
    pub pose: Isometry3<f64>,
    /// Where it came from: `result of run <id> (<path>)`.
    pub source: String,
    /// Who the controller it was made on said it was, when recorded.
    pub controller: Option<handeye_hal::ControllerIdentity>,
}

/// Writes every export file into `dir`, each with [`write_atomically`]; returns their paths.
pub(super) fn write_exports(dir: &Path, exports: &Exports) -> std::io::Result<Vec<PathBuf>> {
    exports
        .files()
        .into_iter()
        .map(|(name, contents)| {
            let path = dir.join(name);
            write_atomically(&path, contents.as_bytes()).map(|()| path)
        })
        .collect()
}

/// The last accepted calibration in `storage` for `mount`, with where it came from and the
/// controller it was made on.
pub fn load_current(storage: &Path, mount: Mount) -> Option<Current> {
    let path = storage.join(CURRENT_DIR).join(CALIBRATION_FILE);
    let text = match read_text_beneath(
        storage,
        &Path::new(CURRENT_DIR).join(CALIBRATION_FILE),
        MAX_RECORD_FILE_BYTES,
    ) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
        Err(e) => {
            tracing::warn!("ignoring {}: {e}", path.display());
            return None;
        }
    };
    let current: CurrentCalibration = match serde_json::from_str(&text) {
        Ok(c) => c,
        Err(e) => {
            tracing::warn!("ignoring {}: {e}", path.display());
            return None;
        }
    };
    if current.mount != mount {
        return None;
    }
    let pose = crate::frames::from_row_major(&current.pose)?;
    Some(Current {
        pose,
        source: format!("result of run {} ({})", current.run_id, path.display()),
        controller: current.controller,
    })
}

/// An accepted result written into the run's folder and staged beside `current/`, not yet
/// current: [`StagedResult::commit`] makes it current (renames only, no new data), dropping
/// it uncommitted removes the staging folder.
#[derive(Debug)]
pub(crate) struct StagedResult {
    storage: PathBuf,
    run_id: String,
    staging: PathBuf,
    /// The staged files, by name.
    names: Vec<std::ffi::OsString>,
    committed: bool,
}

/// Writes the exports of an accepted result into the run's folder and stages them for
/// `current/` (`<storage>/.current.<run_id>/`). Everything that needs room is written here,
/// so a full disk fails before anything is written to the controller; on failure the
/// staging folder is removed.
pub(crate) fn stage_result(
    storage: &Path,
    run_dir: &Path,
    unknown: &Isometry3<f64>,
    mount: Mount,
    record: &RunRecord,
    result: Option<&ResultRecord>,
) -> std::io::Result<StagedResult> {
    let (parent, child) = (mount.parent_frame(), "camera");
    let meta = ExportMeta {
        run_id: record.run_id.clone(),
        outcome: record.outcome.name().to_string(),
        uncertainty_translation_mm: result.map_or(f64::NAN, |r| r.uncertainty.translation_mm),
        uncertainty_rotation_deg: result.map_or(f64::NAN, |r| r.uncertainty.rotation_deg),
        // When the run started, ISO 8601 in UTC (the run id is beside it, in run_id).
        timestamp: crate::calendar::utc_text(record.started_unix_s),
    };
    let exports = Exports::new(unknown, parent, child, meta);
    write_exports(run_dir, &exports)?;
    let current = CurrentCalibration {
        run_id: record.run_id.clone(),
        mount,
        pose: crate::frames::to_row_major(unknown),
        controller: record.preflight.as_ref().and_then(|p| p.controller.clone()),
    };
    write_atomically(&run_dir.join(CALIBRATION_FILE), &json(&current)?)?;
    let staging = storage.join(format!(".{CURRENT_DIR}.{}", record.run_id));
    let _ = std::fs::remove_dir_all(&staging);
    let mut staged = StagedResult {
        storage: storage.to_path_buf(),
        run_id: record.run_id.clone(),
        staging: staging.clone(),
        names: Vec::new(),
        committed: false,
    };
    // `staged` removes the staging folder when a write below fails.
    let paths = write_exports(&staging, &exports)?;
    write_atomically(&staging.join(CALIBRATION_FILE), &json(&current)?)?;
    staged.names = paths
        .iter()
        .filter_map(|p| p.file_name().map(ToOwned::to_owned))
        .collect();
    staged.names.push(CALIBRATION_FILE.into());
    Ok(staged)
}

impl StagedResult {
    /// Replaces `current/` as a whole with the staged result (two renames); returns the paths
    /// in `current/`.
    pub(crate) fn commit(mut self) -> std::io::Result<Vec<PathBuf>> {
        let target = self.storage.join(CURRENT_DIR);
        let old = self
            .storage
            .join(format!(".{CURRENT_DIR}.old.{}", self.run_id));
        if target.exists() {
            std::fs::rename(&target, &old)?;
        }
        if let Err(e) = std::fs::rename(&self.staging, &target) {
            // Put the previous calibration back.
            let _ = std::fs::rename(&old, &target);
            return Err(e);
        }
        self.committed = true;
        if let Ok(d) = std::fs::File::open(&self.storage) {
            let _ = d.sync_all();
        }
        let _ = std::fs::remove_dir_all(&old);
        Ok(self.names.iter().map(|n| target.join(n)).collect())
    }
}

impl Drop for StagedResult {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
    }
}

/// The run whose result `current/` holds (`current/calibration.json`'s `run_id`).
pub fn current_run_id(storage: &Path) -> Option<String> {
    let rel = Path::new(CURRENT_DIR).join(CALIBRATION_FILE);
    let text = read_text_beneath(storage, &rel, MAX_RECORD_FILE_BYTES).ok()?;
    serde_json::from_str::<CurrentCalibration>(&text)
        .ok()
        .map(|c| c.run_id)
}

/// Makes the result files `names` of the run in `run_dir` current (copied into a staging
/// folder, then [`StagedResult::commit`]): how a write-back interrupted before `current/`
/// was replaced is completed. Returns the paths in `current/`.
pub(crate) fn make_current_from_run(
    storage: &Path,
    run_dir: &Path,
    run_id: &str,
    names: &[String],
) -> std::io::Result<Vec<PathBuf>> {
    let staging = storage.join(format!(".{CURRENT_DIR}.{run_id}"));
    let _ = std::fs::remove_dir_all(&staging);
    let mut staged = StagedResult {
        storage: storage.to_path_buf(),
        run_id: run_id.to_string(),
        staging: staging.clone(),
        names: Vec::new(),
        committed: false,
    };
    for name in names {
        if name.contains('/') || name.starts_with('.') {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("`{name}` is not a result file name"),
            ));
        }
        let rel = run_dir
            .strip_prefix(storage)
            .map_err(|_| std::io::Error::other("the run folder is not in the storage folder"))?
            .join(name);
        let bytes = read_beneath(storage, &rel, MAX_RECORD_FILE_BYTES)?;
        write_atomically(&staging.join(name), &bytes)?;
        staged.names.push(name.into());
    }
    staged.commit()
}

impl StagedResult {
    /// The names of the files a staged result puts into `current/`.
    pub(crate) fn file_names(&self) -> Vec<String> {
        self.names
            .iter()
            .map(|n| n.to_string_lossy().into_owned())
            .collect()
    }
}
