//! One arm, one master: whatever moves an arm — `handeye daemon` for as long as it lives,
//! `handeye calibrate` / `check` / `robot move` / `robot set-tcp` for as long as their run
//! lasts — first claims it with an exclusive `flock` on a file named after the controller's
//! address, in a folder every user and every storage of the machine shares:
//! `/run/lock/handeye-arm-<address>-<dashboard port>.lock` (`/run/lock` is the system's folder
//! for lock files, world-writable and sticky). The storage's own lock ([`super::lock`]) keeps
//! one process per storage; this claim keeps one per arm, so a second daemon or a command on
//! another storage refuses to move an arm another process holds, naming it (pid, user, command
//! line and storage, from the kernel: [`crate::lockfile::holder`]).
//!
//! - The key is the address the configuration (or `--host`) names and its dashboard port:
//!   what is known before anything is connected. Two names of one controller (two network
//!   interfaces) are two keys; keep one address per controller.
//! - Without `/run/lock` (or where it is read-only, as under a systemd unit without
//!   `ReadWritePaths=-/run/lock`) the claim is made in the temporary folder, with a warning:
//!   it then holds only against processes that share that folder.
//! - A dry run moves nothing and claims nothing.

use std::fs::File;
use std::net::IpAddr;
use std::path::{Path, PathBuf};

use crate::lockfile::{flock, open_lock_file, FlockMode, Holder};

/// The shared folder of the claims.
pub const CLAIM_DIR: &str = "/run/lock";

/// Why the arm cannot be claimed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ClaimError {
    /// Another process holds the arm.
    #[error(
        "the arm at {arm} is held by another process ({holder}{}): one process moves an arm; \
         stop that one first (`systemctl stop handeye` for a daemon, or wait for a command's \
         run to end), or ask it through its daemon (lock {})",
        storage.as_ref().map_or(String::new(), |s| format!(", storage {}", s.display())),
        path.display()
    )]
    Held {
        /// The controller, `address:dashboard port`.
        arm: String,
        /// The holder as the kernel names it.
        holder: String,
        /// The holder's storage, when its open files can be read.
        storage: Option<PathBuf>,
        /// The claim's file.
        path: PathBuf,
    },
    /// No folder could take the claim.
    #[error(
        "cannot claim the arm at {arm}: {}: {source}; make {CLAIM_DIR} writable for this user \
         (a systemd unit: ReadWritePaths=-{CLAIM_DIR}), or remove the file if another user's \
         stale one cannot be opened",
        path.display()
    )]
    Io {
        /// The controller, `address:dashboard port`.
        arm: String,
        /// The file tried last.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
}

/// The held claim; dropping it (or the process ending) releases it.
#[derive(Debug)]
pub struct ArmClaim {
    _file: File,
    /// Where the claim is.
    pub path: PathBuf,
}

impl ArmClaim {
    /// Claims the arm at `host` (dashboard `port`) without waiting, in [`CLAIM_DIR`] or, when
    /// it cannot take it, the temporary folder (logged). Blocking I/O.
    pub fn take(host: IpAddr, port: u16) -> Result<ArmClaim, ClaimError> {
        let shared = ArmClaim::take_in(Path::new(CLAIM_DIR), host, port);
        match shared {
            Err(ClaimError::Io { path, source, .. }) if folder_unusable(&path, &source) => {
                let fallback = std::env::temp_dir();
                tracing::warn!(
                    "cannot claim the arm in {}: {source}; claiming it in {} instead, which \
                     holds only against processes that share that folder (a systemd unit \
                     needs ReadWritePaths=-{CLAIM_DIR})",
                    path.display(),
                    fallback.display()
                );
                ArmClaim::take_in(&fallback, host, port)
            }
            other => other,
        }
    }

    /// Claims the arm at `host` (dashboard `port`) in `dir`. Blocking I/O.
    pub fn take_in(dir: &Path, host: IpAddr, port: u16) -> Result<ArmClaim, ClaimError> {
        let arm = match host {
            IpAddr::V4(a) => format!("{a}:{port}"),
            IpAddr::V6(a) => format!("[{a}]:{port}"),
        };
        let path = dir.join(file_name(host, port));
        let io = |source| ClaimError::Io {
            arm: arm.clone(),
            path: path.clone(),
            source,
        };
        let file = open_lock_file(&path).map_err(io)?;
        if !flock(&file, FlockMode::ExclusiveNow).map_err(io)? {
            let holder = crate::lockfile::holder(&file);
            return Err(ClaimError::Held {
                storage: holder.as_ref().and_then(storage_of),
                holder: super::lock::named(holder.as_ref()),
                arm,
                path,
            });
        }
        crate::lockfile::let_others_lock(&file);
        tracing::info!("claimed the arm at {arm} ({})", path.display());
        Ok(ArmClaim { _file: file, path })
    }
}

/// Whether `error`, met opening the claim `path`, says that its folder cannot hold claims
/// (absent, read-only, not writable for this user): then the temporary folder serves. A claim
/// file that is there but cannot be opened (another user's, unreadable) is no such case: it
/// may be held, so the claim fails.
fn folder_unusable(path: &Path, error: &std::io::Error) -> bool {
    let absent = std::fs::symlink_metadata(path).is_err();
    #[cfg(unix)]
    let read_only = error.raw_os_error() == Some(libc::EROFS);
    #[cfg(not(unix))]
    let read_only = false;
    read_only
        || !path.parent().is_some_and(Path::is_dir)
        || (absent && error.kind() == std::io::ErrorKind::PermissionDenied)
}

