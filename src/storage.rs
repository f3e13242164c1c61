//! The run folder, one owner: every file a run leaves under the configured storage directory,
//! how it is written, and how old raw scans are removed.
//!
//! ```text
//! <storage>/runs/<run_id>/record.json        the run record (every run)
//! <storage>/runs/<run_id>/capture.json       joints and flange poses per view (replay)
//! <storage>/runs/<run_id>/view<V>_frame<F>.ply  the raw scans (when kept; pruned later)
//! <storage>/runs/<run_id>/result.*           the exports of an accepted calibration
//! <storage>/runs/<run_id>/report.png         the report picture (every run)
//! <storage>/current/                         the exports of the last accepted calibration
//! ```
//!
//! Every file goes through [`write_atomically`] (a temporary file, flushed to disk, renamed over
//! the name, the folder flushed too), so a crash or a power loss leaves the old file or the new
//! one, never half of one; `current/` is replaced as a whole.

use std::path::{Path, PathBuf};

use handeye_hal::PointCloud;
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::calib::export::{ExportMeta, Exports};
use crate::calib::Mount;
use crate::record::{CaptureRecord, ResultRecord, RunRecord};

/// Folder of the per-run folders.
pub const RUNS_DIR: &str = "runs";
/// Folder of the last accepted calibration.
pub const CURRENT_DIR: &str = "current";
/// The replay file in a run's folder.
pub const CAPTURE_FILE: &str = "capture.json";
/// The run record in a run's folder.
pub const RECORD_FILE: &str = "record.json";
/// The machine-readable result in a run's folder and in `current/`.
pub const CALIBRATION_FILE: &str = "calibration.json";
/// The report picture in a run's folder.
pub const REPORT_PICTURE: &str = "report.png";

/// What `capture.json` holds: enough to replay a run with `handeye solve --capture`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CaptureFile {
    /// Robot model name.
    pub model: String,
    /// Eye-in-hand or eye-to-hand.
    pub mount: Mount,
    /// Frame of the flange poses (`base`: the UR controller's).
    pub base_frame: String,
    /// The guess the run registered with: eye-in-hand `flange_from_camera`, eye-to-hand
    /// `base_from_camera` (in `base_frame`), 4×4.
    #[serde(default)]
    pub prior: Option<[[f64; 4]; 4]>,
    /// The controller's calibrated kinematics the run posed the model by (`None`: nominal).
    #[serde(default)]
    pub controller_dh: Option<handeye_hal::ur_dh::DhParams>,
    /// Whether `controller_dh` is the controller's own, which computed the flange poses: they
    /// must then be its forward kinematics to the millimetre. False for a calibration file's
    /// DH, and in captures written before this was recorded (checked against the nominal URDF).
    #[serde(default)]
    pub dh_from_controller: bool,
    /// One entry per view, with its frames' file paths.
    pub views: Vec<CaptureRecord>,
}

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

/// A run id: UTC start time to the second and a random suffix (`20261124T142300Z-3f9a`).
pub fn new_run_id() -> String {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    let (y, m, d, hh, mm, ss) = crate::calendar::utc_fields(now.as_secs() as i64);
    let suffix = (now.subsec_nanos() ^ std::process::id().rotate_left(16)) & 0xffff;
    format!("{y:04}{m:02}{d:02}T{hh:02}{mm:02}{ss:02}Z-{suffix:04x}")
}

/// Whether `id` can be a run id, and so one folder name under `runs/`: 1–64 letters, digits,
/// `-` and `_` (what [`new_run_id`] makes; never `.`, `..` or a path).
pub fn is_run_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= 64
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
}

/// The folder of run `run_id` in `storage`; `None` when `run_id` is not a run id (an id from
/// outside: a URL, a history row).
pub fn run_dir(storage: &Path, run_id: &str) -> Option<PathBuf> {
    is_run_id(run_id).then(|| run_folder(storage, run_id))
}

/// The folder of a run this program names ([`new_run_id`], checked with [`is_run_id`]).
pub(crate) fn run_folder(storage: &Path, run_id: &str) -> PathBuf {
    storage.join(RUNS_DIR).join(run_id)
}

/// The report picture of run `run_id` in `storage`; `None` when `run_id` is not a run id.
pub fn report_picture_path(storage: &Path, run_id: &str) -> Option<PathBuf> {
    run_dir(storage, run_id).map(|d| d.join(REPORT_PICTURE))
}

