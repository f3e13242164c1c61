//! Pruning a run folder: its raw scans (and the temporary files a kill left) removed, never
//! following a link out of the storage.

use std::path::{Path, PathBuf};

use super::{is_real_dir, leftovers, run_dir, StorageError, RUNS_DIR};

/// A raw scan a run kept: `view<V>_frame<F>.ply`.
fn is_raw_capture(name: &str) -> bool {
    name.starts_with("view") && name.contains("_frame") && name.ends_with(".ply")
}

/// Deletes the raw scans (`view*_frame*.ply`) of run `run_id`, and the temporary files
/// (`*.tmp`) a kill left in its folder; its record, `capture.json` and results stay. A missing folder is nothing to do; an id that is not a run id is left
/// alone (logged). Returns the files removed.
pub fn remove_raw_captures(storage: &Path, run_id: &str) -> Result<Vec<PathBuf>, StorageError> {
    let Some(dir) = run_dir(storage, run_id) else {
        tracing::warn!("not pruning run `{run_id}`: its id is not a plain folder name");
        return Ok(Vec::new());
    };
    let io = |action, path: &Path| {
        let path = path.to_path_buf();
        move |source| StorageError {
            action,
            path,
            source,
        }
    };
    // Pruning never leaves the folder: `runs/` and the run's folder must be real folders
    // (a link planted in their place is left alone), and only regular files are removed.
    if std::fs::symlink_metadata(&dir).is_err() {
        return Ok(Vec::new());
    }
    if !is_real_dir(&storage.join(RUNS_DIR)) || !is_real_dir(&dir) {
        tracing::warn!(
            "not pruning {}: it is not a real folder of the storage (a link?)",
            dir.display()
        );
        return Ok(Vec::new());
    }
    let entries = match std::fs::read_dir(&dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(io("read the folder", &dir)(e)),
    };
    let mut removed = Vec::new();
    for entry in entries {
        let entry = entry.map_err(io("read the folder", &dir))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if !(is_raw_capture(&name) || leftovers::is_temporary(&name))
            || !entry.file_type().is_ok_and(|t| t.is_file())
        {
            continue;
        }
        let path = entry.path();
        match std::fs::remove_file(&path) {
            Ok(()) => removed.push(path),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(io("remove", &path)(e)),
        }
    }
    Ok(removed)
}
