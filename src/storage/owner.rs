//! One user owns the storage. The packaged daemon runs as `handeye` and owns
//! `/var/lib/handeye`; a command that writes the storage (a run's files, the history, the
//! locks) run as anyone else would either fail half way ("Permission denied") or, as root,
//! leave files the daemon cannot open, and the daemon would then stop at its next start. So:
//!
//! - [`check_owner`]: a command that writes the storage runs as the storage folder's owner, or
//!   stops before it connects anything, naming the same command under `sudo -u <owner>`;
//! - [`unopenable`]: the daemon, at start, lists the files of its storage it cannot read and
//!   write (left by another user), and says how to give them back (`chown -R`).

use std::path::{Path, PathBuf};

/// Why this process may not write the storage.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OwnerError {
    /// The storage folder belongs to another user.
    #[error(
        "storage.dir {} belongs to user {owner}, and this command runs as {me}: {why}. Run it \
         as the storage's owner: `sudo -u {owner} {command}`",
        dir.display()
    )]
    NotOwner {
        /// The storage folder.
        dir: PathBuf,
        /// Its owner's name (or `uid N`).
        owner: String,
        /// This process's user's name.
        me: String,
        /// What would go wrong.
        why: &'static str,
        /// The command line to run under `sudo -u` (this process's arguments).
        command: String,
    },
    /// Some files of the storage cannot be read and written by its owner.
    #[error(
        "{count} file(s) in storage.dir {} cannot be opened by user {me} (the daemon's user): \
         {listed}; they were left by another user (a command run with sudo?). Give them back: \
         `sudo chown -R {me}: {}`, then start again",
        dir.display(),
        dir.display()
    )]
    Unopenable {
        /// The storage folder.
        dir: PathBuf,
        /// This process's user's name.
        me: String,
        /// How many files.
        count: usize,
        /// The first few, with their owner and mode.
        listed: String,
    },
}

/// What is wrong with a storage folder owned by `owner` for a process of effective user `me`
/// (`None`: nothing, they are the same user).
fn verdict(me: u32, owner: u32) -> Option<&'static str> {
    if me == owner {
        None
    } else if me == 0 {
        Some(
            "as root it would leave files (the history, its locks, run folders) that the \
             storage's owner cannot open, and the daemon would then stop",
        )
    } else {
        Some("it may not write the storage, or would leave files its owner cannot open")
    }
}

/// Checks that this process's effective user owns `dir` (the storage folder) before a command
/// writes to it. A folder that does not exist yet passes: it will be this user's. `command` is
/// the command line the message repeats under `sudo -u <owner>`.
#[cfg(unix)]
pub fn check_owner(dir: &Path, command: &str) -> Result<(), OwnerError> {
    use std::os::unix::fs::MetadataExt as _;
    let Ok(meta) = std::fs::metadata(dir) else {
        return Ok(());
    };
    // SAFETY: geteuid has no preconditions and cannot fail.
    let me = unsafe { libc::geteuid() };
    match verdict(me, meta.uid()) {
        None => Ok(()),
        Some(why) => Err(OwnerError::NotOwner {
            dir: dir.to_path_buf(),
            owner: user_name(meta.uid()),
            me: user_name(me),
            why,
            command: command.to_string(),
        }),
    }
}

/// Without Unix users there is nothing to check.
#[cfg(not(unix))]
pub fn check_owner(_dir: &Path, _command: &str) -> Result<(), OwnerError> {
    Ok(())
}

/// This process's command line, quoted for a shell where needed (for [`check_owner`]'s
/// message): `handeye calibrate --config /etc/handeye/handeye.toml --dry-run`.
pub fn this_command_line() -> String {
    let mut args = std::env::args_os();
    let program = args
        .next()
        .map(|p| {
            Path::new(&p)
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| p.to_string_lossy().into_owned())
        })
        .unwrap_or_else(|| "handeye".to_string());
    std::iter::once(program)
        .chain(args.map(|a| shell_word(&a.to_string_lossy())))
        .collect::<Vec<_>>()
        .join(" ")
}

/// `word` as one shell word: as it is when it holds only safe characters, else single-quoted.
fn shell_word(word: &str) -> String {
    let safe = |c: char| c.is_ascii_alphanumeric() || "-_./=:,@%+".contains(c);
    if !word.is_empty() && word.chars().all(safe) {
        word.to_string()
    } else {
        format!("'{}'", word.replace('\'', r"'\''"))
    }
}

/// Most files [`unopenable`] names in its message (the count says how many in all).
const LISTED: usize = 5;

/// Most entries [`unopenable`] looks at (a storage holds a few files per run; this bounds the
/// start of a daemon on a storage that is something else).
const MAX_ENTRIES: usize = 200_000;

