//! Where a run keeps its files, under the configured storage directory:
//!
//! ```text
//! <storage>/runs/<run_id>/record.json        the run record (every run)
//! <storage>/runs/<run_id>/capture.json       joints and flange poses per view (replay)
//! <storage>/runs/<run_id>/view<V>_frame<F>.ply  the raw scans (when kept)
//! <storage>/runs/<run_id>/result.*           the exports of an accepted calibration
//! <storage>/runs/<run_id>/report.png         the report picture (every run)
//! <storage>/current/                         the exports of the last accepted calibration
//! ```
//!
//! Every file is written to a temporary name and renamed, so a crash never leaves a
//! half-written record or result; `current/` is replaced as a whole.

use std::path::{Path, PathBuf};

use handeye_hal::PointCloud;
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::calib::export::{ExportMeta, Exports};
use crate::calib::Mount;
use crate::record::{CaptureRecord, ResultRecord, RunRecord};

/// Folder of the per-run folders.
pub const RUNS_DIR: &str = "runs";
/// Folder of the last accepted calibration.
pub const CURRENT_DIR: &str = "current";
const CAPTURE_FILE: &str = "capture.json";
const RECORD_FILE: &str = "record.json";
const CALIBRATION_FILE: &str = "calibration.json";
/// The report picture in a run's folder.
pub const REPORT_PICTURE: &str = "report.png";

/// What `capture.json` holds: enough to replay a run with `handeye solve --capture`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CaptureFile {
    /// Robot model name.
    pub model: String,
    /// Eye-in-hand or eye-to-hand.
    pub mount: Mount,
    /// Frame of the flange poses (`base`: the UR controller's).
    pub base_frame: String,
    /// The guess the run registered with: eye-in-hand `flange_from_camera`, eye-to-hand
    /// `base_from_camera` (in `base_frame`), 4×4.
    #[serde(default)]
    pub prior: Option<[[f64; 4]; 4]>,
    /// The controller's calibrated kinematics the run posed the model by (`None`: nominal).
    #[serde(default)]
    pub controller_dh: Option<handeye_hal::ur_dh::DhParams>,
    /// One entry per view, with its frames' file paths.
    pub views: Vec<CaptureRecord>,
}

/// The machine-readable current calibration (`current/calibration.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct CurrentCalibration {
    run_id: String,
    mount: Mount,
    /// `flange_from_camera` (eye-in-hand) or `base_from_camera` in `base` (eye-to-hand), 4×4.
    pose: [[f64; 4]; 4],
}

/// A run id: UTC start time to the second and a random suffix (`20261124T142300Z-3f9a`).
pub fn new_run_id() -> String {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    let (y, m, d, hh, mm, ss) = crate::calendar::utc_fields(now.as_secs() as i64);
    let suffix = (now.subsec_nanos() ^ std::process::id().rotate_left(16)) & 0xffff;
    format!("{y:04}{m:02}{d:02}T{hh:02}{mm:02}{ss:02}Z-{suffix:04x}")
}

/// Writes `bytes` to `path` through a temporary file and a rename.
fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}

fn json<T: Serialize>(value: &T) -> std::io::Result<Vec<u8>> {
    serde_json::to_vec_pretty(value).map_err(std::io::Error::other)
}

/// Writes the run record.
pub(crate) fn write_record(run_dir: &Path, record: &RunRecord) -> std::io::Result<()> {
    write_atomically(&run_dir.join(RECORD_FILE), &json(record)?)
}

/// The scan a run's report picture shows: its first frame, that frame's registration and the
/// kinematics the model was posed with.
#[derive(Debug)]
pub(crate) struct PictureScan {
    pub(crate) frame: super::Frame,
    pub(crate) registration: crate::calib::Registration,
    pub(crate) controller_dh: Option<handeye_hal::ur_dh::DhParams>,
}

/// Renders the run's report picture into `run_dir/report.png` (blocking; a few hundred ms with
/// a scan). Never fails the run: what goes wrong is logged.
pub(crate) fn write_report_picture(
    run_dir: &Path,
    record: &RunRecord,
    model: &crate::model::RobotModel,
    scan: Option<&PictureScan>,
) {
    let t = std::time::Instant::now();
    let view = scan.and_then(|s| {
        let frames = record
            .captures
            .iter()
            .map(|c| c.frames.len())
            .sum::<usize>();
        let caption = format!(
            "view {}, frame 1 of {frames}: {}",
            s.frame.view, s.frame.source
        );
        match crate::report::scan_view(
            model,
            &s.frame.joints,
            s.controller_dh.as_ref(),
            &s.frame.cloud,
            &s.registration,
            &caption,
        ) {
            Ok(v) => Some(v),
            Err(e) => {
                tracing::warn!("report picture without the scan: {e}");
                None
            }
        }
    });
    let summary = crate::report::Summary::from_run(record);
    let written = crate::report::render(&summary, view.as_ref())
        .map_err(|e| e.to_string())
        .and_then(|png| {
            write_atomically(&run_dir.join(REPORT_PICTURE), &png).map_err(|e| e.to_string())
        });
    match written {
        Ok(()) => tracing::debug!(
            ms = t.elapsed().as_secs_f64() * 1e3,
            "report picture written"
        ),
        Err(e) => tracing::error!(
            "cannot write the report picture into {}: {e}",
            run_dir.display()
        ),
    }
}

