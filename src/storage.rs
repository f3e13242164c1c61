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
//! <storage>/writeback-journal.json           a write-back in progress (journal_file.rs)
//! ```
//!
//! Every file goes through [`write_atomically`] (a temporary file, flushed to disk, renamed over
//! the name, the folder flushed too), so a crash or a power loss leaves the old file or the new
//! one, never half of one; `current/` is replaced as a whole.

pub mod owner;

use std::path::{Path, PathBuf};

use handeye_hal::PointCloud;
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

mod journal_file;
mod leftovers;

pub(crate) use journal_file::{
    journal_unrecorded, mark_journal_unrecorded, mark_run_unrecorded, read_journal, remove_journal,
    set_aside_journal, write_journal, JournalLock,
};
pub use journal_file::{run_unrecorded, JOURNAL_FILE};
pub(crate) use leftovers::clean_staging;
pub use leftovers::remove_temporary_files;

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
    let stamp = crate::calendar::utc_stamp(now.as_secs() as i64);
    let suffix = (now.subsec_nanos() ^ std::process::id().rotate_left(16)) & 0xffff;
    format!("{stamp}-{suffix:04x}")
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
        let mut f = create_fresh(&tmp)?;
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

/// Creates `path` as a new, empty regular file: whatever had its name before (a file left by
/// a crash, or a link planted there) is removed first — never followed — and the file is
/// created exclusively (`O_EXCL`, `O_NOFOLLOW`), so a write never lands outside the folder.
fn create_fresh(path: &Path) -> std::io::Result<std::fs::File> {
    match std::fs::remove_file(path) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(e),
    }
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt as _;
        options.custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC);
    }
    options.open(path)
}

/// Reads the file `rel` (plain names, no `..`) beneath the storage directory `storage` the
/// way every file in the storage folder is read back: no link is followed on the way (each
/// folder opened with `openat(O_NOFOLLOW | O_DIRECTORY)` from the one above, the file with
/// `O_NOFOLLOW | O_NONBLOCK`, so a FIFO never blocks), only a regular file is read, and at
/// most `max` bytes of it (a larger one is refused before reading). Blocking I/O.
pub fn read_beneath(storage: &Path, rel: &Path, max: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read as _;
    let file = open_beneath(storage, rel)?;
    let meta = file.metadata()?;
    let shown = storage.join(rel);
    if !meta.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "{} is not a regular file (a folder, FIFO, socket or device was put there); remove it",
                shown.display()
            ),
        ));
    }
    if meta.len() > max {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "{} holds {} bytes, more than the {max} a handeye file has at most; remove it",
                shown.display(),
                meta.len()
            ),
        ));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(max.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("{} grew beyond {max} bytes while read", shown.display()),
        ));
    }
    Ok(bytes)
}

/// [`read_beneath`] as UTF-8 text.
pub fn read_text_beneath(storage: &Path, rel: &Path, max: u64) -> std::io::Result<String> {
    String::from_utf8(read_beneath(storage, rel, max)?)
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))
}

/// Opens `rel` beneath `storage` without following links (see [`read_beneath`]).
#[cfg(unix)]
fn open_beneath(storage: &Path, rel: &Path) -> std::io::Result<std::fs::File> {
    use std::os::fd::{AsRawFd as _, FromRawFd as _, OwnedFd};
    use std::os::unix::ffi::OsStrExt as _;
    use std::os::unix::fs::OpenOptionsExt as _;
    let names: Vec<&std::ffi::OsStr> = rel
        .components()
        .map(|c| match c {
            std::path::Component::Normal(n) => Ok(n),
            _ => Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "`{}` is not a path beneath the storage folder",
                    rel.display()
                ),
            )),
        })
        .collect::<Result<_, _>>()?;
    let Some((last, folders)) = names.split_last() else {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "an empty path",
        ));
    };
    // The storage directory itself is the configured one (it may be a link its owner made).
    let mut dir: OwnedFd = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_DIRECTORY | libc::O_CLOEXEC)
        .open(storage)?
        .into();
    let at = |dir: &OwnedFd, name: &std::ffi::OsStr, flags: i32| -> std::io::Result<OwnedFd> {
        let c = std::ffi::CString::new(name.as_bytes())
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
        // SAFETY: a valid directory descriptor and a NUL-terminated name; the returned
        // descriptor is owned once checked.
        let fd = unsafe { libc::openat(dir.as_raw_fd(), c.as_ptr(), flags) };
        if fd < 0 {
            let e = std::io::Error::last_os_error();
            return Err(match e.raw_os_error() {
                Some(libc::ELOOP) | Some(libc::ENOTDIR) => std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    format!(
                        "{} is a symbolic link or not a folder where one is expected (files in the storage folder are never followed); remove it",
                        storage.join(rel).display()
                    ),
                ),
                _ => e,
            });
        }
        // SAFETY: `fd` is a new descriptor nobody else owns.
        Ok(unsafe { OwnedFd::from_raw_fd(fd) })
    };
    for name in folders {
        dir = at(
            &dir,
            name,
            libc::O_RDONLY | libc::O_DIRECTORY | libc::O_NOFOLLOW | libc::O_CLOEXEC,
        )?;
    }
    let fd = at(
        &dir,
        last,
        libc::O_RDONLY | libc::O_NOFOLLOW | libc::O_NONBLOCK | libc::O_CLOEXEC,
    )?;
    Ok(std::fs::File::from(fd))
}