/// The claim's file name for the arm at `host`, dashboard `port`: letters, digits, `.`, `-`
/// and `_` only (an IPv6 address's colons become `_`).
pub fn file_name(host: IpAddr, port: u16) -> String {
    let host = host.to_string().replace(':', "_");
    format!("handeye-arm-{host}-{port}.lock")
}

/// The storage of `holder`: the folder of the `daemon.lock` among its open files
/// (`/proc/<pid>/fd`, readable for this user's processes and root's view of all). At most
/// 4 096 descriptors are looked at.
fn storage_of(holder: &Holder) -> Option<PathBuf> {
    let fds = std::fs::read_dir(Path::new("/proc").join(holder.pid.to_string()).join("fd")).ok()?;
    fds.take(4096)
        .filter_map(|e| std::fs::read_link(e.ok()?.path()).ok())
        .find(|target| target.file_name() == Some(super::lock::LOCK_FILE.as_ref()))
        .and_then(|lock| lock.parent().map(Path::to_path_buf))
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;
    use std::net::Ipv4Addr;
    use std::os::unix::process::CommandExt as _;

    /// Issue 46: an arm is claimed once, whatever the storage: a second claim of the same
    /// address is refused naming the holder (its pid and, from its open `daemon.lock`, its
    /// storage: here `flock(1)` holding a storage's lock and the claim), another address is
    /// another arm, and the claim goes with its holder.
    #[test]
    fn issue_46_one_arm_is_claimed_once_naming_the_holder_and_its_storage() {
        let dir = std::env::temp_dir().join(format!("handeye-arm-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let storage = dir.join("storage-a");
        std::fs::create_dir_all(&storage).expect("dir");
        let host = IpAddr::V4(Ipv4Addr::new(127, 0, 0, 71));
        let first = ArmClaim::take_in(&dir, host, 29999).expect("first");
        let e = ArmClaim::take_in(&dir, host, 29999).expect_err("second");
        let text = e.to_string();
        assert!(
            text.starts_with(&format!(
                "the arm at 127.0.0.71:29999 is held by another process (pid {}, user ",
                std::process::id()
            )),
            "{text}"
        );
        let other = ArmClaim::take_in(&dir, host, 30000).expect("another arm");
        drop((first, other));
        // Another process holds a storage's lock and the claim.
        let claim = dir.join(file_name(host, 29999));
        let mut holder = std::process::Command::new("flock")
            .arg("-x")
            .arg(storage.join(super::super::lock::LOCK_FILE))
            .args(["flock", "-x"])
            .arg(&claim)
            .args(["sleep", "30"])
            .process_group(0)
            .spawn()
            .expect("flock(1)");
        let mut refused = None;
        for _ in 0..100 {
            match ArmClaim::take_in(&dir, host, 29999) {
                Ok(c) => drop(c),
                Err(e) => {
                    refused = Some(e.to_string());
                    break;
                }
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        // The whole group: the inner flock(1) holds the claim.
        // SAFETY: kill(2) on the process group this test made.
        unsafe { libc::kill(-(holder.id() as i32), libc::SIGKILL) };
        let _ = holder.wait();
        let text = refused.expect("flock(1) never held the claim");
        assert!(
            text.contains(&format!("`flock -x {}", claim.display()))
                && text.contains(&format!("storage {}", storage.display())),
            "{text}"
        );
        let mut again = None;
        for _ in 0..100 {
            if let Ok(c) = ArmClaim::take_in(&dir, host, 29999) {
                again = Some(c);
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        assert!(again.is_some(), "the claim stayed after its holder died");
        drop(again);
        // A link in the claim's place is refused, never followed.
        std::fs::remove_file(&claim).expect("rm");
        std::os::unix::fs::symlink(dir.join("elsewhere"), &claim).expect("link");
        let e = ArmClaim::take_in(&dir, host, 29999).expect_err("a link");
        assert!(e.to_string().contains("is a symbolic link"), "{e}");
        assert!(!dir.join("elsewhere").exists());
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The temporary folder serves only when the shared one cannot hold claims, never when a
    /// claim file there cannot be opened (it may be held: two processes would drive the arm).
    #[test]
    fn the_fallback_is_for_an_unusable_folder_not_an_unopenable_claim() {
        let denied = std::io::Error::from(std::io::ErrorKind::PermissionDenied);
        let dir = std::env::temp_dir().join(format!("handeye-arm-fb-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("dir");
        let claim = dir.join("handeye-arm-x.lock");
        assert!(folder_unusable(&claim, &denied), "no file, no write access");
        assert!(
            folder_unusable(&dir.join("none/x.lock"), &denied),
            "no folder"
        );
        std::fs::write(&claim, "").expect("claim");
        assert!(!folder_unusable(&claim, &denied), "another user's claim");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_file_name_holds_no_separator() {
        let v6: IpAddr = "fe80::1".parse().expect("v6");
        assert_eq!(file_name(v6, 29999), "handeye-arm-fe80__1-29999.lock");
    }
}
