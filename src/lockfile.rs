//! Lock files, one copy for the whole program: opened without following a link
//! ([`open_lock_file`]), locked with `flock` ([`flock`]), and their holder named from the
//! kernel's lock table ([`holder`]: `/proc/locks`), never from what the file says — anyone who
//! can write the file can write anything in it.
//!
//! The daemon's lock on its storage (`daemon.lock`), the history's writers' lock
//! (`history.sqlite-lock`), the write-back journal's lock and the arm's claim
//! (`/run/lock/handeye-arm-*.lock`) all go through here.

use std::fs::File;
use std::path::Path;

/// How [`flock`] locks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlockMode {
    /// Exclusive without waiting; `Ok(false)` when another process holds the lock.
    ExclusiveNow,
    /// Shared, waiting for an exclusive holder.
    Shared,
}

/// Locks `file` (`flock(2)`): `Ok(true)` when taken, `Ok(false)` when [`FlockMode::ExclusiveNow`]
/// finds it held. The lock lasts as long as the open file; the operating system drops it when
/// the process dies, however it dies.
#[cfg(unix)]
pub fn flock(file: &File, mode: FlockMode) -> std::io::Result<bool> {
    use std::os::fd::AsRawFd;
    let op = match mode {
        FlockMode::ExclusiveNow => libc::LOCK_EX | libc::LOCK_NB,
        FlockMode::Shared => libc::LOCK_SH,
    };
    loop {
        // SAFETY: flock on a file descriptor this `File` owns for the duration of the call.
        if unsafe { libc::flock(file.as_raw_fd(), op) } == 0 {
            return Ok(true);
        }
        let e = std::io::Error::last_os_error();
        match e.raw_os_error() {
            Some(libc::EINTR) => continue,
            Some(libc::EWOULDBLOCK) => return Ok(false),
            _ => return Err(e),
        }
    }
}

/// Without `flock`, every lock is taken: run one process at a time.
#[cfg(not(unix))]
pub fn flock(_file: &File, _mode: FlockMode) -> std::io::Result<bool> {
    Ok(true)
}

/// Opens (creating it, mode `0644` less the umask) the lock file `path`
/// without following a link in its place (`O_NOFOLLOW`), and refuses anything but a regular
/// file (a FIFO, a device): an error that names what is there and what to do. An existing
/// file is opened read-only — `flock` needs no write access, and a file another user made
/// in a shared folder (`/run/lock`) is then still usable. Blocking I/O.
pub fn open_lock_file(path: &Path) -> std::io::Result<File> {
    let open = |create: bool| {
        let mut options = std::fs::OpenOptions::new();
        options.read(true);
        if create {
            options.write(true).create_new(true);
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt as _;
            options
                .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK | libc::O_CLOEXEC)
                .mode(0o644);
        }
        options.open(path)
    };
    // Open first, create only when absent: a kernel that protects files in sticky folders
    // (fs.protected_regular) refuses O_CREAT on another user's file there.
    let file = match open(false) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => match open(true) {
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => open(false),
            other => other,
        },
        other => other,
    }
    .map_err(|e| refused_link(path, e))?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "{} is not a regular file (a FIFO, a device or a folder); remove it",
                path.display()
            ),
        ));
    }
    Ok(file)
}

/// Gives the others' read bit back to `file` when it is this user's: a umask (systemd's
/// `UMask=0077`) may have taken it, and another user's process must open the file to take
/// the lock and see it held. A file of another user is left alone.
pub fn let_others_lock(file: &File) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::{MetadataExt as _, PermissionsExt as _};
        let Ok(meta) = file.metadata() else { return };
        // SAFETY: geteuid has no preconditions and cannot fail.
        if meta.uid() == unsafe { libc::geteuid() } && meta.mode() & 0o044 != 0o044 {
            if let Err(e) = file.set_permissions(std::fs::Permissions::from_mode(0o644)) {
                tracing::warn!("cannot let other users read a lock file: {e}");
            }
        }
    }
    #[cfg(not(unix))]
    let _ = file;
}