/// Without `openat`: the bounded reader of regular files.
#[cfg(not(unix))]
fn open_beneath(storage: &Path, rel: &Path) -> std::io::Result<std::fs::File> {
    std::fs::File::open(storage.join(rel))
}

/// Whether `path` is a real folder (not a link to one).
fn is_real_dir(path: &Path) -> bool {
    std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_dir())
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

/// Largest report picture read back (a picture is a few hundred kB).
pub const MAX_PICTURE_BYTES: u64 = 32 << 20;

/// Largest `record.json` read back (a record is tens of kB).
const MAX_RECORD_FILE_BYTES: u64 = 16 << 20;

/// Run `run_id`'s `record.json` read back (beneath `storage`, no link followed, bounded in
/// size), parsed, and checked to be that run's: its id is the folder's and its start is not
/// in the future (a record planted there never passes for a run).
fn read_record_file(storage: &Path, run_id: &str) -> Result<RunRecord, String> {
    let rel = Path::new(RUNS_DIR).join(run_id).join(RECORD_FILE);
    let text =
        read_text_beneath(storage, &rel, MAX_RECORD_FILE_BYTES).map_err(|e| e.to_string())?;
    let record = serde_json::from_str::<RunRecord>(&text).map_err(|e| e.to_string())?;
    if record.run_id != run_id {
        return Err(format!(
            "it names run `{}`, not its folder's run; not a record of this storage",
            handeye_hal::limits::sanitize_message(&record.run_id)
        ));
    }
    let now = crate::calendar::unix_now();
    if !(record.started_unix_s.is_finite() && record.started_unix_s <= now + MAX_CLOCK_AHEAD_S) {
        return Err(format!(
            "it says the run started at {}, after now; not a record this program wrote",
            record.started_unix_s
        ));
    }
    Ok(record)
}

