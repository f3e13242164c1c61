//! Helpers shared by the integration tests.
#![allow(dead_code, unreachable_pub)]

use std::path::PathBuf;
use std::time::Duration;

/// `$REPO/.venv/bin/python` if ur-rtde is installed; otherwise skip (panic under `CI`).
pub fn python() -> Option<PathBuf> {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let py = repo.join(".venv/bin/python");
    if py.exists() {
        return Some(py);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{} is missing in CI: run .ci/install.d/ur-rtde.sh",
        py.display()
    );
    record_skip(&format!(
        "{} not found (run .ci/install.d/ur-rtde.sh to test against ur-rtde)",
        py.display()
    ));
    None
}

/// Records a skipped peer test where `.ci/run` counts skips ([`handeye_hal::skips`]), named
/// by its thread (the test's name).
pub fn record_skip(reason: &str) {
    let test = std::thread::current()
        .name()
        .unwrap_or("handeye-ur peer test")
        .to_string();
    handeye_hal::skips::record(&test, reason);
}

/// Run `tests/python/<script> <host>` (20 s limit) and parse its last stdout line as JSON.
pub async fn run_python(py: &std::path::Path, script: &str, host: &str) -> serde_json::Value {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/python")
        .join(script);
    let child = tokio::process::Command::new(py)
        .arg(&path)
        .arg(host)
        .kill_on_drop(true)
        .output();
    let out = tokio::time::timeout(Duration::from_secs(20), child)
        .await
        .unwrap_or_else(|_| panic!("{script} did not finish in 20 s"))
        .expect("python runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{script} failed: {stderr}\n{stdout}");
    let last = stdout
        .lines()
        .last()
        .unwrap_or_else(|| panic!("{script} printed nothing: {stderr}"));
    serde_json::from_str(last).unwrap_or_else(|e| panic!("{script}: {e}: {last}"))
}