/// The temporary file `path` is written as before it is renamed over `path`: `<path>.tmp`.
fn temporary(path: &Path) -> PathBuf {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    PathBuf::from(tmp)
}

/// Writes `bytes` to `path` durably and atomically: `path.tmp` beside it (the folder created
/// if missing), flushed to disk, renamed over `path`, then the folder flushed so the rename
/// survives a power loss. On failure the temporary file is removed and `path` is untouched.
/// Blocking I/O.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write as _;
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
    if let Some(dir) = dir {
        std::fs::create_dir_all(dir)?;
    }
    let tmp = temporary(path);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        #[cfg(test)]
        tests::stall_before_rename(path);
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result?;
    // The rename is durable once the folder is (not every platform opens a folder: best effort).
    if let Ok(d) = std::fs::File::open(dir.unwrap_or(Path::new("."))) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Writes every export file into `dir`, each with [`write_atomically`]; returns their paths.
fn write_exports(dir: &Path, exports: &Exports) -> std::io::Result<Vec<PathBuf>> {
    exports
        .files()
        .into_iter()
        .map(|(name, contents)| {
            let path = dir.join(name);
            write_atomically(&path, contents.as_bytes()).map(|()| path)
        })
        .collect()
}

fn json<T: Serialize>(value: &T) -> std::io::Result<Vec<u8>> {
    serde_json::to_vec_pretty(value).map_err(std::io::Error::other)
}

/// Writes the run record.
pub(crate) fn write_record(run_dir: &Path, record: &RunRecord) -> std::io::Result<()> {
    write_atomically(&run_dir.join(RECORD_FILE), &json(record)?)
}

/// Writes the run's report picture (PNG bytes) into its folder.
pub(crate) fn write_report_picture(run_dir: &Path, png: &[u8]) -> std::io::Result<()> {
    write_atomically(&run_dir.join(REPORT_PICTURE), png)
}

/// Keeps one raw frame as a binary PLY; returns its path.
pub(crate) fn save_frame(
    run_dir: &Path,
    view: usize,
    frame: usize,
    cloud: &PointCloud,
) -> Result<PathBuf, crate::cloud::CloudError> {
    std::fs::create_dir_all(run_dir).map_err(|source| crate::cloud::CloudError::Io {
        action: "create",
        path: run_dir.to_path_buf(),
        source,
    })?;
    let path = run_dir.join(format!("view{view}_frame{frame}.ply"));
    // Through a temporary file, removed when the write fails (a full disk keeps nothing).
    let tmp = temporary(&path);
    if let Err(e) = crate::cloud::write_ply(&tmp, cloud, Default::default()) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, &path).map_err(|source| {
        let _ = std::fs::remove_file(&tmp);
        crate::cloud::CloudError::Io {
            action: "rename",
            path: path.clone(),
            source,
        }
    })?;
    Ok(path)
}

/// Largest `capture.json` read (a run with many views is a few hundred kB).
const MAX_CAPTURE_FILE_BYTES: u64 = 64 << 20;

/// Writes `capture.json`; returns its path.
pub(crate) fn write_capture_file(
    run_dir: &Path,
    capture: &CaptureFile,
) -> std::io::Result<PathBuf> {
    let path = run_dir.join(CAPTURE_FILE);
    write_atomically(&path, &json(capture)?)?;
    Ok(path)
}

/// Reads a `capture.json` written by a run (its frame paths are absolute or relative to it).
pub fn load_capture(path: &Path) -> Result<CaptureFile, String> {
    // A regular file of bounded size: a FIFO would block the read forever.
    let text = handeye_hal::limits::read_text_file(path, MAX_CAPTURE_FILE_BYTES)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    parse_capture(&text, path)
}

/// Parses the text of a capture file (`path` names it in messages). Its content is checked
/// against a robot model by `solve --capture`.
pub fn parse_capture(text: &str, path: &Path) -> Result<CaptureFile, String> {
    serde_json::from_str(text).map_err(|e| {
        format!(
            "{} is not a capture file written by a handeye run: {}",
            path.display(),
            handeye_hal::limits::sanitize_message(&e.to_string())
        )
    })
}

/// Largest `record.json` read back (a record is tens of kB).
const MAX_RECORD_FILE_BYTES: u64 = 16 << 20;

