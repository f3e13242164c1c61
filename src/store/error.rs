//! What can go wrong with the history ([`StoreError`]), and SQLite's errors mapped to it.

use std::path::{Path, PathBuf};
use std::time::Duration;

use rusqlite::ErrorCode;

/// How long a statement waits for another process's write lock before giving up.
pub(super) const BUSY_TIMEOUT: Duration = Duration::from_secs(5);

/// What can go wrong with the history; each message says what to do.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// There is no history database (read-only open).
    #[error("no history yet at {}: the daemon (or calibrate with history) writes it", .path.display())]
    NoHistory {
        /// The database path.
        path: PathBuf,
    },
    /// A file or folder could not be created, opened or removed.
    #[error("cannot {action} {}: {source}; check that the storage directory (`[storage] dir`) exists and is writable by this user", .path.display())]
    Io {
        /// What was attempted (`create the folder`, `remove`, …).
        action: &'static str,
        /// The file or folder.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// A link stands where the history, or a file SQLite keeps beside it, belongs.
    #[error("{} is a symbolic link; the history is never opened through one (a write would land elsewhere): remove the link", .path.display())]
    Link {
        /// The link.
        path: PathBuf,
    },
    /// SQLite cannot open the file.
    #[error("cannot open the history database {}: {source}; check the permissions of the file and its folder (SQLite also needs to create {}-wal and -shm beside it)", .path.display(), .path.display())]
    Open {
        /// The database path.
        path: PathBuf,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
    /// The file is not a SQLite database, or is damaged.
    #[error("{} is corrupted or not a handeye history database ({source}); the daemon or `handeye calibrate` sets it aside when it starts and rebuilds the history from runs/<run_id>/record.json", .path.display())]
    Corrupt {
        /// The database path.
        path: PathBuf,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
    /// A SQLite database, but someone else's.
    #[error("{} is a SQLite database without handeye's history tables; point `[storage] dir` elsewhere or move the file aside", .path.display())]
    Foreign {
        /// The database path.
        path: PathBuf,
    },
    /// Written by a newer handeye.
    #[error("the history database {} is newer than this program (schema version {found}, this program knows up to {supported}); upgrade handeye, or move the file aside to start a new history", .path.display())]
    TooNew {
        /// The database path.
        path: PathBuf,
        /// The file's schema version.
        found: i64,
        /// The newest version this program knows.
        supported: i64,
    },
    /// Read-only open of a file that needs a migration first.
    #[error("the history database {} has schema version {found} and this program needs {supported}; start the daemon (or any command that writes history) once to upgrade it", .path.display())]
    NeedsUpgrade {
        /// The database path.
        path: PathBuf,
        /// The file's schema version.
        found: i64,
        /// The version this program needs.
        supported: i64,
    },
    /// Another process held the write lock for longer than the busy timeout.
    #[error("the history database {} stayed locked by another process for {} s; retry, and check no process is stuck holding it", .path.display(), BUSY_TIMEOUT.as_secs())]
    Busy {
        /// The database path.
        path: PathBuf,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
    /// A write to a store opened read-only, or to a file this user cannot write.
    #[error("cannot write the history database {}: it was opened read-only, or this user cannot write it or its folder (check the permissions of the file, its -wal and -shm files and the folder)", .path.display())]
    ReadOnly {
        /// The database path.
        path: PathBuf,
    },
    /// The disk is full.
    #[error("cannot write the history database {}: the disk is full; free some space (old raw captures under runs/ can go)", .path.display())]
    DiskFull {
        /// The database path.
        path: PathBuf,
    },
    /// `begin` with a run id that is already in the history.
    #[error("run {run_id} is already in the history; every run needs a new id (handeye::run::new_run_id)")]
    DuplicateRun {
        /// The run id.
        run_id: String,
    },
    /// A stored record is not valid JSON.
    #[error("the stored record of run {run_id} is not valid JSON ({source}); the file runs/{run_id}/record.json holds the same record")]
    BadRecord {
        /// The run id.
        run_id: String,
        /// The parser's error.
        #[source]
        source: serde_json::Error,
    },
    /// A record could not be turned into JSON (a non-finite number where JSON needs one).
    #[error("cannot store the record of run {run_id} as JSON: {source}")]
    Serialize {
        /// The run id.
        run_id: String,
        /// The serialiser's error.
        #[source]
        source: serde_json::Error,
    },
    /// Any other SQLite error.
    #[error("history database {}: cannot {action}: {source}", .path.display())]
    Sqlite {
        /// The database path.
        path: PathBuf,
        /// What was attempted.
        action: &'static str,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
}

/// Maps SQLite's errors to the ones an operator can act on.
pub(super) fn sql_error(path: &Path, action: &'static str, e: rusqlite::Error) -> StoreError {
    let path = path.to_path_buf();
    match e.sqlite_error_code() {
        Some(ErrorCode::NotADatabase | ErrorCode::DatabaseCorrupt) => {
            StoreError::Corrupt { path, source: e }
        }
        Some(ErrorCode::DatabaseBusy | ErrorCode::DatabaseLocked) => {
            StoreError::Busy { path, source: e }
        }
        Some(ErrorCode::ReadOnly) => StoreError::ReadOnly { path },
        Some(ErrorCode::DiskFull) => StoreError::DiskFull { path },
        Some(ErrorCode::CannotOpen | ErrorCode::PermissionDenied) => {
            StoreError::Open { path, source: e }
        }
        _ => StoreError::Sqlite {
            path,
            action,
            source: e,
        },
    }
}
