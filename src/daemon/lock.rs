//! One daemon per storage: `handeye daemon` holds an exclusive advisory lock (`flock`) on
//! `<storage.dir>/daemon.lock` for as long as it lives, with its pid in the file, so a second
//! daemon on the same storage (the same cell) refuses to start and names the first. The
//! operating system drops the lock of a process that dies, however it dies: a stale file
//! never blocks a restart.

use std::fs::File;
use std::io::{Read as _, Seek as _, Write as _};
use std::path::{Path, PathBuf};

use crate::store::{flock, FlockMode};

/// File name of the lock in the storage directory.
pub const LOCK_FILE: &str = "daemon.lock";

/// Why the daemon may not use the storage.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LockError {
    /// Another daemon holds the lock.
    #[error(
        "another handeye daemon ({holder}) already runs on the storage {}; stop it first \
         (`systemctl stop handeye`), or give this daemon its own storage.dir",
        dir.display()
    )]
    Held {
        /// What the lock file says of its holder (`pid 1234`).
        holder: String,
        /// The storage directory.
        dir: PathBuf,
    },
    /// The lock file cannot be created, read or written.
    #[error(
        "cannot {action} {}: {source}; check that the daemon's user may write storage.dir",
        path.display()
    )]
    Io {
        /// What was attempted.
        action: &'static str,
        /// The file or folder.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
}

/// The held lock; dropping it (or the process ending) releases it.
#[derive(Debug)]
pub struct DaemonLock {
    _file: File,
}

impl DaemonLock {
    /// Takes the lock on `storage` (created as needed) without waiting, and writes this
    /// process's pid into it; [`LockError::Held`] when another process holds it.
    pub fn acquire(storage: &Path) -> Result<DaemonLock, LockError> {
        let io = |action, path: &Path| {
            let path = path.to_path_buf();
            move |source| LockError::Io {
                action,
                path,
                source,
            }
        };
        std::fs::create_dir_all(storage).map_err(io("create the folder", storage))?;
        let path = storage.join(LOCK_FILE);
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .read(true)
            .write(true)
            .open(&path)
            .map_err(io("open the lock file", &path))?;
        if !flock(&file, FlockMode::ExclusiveNow).map_err(io("lock", &path))? {
            let mut text = String::new();
            file.read_to_string(&mut text)
                .map_err(io("read the lock file", &path))?;
            let holder = match text.trim() {
                "" => "pid not written yet".to_string(),
                t => t.chars().take(80).collect(),
            };
            return Err(LockError::Held {
                holder,
                dir: storage.to_path_buf(),
            });
        }
        file.set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| writeln!(file, "pid {}", std::process::id()))
            .map_err(io("write the lock file", &path))?;
        Ok(DaemonLock { _file: file })
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    #[test]
    fn a_second_holder_is_refused_naming_the_first_until_the_first_lets_go() {
        let dir = std::env::temp_dir().join(format!("handeye-lock-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let first = DaemonLock::acquire(&dir).expect("first");
        let e = DaemonLock::acquire(&dir).expect_err("second");
        let me = format!("pid {}", std::process::id());
        assert!(
            matches!(&e, LockError::Held { holder, .. } if *holder == me),
            "{e}"
        );
        assert!(
            e.to_string().contains("another handeye daemon (pid "),
            "{e}"
        );
        drop(first);
        let again = DaemonLock::acquire(&dir).expect("free again once dropped");
        drop(again);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