/// A `record.json` read back: bounded in size, parsed.
fn read_record_file(path: &Path) -> Result<RunRecord, String> {
    handeye_hal::limits::read_text_file(path, MAX_RECORD_FILE_BYTES)
        .map_err(|e| e.to_string())
        .and_then(|text| serde_json::from_str::<RunRecord>(&text).map_err(|e| e.to_string()))
}

/// The records of every run folder under `storage` (`runs/<id>/record.json`), oldest first;
/// a folder whose record is missing or does not read back is skipped with a warning.
pub fn run_records(storage: &Path) -> Vec<RunRecord> {
    let runs = storage.join(RUNS_DIR);
    let Ok(entries) = std::fs::read_dir(&runs) else {
        return Vec::new();
    };
    let mut records = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name();
        if !is_run_id(&name.to_string_lossy()) {
            continue;
        }
        let path = entry.path().join(RECORD_FILE);
        match read_record_file(&path) {
            Ok(record) => records.push(record),
            Err(e) => tracing::warn!("skipping {}: {e}", path.display()),
        }
    }
    records.sort_by(|a, b| a.started_unix_s.total_cmp(&b.started_unix_s));
    records
}

/// The record of run `run_id` in `storage` (`runs/<id>/record.json`); `None` (logged unless
/// absent) when it cannot be read.
pub fn read_run_record(storage: &Path, run_id: &str) -> Option<RunRecord> {
    let path = run_dir(storage, run_id)?.join(RECORD_FILE);
    if !path.exists() {
        return None;
    }
    match read_record_file(&path) {
        Ok(r) => Some(r),
        Err(e) => {
            tracing::warn!("cannot read {}: {e}", path.display());
            None
        }
    }
}

/// The last accepted calibration in `storage` for `mount`, with where it came from and the
/// controller it was made on.
pub fn load_current(storage: &Path, mount: Mount) -> Option<Current> {
    let path = storage.join(CURRENT_DIR).join(CALIBRATION_FILE);
    let text = std::fs::read_to_string(&path).ok()?;
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
        timestamp: record.run_id.clone(),
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

/// Room a run needs besides its raw scans: record, capture file, exports, report picture and
/// history row (together a few hundred kB), with margin for the temporary copies.
pub const RUN_BASE_BYTES: u64 = 4 << 20;
/// Bytes per point of a kept raw scan at most: binary PLY with x, y, z, intensity and
/// confidence as 32-bit floats.
const RAW_SCAN_BYTES_PER_POINT: u64 = 20;
/// The probe file [`check_room`] writes and removes.
const PROBE_FILE: &str = ".probe";

/// What a run keeps in storage at most, bytes: [`RUN_BASE_BYTES`] plus, when raw scans are
/// kept, `frames` scans of `width` × `height` points.
pub fn run_bytes(width: u32, height: u32, frames: usize, keep_captures: bool) -> u64 {
    let scans = if keep_captures {
        u64::from(width)
            .saturating_mul(u64::from(height))
            .saturating_mul(RAW_SCAN_BYTES_PER_POINT)
            .saturating_add(4096)
            .saturating_mul(frames as u64)
    } else {
        0
    };
    RUN_BASE_BYTES.saturating_add(scans)
}

/// Why the storage directory cannot take a run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StorageUnusable {
    /// Not enough free space for what the run keeps.
    #[error("the storage directory {} has {:.1} MB free and a run needs about {:.1} MB; free space there (old run folders under runs/) or set `[storage] dir` to a larger disk", .dir.display(), mb(*.available), mb(*.needed))]
    Full {
        /// The storage directory.
        dir: PathBuf,
        /// Free bytes for this user.
        available: u64,
        /// Bytes the run keeps at most ([`run_bytes`]).
        needed: u64,
    },
    /// A file could not be written (read-only, no permission, disk full).
    #[error(transparent)]
    Unwritable(#[from] StorageError),
}

fn mb(bytes: u64) -> f64 {
    bytes as f64 / 1e6
}

/// Checks that `dir` can take a run keeping `needed` bytes: the folder exists or is created,
/// a small file can be written durably there (then removed), and the free space for this user
/// is at least `needed`. Blocking I/O (one fsync).
pub fn check_room(dir: &Path, needed: u64) -> Result<(), StorageUnusable> {
    let io = |action: &'static str, path: &Path| {
        let path = path.to_path_buf();
        move |source| StorageError {
            action,
            path,
            source,
        }
    };
    std::fs::create_dir_all(dir).map_err(io("create", dir))?;
    let available = available_bytes(dir).map_err(io("read the free space of", dir))?;
    if available < needed {
        return Err(StorageUnusable::Full {
            dir: dir.to_path_buf(),
            available,
            needed,
        });
    }
    let probe = dir.join(PROBE_FILE);
    write_atomically(&probe, &[0; 512]).map_err(io("write", &probe))?;
    std::fs::remove_file(&probe).map_err(io("remove", &probe))?;
    Ok(())
}

