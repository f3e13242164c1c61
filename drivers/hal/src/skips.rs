//! The tests' skip registry. A test that cannot run here (no `../shared`, no ur-rtde venv, no
//! Chromium, not root) would pass as `ok`; instead it appends one line to
//! `<workspace>/target/test-skips.txt` (or `$CARGO_TARGET_DIR/test-skips.txt`) and prints it
//! past the harness's capture. `.ci/run` empties the file before the tests, prints the count
//! and the lines in one summary after them, and fails when any test skipped under `CI=1`.
//! Not for production code: the tests of every crate of the workspace call it (the core
//! re-exports it as `handeye::skips`).

use std::io::Write as _;
use std::path::PathBuf;

/// The registry's file name under the target directory.
pub const FILE: &str = "test-skips.txt";

/// The registry file: `$CARGO_TARGET_DIR/test-skips.txt`, else `target/` of this workspace
/// (this crate is `drivers/hal` in it).
pub fn path() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../target"))
        .join(FILE)
}

/// Records that `test` skipped because of `reason`: one line `SKIP <test>: <reason>` appended
/// to [`path`] and written to the process's stderr (past the harness's capture).
pub fn record(test: &str, reason: &str) {
    let line = format!("SKIP {test}: {reason}");
    let _ = writeln!(std::io::stderr(), "{line}");
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path());
    if let Ok(mut f) = file {
        // One write of one line: appends from parallel tests do not interleave.
        let _ = f.write_all(format!("{line}\n").as_bytes());
    }
}
