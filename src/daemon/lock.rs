//! One process moves a cell's arm: `handeye daemon` holds an exclusive advisory lock (`flock`)
//! on `<storage.dir>/daemon.lock` for as long as it lives, and `handeye calibrate` / `check`
//! (and `robot move` / `set-tcp --config`) for as long as their run lasts, with the holder's
//! pid and name in the file. A second daemon
//! on the same storage (the same cell) refuses to start and names the holder; a command beside
//! a running daemon refuses before it connects anything and names the way through the daemon.
//! The operating system drops the lock of a process that dies, however it dies: a stale file
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
    /// A command's run (`handeye calibrate`, `check`, `robot`) holds the lock.
    #[error(
        "another `handeye {command}` run ({holder}) already holds the storage {}: it moves the \
         arm; wait until it has ended, then start the daemon",
        dir.display()
    )]
    HeldByRun {
        /// The command (`calibrate`).
        command: String,
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
    /// Takes the lock on `storage` for a daemon: [`DaemonLock::acquire_for`] `"daemon"`.
    pub fn acquire(storage: &Path) -> Result<DaemonLock, LockError> {
        DaemonLock::acquire_for(storage, DAEMON)
    }

    /// Takes the lock on `storage` (created as needed) without waiting, and writes this
    /// process's pid and `role` (`daemon`, `calibrate`, `check`, `robot`; one word) into it;
    /// [`LockError::Held`] when a daemon holds it, [`LockError::HeldByRun`] a command.
    pub fn acquire_for(storage: &Path, role: &str) -> Result<DaemonLock, LockError> {
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
            let dir = storage.to_path_buf();
            return Err(match holder(&text) {
                (holder, None) => LockError::Held { holder, dir },
                (holder, Some(command)) => LockError::HeldByRun {
                    command,
                    holder,
                    dir,
                },
            });
        }
        file.set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| writeln!(file, "pid {} {role}", std::process::id()))
            .map_err(io("write the lock file", &path))?;
        Ok(DaemonLock { _file: file })
    }
}

/// The role a daemon writes into the lock file.
const DAEMON: &str = "daemon";

/// Who holds the lock, from the file's text (`pid 1234 calibrate`; a daemon of an earlier
/// version wrote `pid 1234` alone): its pid (`pid 1234`), and the command when it is not a
/// daemon.
fn holder(text: &str) -> (String, Option<String>) {
    // The file is the storage's, not ours to trust: cut, and control characters escaped.
    let text: String = text.trim().chars().take(80).collect();
    let text = handeye_hal::limits::sanitize_message(&text);
    let mut words = text.split_whitespace();
    match (words.next(), words.next(), words.next()) {
        (None, ..) => ("pid not written yet".to_string(), None),
        (Some("pid"), Some(pid), role) => (
            format!("pid {pid}"),
            role.filter(|r| *r != DAEMON).map(str::to_string),
        ),
        _ => (text, None),
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
        let again = DaemonLock::acquire_for(&dir, "calibrate").expect("free again once dropped");
        let e = DaemonLock::acquire(&dir).expect_err("held by a run");
        assert!(
            matches!(&e, LockError::HeldByRun { holder, command, .. } if *holder == me && command == "calibrate"),
            "{e}"
        );
        assert!(
            e.to_string().starts_with(&format!(
                "another `handeye calibrate` run ({me}) already holds the storage"
            )),
            "{e}"
        );
        drop(again);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