/// Free bytes on the file system of `dir` for an unprivileged user (`statvfs`).
#[cfg(unix)]
fn available_bytes(dir: &Path) -> std::io::Result<u64> {
    use std::os::unix::ffi::OsStrExt as _;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes())
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
    // SAFETY: `path` is a NUL-terminated string and `st` a plain C struct statvfs fills.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    if unsafe { libc::statvfs(path.as_ptr(), &mut st) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    #[allow(clippy::unnecessary_cast)] // the field types differ between platforms
    Ok((st.f_bavail as u64).saturating_mul(st.f_frsize as u64))
}

/// Without `statvfs`, the probe write of [`check_room`] is the only check.
#[cfg(not(unix))]
fn available_bytes(_dir: &Path) -> std::io::Result<u64> {
    Ok(u64::MAX)
}

/// A raw scan a run kept: `view<V>_frame<F>.ply`.
fn is_raw_capture(name: &str) -> bool {
    name.starts_with("view") && name.contains("_frame") && name.ends_with(".ply")
}

/// Why the run folder could not be read or changed.
#[derive(Debug, thiserror::Error)]
#[error("cannot {action} {}: {source}; check that the storage directory (`[storage] dir`) exists and is writable by this user", .path.display())]
pub struct StorageError {
    /// What was attempted.
    pub action: &'static str,
    /// The file or folder.
    pub path: PathBuf,
    /// The operating system's error.
    #[source]
    pub source: std::io::Error,
}

