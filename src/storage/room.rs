//! Room for a run: what it keeps at most, the check that the storage can take it, and the
//! reserve released to record its end on a full disk.

use std::path::{Path, PathBuf};

use super::{write_atomically, StorageError};

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