/// `O_NOFOLLOW`'s `ELOOP` said in words: a link stands where the lock file belongs.
fn refused_link(path: &Path, e: std::io::Error) -> std::io::Error {
    #[cfg(unix)]
    if e.raw_os_error() == Some(libc::ELOOP) {
        return std::io::Error::new(
            e.kind(),
            format!(
                "{} is a symbolic link; a lock file is never opened through one (it could make \
                 this program create or lock a file elsewhere): remove the link",
                path.display()
            ),
        );
    }
    let _ = path;
    e
}

/// The process that holds a lock, as the kernel knows it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holder {
    /// Its process id.
    pub pid: u32,
    /// Its user's name (`uid 1234` without one), when its `/proc` entry can be read.
    pub user: Option<String>,
    /// Its command line, words joined by spaces (cut to 200 characters, control characters
    /// escaped), when it can be read.
    pub command: Option<String>,
}

impl Holder {
    /// The `handeye` subcommand it runs (`daemon`, `calibrate`, `check`, `robot`), from its
    /// command line: the first word after the program that is not an option.
    pub fn subcommand(&self) -> Option<&str> {
        self.command
            .as_deref()?
            .split(' ')
            .skip(1)
            .find(|w| !w.starts_with('-'))
    }
}

impl std::fmt::Display for Holder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "pid {}", self.pid)?;
        if let Some(user) = &self.user {
            write!(f, ", user {user}")?;
        }
        if let Some(command) = &self.command {
            write!(f, ", `{command}`")?;
        }
        Ok(())
    }
}

/// Who holds the `flock` lock on `file` (this process too, through another open file),
/// from the kernel's table of locks (`/proc/locks`, matched by the file's device and inode).
/// `None` when it cannot be told (no `/proc`, a holder in another pid namespace, the lock
/// already let go). Blocking I/O.
#[cfg(target_os = "linux")]
pub fn holder(file: &File) -> Option<Holder> {
    use std::os::unix::fs::MetadataExt as _;
    let meta = file.metadata().ok()?;
    let table = std::fs::read_to_string("/proc/locks").ok()?;
    let pid = holder_pid(&table, meta.dev(), meta.ino())?;
    Some(describe(pid))
}

/// Without `/proc/locks` the holder cannot be told.
#[cfg(not(target_os = "linux"))]
pub fn holder(_file: &File) -> Option<Holder> {
    None
}

/// The pid of the process holding a `FLOCK` lock on device `dev`, inode `ino` in `table`
/// (`/proc/locks`); waiters (`->`) are not holders. The device is matched
/// when it can be (`MAJOR:MINOR` in hex): a file on an overlay may show the lower file
/// system's device, so the inode alone decides when it names exactly one holder.
fn holder_pid(table: &str, dev: u64, ino: u64) -> Option<u32> {
    #[cfg(target_os = "linux")]
    let want_dev = format!("{:02x}:{:02x}", libc::major(dev), libc::minor(dev));
    #[cfg(not(target_os = "linux"))]
    let want_dev = format!("{dev}");
    let mut exact = None;
    let mut by_inode = Vec::new();
    for line in table.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        // `1: FLOCK  ADVISORY  WRITE 1234 08:02:131090 0 EOF`; a waiter has `->` after `1:`.
        if words.get(1) != Some(&"FLOCK") {
            continue;
        }
        let (Some(pid), Some(id)) = (words.get(4), words.get(5)) else {
            continue;
        };
        let Ok(pid) = pid.parse::<u32>() else {
            continue;
        };
        let Some((device, inode)) = id.rsplit_once(':') else {
            continue;
        };
        if inode.parse::<u64>().ok() != Some(ino) {
            continue;
        }
        if device == want_dev {
            exact.get_or_insert(pid);
        }
        if !by_inode.contains(&pid) {
            by_inode.push(pid);
        }
    }
    exact.or_else(|| (by_inode.len() == 1).then(|| by_inode[0]))
}

