//! Issue 42 (item 3): one user owns the storage. A command that writes the storage, run by
//! another user (root with `sudo`, or the operator's own account on the package's
//! `/var/lib/handeye`), stops before it connects anything and names the same command under
//! `sudo -u <owner>`; it leaves no file behind. The daemon, at start, names every file in its
//! storage that it cannot open and the `chown -R` that gives them back. Nothing listens on
//! 127.0.0.193: a command that got as far as connecting would say so instead.

use std::os::unix::fs::PermissionsExt as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::support::{rig_config, run, secs, TempDir, BIN};

/// The user `nobody` of the CI machine (root gives it the storage).
const NOBODY: u32 = 65534;

fn is_root() -> bool {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() == 0 }
}

/// A configuration whose storage is `storage`, for a controller that is not there.
fn config_with_storage(dir: &TempDir, storage: &Path) -> PathBuf {
    let path = rig_config(dir, "127.0.0.193", "127.0.0.193", "", "");
    let text = std::fs::read_to_string(&path).expect("config");
    let text = text.replace(
        "dir = \"data\"",
        &format!("dir = \"{}\"", storage.display()),
    );
    std::fs::write(&path, text).expect("config");
    path
}

/// A storage folder that belongs to another user than this process's, and that user's name:
/// as root, a fresh folder given to `nobody`; otherwise `/tmp`, which is root's.
fn others_storage(dir: &TempDir) -> (PathBuf, String) {
    if is_root() {
        let storage = dir.join("storage");
        std::fs::create_dir_all(&storage).expect("mkdir");
        std::os::unix::fs::chown(&storage, Some(NOBODY), Some(NOBODY)).expect("chown");
        let name = std::fs::read_to_string("/etc/passwd")
            .ok()
            .and_then(|t| {
                t.lines()
                    .find(|l| l.split(':').nth(2) == Some(&NOBODY.to_string()))
                    .and_then(|l| l.split(':').next().map(str::to_string))
            })
            .unwrap_or_else(|| format!("uid {NOBODY}"));
        (storage, name)
    } else {
        (PathBuf::from("/tmp"), "root".to_string())
    }
}

#[test]
fn issue_42_a_command_on_another_users_storage_stops_naming_sudo_u_owner() {
    let dir = TempDir::new("owner-command");
    let (storage, owner) = others_storage(&dir);
    let cfg = config_with_storage(&dir, &storage);
    let cfg = cfg.to_str().expect("utf-8");
    let before: Vec<_> = std::fs::read_dir(&storage)
        .expect("storage")
        .flatten()
        .map(|e| e.path())
        .collect();
    for args in [
        vec!["calibrate", "--config", cfg, "--dry-run"],
        vec!["calibrate", "--config", cfg],
        vec!["check", "--config", cfg],
        vec!["daemon", "--config", cfg],
    ] {
        let out = run(&args, secs(30));
        assert_eq!(out.code(), 2, "{out:?}");
        let want = format!(
            "Run it as the storage's owner: `sudo -u {owner} handeye {}`",
            args.join(" ")
        );
        assert!(out.stderr.contains(&want), "wanted {want}\n{out:?}");
        assert!(
            out.stderr.contains(&format!(
                "storage.dir {} belongs to user {owner}",
                storage.display()
            )),
            "{out:?}"
        );
        assert!(!out.stderr.contains("127.0.0.193"), "it connected: {out:?}");
    }
    let after: Vec<_> = std::fs::read_dir(&storage)
        .expect("storage")
        .flatten()
        .map(|e| e.path())
        .collect();
    assert_eq!(
        before,
        after,
        "the refused commands left files in {}",
        storage.display()
    );
}

#[test]
fn issue_42_the_daemon_names_the_files_of_its_storage_it_cannot_open() {
    let dir = TempDir::new("owner-daemon");
    let storage = dir.join("storage");
    std::fs::create_dir_all(storage.join("runs/20261128T090525Z-64c5")).expect("mkdir");
    let left = storage.join("history.sqlite");
    std::fs::write(&left, "root's").expect("write");
    std::fs::set_permissions(&left, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    let cfg = config_with_storage(&dir, &storage);
    // As root: the storage is nobody's but for the files a `sudo` run left (root's, 0600),
    // and the daemon runs as nobody, as the package's unit runs it as handeye. Otherwise: a
    // file of this user's that it may not open.
    let (mut command, user) = if is_root() {
        let walk = [storage.clone(), storage.join("runs")];
        for p in walk {
            std::os::unix::fs::chown(&p, Some(NOBODY), Some(NOBODY)).expect("chown");
        }
        let mut c = Command::new("runuser");
        c.args(["-u", "nobody", "--", BIN]);
        (c, "nobody".to_string())
    } else {
        std::fs::set_permissions(&left, std::fs::Permissions::from_mode(0o000)).expect("chmod");
        let user = std::env::var("USER").unwrap_or_default();
        (Command::new(BIN), user)
    };
    let mut child = command
        .args(["daemon", "--config", cfg.to_str().expect("utf-8")])
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn the daemon");
    let deadline = Instant::now() + Duration::from_secs(30);
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("the daemon started on a storage with a file it cannot open");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().expect("stderr"), &mut err)
        .expect("stderr");
    assert!(!status.success(), "{err}");
    assert!(
        err.contains(&format!("{} (owner ", left.display())),
        "the file is not named: {err}"
    );
    if !user.is_empty() {
        let fix = format!("`sudo chown -R {user}: {}`", storage.display());
        assert!(err.contains(&fix), "wanted {fix}: {err}");
    }
    assert!(!err.contains("127.0.0.193"), "it connected: {err}");
}
