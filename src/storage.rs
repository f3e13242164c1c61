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
use serde::{Deserialize, Serialize};

mod current;
mod journal_file;
mod leftovers;
mod prune;
mod room;

pub(crate) use journal_file::{
    journal_unrecorded, mark_journal_unrecorded, mark_run_unrecorded, read_journal, remove_journal,
    set_aside_journal, write_journal, JournalLock,
};
pub use journal_file::{run_unrecorded, JOURNAL_FILE};
pub(crate) use leftovers::clean_staging;
pub use leftovers::remove_temporary_files;

pub use current::{current_run_id, load_current, Current};
pub(crate) use current::{make_current_from_run, stage_result};
pub use prune::remove_raw_captures;
pub use room::{check_room, run_bytes, StorageUnusable, RESERVE_BYTES, RUN_BASE_BYTES};
pub(crate) use room::{keep_reserve, release_reserve};

use crate::calib::Mount;
use crate::record::{CaptureRecord, RunRecord};

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

#[cfg(test)]
mod tests;
