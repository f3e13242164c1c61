//! What a killed process leaves in the storage directory, removed by the next one: the
//! staging folders of `current/` ([`clean_staging`]) and the temporary files of
//! [`super::write_atomically`] (`*.tmp`, [`remove_temporary_files`]).

use std::path::{Path, PathBuf};

use super::{is_real_dir, is_run_id, CURRENT_DIR, RUNS_DIR};

/// Removes what a crash left of replacing `current/`: the staging folders
/// (`.current.<id>`) and the set-aside previous ones (`.current.old.<id>`) — except run
/// `keep`'s staging; when `current/` itself is missing (a crash between the two renames of
/// [`StagedResult::commit`]) the set-aside one is put back first. Returns what was removed.
pub(crate) fn clean_staging(storage: &Path, keep: Option<&str>) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(storage) else {
        return Vec::new();
    };
    let old_prefix = format!(".{CURRENT_DIR}.old.");
    let staging_prefix = format!(".{CURRENT_DIR}.");
    let mut removed = Vec::new();
    let current = storage.join(CURRENT_DIR);
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let id = if let Some(id) = name.strip_prefix(&old_prefix) {
            if !current.exists() && is_run_id(id) && std::fs::rename(entry.path(), &current).is_ok()
            {
                tracing::warn!(
                    "put the previous calibration back into {} from {name} (a crash while it was replaced)",
                    current.display()
                );
                continue;
            }
            id
        } else if let Some(id) = name.strip_prefix(&staging_prefix) {
            if keep == Some(id) {
                continue;
            }
            id
        } else {
            continue;
        };
        // Only our own folders (a run id, a real folder, not a link).
        let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
        if is_run_id(id) && is_dir && std::fs::remove_dir_all(entry.path()).is_ok() {
            removed.push(entry.path());
        }
    }
    removed
}

/// Whether `name` is a temporary file of [`super::write_atomically`] or of a raw scan being
/// saved (`<name>.tmp`).
pub(super) fn is_temporary(name: &str) -> bool {
    name.len() > ".tmp".len() && name.ends_with(".tmp")
}

/// Removes the temporary files (`*.tmp`, regular files only; links and folders are left
/// alone) a killed writer left in `dir`. Returns what was removed.
fn remove_temporary_files_in(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut removed = Vec::new();
    for entry in entries.flatten() {
        let is_file = entry.file_type().is_ok_and(|t| t.is_file());
        if is_file
            && is_temporary(&entry.file_name().to_string_lossy())
            && std::fs::remove_file(entry.path()).is_ok()
        {
            removed.push(entry.path());
        }
    }
    removed
}

/// Removes the temporary files (`*.tmp`) a kill left in the storage directory and in every
/// run folder (a real folder under a real `runs/`; links are not followed). Only for a
/// process that knows no other one writes there (the history's sole writer, at its start):
/// a live writer's temporary file is about to be renamed. Returns what was removed.
/// Blocking I/O.
pub fn remove_temporary_files(storage: &Path) -> Vec<PathBuf> {
    let mut removed = remove_temporary_files_in(storage);
    let runs = storage.join(RUNS_DIR);
    if !is_real_dir(&runs) {
        return removed;
    }
    let Ok(entries) = std::fs::read_dir(&runs) else {
        return removed;
    };
    for entry in entries.flatten() {
        let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
        if is_dir && is_run_id(&entry.file_name().to_string_lossy()) {
            removed.extend(remove_temporary_files_in(&entry.path()));
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Dir(PathBuf);
    impl Drop for Dir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    /// A storage folder with what a kill leaves: temporary files in the storage folder and in
    /// two run folders, beside a record, a raw scan, a link and a folder named `*.tmp`.
    fn killed_storage(tag: &str) -> (Dir, Vec<PathBuf>) {
        let d =
            std::env::temp_dir().join(format!("handeye-leftovers-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        let runs = d.join(RUNS_DIR);
        let a = runs.join("20261128T000000Z-0001");
        let b = runs.join("20261128T000000Z-0002");
        for dir in [&a, &b] {
            std::fs::create_dir_all(dir).expect("run folder");
        }
        let temporary = vec![
            d.join("writeback-journal.json.tmp"),
            a.join("record.json.tmp"),
            b.join("view0_frame0.ply.tmp"),
        ];
        for (i, p) in temporary.iter().enumerate() {
            std::fs::write(p, format!("half {i}")).expect("tmp");
        }
        std::fs::write(a.join("record.json"), "{}").expect("record");
        std::fs::write(b.join("view0_frame0.ply"), "ply").expect("scan");
        std::fs::create_dir_all(a.join("folder.tmp")).expect("folder");
        let outside = d.join("outside");
        std::fs::write(&outside, "not ours").expect("outside");
        #[cfg(unix)]
        std::os::unix::fs::symlink(&outside, b.join("link.tmp")).expect("link");
        (Dir(d), temporary)
    }

    /// What is left of the storage's files and links (not folders), relative.
    fn files(root: &Path) -> Vec<String> {
        let mut out = Vec::new();
        let mut dirs = vec![root.to_path_buf()];
        while let Some(dir) = dirs.pop() {
            for e in std::fs::read_dir(&dir).expect("dir").flatten() {
                let t = e.file_type().expect("type");
                if t.is_dir() {
                    dirs.push(e.path());
                } else {
                    let rel = e.path().strip_prefix(root).expect("rel").to_path_buf();
                    out.push(rel.display().to_string());
                }
            }
        }
        out.sort();
        out
    }

    /// Issue 46: the `*.tmp` files a kill leaves in the storage and run folders are removed
    /// when the history is opened by its sole writer (the daemon's or `calibrate`'s start):
    /// regular files only, links and folders left alone.
    #[test]
    fn issue_46_temporary_files_a_kill_left_are_removed_at_start() {
        let (d, temporary) = killed_storage("start");
        let store =
            crate::run::open_history(&d.0.join(crate::store::HISTORY_FILE)).expect("history");
        drop(store);
        for p in &temporary {
            assert!(!p.exists(), "{} left", p.display());
        }
        let left = files(&d.0);
        for kept in [
            "runs/20261128T000000Z-0001/record.json",
            "runs/20261128T000000Z-0002/view0_frame0.ply",
            "runs/20261128T000000Z-0002/link.tmp",
            "outside",
        ] {
            assert!(left.iter().any(|f| f == kept), "{kept} removed: {left:?}");
        }
        assert!(d.0.join("runs/20261128T000000Z-0001/folder.tmp").is_dir());
        assert_eq!(
            std::fs::read_to_string(d.0.join("outside")).expect("outside"),
            "not ours"
        );
    }

    /// Issue 46: pruning a run's raw scans removes the temporary files a kill left in its
    /// folder too.
    #[test]
    fn issue_46_pruning_removes_temporary_files() {
        let (d, temporary) = killed_storage("prune");
        let removed =
            super::super::remove_raw_captures(&d.0, "20261128T000000Z-0002").expect("pruned");
        assert!(removed.contains(&temporary[2]), "{removed:?}");
        assert!(!temporary[2].exists());
        assert!(d
            .0
            .join("runs/20261128T000000Z-0002/link.tmp")
            .symlink_metadata()
            .is_ok());
    }
}
