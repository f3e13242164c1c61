//! A small file system of its own (tmpfs) for the storage-full tests: a real `ENOSPC` from
//! the kernel, not a simulated error. Shared by the run's unit tests (`src/run/tests/mod.rs`) and the
//! end-to-end tests. Mounting needs root (CI runs as root); elsewhere the test prints SKIP.

use std::path::{Path, PathBuf};

/// A tmpfs mounted on a fresh folder, unmounted (and the folder removed) when dropped.
#[derive(Debug)]
pub(crate) struct SmallFs {
    dir: PathBuf,
}

impl SmallFs {
    /// A tmpfs of `bytes` for test `tag`; `None` with a SKIP line when this user cannot
    /// mount (panics under CI, where the tests run as root).
    pub(crate) fn mount(tag: &str, bytes: u64) -> Option<SmallFs> {
        let dir =
            std::env::temp_dir().join(format!("handeye-smallfs-{tag}-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&dir);
        match mount_tmpfs(&dir, bytes) {
            Ok(()) => Some(SmallFs { dir }),
            Err(e) => {
                let _ = std::fs::remove_dir(&dir);
                assert!(
                    std::env::var_os("CI").is_none(),
                    "cannot mount a tmpfs for {tag} ({e}) and CI is set; run the tests as root"
                );
                use std::io::Write as _;
                let _ = writeln!(
                    std::io::stderr(),
                    "SKIP {tag}: cannot mount a tmpfs ({e}); run as root to test a full disk"
                );
                None
            }
        }
    }

    /// The mounted folder.
    pub(crate) fn path(&self) -> &Path {
        &self.dir
    }

    /// Fills the file system with `filler` until the kernel says it is full (`ENOSPC`).
    pub(crate) fn fill(&self) {
        use std::io::Write as _;
        let mut f = std::fs::File::create(self.filler()).expect("filler file");
        let block = vec![0x5a_u8; 64 << 10];
        loop {
            match f.write(&block) {
                Ok(0) => break,
                Ok(_) => {}
                Err(e) if e.raw_os_error() == Some(libc::ENOSPC) => break,
                Err(e) => panic!("filling {}: {e}", self.dir.display()),
            }
        }
        // The last partial blocks too.
        while let Ok(n) = f.write(&block[..512]) {
            if n == 0 {
                break;
            }
        }
    }

    /// Frees what [`Self::fill`] took.
    pub(crate) fn free(&self) {
        let _ = std::fs::remove_file(self.filler());
    }

    /// Every file under the mount whose name ends in `.tmp` (a write that failed and left it).
    pub(crate) fn temporary_files(&self) -> Vec<PathBuf> {
        fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
            for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
                let path = entry.path();
                if path.is_dir() {
                    walk(&path, out);
                } else if path.to_string_lossy().ends_with(".tmp") {
                    out.push(path);
                }
            }
        }
        let mut out = Vec::new();
        walk(&self.dir, &mut out);
        out
    }

    fn filler(&self) -> PathBuf {
        self.dir.join("filler")
    }
}

impl Drop for SmallFs {
    fn drop(&mut self) {
        if let Ok(c) = std::ffi::CString::new(self.dir.to_string_lossy().as_bytes()) {
            // SAFETY: a NUL-terminated path; MNT_DETACH unmounts even while a file is open.
            unsafe { libc::umount2(c.as_ptr(), libc::MNT_DETACH) };
        }
        let _ = std::fs::remove_dir(&self.dir);
    }
}

fn mount_tmpfs(dir: &Path, bytes: u64) -> std::io::Result<()> {
    let c = |s: &str| std::ffi::CString::new(s).map_err(std::io::Error::other);
    let (target, fstype, options) = (
        c(&dir.to_string_lossy())?,
        c("tmpfs")?,
        c(&format!("size={bytes},mode=0700"))?,
    );
    // SAFETY: NUL-terminated strings that live across the call.
    let r = unsafe {
        libc::mount(
            fstype.as_ptr(),
            target.as_ptr(),
            fstype.as_ptr(),
            0,
            options.as_ptr().cast(),
        )
    };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}
