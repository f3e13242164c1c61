//! One process moves a cell's arm: `handeye daemon` holds an exclusive advisory lock (`flock`)
//! on `<storage.dir>/daemon.lock` for as long as it lives, and `handeye calibrate` / `check`
//! (and `robot move` / `set-tcp --config`) for as long as their run lasts. A second daemon
//! on the same storage (the same cell) refuses to start and names the holder; a command beside
//! a running daemon refuses before it connects anything and names the way through the daemon.
//! The holder is named from the kernel's table of locks ([`crate::lockfile::holder`]: its pid,
//! user and command line), never from the file, which anyone who can write the storage can
//! fill with anything. The file is opened without following a link in its place. The
//! operating system drops the lock of a process that dies, however it dies: a stale file
//! never blocks a restart. The arm itself is claimed apart from the storage:
//! [`super::arm`].

use std::fs::File;
use std::path::{Path, PathBuf};

use crate::lockfile::{flock, open_lock_file, FlockMode, Holder};

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
        /// The holder as the kernel names it (`pid 1234, user handeye, …`).
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
        /// The holder as the kernel names it (`pid 1234, user handeye, …`).
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

    /// Takes the lock on `storage` (created as needed) without waiting, for `role` (`daemon`,
    /// `calibrate`, `check`, `robot`: the holder's subcommand, which a refused process reads
    /// from the holder's command line); [`LockError::Held`] when a daemon (or a process that
    /// cannot be told) holds it, [`LockError::HeldByRun`] a command.
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
        let file = open_lock_file(&path).map_err(io("open the lock file", &path))?;
        if !flock(&file, FlockMode::ExclusiveNow).map_err(io("lock", &path))? {
            let dir = storage.to_path_buf();
            let holder = crate::lockfile::holder(&file);
            return Err(match holder.as_ref().and_then(run_command) {
                Some(command) => LockError::HeldByRun {
                    command: command.to_string(),
                    holder: named(holder.as_ref()),
                    dir,
                },
                None => LockError::Held {
                    holder: named(holder.as_ref()),
                    dir,
                },
            });
        }
        tracing::debug!(role, "took {}", path.display());
        Ok(DaemonLock { _file: file })
    }
}

/// The role a daemon takes the lock for.
const DAEMON: &str = "daemon";

/// The commands that take the lock for a run, as their first word on the command line.
const RUN_COMMANDS: [&str; 3] = ["calibrate", "check", "robot"];

/// The `handeye` command `holder` runs when it is one that takes the lock for a run (not a
/// daemon): the first of its command line's words that names one.
fn run_command(holder: &Holder) -> Option<&'static str> {
    let words = holder.command.as_deref()?.split(' ').skip(1);
    for w in words {
        if w == DAEMON {
            return None;
        }
        if let Some(c) = RUN_COMMANDS.iter().find(|c| **c == w) {
            return Some(c);
        }
    }
    None
}

/// The holder in words: what the kernel tells, or that it could not tell.
pub(crate) fn named(holder: Option<&Holder>) -> String {
    holder.map_or_else(
        || "a process this one cannot name: /proc/locks does not show it".to_string(),
        Holder::to_string,
    )
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    /// Issue 46: the holder is named from the kernel's table, not from the file: a file
    /// saying `pid 1 calibrate` does not make the refusal name pid 1 or a `calibrate` run.
    #[test]
    fn issue_46_the_holder_is_named_from_the_kernel_not_the_file() {
        let dir = std::env::temp_dir().join(format!("handeye-lock-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let first = DaemonLock::acquire(&dir).expect("first");
        std::fs::write(dir.join(LOCK_FILE), "pid 1 calibrate\n").expect("forge");
        let e = DaemonLock::acquire(&dir).expect_err("second");
        let me = format!("pid {}, user ", std::process::id());
        assert!(
            matches!(&e, LockError::Held { holder, .. } if holder.starts_with(&me)),
            "{e}"
        );
        assert!(
            e.to_string().contains("another handeye daemon (pid "),
            "{e}"
        );
        assert!(!e.to_string().contains("pid 1,"), "{e}");
        drop(first);
        let again = DaemonLock::acquire_for(&dir, "calibrate").expect("free again once dropped");
        drop(again);
        // A link in the lock file's place is refused, and its target never created.
        std::fs::remove_file(dir.join(LOCK_FILE)).expect("rm");
        let outside = dir.join("outside");
        std::os::unix::fs::symlink(&outside, dir.join(LOCK_FILE)).expect("link");
        let e = DaemonLock::acquire(&dir).expect_err("a link");
        assert!(e.to_string().contains("is a symbolic link"), "{e}");
        assert!(!outside.exists());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_run_command_is_read_from_the_holder_s_command_line() {
        let holder = |c: &str| Holder {
            pid: 7,
            user: None,
            command: Some(c.to_string()),
        };
        assert_eq!(
            run_command(&holder("/usr/bin/handeye calibrate --config c.toml")),
            Some("calibrate")
        );
        assert_eq!(run_command(&holder("handeye daemon --config check")), None);
        assert_eq!(run_command(&holder("flock -x f sleep 9")), None);
    }
}