/// Keeps one raw frame as a binary PLY; returns its path.
pub(crate) fn save_frame(
    run_dir: &Path,
    view: usize,
    frame: usize,
    cloud: &PointCloud,
) -> Result<PathBuf, crate::cloud::CloudError> {
    std::fs::create_dir_all(run_dir).map_err(|source| crate::cloud::CloudError::Io {
        action: "create",
        path: run_dir.to_path_buf(),
        source,
    })?;
    let path = run_dir.join(format!("view{view}_frame{frame}.ply"));
    crate::cloud::write_ply(&path, cloud, Default::default())?;
    Ok(path)
}

/// Largest `capture.json` read (a run with many views is a few hundred kB).
const MAX_CAPTURE_FILE_BYTES: u64 = 64 << 20;

/// Writes `capture.json`; returns its path.
pub(crate) fn write_capture_file(
    run_dir: &Path,
    capture: &CaptureFile,
) -> std::io::Result<PathBuf> {
    let path = run_dir.join(CAPTURE_FILE);
    write_atomically(&path, &json(capture)?)?;
    Ok(path)
}

/// Reads a `capture.json` written by a run (its frame paths are absolute or relative to it).
pub fn load_capture(path: &Path) -> Result<CaptureFile, String> {
    // A regular file of bounded size: a FIFO would block the read forever.
    let text = handeye_hal::limits::read_text_file(path, MAX_CAPTURE_FILE_BYTES)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| {
        format!(
            "{} is not a capture file written by a handeye run: {e}",
            path.display()
        )
    })
}

/// The last accepted calibration in `storage` for `mount`, with where it came from.
pub fn load_current(storage: &Path, mount: Mount) -> Option<(Isometry3<f64>, String)> {
    let path = storage.join(CURRENT_DIR).join(CALIBRATION_FILE);
    let text = std::fs::read_to_string(&path).ok()?;
    let current: CurrentCalibration = match serde_json::from_str(&text) {
        Ok(c) => c,
        Err(e) => {
            tracing::warn!("ignoring {}: {e}", path.display());
            return None;
        }
    };
    if current.mount != mount {
        return None;
    }
    let pose = crate::frames::from_row_major(&current.pose)?;
    Some((
        pose,
        format!("result of run {} ({})", current.run_id, path.display()),
    ))
}

/// Writes the exports of an accepted result into the run's folder and replaces `current/`
/// with them; returns the paths in `current/`.
pub(crate) fn write_result(
    storage: &Path,
    run_dir: &Path,
    unknown: &Isometry3<f64>,
    mount: Mount,
    record: &RunRecord,
    result: Option<&ResultRecord>,
) -> std::io::Result<Vec<PathBuf>> {
    let (parent, child) = match mount {
        Mount::EyeInHand => ("tool0", "camera"),
        Mount::EyeToHand => ("base", "camera"),
    };
    let meta = ExportMeta {
        run_id: record.run_id.clone(),
        outcome: record.outcome.name().to_string(),
        uncertainty_translation_mm: result.map_or(f64::NAN, |r| r.uncertainty.translation_mm),
        uncertainty_rotation_deg: result.map_or(f64::NAN, |r| r.uncertainty.rotation_deg),
        timestamp: record.run_id.clone(),
    };
    let exports = Exports::new(unknown, parent, child, meta);
    exports.write_to(run_dir)?;
    let current = CurrentCalibration {
        run_id: record.run_id.clone(),
        mount,
        pose: crate::frames::to_row_major(unknown),
    };
    write_atomically(&run_dir.join(CALIBRATION_FILE), &json(&current)?)?;
    // Replace current/ as a whole: build it beside, then swap.
    let staging = storage.join(format!(".{CURRENT_DIR}.{}", record.run_id));
    let _ = std::fs::remove_dir_all(&staging);
    let mut paths = exports.write_to(&staging)?;
    write_atomically(&staging.join(CALIBRATION_FILE), &json(&current)?)?;
    let target = storage.join(CURRENT_DIR);
    let old = storage.join(format!(".{CURRENT_DIR}.old.{}", record.run_id));
    if target.exists() {
        std::fs::rename(&target, &old)?;
    }
    std::fs::rename(&staging, &target)?;
    let _ = std::fs::remove_dir_all(&old);
    for p in &mut paths {
        if let Some(name) = p.file_name() {
            *p = target.join(name);
        }
    }
    paths.push(target.join(CALIBRATION_FILE));
    Ok(paths)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_ids_carry_the_utc_date() {
        let id = new_run_id();
        assert_eq!(id.len(), "20261124T142300Z-3f9a".len(), "{id}");
        assert!(id.as_bytes()[8] == b'T' && id.contains("Z-"), "{id}");
    }
}