/// Deletes the raw scans (`view*_frame*.ply`) of run `run_id`; its record, `capture.json`
/// and results stay. A missing folder is nothing to do; an id that is not a run id is left
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
    let entries = match std::fs::read_dir(&dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(io("read the folder", &dir)(e)),
    };
    let mut removed = Vec::new();
    for entry in entries {
        let entry = entry.map_err(io("read the folder", &dir))?;
        if !is_raw_capture(&entry.file_name().to_string_lossy()) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::RunMode;
    use std::time::{Duration, Instant};

    /// Names the file whose write stops between the flushed temporary file and the rename.
    const STALL_ENV: &str = "HANDEYE_TEST_STALL_BEFORE_RENAME";
    /// Set in the child process of the crash test: the folder it writes into.
    const CHILD_ENV: &str = "HANDEYE_TEST_STORAGE_CHILD";

    /// Test hook of [`write_atomically`]: with [`STALL_ENV`] naming `path`'s file name, the
    /// write leaves `<path>.stalled` as a sign and waits forever before the rename (to be
    /// killed there).
    pub(super) fn stall_before_rename(path: &Path) {
        let Ok(name) = std::env::var(STALL_ENV) else {
            return;
        };
        if path.file_name().is_some_and(|n| n == name.as_str()) {
            let _ = std::fs::write(path.with_extension("stalled"), b"");
            loop {
                std::thread::sleep(Duration::from_secs(1));
            }
        }
    }

    fn temp_dir(tag: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("handeye-storage-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("dir");
        dir
    }

    /// The id of the record in `dir`, which must parse whole.
    fn read_record(dir: &Path) -> String {
        let text = std::fs::read_to_string(dir.join(RECORD_FILE)).expect("record.json");
        let record: RunRecord =
            serde_json::from_str(&text).unwrap_or_else(|e| panic!("a torn record ({e}): {text}"));
        record.run_id
    }

    #[test]
    fn run_ids_carry_the_utc_date_and_name_one_folder() {
        let id = new_run_id();
        assert_eq!(id.len(), "20261124T142300Z-3f9a".len(), "{id}");
        assert!(id.as_bytes()[8] == b'T' && id.contains("Z-"), "{id}");
        assert!(is_run_id(&id));
        for bad in ["", ".", "..", "../x", "a/b", "a b", "x%2F", &"a".repeat(65)] {
            assert!(!is_run_id(bad), "{bad}");
            assert_eq!(run_dir(Path::new("/s"), bad), None, "{bad}");
        }
        assert_eq!(
            report_picture_path(Path::new("/s"), &id),
            Some(PathBuf::from(format!("/s/runs/{id}/report.png")))
        );
    }

    /// A `kill -9` between the record's write and its rename leaves the old record whole (and
    /// the next write replaces it), never a torn one.
    #[test]
    fn a_kill_between_write_and_rename_leaves_the_old_or_the_new_record() {
        if let Ok(dir) = std::env::var(CHILD_ENV) {
            let new = RunRecord::starting("new".into(), RunMode::Check, false, "child".into());
            let _ = write_record(Path::new(&dir), &new);
            return;
        }
        let dir = temp_dir("crash");
        let old = RunRecord::starting("old".into(), RunMode::Calibrate, false, "parent".into());
        write_record(&dir, &old).expect("old record");
        let mut child = std::process::Command::new(std::env::current_exe().expect("test binary"))
            .args([
                "--exact",
                "storage::tests::a_kill_between_write_and_rename_leaves_the_old_or_the_new_record",
                "--test-threads=1",
                "--nocapture",
            ])
            .env(CHILD_ENV, &dir)
            .env(STALL_ENV, RECORD_FILE)
            .stdout(std::process::Stdio::null())
            .spawn()
            .expect("child");
        let sign = dir.join(RECORD_FILE).with_extension("stalled");
        let t = Instant::now();
        while !sign.exists() {
            assert!(
                t.elapsed() < Duration::from_secs(60),
                "the child never reached the rename"
            );
            if let Some(status) = child.try_wait().expect("child") {
                panic!("the child ended before the rename: {status}");
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        child.kill().expect("kill -9"); // SIGKILL on unix
        child.wait().expect("reaped");
        assert_eq!(read_record(&dir), old.run_id, "the old record, whole");
        // The new one was complete on disk beside it, only not yet renamed.
        let mut tmp = dir.join(RECORD_FILE).into_os_string();
        tmp.push(".tmp");
        let text = std::fs::read_to_string(&tmp).expect("temporary file");
        let pending: RunRecord = serde_json::from_str(&text).expect("complete");
        assert_eq!(pending.run_id, "new");
        // The next write goes through and leaves no temporary file behind.
        let newer = RunRecord::starting("newer".into(), RunMode::Check, false, "parent".into());
        write_record(&dir, &newer).expect("newer record");
        assert_eq!(read_record(&dir), newer.run_id);
        assert!(!PathBuf::from(tmp).exists());
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }

    #[test]
    fn exports_are_written_atomically() {
        use crate::calib::export::RESULT_JSON;
        let dir = temp_dir("exports");
        let meta = || ExportMeta {
            run_id: "r".into(),
            outcome: "accepted".into(),
            uncertainty_translation_mm: 0.1,
            uncertainty_rotation_deg: 0.01,
            timestamp: "r".into(),
        };
        let p = Isometry3::translation(0.0, -0.08, 0.04);
        let e = Exports::new(&p, "tool0", "camera", meta());
        let paths = write_exports(&dir.join("run"), &e).expect("written");
        assert_eq!(paths.len(), 5);
        for ((name, contents), path) in e.files().into_iter().zip(&paths) {
            assert_eq!(path.file_name().and_then(|n| n.to_str()), Some(name));
            assert_eq!(std::fs::read_to_string(path).expect("read"), contents);
        }
        // Overwriting replaces the files and leaves no temporary behind.
        let e2 = Exports::new(&p.inverse(), "tool0", "camera", meta());
        write_exports(&dir.join("run"), &e2).expect("rewritten");
        let names: Vec<String> = std::fs::read_dir(dir.join("run"))
            .expect("dir")
            .map(|d| d.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names.len(), 5, "{names:?}");
        assert!(names.iter().all(|n| !n.ends_with(".tmp")));
        assert_eq!(
            std::fs::read_to_string(dir.join("run").join(RESULT_JSON)).expect("read"),
            e2.json()
        );
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }
}