pub use crate::calendar::MAX_CLOCK_AHEAD_S;

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
        match read_record_file(storage, &name.to_string_lossy()) {
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
    if std::fs::symlink_metadata(&path).is_err() {
        return None;
    }
    match read_record_file(storage, run_id) {
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

/// Space kept in reserve (`<storage>/space-reserve`) for the end of a run: when the disk
/// fills during a run, its final record and history row are written after the reserve is
/// released (`release_reserve`), so a result the controller took is never left unrecorded.
pub const RESERVE_BYTES: u64 = 2 << 20;
const RESERVE_FILE: &str = "space-reserve";

/// Makes sure the reserve is there (written, not sparse, so the space is really taken).
/// Blocking I/O.
pub(crate) fn keep_reserve(storage: &Path) -> std::io::Result<()> {
    let path = storage.join(RESERVE_FILE);
    if std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_file() && m.len() == RESERVE_BYTES) {
        return Ok(());
    }
    write_atomically(&path, &vec![0u8; RESERVE_BYTES as usize])
}

/// Frees the reserve for the end of a run on a full disk; whether there was one.
pub(crate) fn release_reserve(storage: &Path) -> bool {
    let released = std::fs::remove_file(storage.join(RESERVE_FILE)).is_ok();
    if released {
        tracing::warn!(
            "the storage {} is full: its {} MB reserve was released to record the end of the run; free space there",
            storage.display(),
            RESERVE_BYTES >> 20
        );
    }
    released
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

    /// Issue 36: links and special files planted in the storage folder are never followed:
    /// a write's temporary file, reads (a link, a FIFO, a file too large) and pruning.
    #[cfg(unix)]
    #[test]
    fn issue_36_planted_links_and_special_files_are_not_followed() {
        use std::os::unix::fs::symlink;
        let dir = temp_dir("planted");
        let storage = dir.join("storage");
        let outside = dir.join("outside");
        std::fs::create_dir_all(storage.join(RUNS_DIR)).expect("storage");
        std::fs::create_dir_all(&outside).expect("outside");
        let victim = outside.join("victim");
        std::fs::write(&victim, "keep").expect("victim");
        // The check's probe: its temporary file planted as a link.
        symlink(&victim, storage.join(".probe.tmp")).expect("link");
        check_room(&storage, 0).expect("room");
        assert_eq!(std::fs::read_to_string(&victim).expect("victim"), "keep");
        // Reads: a link, a FIFO (must not block), a file beyond the bound.
        std::fs::create_dir_all(storage.join(CURRENT_DIR)).expect("current");
        let current = storage.join(CURRENT_DIR).join(CALIBRATION_FILE);
        let rel = Path::new(CURRENT_DIR).join(CALIBRATION_FILE);
        symlink("/dev/zero", &current).expect("link");
        let e = read_beneath(&storage, &rel, 1 << 20).expect_err("a link");
        assert!(e.to_string().contains("symbolic link"), "{e}");
        assert_eq!(load_current(&storage, Mount::EyeInHand), None);
        std::fs::remove_file(&current).expect("rm");
        let c = std::ffi::CString::new(current.to_str().expect("utf-8")).expect("c");
        // SAFETY: a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let t = Instant::now();
        let e = read_beneath(&storage, &rel, 1 << 20).expect_err("a FIFO");
        assert!(e.to_string().contains("not a regular file"), "{e}");
        assert_eq!(load_current(&storage, Mount::EyeInHand), None);
        assert!(t.elapsed() < Duration::from_secs(1));
        std::fs::remove_file(&current).expect("rm");
        std::fs::File::create(&current)
            .and_then(|f| f.set_len(2 << 20))
            .expect("large");
        let e = read_beneath(&storage, &rel, 1 << 20).expect_err("too large");
        assert!(e.to_string().contains("more than"), "{e}");
        // A folder on the way as a link.
        std::fs::remove_dir_all(storage.join(CURRENT_DIR)).expect("rm");
        std::fs::create_dir_all(outside.join("cur")).expect("dir");
        std::fs::write(outside.join("cur").join(CALIBRATION_FILE), "{}").expect("file");
        symlink(outside.join("cur"), storage.join(CURRENT_DIR)).expect("link");
        assert!(read_beneath(&storage, &rel, 1 << 20).is_err());
        // Pruning: a run folder replaced by a link to a folder outside.
        let scan = outside.join("view0_frame0.ply");
        std::fs::write(&scan, "keep").expect("scan");
        symlink(
            &outside,
            storage.join(RUNS_DIR).join("20261128T000000Z-0001"),
        )
        .expect("link");
        let removed = remove_raw_captures(&storage, "20261128T000000Z-0001").expect("prune");
        assert!(removed.is_empty(), "{removed:?}");
        assert_eq!(std::fs::read_to_string(&scan).expect("scan"), "keep");
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }

    /// Issue 36: a record planted in a run folder — dated after now, or naming another run —
    /// is not taken for a run when the history is rebuilt.
    #[test]
    fn issue_36_forged_records_are_not_runs() {
        let dir = temp_dir("forged");
        let good = RunRecord::starting(new_run_id(), RunMode::Calibrate, false, "t".into());
        write_record(&run_folder(&dir, &good.run_id), &good).expect("good");
        let mut future = RunRecord::starting(
            "20991231T000000Z-ffff".into(),
            RunMode::Calibrate,
            false,
            "t".into(),
        );
        future.started_unix_s = 4_102_444_800.0;
        write_record(&run_folder(&dir, &future.run_id), &future).expect("future");
        let other = RunRecord::starting(good.run_id.clone(), RunMode::Calibrate, false, "t".into());
        write_record(&run_folder(&dir, "20261128T000000Z-0002"), &other).expect("other");
        let ids: Vec<String> = run_records(&dir).into_iter().map(|r| r.run_id).collect();
        assert_eq!(ids, vec![good.run_id.clone()]);
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }

    /// Issue 42 (item 7): `result.json`'s `timestamp` is when the run started, ISO 8601 in
    /// UTC; it held the run id.
    #[test]
    fn issue_42_the_results_timestamp_is_an_iso_8601_time() {
        let dir = temp_dir("timestamp");
        let mut record = RunRecord::starting(
            "20261128T090525Z-64c5".into(),
            RunMode::Calibrate,
            false,
            "c.toml".into(),
        );
        record.started_unix_s = 1_795_857_925.4;
        let run = dir.join("runs/20261128T090525Z-64c5");
        let p = Isometry3::translation(0.0, -0.08, 0.04);
        let staged = stage_result(&dir, &run, &p, Mount::EyeInHand, &record, None).expect("staged");
        drop(staged);
        let text = std::fs::read_to_string(run.join(crate::calib::export::RESULT_JSON))
            .expect("result.json");
        let doc: serde_json::Value = serde_json::from_str(&text).expect("json");
        assert_eq!(doc["timestamp"], "2026-11-28T09:25:25Z", "{text}");
        assert_eq!(doc["run_id"], "20261128T090525Z-64c5", "{text}");
        let _ = std::fs::remove_dir_all(&dir);
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
