//! The history's files: the writers' advisory lock on `<db>-lock` ([`WriterLock`], see the
//! store's module docs) and the refusal of links in the place of the database or the files
//! SQLite keeps beside it ([`no_links`]).

use std::fs::File;
use std::path::{Path, PathBuf};

use super::StoreError;
use crate::lockfile::{flock, open_lock_file, FlockMode};

/// The advisory lock writers hold on `<db>-lock` (see the module docs).
pub(super) struct WriterLock {
    pub(super) file: File,
    /// No other writer was alive: interrupted runs are ours to recover.
    pub(super) sole: bool,
}

impl WriterLock {
    fn lock_path(db: &Path) -> PathBuf {
        let mut name = db.as_os_str().to_owned();
        name.push("-lock");
        PathBuf::from(name)
    }

    /// Exclusive when no other writer holds the lock, shared otherwise.
    pub(super) fn acquire(db: &Path) -> Result<WriterLock, StoreError> {
        let path = Self::lock_path(db);
        let file = open_lock_file(&path).map_err(|source| StoreError::Io {
            action: "open the lock file",
            path: path.clone(),
            source,
        })?;
        let sole = flock(&file, FlockMode::ExclusiveNow).map_err(|source| StoreError::Io {
            action: "lock",
            path: path.clone(),
            source,
        })?;
        if !sole {
            // Blocks only while another writer is between its exclusive check and sharing.
            flock(&file, FlockMode::Shared).map_err(|source| StoreError::Io {
                action: "lock",
                path,
                source,
            })?;
        }
        Ok(WriterLock { file, sole })
    }

    /// Turns the exclusive lock into a shared one, once recovery is done.
    pub(super) fn share(self, db: &Path) -> Result<File, StoreError> {
        flock(&self.file, FlockMode::Shared).map_err(|source| StoreError::Io {
            action: "lock",
            path: Self::lock_path(db),
            source,
        })?;
        Ok(self.file)
    }
}

/// Refuses the history when it, or a file SQLite keeps beside it, is a link: it is never
/// opened through one (a write would land elsewhere). A link among the folders above it is
/// the operator's (a storage moved to another disk), and allowed: SQLite's
/// `SQLITE_OPEN_NOFOLLOW` would refuse that too.
pub(super) fn no_links(db: &Path) -> Result<(), StoreError> {
    for suffix in ["", "-wal", "-shm", "-journal"] {
        let mut name = db.as_os_str().to_owned();
        name.push(suffix);
        let path = PathBuf::from(name);
        if std::fs::symlink_metadata(&path).is_ok_and(|m| m.file_type().is_symlink()) {
            return Err(StoreError::Link { path });
        }
    }
    Ok(())
}
