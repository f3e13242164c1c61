//! A damaged history file: how [`Store::open`](super::Store::open) recognises one, and how it
//! moves it aside (kept, never deleted) to start a new history.

use std::path::{Path, PathBuf};

use rusqlite::{Connection, ErrorCode, OpenFlags};
use serde::{Deserialize, Serialize};

use super::error::{StoreError, BUSY_TIMEOUT};
use crate::calendar::unix_now;

/// A damaged history file that [`Store::open`](super::Store::open) moved aside (kept, never
/// deleted) before it started a new one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetAside {
    /// Where the damaged file is now (its -wal and -shm files beside it, same name + suffix).
    pub path: PathBuf,
    /// What was wrong (SQLite's `quick_check`, or an empty file).
    pub why: String,
}

/// What is wrong with the history file at `path`, if anything: empty (0 bytes: SQLite would
/// silently start a new history), not a database, or pages that SQLite's `quick_check` finds
/// damaged. `None` also when the file is missing or cannot be opened for another reason (the
/// open that follows says why).
pub(super) fn damage(path: &Path) -> Option<String> {
    let meta = std::fs::metadata(path).ok()?;
    if meta.len() == 0 {
        return Some("the file is empty (0 bytes)".into());
    }
    let corrupt = |e: &rusqlite::Error| {
        matches!(
            e.sqlite_error_code(),
            Some(ErrorCode::DatabaseCorrupt | ErrorCode::NotADatabase)
        )
    };
    let flags = OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX;
    let conn = match Connection::open_with_flags(path, flags) {
        Ok(c) => c,
        Err(e) if corrupt(&e) => return Some(e.to_string()),
        Err(_) => return None,
    };
    let _ = conn.busy_timeout(BUSY_TIMEOUT);
    let checked = (|| {
        let mut stmt = conn.prepare("PRAGMA quick_check")?;
        let rows = stmt.query_map([], |r| r.get::<_, String>(0))?;
        rows.take(5).collect::<rusqlite::Result<Vec<String>>>()
    })();
    match checked {
        Ok(lines) if lines.iter().all(|l| l == "ok") => None,
        Ok(lines) => Some(format!("quick_check: {}", lines.join("; "))),
        Err(e) if corrupt(&e) => Some(e.to_string()),
        Err(_) => None,
    }
}

/// Moves the damaged history at `path` (and its -wal and -shm files) to
/// `<path>.damaged-<UTC time>`, logged, so a new one can start; nothing is deleted.
pub(super) fn set_aside(path: &Path, why: String) -> Result<SetAside, StoreError> {
    let mut aside = path.as_os_str().to_owned();
    aside.push(format!(
        ".damaged-{}",
        crate::calendar::utc_stamp(unix_now().floor() as i64)
    ));
    let aside = PathBuf::from(aside);
    let io = |source| StoreError::Io {
        action: "move aside the damaged",
        path: path.to_path_buf(),
        source,
    };
    std::fs::rename(path, &aside).map_err(io)?;
    for suffix in ["-wal", "-shm"] {
        let (mut from, mut to) = (path.as_os_str().to_owned(), aside.as_os_str().to_owned());
        from.push(suffix);
        to.push(suffix);
        if Path::new(&from).exists() {
            std::fs::rename(&from, &to).map_err(io)?;
        }
    }
    tracing::error!(
        "the history {} is damaged ({why}); kept as {} and a new history started",
        path.display(),
        aside.display()
    );
    Ok(SetAside { path: aside, why })
}