/// The files and folders under `dir` (itself included) that this process cannot read and
/// write (folders: and enter): `Err` naming them and the `chown -R` that gives them back;
/// `Ok` when there are none or `dir` does not exist yet. Symbolic links are not followed.
#[cfg(unix)]
pub fn unopenable(dir: &Path) -> Result<(), OwnerError> {
    use std::os::unix::ffi::OsStrExt as _;
    use std::os::unix::fs::MetadataExt as _;
    if !dir.exists() {
        return Ok(());
    }
    let mut bad = Vec::new();
    let mut count = 0usize;
    let mut seen = 0usize;
    let mut stack = vec![dir.to_path_buf()];
    while let Some(path) = stack.pop() {
        seen += 1;
        if seen > MAX_ENTRIES {
            break;
        }
        let Ok(meta) = std::fs::symlink_metadata(&path) else {
            continue;
        };
        if meta.file_type().is_symlink() {
            continue;
        }
        let mode = if meta.is_dir() {
            libc::R_OK | libc::W_OK | libc::X_OK
        } else {
            libc::R_OK | libc::W_OK
        };
        let Ok(c_path) = std::ffi::CString::new(path.as_os_str().as_bytes()) else {
            continue;
        };
        // SAFETY: a valid NUL-terminated path; access only reads it.
        let ok = unsafe { libc::access(c_path.as_ptr(), mode) } == 0;
        if !ok {
            count += 1;
            if bad.len() < LISTED {
                bad.push(format!(
                    "{} (owner {}, mode {:04o})",
                    path.display(),
                    user_name(meta.uid()),
                    meta.mode() & 0o7777
                ));
            }
        }
        if meta.is_dir() && ok {
            if let Ok(entries) = std::fs::read_dir(&path) {
                stack.extend(entries.flatten().map(|e| e.path()));
            }
        }
    }
    if count == 0 {
        return Ok(());
    }
    if count > bad.len() {
        bad.push(format!("and {} more", count - bad.len()));
    }
    // SAFETY: geteuid has no preconditions and cannot fail.
    let me = unsafe { libc::geteuid() };
    Err(OwnerError::Unopenable {
        dir: dir.to_path_buf(),
        me: user_name(me),
        count,
        listed: bad.join(", "),
    })
}

/// Without Unix users there is nothing to check.
#[cfg(not(unix))]
pub fn unopenable(_dir: &Path) -> Result<(), OwnerError> {
    Ok(())
}

#[cfg(unix)]
pub use crate::lockfile::user_name;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_owner_writes_the_storage() {
        assert_eq!(verdict(998, 998), None);
        assert_eq!(verdict(0, 0), None);
        let root = verdict(0, 998).expect("root on another user's storage");
        assert!(root.contains("as root"), "{root}");
        assert!(verdict(1000, 998).is_some());
        assert!(verdict(1000, 0).is_some());
    }

    #[test]
    fn the_refusal_names_the_command_under_sudo_as_the_owner() {
        let e = OwnerError::NotOwner {
            dir: PathBuf::from("/var/lib/handeye"),
            owner: "handeye".into(),
            me: "root".into(),
            why: verdict(0, 998).expect("refused"),
            command: "handeye calibrate --config /etc/handeye/handeye.toml --dry-run".into(),
        };
        let text = e.to_string();
        assert!(
            text.starts_with("storage.dir /var/lib/handeye belongs to user handeye, and this command runs as root"),
            "{text}"
        );
        assert!(
            text.ends_with(
                "`sudo -u handeye handeye calibrate --config /etc/handeye/handeye.toml --dry-run`"
            ),
            "{text}"
        );
    }

    #[test]
    fn a_command_line_is_quoted_for_the_shell() {
        assert_eq!(
            shell_word("/etc/handeye/handeye.toml"),
            "/etc/handeye/handeye.toml"
        );
        assert_eq!(shell_word("a b"), "'a b'");
        assert_eq!(shell_word("it's"), r"'it'\''s'");
        assert_eq!(shell_word(""), "''");
    }

    #[cfg(unix)]
    #[test]
    fn the_owner_passes_and_a_missing_storage_passes() {
        let dir = std::env::temp_dir().join(format!("handeye-owner-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        check_owner(&dir, "handeye x").expect("a storage not made yet");
        unopenable(&dir).expect("a storage not made yet");
        std::fs::create_dir_all(dir.join("runs/r1")).expect("mkdir");
        std::fs::write(dir.join("runs/r1/record.json"), "{}").expect("write");
        check_owner(&dir, "handeye x").expect("this user's own storage");
        unopenable(&dir).expect("this user's own files");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// As root (CI): a storage given to another user refuses root and names that user; root's
    /// files in it are named by `unopenable` as that user sees them (checked through access(2)
    /// by a child process of that user in tests/e2e/storage.rs).
    #[cfg(unix)]
    #[test]
    fn root_is_refused_on_another_users_storage() {
        // SAFETY: geteuid has no preconditions and cannot fail.
        if unsafe { libc::geteuid() } != 0 {
            // Only root can give a folder to another user; the verdict is tested above.
            return;
        }
        let dir = std::env::temp_dir().join(format!("handeye-owner-root-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("mkdir");
        std::os::unix::fs::chown(&dir, Some(65534), Some(65534)).expect("chown");
        let e = check_owner(&dir, "handeye calibrate --config c.toml").expect_err("root refused");
        let text = e.to_string();
        assert!(
            text.contains(&format!(
                "`sudo -u {} handeye calibrate --config c.toml`",
                user_name(65534)
            )),
            "{text}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
