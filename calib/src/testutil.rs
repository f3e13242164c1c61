//! Helpers shared by the unit tests of the calibration core and (feature `testutil`) of the
//! crates above it.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use crate::model::RobotModel;

/// `../shared/<relative>` (beside the checkout), or `None` (with a SKIP line) when it is
/// absent; panics under CI, where a missing peer must fail, never pass silently.
pub fn shared(relative: &str) -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared")
        .join(relative);
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{} is missing and CI is set",
        dir.display()
    );
    skip(&format!(
        "SKIP: {} not found; this test needs ../shared/{relative}",
        dir.display()
    ));
    None
}

/// `../shared/robots` (see [`shared`]).
pub fn shared_robots() -> Option<PathBuf> {
    shared("robots")
}

/// Prints a SKIP line where the person running the tests sees it: straight to the process's
/// stderr, which the test harness does not capture (`eprintln!` output is shown only for
/// failing tests, so a passing skip would be silent).
pub fn skip(line: &str) {
    use std::io::Write as _;
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// A robot from `../shared/robots` (e.g. `ur/ur5e/ur5e.urdf`), loaded once per test binary.
pub fn shared_robot(relative: &str) -> Option<Arc<RobotModel>> {
    static CACHE: OnceLock<Mutex<HashMap<String, Arc<RobotModel>>>> = OnceLock::new();
    let path = shared_robots()?.join(relative);
    let cache = CACHE.get_or_init(Default::default);
    let mut cache = cache.lock().unwrap_or_else(|e| e.into_inner());
    let model = cache
        .entry(relative.to_string())
        .or_insert_with(|| Arc::new(RobotModel::load(&path).expect("shared robot loads")));
    Some(Arc::clone(model))
}