/// What `/proc/<pid>` tells of a process: its user (the owner of the entry) and command line.
fn describe(pid: u32) -> Holder {
    let dir = Path::new("/proc").join(pid.to_string());
    #[cfg(unix)]
    let user = {
        use std::os::unix::fs::MetadataExt as _;
        std::fs::metadata(&dir).ok().map(|m| user_name(m.uid()))
    };
    #[cfg(not(unix))]
    let user = None;
    let command = std::fs::read(dir.join("cmdline"))
        .ok()
        .filter(|b| !b.is_empty())
        .map(|b| {
            let words: Vec<String> = b
                .split(|c| *c == 0)
                .filter(|w| !w.is_empty())
                .map(|w| String::from_utf8_lossy(w).into_owned())
                .collect();
            let line: String = words.join(" ").chars().take(200).collect();
            handeye_hal::limits::sanitize_message(&line)
        });
    Holder { pid, user, command }
}

/// The name of user `uid` (`uid 1234` when it has none: a user removed since).
#[cfg(unix)]
pub fn user_name(uid: u32) -> String {
    let mut buf = vec![0 as libc::c_char; 4096];
    // SAFETY: zeroed passwd is a valid out-parameter for getpwuid_r.
    let mut pwd: libc::passwd = unsafe { std::mem::zeroed() };
    let mut result: *mut libc::passwd = std::ptr::null_mut();
    // SAFETY: every pointer is valid for the call; buf outlives the use of pwd's fields.
    let r = unsafe { libc::getpwuid_r(uid, &mut pwd, buf.as_mut_ptr(), buf.len(), &mut result) };
    if r != 0 || result.is_null() || pwd.pw_name.is_null() {
        return format!("uid {uid}");
    }
    // SAFETY: getpwuid_r succeeded: pw_name points at a NUL-terminated string inside buf.
    unsafe { std::ffi::CStr::from_ptr(pwd.pw_name) }
        .to_string_lossy()
        .into_owned()
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn the_holder_is_read_from_the_kernel_s_table_not_a_waiter() {
        let dev = libc::makedev(8, 2);
        let table = "1: FLOCK  ADVISORY  WRITE 4321 08:02:131090 0 EOF\n\
                     1: -> FLOCK  ADVISORY  WRITE 999 08:02:131090 0 EOF\n\
                     2: POSIX  ADVISORY  WRITE 555 08:02:777 0 EOF\n\
                     3: FLOCK  ADVISORY  WRITE 77 08:02:777 0 EOF\n";
        assert_eq!(holder_pid(table, dev, 131_090), Some(4321));
        // Another device, one holder of that inode: it.
        assert_eq!(holder_pid(table, libc::makedev(0, 40), 777), Some(77));
        assert_eq!(holder_pid(table, dev, 5), None);
    }

    /// Issue 46: a link where a lock file belongs is refused, never followed (the file it
    /// points at is neither created nor locked).
    #[test]
    fn issue_46_a_lock_file_is_never_opened_through_a_link() {
        let dir = std::env::temp_dir().join(format!("handeye-lockfile-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("dir");
        let outside = dir.join("outside");
        let link = dir.join("x.lock");
        std::os::unix::fs::symlink(&outside, &link).expect("link");
        let e = open_lock_file(&link).expect_err("a link");
        assert!(e.to_string().contains("is a symbolic link"), "{e}");
        assert!(!outside.exists(), "the link's target was created");
        std::fs::remove_file(&link).expect("rm");
        let fifo = std::ffi::CString::new(link.to_str().expect("utf-8")).expect("c");
        // SAFETY: a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(fifo.as_ptr(), 0o600) }, 0);
        let e = open_lock_file(&link).expect_err("a FIFO");
        assert!(e.to_string().contains("not a regular file"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
