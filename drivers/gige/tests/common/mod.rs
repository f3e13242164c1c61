//! Shared by the tests that ask the EMVA reference GenApi (PyPI `genicam` in `$REPO/.venv`).

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

/// `$REPO/.venv/bin/python` when it has `genicam`; `None` (after printing SKIP) without it,
/// a panic instead when env `CI` is set.
pub(crate) fn reference_python() -> Option<PathBuf> {
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    let ok = python.exists()
        && Command::new(&python)
            .args(["-c", "import genicam.genapi"])
            .status()
            .is_ok_and(|s| s.success());
    if ok {
        return Some(python);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "no genicam in {}; run .ci/install.d/aravis.sh",
        python.display()
    );
    // Straight to stderr: the harness captures eprintln! and shows it only on failure.
    let _ = writeln!(
        std::io::stderr(),
        "SKIP: no `genicam` in {}; run .ci/install.d/aravis.sh",
        python.display()
    );
    None
}
